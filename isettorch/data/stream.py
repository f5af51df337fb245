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

Batch ``k`` is a pure function of ``(seed, k, config, targets, device type)``, bitwise for a fixed device type and
intra-op thread count (see :class:`PairStream`, "Repeatability"; the targets count because a colour target projects
the camera channels together with the XYZ weightings: float rounding). Under ``torch.distributed``, rank ``r`` of
``W`` iterates over batches ``r, W + r, 2 W + r, ...``, so ranks never draw the same batch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from concurrent.futures import ThreadPoolExecutor, wait

import torch

from .._autograd import full_precision
from .._cache import BoundedCache
from .._checks import check_device, check_float_dtype, is_integer
from ..image import SRGB_WHITE_XYZ, XYZ_TO_LINEAR_SRGB, angle_for_extent, bradford_matrix, srgb_encode
from ..optics.geometry import image_distance
from .batched import _log_uniform, _uniform, draw_layout_scenes
from .batched_natural import draw_natural_scenes
from .camera_pairs import (
    TARGETS,
    _Cache,
    _d5100_qe,
    _diffraction_config,
    _unit_qe,
    _xyz_weights,
    check_targets,
)
from .config import check_integer, check_seed, one_thread, pair_config, seed_for

__all__ = ["PairStream", "StreamGroup"]

#: the batched scene draws by ``scene.generator`` (the per-item generators' distributions)
_SCENE_DRAWS = {"layouts": draw_layout_scenes, "natural": draw_natural_scenes}


#: the first random-stream number of PairStream's generators (``seed_for``'s ``stream``): CameraPairDataset's
#: items use streams 0-3, a stream's parts 16 apart from here
STREAM_DOMAIN = 1 << 20


@dataclasses.dataclass
class StreamGroup:
    """The items of a batch that share one CFA: ``index`` ``[b]`` (their positions in the batch, not necessarily
    consecutive: an item's CFA does not depend on its position), the ``camera``
    (:class:`isettorch.Camera` whose optics hold the items' ``[b]`` f-numbers), the factored ``scene`` ``[b]`` and
    the per-call sensor settings ``kwargs`` (``[b]`` tensors, the pixel pitch among them). ``camera(scene,
    return_intermediates=True, generator=g, **kwargs)`` renders what the stream renders (with the noise of ``g``):
    bitwise with ``qe_variation`` 0; with per-item QE shifts, to float rounding (the stream projects on the shifted
    QEs along another path: the exposure 1 ulp apart, the noise-free raw 2e-5 relative). The noisy raw then differs
    by more than a rounding: a CPU Poisson draw takes a number of random numbers that depends on its rate, so a rate
    1 ulp apart redraws that pixel's shot noise and the draws after it (another sample of the same distribution:
    up to 343 DN, 3.6 sigma, in 1 of 98,304 pixels over 12 batches). Compare noisy raws bitwise with ``qe_variation``
    0 or ``shot_noise='gaussian'``."""

    index: torch.Tensor
    camera: torch.nn.Module
    scene: object
    kwargs: dict
    batch_index: int = 0
    part: int = 0


class PairStream:
    """An endless iterable of camera training batches generated on ``device``.

    Args:
        batch_size: items per batch.
        seed: stream seed, an integer in ``[0, 2^64)`` (mixed as a 64-bit word: others would repeat a seed in it,
            :func:`~isettorch.data.config.check_seed`); batch ``k`` depends only on ``(seed, k, config, device
            type)``.
        scene: scene config (keys of :data:`~isettorch.data.config.SCENE_DEFAULTS`; generator ``layouts`` or
            ``natural``, with its options in ``natural``; not ``hfov_deg``: the sensor sets the field of view),
            validated with ``camera`` by :func:`~isettorch.data.config.pair_config`.
        camera: a camera config (keys of :data:`~isettorch.data.config.CAMERA_DEFAULTS`: the camera is drawn per
            item as in :class:`~isettorch.data.camera_pairs.CameraPairDataset`), or an :class:`isettorch.Camera`
            module to render every item through as it is (its own optics, sensor, QE, exposure and noise settings;
            its learnable parameters receive gradients with ``grad=True``). The scene's field of view puts one scene
            sample on one pixel of that camera (at the thin-lens image distance of the scene distance; a ray-traced
            lens, ``LensOptics``, at its ``image_distance_m``, as the drawn ``optics: {type: lens}``, which takes
            one pixel pitch and, with ``object_distance: scene``, one scene distance). A module's sensor must
            have ``rows, cols`` = ``scene.height, scene.width`` (a batch is the scene's size, as a
            ``CameraPairDataset`` batch; the shipped camera YAMLs leave them None: set them) and colour channels
            (not monochrome: the white balance and colour targets are relative to its second channel); checked at
            construction, naming ``camera``.
        targets: targets besides ``raw`` and ``meta`` (:data:`~isettorch.data.camera_pairs.TARGETS`).
        device, dtype: where and in what precision batches are generated; ``device`` is checked at construction
            (:func:`isettorch._checks.check_device`: a device this machine computes on).
        grad: build the autograd graph (default False: batches are generated under ``torch.no_grad``).
        rank, world_size: this process's share of the batches (default: ``torch.distributed``'s when it is
            initialised, else 0 of 1).
        parts: a batch is drawn and rendered in this many parts of consecutive items, each with its own generators
            (default: on a CPU without a camera module one per 32 items, at least one; else 1). It is part of the
            config: batch ``k`` depends on it, not on ``threads``. Within a part, the items are in the order of their
            drawn CFAs, and a part renders as one group per CFA: its tensors pad every item to the group's most
            scene terms, so groups of about 32 items render fastest on a CPU (2 cores, 128^2, the iterator on
            three threads against the README loader: batch 64 in two parts 1.23-1.30x, in one 1.10x, in four
            1.09x; batch 128 in two or four parts 1.10-1.12x, in one 1.01x). Parts also let ``batch(k)``, called
            directly, render on threads.
        threads: on a CPU, how many Python threads render (torch releases the GIL in its kernels; on other
            devices 1). ``iter(stream)`` renders this many whole batches at once, each on its own thread (default:
            torch's intra-op thread count, plus one from 64 items); ``batch(k)`` renders its parts on up to this
            many threads (default: as many as parts, up to the intra-op thread count). Without gradients or a
            camera module a part renders on one intra-op thread either way. Batches do not depend on it.
            Measured on 2 CPU cores at 128^2 against the README loader in alternating rounds
            (``benchmarks/THROUGHPUT.md``): three iterator threads against two, batch 64 1.25x against 1.04x,
            batch 128 1.23x against 1.09x, but batch 16 0.99x against 1.01x and batch 32 0.90x against 0.99x
            (more torch calls per pair: a third thread adds GIL contention). Each batch in flight holds its
            temporaries: batch 64 at 256^2 peaked at 3.7-3.8 GiB resident on three threads against 1.8 GiB on
            one (``threads=1``: in turn, on the caller's thread; docs/training_in_the_loop.md).

    Each batch is a dict with ``raw`` ``[B, 1, H, W]`` and the targets in normalised raw units (0 = black,
    1 = white level), as :func:`~isettorch.data.camera_pairs.render_pairs`, and ``meta`` (``[B, ...]`` tensors of
    :data:`~isettorch.data.camera_pairs.META_KEYS`), all on ``device``. The noise metadata is the capturing sensor's
    own model (:meth:`isettorch.sensor.Sensor.poisson_gaussian`: CDS, an analog or DN readout, its noise terms) and
    ``full_well_e`` where it saturates (the well capacity, or its photodiode clip ``full_well_e`` when lower).

    Repeatability: ``batch(k)`` is bitwise the same for a fixed device type and intra-op thread count. Drawn
    cameras without gradients render each part on one intra-op thread, so their batches do not depend on the thread
    count at all. A camera module, or ``grad=True``, renders on the caller's intra-op threads, where some torch
    kernels may round differently with their number: measured bitwise equal on 1 and 2 CPU threads for the five
    shipped camera configs at 64^2 (sensor rows/cols set to the scene) and a learnable camera at 128^2
    (``tests/data/test_stream.py``), while an audit found a 1-ulp difference (2026-11) for a module whose sensor
    resampled the whole optical image (rows None then; now sized to the scene); compare runs at one thread count.
    Gradients are summed by thread and do depend on it.

    Example:
        >>> stream = PairStream(4, seed=0, scene={"height": 32, "width": 32}, targets=("camera_rgb",))
        >>> batch = stream.batch(0)
        >>> batch["raw"].shape, batch["camera_rgb"].shape, batch["meta"]["exposure_s"].shape
        (torch.Size([4, 1, 32, 32]), torch.Size([4, 3, 32, 32]), torch.Size([4]))
    """

    def __init__(self, batch_size: int, seed: int = 0, scene: dict | None = None, camera=None, targets=TARGETS,
                 device="cpu", dtype=torch.float32, *, grad: bool = False, rank: int | None = None,
                 world_size: int | None = None, parts: int | None = None, threads: int | None = None):
        batch_size = check_integer(batch_size, "batch_size", 1)
        check_float_dtype(dtype)
        self.batch_size, self.seed, self.dtype = batch_size, check_seed(seed), dtype
        self.device = check_device(device)  # at construction: batch(k) then never meets a device it cannot use
        # a camera module renders as it is: the scene config is checked with the default camera's (its margin)
        self.camera_module = camera if isinstance(camera, torch.nn.Module) else None
        self.scene_config, self.camera_config = pair_config(scene, None if self.camera_module is not None else camera)
        self.targets = check_targets(targets)
        # a camera module's ray-traced lens images the scene at its image_distance_m, as a drawn camera's (_draw_part)
        self._module_lens, self._module_view_size = False, None
        if self.camera_module is not None:
            self._module_lens, self._module_view_size = _check_camera_module(self.camera_module, self.scene_config)
        if not isinstance(grad, bool):
            raise ValueError(f"grad: expected True or False, got {grad!r}")
        self.grad = grad
        for name, v in (("rank", rank), ("world_size", world_size)):
            if v is not None and not is_integer(v):
                raise ValueError(f"{name}: expected an integer or None, got {v!r}")
        if world_size is not None and world_size < 1:
            raise ValueError(f"world_size: expected a positive number of processes, got {world_size!r}")
        if rank is None or world_size is None:
            dist = torch.distributed
            on = dist.is_available() and dist.is_initialized()
            if rank is None and not on and world_size is not None and world_size > 1:
                # (it became rank 0: processes that all left it out trained batches 0, 2, 4, ... each, and no
                # process the others)
                raise ValueError(f"rank: world_size {world_size} given without rank (and torch.distributed is not "
                                 f"initialised to tell it); give each process its rank in 0..{world_size - 1}")
            rank = dist.get_rank() if on and rank is None else (rank or 0)
            world_size = dist.get_world_size() if on and world_size is None else (world_size or 1)
        if not 0 <= int(rank) < int(world_size):
            raise ValueError(f"rank: expected 0 <= rank < world_size = {world_size}, got {rank}")
        self.rank, self.world_size = int(rank), int(world_size)
        if parts is None:  # on a CPU one part per 32 items (see the docstring); on an accelerator one launch set
            cpu = self.device.type == "cpu" and self.camera_module is None
            parts = max(1, batch_size // 32) if cpu else 1
        if not is_integer(parts) or not 1 <= parts <= batch_size:
            raise ValueError(f"parts: expected an integer in [1, batch_size = {batch_size}], got {parts!r}")
        if threads is not None and (not is_integer(threads) or threads < 1):
            raise ValueError(f"threads: expected a positive integer or None, got {threads!r}")
        self.parts, self.threads = int(parts), None if threads is None else int(threads)
        # batch k holds items k * batch_size ... (k + 1) * batch_size - 1, reported in meta["index"] (int64)
        self.max_batch_index = (2 ** 63 - self.batch_size) // self.batch_size
        # drawn cameras on a CPU without gradients: each part renders on one intra-op thread (_render_part), and the
        # iterator renders whole batches on threads (_pipeline_width)
        self._cpu_batches = self.device.type == "cpu" and self.camera_module is None and not self.grad
        # part p holds items [start_p, start_p + size_p): sizes differ by at most one
        sizes = [batch_size // parts + (p < batch_size % parts) for p in range(parts)]
        self._part_starts = [sum(sizes[:p]) for p in range(parts)]
        self._part_sizes = sizes
        if self.camera_module is None and max(sizes) > 1:  # (a part of one item renders it alone)
            _check_drawn_lens(self.camera_config, self.scene_config)
        self._caches = [_Cache() for _ in range(parts)]  # per part: parts may render concurrently
        self._otf_rows = BoundedCache(64)  # shared by the groups' optics (DiffractionLimitedOptics)
        self._negligible_memo: dict = {}  # their blur tests, keyed on plain numbers (blur_negligible), shared too
        self._pool = None

    # --- iteration ------------------------------------------------------------------------------------------
    def __iter__(self):
        return self.batches()

    def batches(self, start: int = 0):
        """Batches ``(start + i) * world_size + rank`` for ``i = 0, 1, ...`` without end, each bitwise
        ``batch(k)`` (``iter(stream)`` is ``batches(0)``; a resumed training run starts where it stopped)."""
        return self._iterate(self._first_batch(start))

    def _first_batch(self, start) -> int:
        """The batch index of this rank's ``start``-th batch, checked (``start`` of :meth:`batches`, :meth:`loader`)."""
        if not is_integer(start) or start < 0:
            raise ValueError(f"start: expected a non-negative index into this rank's batches, got {start!r}")
        k = int(start) * self.world_size + self.rank
        if k > self.max_batch_index:
            raise ValueError(f"start: batch {k} of this rank's share is beyond the last batch index "
                             f"{self.max_batch_index} (meta['index'] holds item numbers as int64), got {start!r}")
        return k

    def _iterate(self, k: int):
        """Batches ``k, k + world_size, ...``, each bitwise ``batch(k)``. On a CPU (no camera module, no gradients)
        ``threads`` batches render at once, each whole on its own Python thread with one intra-op thread, while the
        caller uses the previous one: whole batches in flight keep the cores busy without a barrier per batch,
        where a batch's parts on threads wait for the slower part (``benchmarks/THROUGHPUT.md``). The caller's
        intra-op thread count is not changed."""
        n = self._pipeline_width()
        if n == 1:
            while True:
                yield self.batch(k)
                k += self.world_size
        intra = torch.get_num_threads()  # initialises this thread's count before the workers set theirs
        pool = self._executor(n, pipeline=True)
        pending = []
        try:
            while True:
                while len(pending) < n:
                    pending.append(pool.submit(self._whole_batch, k))
                    k += self.world_size
                out = pending.pop(0).result()
                if torch.get_num_threads() != intra:  # pragma: no cover - depends on the OpenMP runtime
                    torch.set_num_threads(intra)
                yield out
        finally:  # the consumer stopped: batches not started are dropped, running ones are waited for
            # (a render left running after the iterator is closed took cores from what the caller did next, and a
            # fork meanwhile, e.g. a DataLoader's workers, copied whatever locks its torch kernels held)
            running = [f for f in pending if not f.cancel()]
            wait(running)

    def loader(self, num_workers: int = 2, *, prefetch_factor: int = 2, start: int = 0):
        """This stream's batches rendered by worker processes, bitwise those of ``batches(start)`` in the same order
        (:func:`~isettorch.data.stream_workers.stream_loader`; a CPU stream without gradients; ``start``: a resumed
        run's first batch, as in :meth:`batches`): on 2 CPU cores
        0.9-1.0x :func:`~isettorch.data.camera_pairs.batch_loader` with as many workers at batch 16, where the
        stream's own iterator runs at 1.00-1.03x it (1.1-1.3x from batch 64; ``benchmarks/THROUGHPUT.md``)."""
        from .stream_workers import stream_loader

        return stream_loader(self, num_workers, prefetch_factor=prefetch_factor, start=start)

    def _generator(self, k: int, stream: int, part: int = 0) -> torch.Generator:
        """The generator of random ``stream`` (0 scenes and cameras, 2 noise) of part ``part`` of batch ``k``, in
        streams of their own (:data:`STREAM_DOMAIN` on): at the numbers of CameraPairDataset's item streams (0-3), a
        stream and a dataset of one seed drew batch k's part 0 from item k's generators (their scenes and noise
        correlated, r 0.1-0.2: a validation set of the training seed was not independent of training)."""
        return torch.Generator(device=self.device).manual_seed(
            seed_for(self.seed, int(k), stream=STREAM_DOMAIN + stream + 16 * part))

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
        var = float(cam["qe_variation"])
        if var > 0:  # per-item QE shifts (R, G, B) as CameraPairDataset's, drawn last (none drawn at 0)
            d["shifts"] = (torch.rand(nb, 3, generator=g, device=dev, dtype=torch.float64) * 2 - 1) * 10.0 * var
        return d

    def draw(self, k: int) -> list[StreamGroup]:
        """The scenes and cameras of batch ``k``, grouped by part and discrete camera (see :class:`StreamGroup`),
        before rendering."""
        k = self._check_k(k)
        return [grp for p in range(self.parts) for grp in self._draw_part(k, p)]

    def _draw_part(self, k: int, part: int) -> list[StreamGroup]:
        """The groups of part ``part`` of batch ``k`` (drawn with the part's own generator; indices in the batch)."""
        nb, dev, dt = self._part_sizes[part], self.device, self.dtype
        start = self._part_starts[part]
        h, w = self.scene_config["height"], self.scene_config["width"]
        m = int(self.camera_config["margin_px"])
        g = self._generator(k, 0, part)
        cache = self._caches[part]
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
            if self._module_view_size is not None:  # a view made at each batch: the camera as it is now (a view
                # made once kept the noise flag, gains, optics and buffers of the stream's construction)
                camera = _sized_view(camera, *self._module_view_size)
            pitch = float(camera.sensor.pixel_size_m)
            focal = camera.optics.focal_length_m.detach().reshape(-1)[0].to(torch.float64)
            if self._module_lens:  # the drawn path's geometry for a ray-traced lens (below)
                hfov = _hfov_for(pitch, torch.tensor(camera.optics.image_distance_m, dtype=torch.float64),
                                 w + 2 * m).expand(nb)
            else:
                hfov = self._hfov(pitch, focal, d["distance"], w + 2 * m, dt)
            scene = self._scene(drawn, slice(None), wl, hfov, d["distance"], k)
            return [StreamGroup(torch.arange(start, start + nb, device=dev), camera, scene, {}, k, part)]
        patterns = list(self.camera_config["cfa_patterns"])
        pitches = self.camera_config["pixel_size_m"]
        pitches = pitches if isinstance(pitches, (list, tuple)) else [pitches]
        # groups: the CFAs of this part (the pixel pitch is a per-item sensor setting: one sample per pixel, the
        # sensor's per-call pixel_size_m). The part's camera draws are put in CFA order (stable), so each group is a
        # run of them, rendered with a run of the part's scenes (views of the draw); its outputs go back to the
        # positions of its camera draws (StreamGroup.index), so that position i holds the i-th CFA draw: placed in
        # CFA order, the positions held the draws' order statistics (a batch's first slices one CFA only)
        camera_key = d["pattern_index"]
        order = torch.argsort(camera_key, stable=True)
        d = {key: v[order] for key, v in d.items()}
        keys, counts = torch.unique_consecutive(camera_key[order], return_counts=True)
        nominal = min(float(p_) for p_ in pitches)  # the sensors' own pitch; each item renders at its own
        first = 0
        for c, count in zip(keys.tolist(), counts.tolist()):  # one host read per part
            idx = slice(first, first + count)
            first += count
            pitch, pattern = d["pitch"][idx], patterns[c]
            optics_cfg = self.camera_config.get("optics") or {}
            if optics_cfg:
                optics = cache.get_built_optics(optics_cfg)
                if optics_cfg.get("type") != "lens":  # built on the CPU (a lens keeps its tables there on purpose)
                    optics = optics.to(dev)
                image_distance = torch.tensor(optics.image_distance_m, dtype=torch.float64) \
                    if optics_cfg.get("type") == "lens" else None
                focal = optics.focal_length_m.detach().reshape(-1)[0].to(torch.float64)
            else:
                focal = d["focal"][idx]
                optics = self._optics_for(pitch, d["f_number"][idx], focal, m)
                image_distance = None
            sensor = cache.get_sensor({"pitch": nominal, "fill": float(self.camera_config["fill_factor"]),
                                             "pattern": pattern, "bits": int(self.camera_config["bits"]),
                                             "black": float(self.camera_config["black_level_dn"]), "h": h, "w": w,
                                             "full_well": 1.0}).to(dev)
            sensor.spectral_qe = _unit_qe(pattern, (0.0, 0.0, 0.0))
            camera = cache.get_camera(optics, sensor)
            dist = d["distance"][idx]
            if image_distance is None:
                hfov = self._hfov(pitch, focal, dist, w + 2 * m, dt)
            else:
                hfov = _hfov_for(pitch, image_distance, w + 2 * m).expand(count)
            scene = self._scene(drawn, idx, wl, hfov, dist, k)
            cg = 1.0 / d["full_well"][idx]  # volts per electron with a 1 V swing: well capacity = full well
            kw = {"pixel_size_m": pitch, "analog_gain": d["gain"][idx], "exposure_ev": d["ev"][idx],
                  "qe_scale": d["peak"][idx],
                  "conversion_gain_v_per_e": cg, "read_noise_v": d["read_e"][idx] * cg,
                  "dark_current_e_per_s": d["dark"][idx], "dsnu_sigma_v": d["dsnu_e"][idx] * cg,
                  "prnu_sigma_percent": d["prnu"][idx]}
            if "shifts" in d:  # the items' shifted QE curves (per call; the sensor keeps the unshifted QE)
                kw["spectral_qe"] = _d5100_qe(pattern, d["shifts"][idx])
            groups.append(StreamGroup(start + order[idx].to(dev), camera, scene, kw, k, part))
        return groups

    def _optics_for(self, pitch: float, f_number: torch.Tensor, focal_length_m: torch.Tensor, margin: int):
        """The diffraction-limited optics of a group, with the items' ``[b]`` f-numbers and focal lengths. A new
        module per group (a group's camera stays valid after later batches), sharing one cache of OTF rows per
        (f-number, spacing) across batches, so a batch's OTF is assembled from rows, not evaluated again."""
        from ..optics.factory import build_optics

        # the pairs' optics config (CameraPairDataset's), built by the optics' own factory with [b] tensors
        optics = build_optics(_diffraction_config(f_number, focal_length_m, margin)).to(self.device)
        optics._otf_rows = self._otf_rows
        optics._negligible_memo = self._negligible_memo
        return optics

    @staticmethod
    def _hfov(pitch, focal, distance, width, dtype):
        """Scene FOV that puts one scene sample on one pixel, ``pitch = 2 d_i tan(hfov / 2) / W_s``, with ``d_i``
        the thin-lens image distance of the object distance (Hecht 5.17) computed as the optics compute it
        (``optics.geometry.image_distance`` on the scene's ``dtype`` values), so that the optical image's spacing
        is the pitch to that dtype's rounding also where ``1/f - 1/d`` cancels (objects near the focal length:
        at 4.1 mm from a 4 mm lens a float64 ``d_i`` is 20 float32 steps from the optics')."""
        f, s = focal.to(dtype), distance.to(dtype)
        try:  # (image_distance refuses an object at or inside the focal length; in this dtype 1/f - 1/d may be 0)
            d_i = image_distance(f, s)
            real = bool(torch.isfinite(d_i).all())
        except ValueError:
            real = False
        if not real:
            raise ValueError(f"scene.distance_m: expected object distances beyond the focal length "
                             f"{focal.reshape(-1).tolist()} m (a real image; in {dtype}), got {distance.tolist()} m")
        return _hfov_for(pitch, d_i.to(torch.float64), width)

    def _scene(self, drawn, idx, wl, hfov, distance, k):
        from ..scene import Scene

        dt = self.dtype
        # each item's terms whose map is not 0 everywhere first, J = the most any item of the group uses (one host
        # read), and each item's count (``terms``): the others add exactly 0, so the optics transform only the
        # maps each item uses (as the per-item path drops them). A draw that gives ``terms`` has them first already.
        if "terms" in drawn:
            counts = drawn["terms"][idx].tolist()
            n_terms = max(1, max(counts))
            maps, spectra = drawn["maps"][idx, :n_terms], drawn["spectra"][idx, :n_terms]
        else:
            rows = torch.arange(drawn["maps"].shape[0], device=self.device)[idx][:, None]
            used = drawn["used"][idx]
            counts = used.sum(1).tolist()
            n_terms = max(1, max(counts))
            order = torch.argsort((~used).to(torch.uint8), dim=1, stable=True)[:, :n_terms]
            maps, spectra = drawn["maps"][rows, order], drawn["spectra"][rows, order]
        return Scene.from_factors(maps, spectra.to(dt), wl, terms=counts,
                                  name=f"stream-{k}",
                                  hfov_deg=hfov.to(dt), distance_m=distance.to(dt),
                                  illuminant_photons=drawn["white"][idx].to(dt), validate=False,
                                  metadata={key: v[idx] for key, v in drawn["meta"].items()})

    # --- rendering ------------------------------------------------------------------------------------------
    def _check_k(self, k) -> int:
        """``k`` as a batch index: an integer in ``[0, max_batch_index]`` (its items' numbers ``k * batch_size + i``
        are ``meta["index"]``, int64)."""
        if not is_integer(k) or not 0 <= k <= self.max_batch_index:
            raise ValueError(f"k: expected a batch index in [0, {self.max_batch_index}] (its items are numbered "
                             f"k x batch_size + i in meta['index'], an int64), got {k!r}")
        return int(k)

    @full_precision
    def batch(self, k: int) -> dict:
        """Batch ``k`` (a pure function of ``(seed, k, config, targets, device type)``), rendered on the stream's
        device; ``k`` an integer in ``[0, max_batch_index]``."""
        k = self._check_k(k)
        n_threads = self._thread_count()
        if n_threads == 1:
            done = [self._render_part(k, p) for p in range(self.parts)]
        else:
            # parts on concurrent threads (torch releases the GIL in its kernels), each with an equal share of the
            # intra-op threads (measured: see the class docstring, ``threads``)
            intra = torch.get_num_threads()
            torch.set_num_threads(max(1, intra // n_threads))
            try:
                done = list(self._executor(n_threads).map(lambda p: self._render_part(k, p), range(self.parts)))
            finally:
                torch.set_num_threads(intra)
        return self._assemble(done)

    def _whole_batch(self, k: int) -> dict:
        """Batch ``k`` rendered on this thread, its parts in turn (the pipelined iterator's workers)."""
        k = self._check_k(k)
        return self._assemble([self._render_part(k, p) for p in range(self.parts)])

    @staticmethod
    def _assemble(done: list) -> dict:
        """A batch from its rendered parts (``_render_part`` results, in part order)."""
        parts = [out for part in done for out in part[1]]
        if len(parts) == 1:
            return parts[0]
        # the groups' outputs in turn, then each item at its position (StreamGroup.index, see _draw_part)
        out = {key: torch.cat([p[key] for p in parts]) for key in parts[0] if key != "meta"}
        out["meta"] = {key: torch.cat([p["meta"][key] for p in parts]) for key in parts[0]["meta"]}
        index = out["meta"]["index"]
        if bool((index[1:] < index[:-1]).any()):
            where = torch.argsort(index)
            out = {key: v[where] for key, v in out.items() if key != "meta"} | {
                "meta": {key: v[where] for key, v in out["meta"].items()}}
        return out

    def _render_part(self, k: int, part: int) -> tuple[list, list]:
        """Part ``part`` of batch ``k``: its groups and their outputs (the part's noise generator, in group order).
        On a CPU without gradients or a camera module the part renders on one intra-op thread, as
        ``CameraPairDataset`` renders its items: some kernels (``irfft2`` at some sizes) round differently with more
        threads, and a batch must not depend on the machine (the iterator renders batches on threads instead)."""
        with one_thread() if self._cpu_batches else contextlib.nullcontext():
            groups = self._draw_part(k, part)
            noise = self._generator(k, 2, part)
            with torch.set_grad_enabled(self.grad):  # grad mode is per thread
                return groups, [self._render(grp, noise) for grp in groups]

    def _thread_count(self) -> int:
        """Threads rendering the parts: ``threads``, or on CPU as many as parts up to torch's intra-op threads (a
        camera module given to the stream is rendered on one thread: its caches are not shared across threads)."""
        if self.parts == 1 or self.camera_module is not None:
            return 1
        if self.threads is not None:
            return min(self.threads, self.parts)
        return min(self.parts, torch.get_num_threads()) if self.device.type == "cpu" else 1

    def _pipeline_width(self) -> int:
        """Batches the iterator renders at once: ``threads`` (default torch's intra-op thread count, plus one from
        64 items, where a thread waiting for the GIL leaves its core to the extra one) on a CPU without a camera
        module or gradients; else 1 (in turn, on the caller's thread)."""
        if not self._cpu_batches:
            return 1
        if self.threads is not None:
            return self.threads
        return torch.get_num_threads() + (self.batch_size >= 64)

    def _executor(self, n: int, pipeline: bool = False):
        """The thread pool of ``n`` part threads, or with ``pipeline`` of ``n`` whole-batch threads (each running
        torch on one intra-op thread)."""
        pid, key = os.getpid(), ("pipeline" if pipeline else "parts", n)
        pools = self._pool if self._pool is not None and self._pool[0] == pid else (pid, {})  # a fork makes its own
        self._pool = pools
        if key not in pools[1]:
            init = (lambda: torch.set_num_threads(1)) if pipeline else None
            pools[1][key] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="PairStream", initializer=init)
        return pools[1][key]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_pool"] = None
        return state

    def _render(self, grp: StreamGroup, noise: torch.Generator) -> dict:
        """One group through its camera: the calls of :func:`~isettorch.data.camera_pairs.render_pairs`, batched
        (optics on the factored scene, the sensor's channel rates with the XYZ weightings, auto-exposure on the
        mosaic, capture with noise, the readout without the CFA for ``camera_rgb``)."""
        camera, scene, kw = grp.camera, grp.scene, dict(grp.kwargs)
        sensor = camera.sensor
        targets = self.targets
        colour = bool({"xyz", "linear_srgb", "srgb"} & set(targets))
        peak, qe = kw.pop("qe_scale", None), kw.pop("spectral_qe", None)
        gain, ev = kw.pop("analog_gain", None), kw.pop("exposure_ev", None)
        cg = kw.get("conversion_gain_v_per_e")
        pitch = kw.get("pixel_size_m")
        oi = camera.optical_image(scene, pixel_size_m=pitch)
        grid = tuple(scene.wavelengths_nm.tolist())
        xyz_w, _, xyz_wt = _xyz_weights(grid)
        rates, xyz_d = sensor.channel_rates(oi, xyz_wt if colour else None, qe_scale=peak, spectral_qe=qe,
                                            pixel_size_m=pitch)
        mosaic = sensor.cfa.mosaic(rates)
        exposure = sensor.exposure_for(None, mosaic, gain, exposure_ev=ev, conversion_gain_v_per_e=cg)
        raw = sensor.capture(mosaic, exposure_s=exposure, analog_gain=gain, noise=camera.noise, generator=noise,
                             spectral_qe=qe, **kw)
        nb = rates.shape[0]
        # normalised by the capture's zero level (black level and any analog offset) and white level, per item when
        # the levels are; the offset is not signal (Sensor.zero_level), so the noise metadata below describe it
        span = raw.white_level - raw.black_level
        black, white = raw.levels()
        span_map = white - black
        out = {"raw": (raw.data - black) / span_map}
        if "noise_free_raw" in targets:
            out["noise_free_raw"] = (raw.noise_free - black) / span_map
        if "camera_rgb" in targets:
            out["camera_rgb"] = (sensor.readout(rates, exposure, gain, conversion_gain_v_per_e=cg) - black) / span_map
        dev, dt = rates.device, rates.dtype
        f64 = torch.float64
        white_p = scene.illuminant_photons.to(f64)
        peak_t = torch.ones(nb, dtype=f64, device=dev) if peak is None else peak.to(f64)
        qe_w = sensor.spectral_weights(oi, qe).to(f64)  # [L, 3], or [b, L, 3] per item
        white_cam = (white_p @ qe_w if qe_w.dim() == 2 else (white_p[:, None] @ qe_w)[:, 0]) * peak_t[:, None]
        white_xyz = white_p @ xyz_w.to(dev).T  # [b, 3]
        to_norm = sensor.gain_per_electron(gain, batch=nb, dtype=f64, device=dev,
                                           conversion_gain_v_per_e=None if cg is None else cg.to(f64)) / span
        if colour:
            # XYZ scaled so a perfect white under light 1 has Y equal to its normalised green camera value
            k_white = white_cam[:, 1] / white_xyz[:, 1]
            area = sensor.collecting_area_m2(None if pitch is None else pitch.to(f64))  # [b] per-item pitches
            scale = k_white * area * exposure.to(f64) * to_norm
            xyz = xyz_d * scale.to(dt).reshape(-1, 1, 1, 1)
            if "xyz" in targets:
                out["xyz"] = xyz
            cat = bradford_matrix(white_xyz / white_xyz[:, 1:2], torch.tensor(SRGB_WHITE_XYZ, dtype=f64, device=dev))
            m_srgb = (torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=f64, device=dev) @ cat).to(dt)  # [b, 3, 3]
            lin = torch.einsum("bij,bjhw->bihw", m_srgb, xyz)
            if "linear_srgb" in targets:
                out["linear_srgb"] = lin
            if "srgb" in targets:
                # the clamped copy is the encoding's scratch (bitwise the same, fewer passes) unless it needs a gradient
                out["srgb"] = srgb_encode(lin.clamp(0, 1), inplace=not lin.requires_grad)
        out = {key: out[key] for key in ("raw", *targets)}
        out["meta"] = self._meta(grp, raw, exposure, span, white_cam, white_xyz, sensor, oi, peak_t)
        return out

    def _meta(self, grp, raw, exposure, span, white_cam, white_xyz, sensor, oi, peak) -> dict:
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

        def per_item(v):  # a raw's level: a float, or [b] per item
            return v.detach().to(f64).reshape(-1) * full if isinstance(v, torch.Tensor) else full * float(v)

        cg = level("conversion_gain_v_per_e", 1.0)
        gain = level("analog_gain", 1.0)
        read_e, dsnu_e = level("read_noise_v", 0.0) / cg, level("dsnu_sigma_v", 0.0) / cg
        dark = level("dark_current_e_per_s", 0.0)
        t = exposure.detach().to(f64)
        # the capture's Poisson-Gaussian model (its sensor's: CDS, analog or DN readout, the levels it used)
        a, b = sensor.poisson_gaussian(raw)
        span = span.detach().to(f64) if isinstance(span, torch.Tensor) else span
        scene_meta = grp.scene.metadata
        wave = grp.scene.wavelengths_nm.detach()
        qe = sensor.qe(oi, kw.get("spectral_qe")).detach().to(f64)  # [C, L], or [b, C, L] per item
        qe = (qe if qe.dim() == 3 else qe[None]) * peak.detach()[:, None, None]
        wc, wx = white_cam.detach(), white_xyz.detach()
        meta = {
            "index": grp.index + grp.batch_index * self.batch_size,
            "exposure_s": t, "analog_gain": gain, "iso": 100.0 * gain,
            "f_number": optics.f_number.detach().to(f64).reshape(-1).expand(nb),
            "focal_length_m": optics.focal_length_m.detach().to(f64).reshape(-1).expand(nb),
            "pixel_size_m": level("pixel_size_m", sensor.pixel_size_m), "full_well_e": sensor.saturation_e(cg),
            "read_noise_e": read_e, "dark_current_e_per_s": dark, "dsnu_sigma_e": dsnu_e,
            "prnu_sigma_percent": level("prnu_sigma_percent", 0.0),
            "black_level_dn": per_item(raw.black_level), "white_level_dn": per_item(raw.white_level),
            # Poisson-Gaussian noise model in normalised units: var(x) = noise_gain x + noise_floor_var (Foi et al.,
            # IEEE TIP 17(10), 2008), as CameraPairDataset's metadata: without PRNU, which adds
            # (prnu_sigma_percent / 100 * x)^2 across pixels (isettorch.data.camera_pairs, "Noise metadata")
            "noise_gain": a / span,
            "noise_floor_var": b / span ** 2,
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


def _sized_view(camera, rows: int, cols: int):
    """``camera`` with a sensor of ``rows x cols`` pixels that shares every parameter, buffer value and submodule
    with the given one (gradients reach the user's parameters), without resizing the user's own sensor: a shallow
    copy of the camera and of its sensor with their own module / buffer dictionaries and no size-keyed memos."""
    import copy

    sensor = copy.copy(camera.sensor)
    sensor._buffers = dict(camera.sensor._buffers)  # fixed patterns are redrawn at the new size, in the copy only
    for key in [k for k in sensor.__dict__ if k.endswith("_memo")]:
        del sensor.__dict__[key]
    sensor.rows, sensor.cols = int(rows), int(cols)
    view = copy.copy(camera)
    view._modules = dict(camera._modules)
    view._modules["sensor"] = sensor
    return view


def _check_camera_module(camera, scene_cfg: dict):
    """A camera module the stream can render pairs through (ValueError naming ``camera`` otherwise): an
    :class:`isettorch.Camera` whose :class:`~isettorch.sensor.Sensor` has colour channels (the metadata's
    ``white_camera_rgb`` and the colour targets are relative to its second channel) and the scene's size (a batch
    is ``scene.height x scene.width``, as ``CameraPairDataset``'s). A sensor sized to each optical image (``rows``
    and ``cols`` None, as in every shipped camera config) renders at the scene's size through :func:`_sized_view`,
    made at each batch. Returns whether its optics are a ray-traced lens
    (:class:`~isettorch.optics.lens.optics.LensOptics`, imaging at its ``image_distance_m``) and the size of that
    view (None: the sensor is the scene's size)."""
    from ..camera import Camera
    from ..optics.lens.optics import LensOptics

    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected None, a camera config mapping (keys of CAMERA_DEFAULTS) or an "
                         f"isettorch.Camera module, got a {type(camera).__name__}")
    sensor = camera.sensor
    if not all(hasattr(sensor, name) for name in ("channel_rates", "capture", "readout", "cfa")):
        raise ValueError(f"camera: expected a Camera with an isettorch.sensor.Sensor (its channel rates, capture and "
                         f"readout render the pairs), its sensor is a {type(sensor).__name__}")
    if sensor.cfa.num_channels < 2:
        raise ValueError(f"camera: its sensor is monochrome (one channel, {sensor.cfa.channel_names}), but camera "
                         f"pairs are colour: meta['white_camera_rgb'] and the targets camera_rgb, xyz, linear_srgb "
                         f"and srgb are relative to the camera's second (green) channel, and CameraPairDataset "
                         f"draws Bayer sensors only (camera.cfa_patterns); expected a sensor with colour channels")
    h, w = scene_cfg["height"], scene_cfg["width"]
    view = None
    if sensor.rows is None and sensor.cols is None:
        view = (h, w)
    elif (sensor.rows, sensor.cols) != (h, w):
        raise ValueError(f"camera: its sensor is {sensor.rows}x{sensor.cols} pixels, but scene.height x scene.width "
                         f"is {h}x{w}: a batch is the scene's size, as CameraPairDataset's; build the sensor with "
                         f"rows={h}, cols={w} (or both None: sized to the scene)")
    return isinstance(camera.optics, LensOptics), view


def _draw_range(values, g: torch.Generator, nb: int, device, log: bool = False) -> torch.Tensor:
    """``[B]`` float64 draws uniform (or log-uniform) in ``[lo, hi]``; a number is a constant."""
    u = torch.rand(nb, generator=g, device=device, dtype=torch.float64)
    return (_log_uniform if log else _uniform)(values, u)


def _check_drawn_lens(camera_config: dict, scene_config: dict) -> None:
    """A drawn ray-traced lens renders a part's items at one field of view and one object distance (LensOptics):
    several pixel pitches (one field of view each) or, with ``object_distance: scene``, a range of scene distances
    failed at the first batch (the pitches naming ``scene.hfov_deg``, a key the config does not set).
    ``CameraPairDataset`` renders item by item and takes them, as does a stream of one item per part."""
    optics = camera_config.get("optics") or {}
    if optics.get("type") != "lens":
        return
    pitches = camera_config["pixel_size_m"]
    if isinstance(pitches, (list, tuple)) and len({float(p) for p in pitches}) > 1:
        raise ValueError(f"camera.pixel_size_m: a ray-traced lens renders a stream batch at one field of view, so one "
                         f"pixel pitch; got {list(pitches)} (CameraPairDataset renders several)")
    dist = scene_config["distance_m"]
    if optics.get("object_distance") == "scene" and isinstance(dist, (list, tuple)) and dist[0] != dist[-1]:
        raise ValueError(f"scene.distance_m: a ray-traced lens with object_distance 'scene' renders a stream batch at "
                         f"one object distance; got the range {list(dist)} (CameraPairDataset renders it)")


def _hfov_for(pitch: float, image_distance_m, width: int) -> torch.Tensor:
    """The full angle (deg) of ``width`` pixels of ``pitch`` at ``image_distance_m``: one scene sample a pixel."""
    d_i = torch.as_tensor(image_distance_m, dtype=torch.float64)
    return angle_for_extent(pitch * width, d_i).reshape(-1)

