"""Synthetic-scene batches of the demosaic trainer: the ``natural`` / ``isettorch`` scene pool (:class:`ScenePool`,
a fixed :class:`SceneBank` with ``data.bank``), the source of ``data.source`` (:func:`make_sampler`) and one batch
for one (seed, step) (:func:`make_batch`). Part of ``training/train_demosaic.py``."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from isettorch._progress import progress as progress_bar
from isettorch.data import natural as nat
from isettorch.data import spectra as data_spectra
from isettorch.data.config import seed_for
from isettorch.isp.demosaicing import demosaic_malvar2004, mosaic
from training import common
from training.demosaic_noise import add_noise, gaussian_params, noise_features, noise_params
from training.demosaic_pairs import CameraPairSource, StreamSource

SOURCES = ("natural", "isettorch", "camera_pairs", "stream")
#: colour spaces of the ``natural`` pool's images: the white-balanced camera RGB of the pool's sensor (Nikon D5100
#: QE), or the scene's colorimetric linear sRGB (the Camera's ``linear_srgb`` target: CIE XYZ at the sensor,
#: Bradford-adapted to D65, IEC 61966-2-1 primaries), the space of display-referred photographs such as Kodak
COLOUR_SPACES = ("camera_rgb", "linear_srgb")


def mosaic_rggb(rgb: torch.Tensor) -> torch.Tensor:
    """[B, 3, H, W] -> RGGB mosaic [B, 1, H, W] (the library's :func:`isettorch.isp.demosaicing.mosaic`)."""
    return mosaic(rgb, "RGGB")


def augment_flips(img: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """A random horizontal flip and transpose of the whole batch (even sizes keep the RGGB phase after the
    mosaic is taken)."""
    if float(torch.rand(1, generator=g)) < 0.5:
        img = img.flip(-1)
    if float(torch.rand(1, generator=g)) < 0.5:
        img = img.transpose(-1, -2)
    return img


#: the camera of the ``natural`` pool unless ``data.camera`` says otherwise: the sharpest stop and largest pitch of
#: the camera-pair defaults (Airy radius 1.34 um at 550 nm, f/2, against 2.8 um pixels: little optical blur, as the
#: network's input is a sharp mosaic), one Bayer order (the pool is cropped at even offsets: RGGB), the nominal
#: auto-exposure one stop down (98th percentile at 40 % of white: few clipped highlights; expose_and_encode then
#: sets the training exposure) and channel curves shifted by up to +-5 nm (camera variety).
POOL_CAMERA = {"f_number": [2.0], "pixel_size_m": [2.8e-6], "cfa_patterns": ["RGGB"], "exposure_ev": [-1.0, -1.0],
               "qe_variation": 0.5}


class ScenePool:
    """White-balanced linear camera-RGB images of generated scenes, rendered once and cropped many times.

    Sources: ``natural``: items of :class:`isettorch.data.camera_pairs.CameraPairDataset` with ``scene.generator:
    natural`` (:func:`isettorch.data.natural.generate_natural`, config ``data.natural``, components switched off with
    ``data.disable``) rendered by the library's `Camera` (diffraction-limited optics, the D5100 sensor; camera
    config :data:`POOL_CAMERA` updated by ``data.camera``), noise-free ``camera_rgb`` (every channel at every pixel;
    its RGGB mosaic is the pair's ``noise_free_raw``) white-balanced by the item's white (von Kries gains from
    ``meta['white_camera_rgb']``, :func:`isettorch.isp.colour.apply_gains`); ``isettorch``
    (:func:`isettorch.data.generate_scene`, config ``data.scene_config``) projected by ``Scene.project`` on random
    camera sensitivities (:func:`isettorch.data.spectra.random_sensitivities`, weights ``data.sensitivities``) and
    white-balanced for its main light. A scene costs far more than a training step on CPU, so ``pool`` scenes are
    kept and ``refresh`` new ones replace the oldest at every step: at step ``s`` the pool holds scene indices
    ``[s * refresh, s * refresh + pool)``, so every batch depends only on (seed, step) and a run resumes exactly.
    """

    def __init__(self, cfg: dict, seed: int, scene_size: int | None = None):
        d = cfg.get("data", {})
        self.source = d.get("source", "natural")
        if self.source == "synth":
            raise ValueError("data.source: 'synth' (training/synth.py) is retired; use 'natural' (isettorch.data."
                             "natural), 'isettorch' or 'camera_pairs'")
        if self.source not in ("natural", "isettorch"):
            raise ValueError(f"data.source: expected one of {SOURCES}, got {self.source!r}")
        self.patch = int(d.get("patch", 80))
        self.scene_size = int(scene_size or d.get("scene_size", 128))
        if self.patch < 4 or self.patch % 2 or self.scene_size < self.patch:
            raise ValueError(f"data.patch, data.scene_size: expected an even patch >= 4 and scene_size >= patch, got "
                             f"{self.patch}, {self.scene_size}")
        self.seed, self.pool_size, self.refresh = int(seed), int(d.get("pool", 64)), int(d.get("refresh", 2))
        self.sens_kinds = d.get("sensitivities") if isinstance(d.get("sensitivities"), dict) else None
        self.scene_config = dict(d.get("scene_config") or {}, height=self.scene_size, width=self.scene_size)
        self.colour_space = d.get("colour_space", "camera_rgb")
        if self.colour_space not in COLOUR_SPACES:
            raise ValueError(f"data.colour_space: expected one of {COLOUR_SPACES}, got {self.colour_space!r}")
        if self.colour_space != "camera_rgb" and self.source != "natural":
            raise ValueError(f"data.colour_space: {self.colour_space!r} needs data.source 'natural' (the Camera's "
                             f"colorimetric targets), got source {self.source!r}")
        self.pairs = None
        if self.source == "natural":
            if d.get("sensitivities") is not None:
                raise ValueError("data.sensitivities: the natural source renders through the Camera's sensor (Nikon "
                                 "D5100 QE, shifted by data.camera.qe_variation); random sensitivities apply to "
                                 "data.source 'isettorch' only")
            natural = json.loads(json.dumps(d.get("natural") or {}))
            disable = tuple(d.get("disable") or ())
            nat.natural_config(natural, disable=disable)  # validates the options and component names
            for name in disable:
                natural.setdefault("components", {}).setdefault(name, {})["enabled"] = False
            from isettorch.data.camera_pairs import CameraPairDataset

            self.pairs = CameraPairDataset(CameraPairSource.LENGTH, seed=self.seed, scene={
                "generator": "natural", "natural": natural, "height": self.scene_size, "width": self.scene_size},
                camera={**POOL_CAMERA, **(d.get("camera") or {})}, targets=(self.colour_space,))
            if self.pairs.camera_config["cfa_patterns"] != ["RGGB"]:
                raise ValueError(f"data.camera.cfa_patterns: the natural pool is mosaicked RGGB, expected ['RGGB'], "
                                 f"got {self.pairs.camera_config['cfa_patterns']}")
        self.scenes: dict[int, torch.Tensor] = {}

    def render(self, index: int) -> torch.Tensor:
        if self.source == "natural":
            from isettorch.isp.colour import apply_gains

            item = self.pairs.get_batch([index])
            if self.colour_space == "linear_srgb":  # already adapted to D65 (Bradford): white is neutral
                return item["linear_srgb"][0].clamp_min(0)  # out-of-gamut colours clip at 0, as on a display
            return apply_gains(item["camera_rgb"], 1.0 / item["meta"]["white_camera_rgb"])[0].clamp_min(0)
        from isettorch import spectral
        from isettorch.data import generate_scene

        g = torch.Generator().manual_seed(seed_for(self.seed + 7_919, index))  # the camera's draws
        s = generate_scene(index, seed=self.seed, config=self.scene_config, dtype=torch.float32)
        w = s.wavelengths_nm.to(torch.float64)
        sens = data_spectra.random_sensitivities(w, g, self.sens_kinds)
        m = (sens * spectral.wavelength_weights(w)).float()  # photon counting: sum_l S(l) N(l) dl
        rgb = s.project(m.T)[0]  # the Scene's projection (factored: J maps, no cube)
        return (rgb / (m @ s.illuminant_photons[0])[:, None, None]).clamp_min(0)

    def advance(self, step: int) -> None:
        lo = step * self.refresh
        keep = range(lo, lo + self.pool_size)
        for k in [k for k in self.scenes if k not in keep]:
            del self.scenes[k]
        for k in keep:
            if k not in self.scenes:
                self.scenes[k] = self.render(k)

    def sample(self, batch: int, step: int, g: torch.Generator) -> torch.Tensor:
        """[B, 3, patch, patch] random crops (even offsets keep the Bayer phase) from the pool at ``step``."""
        self.advance(step)
        keys = sorted(self.scenes)
        p, n = self.patch, self.scene_size
        out = []
        for _ in range(batch):
            img = self.scenes[keys[int(torch.randint(0, len(keys), (1,), generator=g))]]
            y, x = (2 * int(torch.randint(0, (n - p) // 2 + 1, (1,), generator=g)) for _ in range(2))
            out.append(img[:, y:y + p, x:x + p])
        return torch.stack(out)


BANK_CHUNK = 128  # scenes per file of a scene bank (the unit of resuming and of parallel rendering)


def _render_chunk(args):
    """Worker of :class:`SceneBank`: scenes ``[lo, hi)`` of one pool, float16 ``[n, 3, S, S]`` (one thread)."""
    cfg, seed, scene_size, lo, hi = args
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # (the same rounding in a worker and in the trainer's own process)
    try:
        pool = ScenePool(cfg, seed, scene_size)
        return torch.stack([pool.render(i) for i in range(lo, hi)]).half()
    finally:  # rendered in the trainer's process (one worker or one chunk left), it trained on one thread after
        torch.set_num_threads(threads)


class SceneBank(ScenePool):
    """``data.bank: N``: the pool's first ``N`` scenes, rendered once and kept in memory as float16 (a natural
    scene costs ~0.15 s of CPU, 10-20 training steps' worth of data: rendering them once and cropping each many
    times makes the training step, not the generator, the cost). Batches are random crops of uniformly drawn bank
    scenes, so every batch still depends only on (seed, step).

    The bank is cached in ``data.bank_dir`` (default ``out/scene_banks``) under a hash of the data config, seed
    and size, in files of :data:`BANK_CHUNK` scenes written atomically: an interrupted render resumes, and runs with
    the same data (a noise-free and a joint run) share it. ``data.bank_workers`` processes render in parallel.
    float16 keeps ~3 significant digits (relative step 2^-11), below the 8-bit steps of the benchmarks' images.
    """

    def __init__(self, cfg: dict, seed: int, scene_size: int | None = None, progress: bool = False):
        super().__init__(cfg, seed, scene_size)
        d = cfg.get("data", {})
        self.count = int(d["bank"])
        if self.count < 1:
            raise ValueError(f"data.bank: expected a number of scenes >= 1, got {d['bank']!r}")
        workers = int(d.get("bank_workers", 1))
        if workers < 1:
            raise ValueError(f"data.bank_workers: expected >= 1 processes, got {workers}")
        import hashlib

        keep = {k: v for k, v in d.items() if k not in ("bank", "bank_dir", "bank_workers", "batch", "patch",
                                                          "hard_mining", "domain", "encoded_fraction", "scene_seed")}
        from isettorch.data.camera_pairs import GENERATOR_VERSION

        key = json.dumps({"data": keep, "seed": self.seed, "size": self.scene_size, "generator": GENERATOR_VERSION},
                         sort_keys=True, default=str)
        digest = hashlib.sha256(key.encode()).hexdigest()[:16]
        self.folder = Path(d.get("bank_dir") or "out/scene_banks") / digest
        self.folder.mkdir(parents=True, exist_ok=True)
        (self.folder / "config.json").write_text(key)
        chunks = [(lo, min(lo + BANK_CHUNK, self.count)) for lo in range(0, self.count, BANK_CHUNK)]
        todo = [c for c in chunks if not self._chunk_path(c).is_file()]
        bar = progress_bar(total=len(chunks), initial=len(chunks) - len(todo), desc="scene bank", unit="chunk",
                           quiet=not progress)
        jobs = [(cfg, self.seed, self.scene_size, lo, hi) for lo, hi in todo]
        if workers > 1 and len(todo) > 1:
            import multiprocessing as mp

            with mp.get_context("spawn").Pool(min(workers, len(todo))) as pool:
                for c, imgs in zip(todo, pool.imap(_render_chunk, jobs)):
                    self._save(c, imgs)
                    bar.update(1)
        else:
            for c, job in zip(todo, jobs):
                self._save(c, _render_chunk(job))
                bar.update(1)
        bar.close()
        self.images = torch.cat([torch.load(self._chunk_path(c), weights_only=True) for c in chunks])
        if tuple(self.images.shape) != (self.count, 3, self.scene_size, self.scene_size):
            raise ValueError(f"data.bank_dir: {self.folder} holds images of shape {tuple(self.images.shape)}, "
                             f"expected {(self.count, 3, self.scene_size, self.scene_size)}; delete the folder")

    def _chunk_path(self, chunk) -> Path:
        return self.folder / f"scenes_{chunk[0]:07d}_{chunk[1]:07d}.pt"

    def _save(self, chunk, imgs: torch.Tensor) -> None:
        common.save_atomic(imgs, self._chunk_path(chunk))

    def advance(self, step: int) -> None:  # the bank is fixed
        return None

    def sample(self, batch: int, step: int, g: torch.Generator) -> torch.Tensor:
        """[B, 3, patch, patch] float32 random crops (even offsets keep the Bayer phase) of random bank scenes."""
        p, n = self.patch, self.scene_size
        idx = torch.randint(0, self.count, (batch,), generator=g).tolist()
        offs = (2 * torch.randint(0, (n - p) // 2 + 1, (batch, 2), generator=g)).tolist()
        return torch.stack([self.images[i, :, y:y + p, x:x + p] for i, (y, x) in zip(idx, offs)]).float()


def make_sampler(cfg: dict, seed_offset: int = 0, seed: int | None = None, scene_size: int | None = None,
                 progress: bool = False, device=None, batch: int | None = None):
    """The batch source of ``data.source``: a :class:`ScenePool` (a :class:`SceneBank` with ``data.bank``), a
    :class:`CameraPairSource` or a :class:`StreamSource` (on ``device``, batches of ``batch``)."""
    d = cfg.get("data", {})
    source = d.get("source", "natural")
    if source == "camera_pairs":
        return CameraPairSource(cfg, seed_offset)
    if source == "stream":
        return StreamSource(cfg, seed_offset, device=device, batch=batch)
    base = int(cfg.get("seed", 0)) * 1_000_003 if seed is None else int(seed)
    if d.get("bank") and not seed_offset:  # validation (its own seed offset) renders its own scenes
        return SceneBank(cfg, base, scene_size, progress=progress)
    return ScenePool(cfg, base + int(seed_offset), scene_size)


def make_batch(sampler, cfg: dict, seed: int, batch: int, step: int = 0):
    """(raw [B,1,H,W], target [B,3,H,W], noise features [B,2] or None) for one (seed, step).

    ``data.domain`` (linear | encoded | mixed, ``data.encoded_fraction``) picks the training domain
    (:func:`isettorch.data.natural.expose_and_encode`); ``data.hard_mining: k`` > 1 draws ``k x batch`` crops and
    keeps the ``batch`` with the largest Malvar-He-Cutler error (Gharbi et al. 2016)."""
    if isinstance(sampler, CameraPairSource):
        return sampler.batch(seed, batch)
    if isinstance(sampler, StreamSource):
        return sampler.batch(step, batch)
    d = cfg.get("data", {})
    g = torch.Generator().manual_seed(int(seed))
    k = int(d.get("hard_mining", 0) or 0)
    n = batch * k if k > 1 else batch
    rgb = nat.expose_and_encode(sampler.sample(n, step, g), g, d.get("domain", "mixed"),
                                encoded_fraction=float(d.get("encoded_fraction", 0.8)))
    if k > 1:
        with torch.no_grad():
            est = demosaic_malvar2004(mosaic_rggb(rgb))
        rgb = rgb[nat.hard_patch_indices(rgb, est, keep=1.0 / k)[:batch].sort().values]
    rgb = augment_flips(rgb, g)
    raw = mosaic_rggb(rgb)
    feats = None
    if cfg.get("noise", {}).get("enabled", False):
        ab = noise_params(batch, cfg, g)
        n = cfg["noise"]
        extra = any(float(n.get(k, 0) or 0) for k in ("prnu_percent", "dark_e", "dsnu_e", "bits"))
        k_gauss = round(float(n.get("gaussian_fraction", 0.0)) * batch)
        if k_gauss:  # the first k images: white Gaussian noise only (a = 0), the benchmarks' --noise-sigma model
            ab[:k_gauss] = gaussian_params(k_gauss, n, g)
            raw = torch.cat([add_noise(raw[:k_gauss], ab[:k_gauss], g),
                             add_noise(raw[k_gauss:], ab[k_gauss:], g, n if extra else None)])
        else:
            raw = add_noise(raw, ab, g, n if extra else None)
        k_clean = round(float(n.get("clean_fraction", 0.0)) * batch)
        if not 0 <= k_clean + k_gauss <= batch:
            raise ValueError(f"noise.clean_fraction, noise.gaussian_fraction: expected fractions with a sum in "
                             f"[0, 1], got {n.get('clean_fraction')}, {n.get('gaussian_fraction')}")
        if k_clean:  # the last k images: no noise at all (a = b = 0), so the joint model keeps the noise-free one's
            raw[batch - k_clean:] = mosaic_rggb(rgb[batch - k_clean:])  # accuracy at sigma = 0
            ab[batch - k_clean:] = 0
        feats = noise_features(ab)
    return raw, rgb, feats
