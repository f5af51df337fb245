"""`PairStream`: camera training pairs generated in batches on the training device, with the camera in the loop.

:class:`~isettorch.data.camera_pairs.CameraPairDataset` draws each item with its own CPU generator in DataLoader
workers. A :class:`PairStream` draws a whole batch with one ``torch.Generator`` on the batch's device (scenes by
:func:`isettorch.data.batched.draw_layout_scenes` or, ``scene.generator: natural``,
:func:`isettorch.data.batched_natural.draw_natural_scenes`, camera settings as ``[B]`` tensors) and renders it
through the same camera modules (:class:`~isettorch.optics.DiffractionLimitedOptics` or the configured optics, and the
:class:`~isettorch.sensor.Sensor` with its QE, auto-exposure, noise and ADC, via :class:`isettorch.Camera`), with
the same targets, units and metadata as a ``CameraPairDataset`` batch. Items are not the dataset's items (other
random numbers) but are drawn from the same distribution (``tests/data/test_stream.py`` compares summary
statistics).

Batch ``k`` is a pure function of ``(seed, k, config, device type)``. Under ``torch.distributed``, rank ``r`` of
``W`` iterates over batches ``r, W + r, 2 W + r, ...``, so ranks never draw the same batch.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict

import torch

from ..image import XYZ_TO_LINEAR_SRGB, bradford_matrix, srgb_encode
from ..sensor.noise import poisson_gaussian_floor
from .batched import _log_uniform, _uniform, draw_layout_scenes
from .batched_natural import draw_natural_scenes
from .camera_pairs import _D65_XYZ, TARGETS, _Cache, _unit_qe, _xyz_weights, check_targets
from .config import CAMERA_DEFAULTS, SCENE_DEFAULTS, merge_config, seed_for

__all__ = ["PairStream", "StreamGroup"]

#: the batched scene draws by ``scene.generator`` (the per-item generators' distributions)
_SCENE_DRAWS = {"layouts": draw_layout_scenes, "natural": draw_natural_scenes}
_SPLIT_ITEMS = 12  # items of one camera from which a group is split by term count (measured: batch 64 -> 22 %
#                    less CPU per pair, batch 16 -> 12 % more when always split)


@dataclasses.dataclass
class StreamGroup:
    """The items of a batch that share one discrete camera (pixel pitch, CFA): ``index`` ``[b]`` (positions in the
    batch), the ``camera`` (:class:`isettorch.Camera` whose optics hold the items' ``[b]`` f-numbers), the factored
    ``scene`` ``[b]`` and the per-call sensor settings ``kwargs`` (``[b]`` tensors). ``camera(scene,
    return_intermediates=True, generator=g, **kwargs)`` renders exactly what the stream renders (with the noise of
    ``g``)."""

    index: torch.Tensor
    camera: torch.nn.Module
    scene: object
    kwargs: dict
    batch_index: int = 0


class PairStream:
    """An endless iterable of camera training batches generated on ``device``.

    Args:
        batch_size: items per batch.
        seed: stream seed; batch ``k`` depends only on ``(seed, k, config, device type)``.
        scene: scene config (keys of :data:`~isettorch.data.config.SCENE_DEFAULTS`; generator ``layouts`` or
            ``natural``, with its options in ``natural``).
        camera: a camera config (keys of :data:`~isettorch.data.config.CAMERA_DEFAULTS`: the camera is drawn per
            item as in :class:`~isettorch.data.camera_pairs.CameraPairDataset`), or an :class:`isettorch.Camera`
            module to render every item through as it is (its own optics, sensor, QE, exposure and noise settings;
            its learnable parameters receive gradients with ``grad=True``). The scene's field of view puts one scene
            sample on one pixel of that camera.
        targets: targets besides ``raw`` and ``meta`` (:data:`~isettorch.data.camera_pairs.TARGETS`).
        device, dtype: where and in what precision batches are generated.
        grad: build the autograd graph (default False: batches are generated under ``torch.no_grad``).
        rank, world_size: this process's share of the batches (default: ``torch.distributed``'s when it is
            initialised, else 0 of 1).

    Each batch is a dict with ``raw`` ``[B, 1, H, W]`` and the targets in normalised raw units (0 = black,
    1 = white level), as :func:`~isettorch.data.camera_pairs.render_pairs`, and ``meta`` (``[B, ...]`` tensors of
    :data:`~isettorch.data.camera_pairs.META_KEYS`), all on ``device``.

    Example:
        >>> stream = PairStream(4, seed=0, scene={"height": 32, "width": 32}, targets=("camera_rgb",))
        >>> batch = stream.batch(0)
        >>> batch["raw"].shape, batch["camera_rgb"].shape, batch["meta"]["exposure_s"].shape
        (torch.Size([4, 1, 32, 32]), torch.Size([4, 3, 32, 32]), torch.Size([4]))
    """

    def __init__(self, batch_size: int, seed: int = 0, scene: dict | None = None, camera=None, targets=TARGETS,
                 device="cpu", dtype=torch.float32, *, grad: bool = False, rank: int | None = None,
                 world_size: int | None = None):
        if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
            raise ValueError(f"batch_size: expected a positive integer, got {batch_size!r}")
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"dtype: expected torch.float32 or torch.float64, got {dtype}")
        self.batch_size, self.seed, self.dtype = batch_size, int(seed), dtype
        self.device = torch.device(device)
        self.scene_config = merge_config(scene, SCENE_DEFAULTS, "scene")
        h, w = self.scene_config["height"], self.scene_config["width"]
        if h % 2 or w % 2:
            raise ValueError(f"scene.height/width: expected even sizes (whole Bayer cells), got {h}x{w}")
        self.camera_module = None
        if isinstance(camera, torch.nn.Module):
            self.camera_module = camera
            self.camera_config = merge_config({}, CAMERA_DEFAULTS, "camera")
        else:
            self.camera_config = merge_config(camera, CAMERA_DEFAULTS, "camera")
            if float(self.camera_config["qe_variation"]) != 0:
                raise ValueError("camera.qe_variation: PairStream renders one QE per pixel pitch and CFA; per-item "
                                 "shifted QE curves need CameraPairDataset (expected 0)")
        self.targets = check_targets(targets)
        self.grad = bool(grad)
        if rank is None or world_size is None:
            dist = torch.distributed
            on = dist.is_available() and dist.is_initialized()
            rank = dist.get_rank() if on and rank is None else (rank or 0)
            world_size = dist.get_world_size() if on and world_size is None else (world_size or 1)
        if not 0 <= int(rank) < int(world_size):
            raise ValueError(f"rank: expected 0 <= rank < world_size = {world_size}, got {rank}")
        self.rank, self.world_size = int(rank), int(world_size)
        self._cache = _Cache()
        self._otf_rows: OrderedDict = OrderedDict()  # shared by the groups' optics (DiffractionLimitedOptics)

    # --- iteration ------------------------------------------------------------------------------------------
    def __iter__(self):
        k = 0
        while True:
            yield self.batch(k * self.world_size + self.rank)
            k += 1

    def _generator(self, k: int, stream: int) -> torch.Generator:
        return torch.Generator(device=self.device).manual_seed(seed_for(self.seed, int(k), stream=stream))

    # --- drawing --------------------------------------------------------------------------------------------
    def _draw_camera(self, g: torch.Generator, nb: int) -> dict:
        """The per-item camera of ``CameraPairDataset`` (:func:`~isettorch.data.camera_pairs._draw_camera`), each
        setting a ``[B]`` tensor: discrete f-number, pitch and focal length by index, the continuous ones uniform or
        log-uniform in their ranges, the CFA pattern by index."""
        cam, dev = self.camera_config, self.device

        def pick(values):
            vals = torch.as_tensor(values if isinstance(values, (list, tuple)) else [values], dtype=torch.float64)
            idx = torch.randint(0, vals.numel(), (nb,), generator=g, device=dev)
            return vals.to(dev)[idx], idx

        def rng(values, log=False):
            return _draw_range(values, g, nb, dev, log)

        d = {}
        d["f_number"], _ = pick(cam["f_number"])
        d["pitch"], d["pitch_index"] = pick(cam["pixel_size_m"])
        d["focal"], _ = pick(cam["focal_length_m"])
        d["full_well"] = rng(cam["full_well_e"], log=True)
        d["read_e"] = rng(cam["read_noise_e"])
        d["dark"] = rng(cam["dark_current_e_per_s"], log=True)
        d["dsnu_e"] = rng(cam["dsnu_sigma_e"])
        d["prnu"] = rng(cam["prnu_sigma_percent"])
        d["gain"] = rng(cam["analog_gain"], log=True)
        d["ev"] = rng(cam["exposure_ev"])
        d["peak"] = rng(cam["peak_qe"])
        patterns = list(cam["cfa_patterns"])
        d["pattern_index"] = torch.randint(0, len(patterns), (nb,), generator=g, device=dev)
        d["distance"] = rng(self.scene_config["distance_m"])
        return d

    def draw(self, k: int) -> list[StreamGroup]:
        """The scenes and cameras of batch ``k``, grouped by discrete camera (see :class:`StreamGroup`), before
        rendering."""
        nb, dev, dt = self.batch_size, self.device, self.dtype
        h, w = self.scene_config["height"], self.scene_config["width"]
        m = int(self.camera_config["margin_px"])
        g = self._generator(k, 0)
        with torch.no_grad():
            if self.camera_module is None:
                d = self._draw_camera(g, nb)
            else:
                d = {"distance": _draw_range(self.scene_config["distance_m"], g, nb, dev)}
            drawn = _SCENE_DRAWS[self.scene_config["generator"]](nb, g, self.scene_config, size=(h + 2 * m, w + 2 * m),
                                                                 device=dev, dtype=dt)
        wl = drawn["wavelengths_nm"].to(dt)
        groups = []
        if self.camera_module is not None:
            camera = self.camera_module
            pitch = float(camera.sensor.pixel_size_m)
            hfov = self._hfov(pitch, camera.optics.focal_length_m.detach().reshape(-1)[0].to(torch.float64),
                              d["distance"], w + 2 * m)
            scene = self._scene(drawn, slice(None), wl, hfov, d["distance"], k)
            return [StreamGroup(torch.arange(nb, device=dev), camera, scene, {}, k)]
        patterns = list(self.camera_config["cfa_patterns"])
        pitches = self.camera_config["pixel_size_m"]
        pitches = pitches if isinstance(pitches, (list, tuple)) else [pitches]
        # groups: the discrete cameras of this batch (pixel pitch, CFA); one of _SPLIT_ITEMS items or more is split
        # by how many factored terms its items use (<= 4, <= 8, more), so its optics transform about as many maps
        # as the items need (smaller groups are kept whole: a group's fixed cost would outweigh the saving)
        terms = drawn["used"].sum(1)
        camera_key = d["pitch_index"] * len(patterns) + d["pattern_index"]
        big = torch.bincount(camera_key, minlength=len(pitches) * len(patterns))[camera_key] >= _SPLIT_ITEMS
        bucket = torch.where(big, (terms > 4).long() + (terms > 8).long(), 0)
        combo = camera_key * 3 + bucket
        present = torch.unique(combo).tolist()  # one host read per batch
        for key in present:
            idx = (combo == key).nonzero().reshape(-1)
            c = key // 3
            pitch, pattern = float(pitches[c // len(patterns)]), patterns[c % len(patterns)]
            optics_cfg = self.camera_config.get("optics") or {}
            if optics_cfg:
                optics = self._cache.get_built_optics(optics_cfg)
                image_distance = optics.focal_length_m.detach().reshape(-1)[0].to(torch.float64) \
                    if optics_cfg.get("type") == "lens" else None
                focal = optics.focal_length_m.detach().reshape(-1)[0].to(torch.float64)
            else:
                focal = d["focal"][idx]
                optics = self._optics_for(pitch, d["f_number"][idx], focal, m)
                image_distance = None
            sensor = self._cache.get_sensor({"pitch": pitch, "fill": float(self.camera_config["fill_factor"]),
                                             "pattern": pattern, "bits": int(self.camera_config["bits"]),
                                             "black": float(self.camera_config["black_level_dn"]), "h": h, "w": w,
                                             "full_well": 1.0}).to(dev)
            sensor.spectral_qe = _unit_qe(pattern, (0.0, 0.0, 0.0))
            camera = self._cache.get_camera(optics, sensor)
            dist = d["distance"][idx]
            if image_distance is None:
                hfov = self._hfov(pitch, focal, dist, w + 2 * m)
            else:
                hfov = _hfov_for(pitch, image_distance, w + 2 * m).expand(idx.numel())
            scene = self._scene(drawn, idx, wl, hfov, dist, k)
            cg = 1.0 / d["full_well"][idx]  # volts per electron with a 1 V swing: well capacity = full well
            kw = {"analog_gain": d["gain"][idx], "exposure_ev": d["ev"][idx], "qe_scale": d["peak"][idx],
                  "conversion_gain_v_per_e": cg, "read_noise_v": d["read_e"][idx] * cg,
                  "dark_current_e_per_s": d["dark"][idx], "dsnu_sigma_v": d["dsnu_e"][idx] * cg,
                  "prnu_sigma_percent": d["prnu"][idx]}
            groups.append(StreamGroup(idx, camera, scene, kw, k))
        return groups

    def _optics_for(self, pitch: float, f_number: torch.Tensor, focal_length_m: torch.Tensor, margin: int):
        """The diffraction-limited optics of a group, with the items' ``[b]`` f-numbers and focal lengths. A new
        module per group (a group's camera stays valid after later batches), sharing one cache of OTF rows per
        (f-number, spacing) across batches, so a batch's OTF is assembled from rows, not evaluated again."""
        from ..optics import DiffractionLimitedOptics

        optics = DiffractionLimitedOptics(f_number=f_number, focal_length_m=focal_length_m, margin=margin,
                                          pad_mode="zero").to(self.device)
        optics._otf_rows = self._otf_rows
        return optics

    @staticmethod
    def _hfov(pitch, focal, distance, width):
        """Scene FOV that puts one scene sample on one pixel, ``pitch = 2 d_i tan(hfov / 2) / W_s``, with ``d_i``
        the thin-lens image distance of the object distance (Hecht 5.17)."""
        if bool((distance <= focal).any()):
            raise ValueError(f"scene.distance_m: expected object distances beyond the focal length, got "
                             f"{distance.min().item()} m")
        return _hfov_for(pitch, 1.0 / (1.0 / focal - 1.0 / distance), width)

    def _scene(self, drawn, idx, wl, hfov, distance, k):
        from ..scene import Scene

        dt = self.dtype
        # the group's terms whose map is not 0 everywhere first, J = the most any item uses (one host read): the
        # others add exactly 0, so the optics transform fewer maps (as the per-item path drops them)
        idx = torch.arange(drawn["maps"].shape[0], device=self.device) if isinstance(idx, slice) else idx
        used = drawn["used"][idx]
        n_terms = max(1, int(used.sum(1).max()))
        order = torch.argsort((~used).to(torch.uint8), dim=1, stable=True)[:, :n_terms]
        rows = idx[:, None]
        return Scene.from_factors(drawn["maps"][rows, order], drawn["spectra"][rows, order].to(dt), wl,
                                  name=f"stream-{k}",
                                  hfov_deg=hfov.to(dt), distance_m=distance.to(dt),
                                  illuminant_photons=drawn["white"][idx].to(dt), validate=False,
                                  metadata={key: v[idx] for key, v in drawn["meta"].items()})

    # --- rendering ------------------------------------------------------------------------------------------
    def batch(self, k: int) -> dict:
        """Batch ``k`` (a pure function of ``(seed, k, config, device type)``), rendered on the stream's device."""
        if not isinstance(k, int) or isinstance(k, bool) or k < 0:
            raise ValueError(f"k: expected a non-negative batch index, got {k!r}")
        groups = self.draw(k)
        noise = self._generator(k, 2)
        with torch.set_grad_enabled(self.grad):
            parts = [self._render(grp, noise) for grp in groups]
        nb = self.batch_size
        if len(parts) == 1:
            return parts[0]
        order = torch.cat([grp.index for grp in groups])
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(nb, device=order.device)

        def merge(values):
            return torch.cat(values).index_select(0, inverse)

        out = {key: merge([p[key] for p in parts]) for key in parts[0] if key != "meta"}
        out["meta"] = {key: merge([p["meta"][key] for p in parts]) for key in parts[0]["meta"]}
        return out

    def _render(self, grp: StreamGroup, noise: torch.Generator) -> dict:
        """One group through its camera: the calls of :func:`~isettorch.data.camera_pairs.render_pairs`, batched
        (optics on the factored scene, the sensor's channel rates with the XYZ weightings, auto-exposure on the
        mosaic, capture with noise, the readout without the CFA for ``camera_rgb``)."""
        camera, scene, kw = grp.camera, grp.scene, dict(grp.kwargs)
        sensor = camera.sensor
        targets = self.targets
        colour = bool({"xyz", "linear_srgb", "srgb"} & set(targets))
        peak = kw.pop("qe_scale", None)
        gain, ev = kw.pop("analog_gain", None), kw.pop("exposure_ev", None)
        cg = kw.get("conversion_gain_v_per_e")
        oi = camera.optical_image(scene)
        grid = tuple(scene.wavelengths_nm.tolist())
        xyz_w, _, xyz_wt = _xyz_weights(grid)
        rates, xyz_d = sensor.channel_rates(oi, xyz_wt if colour else None, qe_scale=peak)
        mosaic = sensor.cfa.mosaic(rates)
        exposure = sensor.exposure_for(None, mosaic, gain, exposure_ev=ev, conversion_gain_v_per_e=cg)
        raw = sensor.capture(mosaic, exposure_s=exposure, analog_gain=gain, noise=camera.noise, generator=noise,
                             **kw)
        nb = rates.shape[0]
        black = raw.black_level
        span = raw.white_level - raw.black_level
        out = {"raw": (raw.data - black) / span}
        if "noise_free_raw" in targets:
            out["noise_free_raw"] = (raw.noise_free - black) / span
        if "camera_rgb" in targets:
            out["camera_rgb"] = (sensor.readout(rates, exposure, gain, conversion_gain_v_per_e=cg) - black) / span
        dev, dt = rates.device, rates.dtype
        f64 = torch.float64
        white_p = scene.illuminant_photons.to(f64)
        peak_t = torch.ones(nb, dtype=f64, device=dev) if peak is None else peak.to(f64)
        white_cam = (white_p @ sensor.spectral_weights(oi).to(f64)) * peak_t[:, None]  # [b, 3]
        white_xyz = white_p @ xyz_w.to(dev).T  # [b, 3]
        to_norm = sensor.gain_per_electron(gain, batch=nb, dtype=f64, device=dev,
                                           conversion_gain_v_per_e=None if cg is None else cg.to(f64)) / span
        if colour:
            # XYZ scaled so a perfect white under light 1 has Y equal to its normalised green camera value
            k_white = white_cam[:, 1] / white_xyz[:, 1]
            scale = k_white * sensor.fill_factor * sensor.pixel_area_m2 * exposure.to(f64) * to_norm
            xyz = xyz_d * scale.to(dt).reshape(-1, 1, 1, 1)
            if "xyz" in targets:
                out["xyz"] = xyz
            cat = bradford_matrix(white_xyz / white_xyz[:, 1:2], torch.tensor(_D65_XYZ, dtype=f64, device=dev))
            m_srgb = (torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=f64, device=dev) @ cat).to(dt)  # [b, 3, 3]
            lin = torch.einsum("bij,bjhw->bihw", m_srgb, xyz)
            if "linear_srgb" in targets:
                out["linear_srgb"] = lin
            if "srgb" in targets:
                out["srgb"] = srgb_encode(lin.clamp(0, 1))
        out = {key: out[key] for key in ("raw", *targets)}
        out["meta"] = self._meta(grp, raw, exposure, to_norm, span, white_cam, white_xyz, sensor, oi, peak_t)
        return out

    def _meta(self, grp, raw, exposure, to_norm, span, white_cam, white_xyz, sensor, oi, peak) -> dict:
        """:data:`~isettorch.data.camera_pairs.META_KEYS` as ``[b, ...]`` tensors (the dataset's units)."""
        nb = exposure.shape[0]
        dev, dt, f64 = exposure.device, self.dtype, torch.float64
        kw = grp.kwargs
        optics = grp.camera.optics
        full = torch.full((nb,), 1.0, dtype=f64, device=dev)

        def level(name, default):
            v = kw.get(name)
            if v is None:
                v = getattr(sensor, name, default)
            return torch.as_tensor(v, dtype=f64, device=dev).detach().reshape(-1).expand(nb)

        cg = level("conversion_gain_v_per_e", 1.0)
        gain = level("analog_gain", 1.0)
        read_e, dsnu_e = level("read_noise_v", 0.0) / cg, level("dsnu_sigma_v", 0.0) / cg
        dark = level("dark_current_e_per_s", 0.0)
        t = exposure.detach().to(f64)
        to_norm = to_norm.detach()
        scene_meta = grp.scene.metadata
        wave = grp.scene.wavelengths_nm.detach()
        qe = (sensor.qe(oi).detach().to(f64)[None] * peak.detach()[:, None, None])
        wc, wx = white_cam.detach(), white_xyz.detach()
        meta = {
            "index": grp.index + grp.batch_index * self.batch_size,
            "exposure_s": t, "analog_gain": gain, "iso": 100.0 * gain,
            "f_number": optics.f_number.detach().to(f64).reshape(-1).expand(nb),
            "focal_length_m": optics.focal_length_m.detach().to(f64).reshape(-1).expand(nb),
            "pixel_size_m": full * float(sensor.pixel_size_m), "full_well_e": 1.0 / cg,
            "read_noise_e": read_e, "dark_current_e_per_s": dark, "dsnu_sigma_e": dsnu_e,
            "prnu_sigma_percent": level("prnu_sigma_percent", 0.0),
            "black_level_dn": full * float(raw.black_level), "white_level_dn": full * float(raw.white_level),
            # Poisson-Gaussian noise model in normalised units: var(x) = noise_gain x + noise_floor_var (Foi et al.,
            # IEEE TIP 17(10), 2008), as CameraPairDataset's metadata
            "noise_gain": to_norm,
            "noise_floor_var": poisson_gaussian_floor(to_norm, read_e, dsnu_e, dark, t, span),
            "cfa": sensor.cfa.index_map.to(dev)[None].expand(nb, -1, -1),
            "cct_k": scene_meta["cct_k"], "illuminant_code": scene_meta["illuminant_code"],
            "white_camera_rgb": wc / wc[:, 1:2], "white_xyz": wx / wx[:, 1:2],
            "qe": qe, "wavelengths_nm": wave[None].expand(nb, -1),
            "hdr_decades": scene_meta["hdr_decades"], "mean_luminance_cd_m2": scene_meta["mean_luminance_cd_m2"],
        }
        longs = ("index", "illuminant_code", "cfa")
        return {key: v.to(dev, torch.long if key in longs else dt) for key, v in meta.items()}

    def __repr__(self) -> str:
        return (f"PairStream(batch_size={self.batch_size}, seed={self.seed}, device={str(self.device)!r}, "
                f"targets={self.targets}, rank={self.rank}/{self.world_size})")


def _draw_range(values, g: torch.Generator, nb: int, device, log: bool = False) -> torch.Tensor:
    """``[B]`` float64 draws uniform (or log-uniform) in ``[lo, hi]``; a number is a constant."""
    u = torch.rand(nb, generator=g, device=device, dtype=torch.float64)
    return (_log_uniform if log else _uniform)(values, u)


def _hfov_for(pitch: float, image_distance_m, width: int) -> torch.Tensor:
    d_i = torch.as_tensor(image_distance_m, dtype=torch.float64)
    return torch.rad2deg(2 * torch.atan(pitch * width / (2 * d_i))).reshape(-1)

