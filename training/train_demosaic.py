"""Train the compact demosaic CNN (:class:`isettorch.isp.learned.DemosaicNet`) on synthetic scenes made on the fly.

Data come only from the library: ``data.source: natural`` (default; :mod:`isettorch.data.natural`, the
natural-statistics generator, components switched off with ``data.disable: [name, ...]``, its scenes rendered by
:class:`isettorch.data.camera_pairs.CameraPairDataset` through the library's Camera: :class:`ScenePool`),
``isettorch``
(:func:`isettorch.data.generate_scene`) or ``camera_pairs`` (below). ``data.domain`` (``linear``, ``encoded`` or
``mixed`` with ``data.encoded_fraction``) is the training domain: Kodak/McMaster are 8-bit encoded sRGB mosaics
scored as linear, so a linear-domain model and an encoded-domain model are different models.

Usage::

    python training/train_demosaic.py --config configs/train/demosaic_noise_free.yaml [--out DIR] [--steps N]
    torchrun --nproc_per_node 2 training/train_demosaic.py --config ...   # DistributedDataParallel (gloo on CPU)

Every batch depends only on (seed, step, rank), so a run resumes exactly from its last checkpoint
(``--resume``, or automatically when ``out/last.pt`` exists). Validation uses held-out synthetic scenes (their
own seeds, never drawn for training); the model with the best validation CPSNR is kept as ``best.pt``. Kodak and
McMaster are scored only for reporting (``eval.benchmarks``), never for selection. Checkpoints are read with
``torch.load(weights_only=True)``. Outputs: ``last.pt``, ``best.pt``, ``history.csv``, ``curves.png``,
``record.json``.

The joint denoise+demosaic variant (``noise.enabled: true``) adds heteroscedastic sensor noise at a random gain
per image: ``var = a * x + b`` (Poisson shot noise of ``x / a`` electrons plus Gaussian read noise, the
photon-transfer model of EMVA 1288), with ``a = gain / full_well_e`` and ``b = (read_noise_e * a)^2``;
``(sqrt(a), sqrt(b))`` are given to the network as two extra input planes. With dark current, DSNU, PRNU or
``bits`` set, the noise is drawn by one :class:`isettorch.sensor.Sensor` with per-image levels (:func:`add_noise`).

``data.source: stream`` (with ``data.device``, default the training device) draws the same kind of batches from
:class:`isettorch.data.PairStream`, generated and rendered on that device (:class:`StreamSource`).

``data.source: camera_pairs`` draws batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` instead
(scene -> diffraction-limited optics -> the isettorch sensor with its own noise model; ``data.scene`` /
``data.camera`` are passed to the dataset). Input: the noisy quantised raw mosaic (``noise.enabled: true``, the
joint variant) or ``noise_free_raw`` (noise-free variant); target: ``camera_rgb``; all in normalised raw units
(0 = black, 1 = white level; camera RGB, not white-balanced). Noise inputs from each item's metadata: the dataset's
Poisson-Gaussian model ``var = a x + b`` in normalised units (Foi et al., IEEE TIP 2008) has
``a = meta['noise_gain']`` (normalised units per electron, so shot noise gives ``a x``) and
``b = meta['noise_floor_var']`` (read noise, DSNU, dark current and quantisation); PRNU (multiplicative,
< 1.5 %) is left out of the model. Items are rendered ``patch + 2`` pixels wide and cropped at the offset that
puts an R pixel top-left, so every Bayer order the dataset draws reaches the network as RGGB.

``distill: {teacher: CKPT, weight: w, self_ensemble: true}`` trains towards ``(1 - w) * target + w * teacher``,
where ``teacher`` is a trained checkpoint's output on the same mosaic (:func:`distill_target`; knowledge
distillation, Hinton, Vinyals & Dean 2015). With ``self_ensemble`` the teacher's output is its geometric
self-ensemble (:func:`isettorch.isp.learned.demosaic_learned`, the mean over the mosaic and its transpose), so a
one-pass student is taught the two-pass network's exactly transpose-equivariant output; ``self_ensemble: dihedral``
teaches the eight-pass ensemble over flips and transposes.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._progress import add_quiet_argument  # noqa: E402
from isettorch._progress import progress as progress_bar  # noqa: E402
from isettorch.data import natural as nat  # noqa: E402
from isettorch.data import spectra as data_spectra  # noqa: E402
from isettorch.data.config import seed_for  # noqa: E402
from isettorch.isp import learned  # noqa: E402
from isettorch.isp.demosaicing import demosaic_malvar2004, mosaic  # noqa: E402
from isettorch.isp.learned import DemosaicNet  # noqa: E402
from isettorch.paths import data_path  # noqa: E402
from isettorch.sensor import Sensor  # noqa: E402
from isettorch.sensor.noise import poisson_gaussian  # noqa: E402
from training import common  # noqa: E402

VAL_SEED_OFFSET = 1_000_003_000  # validation scenes use seeds far from any training (seed, step, rank)


SOURCES = ("natural", "isettorch", "camera_pairs", "stream")
LOG_EVERY = 10  # steps between reads of the loss for the progress bar (a host read synchronises the device)
#: colour spaces of the ``natural`` pool's images: the white-balanced camera RGB of the pool's sensor (Nikon D5100
#: QE), or the scene's colorimetric linear sRGB (the Camera's ``linear_srgb`` target: CIE XYZ at the sensor,
#: Bradford-adapted to D65, IEC 61966-2-1 primaries), the space of display-referred photographs such as Kodak
COLOUR_SPACES = ("camera_rgb", "linear_srgb")
#: training arithmetic: float32, or bfloat16 autocast for the network's body (``optim.precision``; the MHC base,
#: the loss and the weights stay float32, validation and benchmarks run in float32). On a CPU with AVX-512 BF16
#: a 64 x 8 step of 12 x 80^2 took 98 ms against 188 ms float32 (2 threads, 2026-11-26).
PRECISIONS = ("fp32", "bf16")
TEST_SEED_OFFSET = 2_000_006_000  # held-out camera-pair items for evaluation (dataset seed = seed + this)


def rggb_offset(index_map: torch.Tensor) -> tuple[int, int]:
    """(dy, dx) of the R pixel (channel 0) in a 2x2 Bayer cell ``index_map`` (R, G, B = 0, 1, 2)."""
    im = index_map.tolist()
    for dy in (0, 1):
        for dx in (0, 1):
            if im[dy][dx] == 0 and im[1 - dy][1 - dx] == 2:
                return dy, dx
    raise ValueError(f"cfa: expected a 2x2 Bayer cell (R, G, G, B), got {im}")


class CameraPairSource:
    """Training batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` (source ``camera_pairs``).

    ``batch(batch_seed, n)`` renders items ``batch_seed * n + i`` (i < n) of one dataset (seed ``cfg.seed +
    seed_offset``), so a batch depends only on (seed, step, rank) like the other sources, and crops each to
    ``patch x patch`` RGGB. Returns (raw [B,1,P,P], camera_rgb [B,3,P,P], noise features [B,2] or None).
    """

    LENGTH = 2**62

    def __init__(self, cfg: dict, seed_offset: int = 0):
        from isettorch.data.camera_pairs import CameraPairDataset
        from isettorch.data.config import CAMERA_DEFAULTS
        from isettorch.isp.learned import BAYER_PATTERNS

        d = cfg.get("data", {})
        self.patch = int(d.get("patch", 80))
        if self.patch < 4 or self.patch % 2:
            raise ValueError(f"data.patch: expected an even size >= 4, got {self.patch}")
        self.noisy = bool(cfg.get("noise", {}).get("enabled", False))
        scene = dict(d.get("scene") or {}, height=self.patch + 2, width=self.patch + 2)
        camera = dict(d.get("camera") or {})
        pats = camera.get("cfa_patterns", CAMERA_DEFAULTS["cfa_patterns"])
        bad = [p for p in pats if str(p).upper() not in BAYER_PATTERNS]
        if bad:
            raise ValueError(f"data.camera.cfa_patterns: expected Bayer patterns {BAYER_PATTERNS}, got {bad}")
        # only the targets demosaicking uses: no colour targets, so 3 spectral projections instead of 6
        self.ds = CameraPairDataset(self.LENGTH, seed=int(cfg.get("seed", 0)) + int(seed_offset), scene=scene,
                                    camera=camera, targets=("noise_free_raw", "camera_rgb"))

    def indices(self, batch_seed: int, n: int) -> list[int]:
        return [(int(batch_seed) * n + i) % self.LENGTH for i in range(n)]

    def batch(self, batch_seed: int, n: int):
        return pair_batch(self.ds.get_batch(self.indices(batch_seed, n)), self.patch, self.noisy)


class StreamSource:
    """Training batches from :class:`isettorch.data.PairStream` (source ``stream``): scenes drawn and rendered by
    the Camera modules on ``data.device`` (default: the training device), batch ``step * world + rank`` of a stream
    seeded ``cfg.seed + seed_offset`` (so a batch depends only on (seed, step, rank) and ranks never share one),
    cropped on the device to ``patch x patch`` RGGB (no per-item host read). Same inputs and targets as
    :class:`CameraPairSource`: (raw [B,1,P,P], camera_rgb [B,3,P,P], noise features [B,2] or None)."""

    def __init__(self, cfg: dict, seed_offset: int = 0, device=None, batch: int | None = None):
        from isettorch.data import PairStream
        from isettorch.data.config import CAMERA_DEFAULTS
        from isettorch.isp.learned import BAYER_PATTERNS

        d = cfg.get("data", {})
        self.patch = int(d.get("patch", 80))
        if self.patch < 4 or self.patch % 2:
            raise ValueError(f"data.patch: expected an even size >= 4, got {self.patch}")
        self.noisy = bool(cfg.get("noise", {}).get("enabled", False))
        camera = dict(d.get("camera") or {})
        pats = camera.get("cfa_patterns", CAMERA_DEFAULTS["cfa_patterns"])
        bad = [p for p in pats if str(p).upper() not in BAYER_PATTERNS]
        if bad:
            raise ValueError(f"data.camera.cfa_patterns: expected Bayer patterns {BAYER_PATTERNS}, got {bad}")
        dev = torch.device(d.get("device") or device or "cpu")
        self.batch_size = int(batch or d.get("batch", 16))
        self.stream = PairStream(self.batch_size, seed=int(cfg.get("seed", 0)) + int(seed_offset),
                                 scene=dict(d.get("scene") or {}, height=self.patch + 2, width=self.patch + 2),
                                 camera=camera, targets=("noise_free_raw", "camera_rgb"), device=dev)

    def batch(self, step: int, n: int):
        if n != self.batch_size:
            raise ValueError(f"data.batch: the stream draws batches of {self.batch_size}, asked for {n}")
        b = self.stream.batch(int(step) * self.stream.world_size + self.stream.rank)
        src = b["raw"] if self.noisy else b["noise_free_raw"]
        # the offset (dy, dx) of the R pixel in each item's 2x2 cell, read on the device; the four shifted crops
        # are gathered, so every Bayer order reaches the network as RGGB
        pos = (b["meta"]["cfa"].reshape(n, 4) == 0).float().argmax(1)  # R is channel 0

        def crop(img):
            shifts = torch.stack([img[:, :, dy:dy + self.patch, dx:dx + self.patch] for dy in (0, 1) for dx in (0, 1)])
            return shifts[pos, torch.arange(n, device=img.device)]

        feats = None
        if self.noisy:
            feats = noise_features(torch.stack([b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]], 1).float())
        return crop(src).float(), crop(b["camera_rgb"]).float(), feats


def pair_batch(b: dict, patch: int, noisy: bool):
    """(raw, camera_rgb, noise features or None) cropped to ``patch`` RGGB from a camera-pair batch.

    Noise features: ``noise_features((a, b))`` with ``a = meta['noise_gain']``, ``b = meta['noise_floor_var']``
    (``var = a x + b`` in normalised units, the dataset's Poisson-Gaussian model)."""
    src = b["raw"] if noisy else b["noise_free_raw"]
    raws, rgbs = [], []
    for i in range(src.shape[0]):
        dy, dx = rggb_offset(b["meta"]["cfa"][i])
        raws.append(src[i, :, dy:dy + patch, dx:dx + patch])
        rgbs.append(b["camera_rgb"][i, :, dy:dy + patch, dx:dx + patch])
    feats = None
    if noisy:
        ab = torch.stack([b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]], 1).float()
        feats = noise_features(ab)
    return torch.stack(raws).float(), torch.stack(rgbs).float(), feats


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
    torch.set_num_threads(1)
    pool = ScenePool(cfg, seed, scene_size)
    return torch.stack([pool.render(i) for i in range(lo, hi)]).half()


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
        path = self._chunk_path(chunk)
        tmp = path.with_suffix(".tmp")
        torch.save(imgs, tmp)
        tmp.replace(path)

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


def noise_params(batch: int, cfg: dict, g: torch.Generator) -> torch.Tensor:
    """[B, 2] (a, b) of ``var = a x + b`` at log-uniform random gains (x relative to white = 1), the photon-transfer
    model (EMVA 1288; Foi et al. 2008): shot noise of ``x / a`` electrons, ``a = gain / full_well_e``, and
    ``b = a^2 (read_noise_e^2 + dsnu_e^2 + dark_e) + q^2 / 12`` (read noise, DSNU, dark-current shot noise after
    black-level subtraction, and quantisation with step ``q = 1 / (2^bits - 1)`` when ``bits`` is set)."""
    n = cfg["noise"]
    lo, hi = float(n.get("gain_min", 1.0)), float(n.get("gain_max", 32.0))
    gain = lo * (hi / lo) ** torch.rand(batch, generator=g)
    a = gain / float(n.get("full_well_e", 10000.0))
    add_e2 = float(n.get("read_noise_e", 3.0)) ** 2 + float(n.get("dsnu_e", 0.0)) ** 2 + float(n.get("dark_e", 0.0))
    bits = int(n.get("bits", 0) or 0)
    q2 = (1.0 / (2**bits - 1)) ** 2 / 12 if bits else 0.0
    return torch.stack([a, a * a * add_e2 + q2], 1)


def gaussian_params(batch: int, noise_cfg: dict, g: torch.Generator) -> torch.Tensor:
    """[B, 2] (a, b) = (0, sigma^2) with ``sigma`` log-uniform in [``sigma_min``, ``sigma_max``] (of the [0, 1]
    mosaic): signal-independent white Gaussian noise, the noise of ``isettorch demosaic-eval --noise-sigma``
    (``noise.gaussian_fraction`` of every batch is drawn this way)."""
    lo, hi = float(noise_cfg.get("sigma_min", 0.002)), float(noise_cfg.get("sigma_max", 0.08))
    if not 0 < lo <= hi:
        raise ValueError(f"noise.sigma_min, noise.sigma_max: expected 0 < sigma_min <= sigma_max, got {lo}, {hi}")
    sigma = lo * (hi / lo) ** torch.rand(batch, generator=g)
    return torch.stack([torch.zeros_like(sigma), sigma * sigma], 1)


# Pedestal below black: this many standard deviations of the largest noise floor, so read noise and DSNU at x = 0
# are not clipped by the sensor's low clip (EMVA 1288 section 4.6 asks for an offset that keeps the dark signal
# above zero).
_PEDESTAL_SIGMAS = 6.0


@functools.lru_cache(maxsize=8)
def _noise_sensor(bits: int, prnu_percent: float, dark_e: float, pedestal: float) -> Sensor:
    """The run's one noise sensor (mono CFA, fixed patterns redrawn per frame, 1 s exposure, unit analog gain),
    in normalised units: 1 V is white. ``bits``: an ADC with one bit of headroom (``bits + 1``) whose step is
    ``lsb = 1 / (2^bits - 1)`` V, so white sits at code ``2^bits - 1`` above a black level of ``pedestal`` codes;
    ``bits = 0``: an analog readout with a ``pedestal`` V offset. Either way the clip is about 2x white, above."""
    common_kw = dict(cfa="mono", exposure_s=1.0, fpn_mode="per_frame", shot_noise="poisson", noise_model="physical",
                     prnu_sigma_percent=prnu_percent, dark_current_e_per_s=dark_e)
    if bits:
        lsb = 1.0 / (2**bits - 1)
        return Sensor(adc_bits=bits + 1, black_level_dn=pedestal, voltage_swing_v=2 ** (bits + 1) * lsb,
                      output_units="dn", **common_kw)
    return Sensor(adc_bits=None, analog_offset_v=pedestal, voltage_swing_v=2.0 + pedestal, output_units="volts",
                  **common_kw)


def add_noise(raw: torch.Tensor, ab: torch.Tensor, g: torch.Generator, noise_cfg: dict | None = None
              ) -> torch.Tensor:
    """Sensor noise per image from :class:`isettorch.sensor.Sensor` (one sensor per run, per-image levels as [B]
    tensors): PRNU (``prnu_percent``, redrawn per frame), Poisson shot noise of signal + dark electrons
    (``dark_e``, its mean subtracted again as a dark frame), DSNU (``dsnu_e``), Gaussian read noise
    (``read_noise_e``) and ADC quantisation (``bits``).

    Photon-transfer model (EMVA 1288 release 4.0 eq. 6; Foi et al., IEEE TIP 17(10) 2008): a pixel with ``n_e``
    mean electrons reads ``y = K (n_e + n_d) + noise`` with variance ``K^2 (n_e + sigma_d^2) + sigma_q^2``. The
    input ``raw`` x (0 black, 1 white) holds ``n_e = x / a`` electrons with ``a`` = ``ab[:, 0]`` from
    :func:`noise_params`; choosing the conversion gain ``K = a`` V/e- (1 V = white, analog gain 1) gives
    ``var(y) = a^2 (x / a) + a^2 (read_e^2 + dsnu_e^2 + dark_e) + q^2 / 12 = a x + b``, the ``b`` of
    :func:`noise_params` with ``q = 1 / (2^bits - 1)`` the ADC step, so the network's noise inputs
    ``(sqrt(a), sqrt(b))`` describe the batch (plus PRNU's ``(prnu x)^2``, left out of them). Read noise and DSNU
    are passed in volts, ``read_e * a`` and ``dsnu_e * a``. The output is ``(DN - black) * q - a dark_e`` (or
    ``v - pedestal - a dark_e`` with no ADC), clipped only above about 2x white.
    With no ``noise_cfg`` it is :func:`isettorch.sensor.noise.poisson_gaussian` (shot + Gaussian floor ``b``)."""
    if not noise_cfg:
        return torch.stack([poisson_gaussian(raw[i].clamp_min(0), float(ab[i, 0]), float(ab[i, 1]) ** 0.5, g)
                            for i in range(raw.shape[0])])
    prnu = float(noise_cfg.get("prnu_percent", 0.0))
    dark, dsnu = float(noise_cfg.get("dark_e", 0.0)), float(noise_cfg.get("dsnu_e", 0.0))
    read, bits = float(noise_cfg.get("read_noise_e", 3.0)), int(noise_cfg.get("bits", 0) or 0)
    # the largest floor (at gain_max), in normalised units, sets the pedestal below black
    a_max = float(noise_cfg.get("gain_max", 32.0)) / float(noise_cfg.get("full_well_e", 10000.0))
    sigma_max = a_max * math.sqrt(read * read + dsnu * dsnu + dark)
    if bits:
        white = 2**bits - 1
        pedestal = float(math.ceil(_PEDESTAL_SIGMAS * sigma_max * white))
        if pedestal >= 2**bits:
            raise ValueError(f"noise: a {_PEDESTAL_SIGMAS:g} sigma pedestal of {pedestal:g} DN for a floor of "
                             f"{sigma_max:.4g} (white = 1) does not fit below the {bits}-bit white; expected a "
                             f"floor under {2**bits / white / _PEDESTAL_SIGMAS:.3g} (lower gain_max or noise)")
    else:
        pedestal = _PEDESTAL_SIGMAS * sigma_max
    sensor = _noise_sensor(bits, prnu, dark, pedestal)
    a = ab[:, 0].double()
    rate = raw.clamp_min(0).double() / a.reshape(-1, 1, 1, 1)  # electrons (1 s exposure)
    out = sensor.capture(rate, exposure_s=1.0, analog_gain=1.0, noise=True, generator=g,
                         conversion_gain_v_per_e=a, read_noise_v=read * a, dsnu_sigma_v=dsnu * a).data
    x = (out - pedestal) / (2**bits - 1) if bits else out - pedestal
    return (x - dark * a.reshape(-1, 1, 1, 1)).to(raw.dtype)


def noise_features(ab: torch.Tensor) -> torch.Tensor:
    return learned.noise_features(ab[:, 0], ab[:, 1]).to(ab.dtype)


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
        feats = noise_features(ab)
    return raw, rgb, feats


def load_teacher(cfg: dict, device) -> tuple[DemosaicNet | None, float, bool | str]:
    """(teacher network in eval mode or None, weight, self_ensemble) from the config's ``distill`` block."""
    d = cfg.get("distill") or {}
    if not d:
        return None, 0.0, False
    unknown = set(d) - {"teacher", "weight", "self_ensemble"}
    if unknown:
        raise ValueError(f"distill: unknown keys {sorted(unknown)}; expected teacher, weight, self_ensemble")
    weight = float(d.get("weight", 1.0))
    if not 0.0 < weight <= 1.0:
        raise ValueError(f"distill.weight: expected a value in (0, 1], got {weight}")
    ens = learned.check_self_ensemble(d.get("self_ensemble", True), "distill.self_ensemble")
    if "teacher" not in d:
        raise ValueError("distill.teacher: expected the path of a DemosaicNet checkpoint")
    teacher, _ = learned.load_checkpoint(d["teacher"], device=device)
    want = 2 if cfg.get("noise", {}).get("enabled", False) else 0
    if teacher.noise_inputs != want:
        raise ValueError(f"distill.teacher: {d['teacher']} takes {teacher.noise_inputs} noise inputs, this run's "
                         f"network {want}")
    return teacher, weight, ens


@torch.no_grad()
def distill_target(raw: torch.Tensor, rgb: torch.Tensor, feats: torch.Tensor | None, teacher: DemosaicNet,
                   weight: float, self_ensemble: bool | str) -> torch.Tensor:
    """``(1 - weight) * rgb + weight * teacher(raw)`` (float32); the teacher's output through the library's
    :func:`~isettorch.isp.learned.demosaic_learned` (RGGB), its self-ensemble when ``self_ensemble`` (True or
    ``"transpose"``: two passes; ``"dihedral"``: eight)."""
    out = learned.demosaic_learned(raw, "RGGB", model=teacher, noise=feats, self_ensemble=self_ensemble)
    return torch.lerp(rgb, out.float(), weight)


def make_validation(cfg: dict) -> list:
    """Held-out synthetic validation batches: scenes of their own seed (never drawn in training), whole scenes of
    ``val.size`` pixels, the training domain and noise; never Kodak/McMaster."""
    v = cfg.get("val", {})
    size = int(v.get("size", 128))
    vcfg = json.loads(json.dumps(cfg))
    vcfg["data"] = dict(cfg.get("data", {}), patch=size, hard_mining=0)
    vcfg["data"]["scene_size"] = size
    vseed = int(cfg.get("seed", 0)) + VAL_SEED_OFFSET
    n, bs = int(v.get("images", 32)), 8
    sampler = make_sampler(vcfg, VAL_SEED_OFFSET, seed=vseed, scene_size=size, batch=bs)
    if isinstance(sampler, StreamSource):  # whole batches of bs on the stream (the last one cut to n)
        return [tuple(None if x is None else x[:min(bs, n - i)] for x in make_batch(sampler, vcfg, vseed, bs, i // bs))
                for i in range(0, n, bs)]
    if isinstance(sampler, ScenePool):  # every validation image a different scene
        sampler.pool_size, sampler.refresh = bs, bs // 1
    return [make_batch(sampler, vcfg, vseed + i, min(bs, n - i), i // bs) for i in range(0, n, bs)]


@torch.no_grad()
def validate(net: torch.nn.Module, val: list, device) -> dict:
    net.eval()
    ps, pm = [], []
    for raw, rgb, feats in val:
        raw, rgb = raw.to(device), rgb.to(device)
        out = net(raw, None if feats is None else feats.to(device))
        ps.append(common.cpsnr(out, rgb, crop=4))
        pm.append(common.cpsnr(demosaic_malvar2004(raw), rgb, crop=4))
    net.train()
    v, m = float(torch.cat(ps).mean()), float(torch.cat(pm).mean())
    return {"val_cpsnr": v, "val_cpsnr_mhc": m, "val_gain_db": v - m}


@torch.no_grad()
def benchmark(net: torch.nn.Module, folder: str, device, crop: int = 10, limit: int | None = None) -> float:
    """Mean CPSNR on a benchmark folder with ``isettorch demosaic-eval``'s code (RGGB, noise-free, clip, crop;
    a noise-input network gets zero noise); reporting only."""
    from isettorch.isp.evaluation import evaluate_demosaic, load_images

    net.eval()
    items = load_images(folder)[:limit]
    res = evaluate_demosaic(items, "learned", "RGGB", crop, model=net, device=device)
    net.train()
    return res["mean_cpsnr"]


def progress(step: int, wall_s: float, cfg: dict) -> float:
    """Fraction of the run done: by steps, or by wall time when ``optim.time_budget_s`` is set (whichever first)."""
    o = cfg["optim"]
    t = step / max(1, int(o["steps"]))
    budget = float(o.get("time_budget_s", 0) or 0)
    return max(t, wall_s / budget) if budget > 0 else t


def lr_at(step: int, frac: float, cfg: dict) -> float:
    o = cfg["optim"]
    warm = int(o.get("warmup", 50))
    lr, lr_min = float(o["lr"]), float(o.get("lr_min", 1e-5))
    if step < warm:
        return lr * (step + 1) / warm
    t = min(1.0, frac)
    return lr_min + 0.5 * (lr - lr_min) * (1 + math.cos(math.pi * t))  # cosine decay (Loshchilov & Hutter 2017)


class AdaptiveGradClip:
    """``optim.clip_grad_factor: k`` (> 0): scale the gradient down to ``k`` times the running mean (EMA, 0.99) of
    the earlier steps' clipped gradient norms when its norm exceeds that, so one outlier batch cannot throw Adam off
    (a residual 64 x 13 at lr 1e-3 lost 4 dB of validation CPSNR in one such step). Scale-free: no absolute norm to
    tune. ``state`` goes into the checkpoint, so a resumed run clips exactly as the uninterrupted one."""

    def __init__(self, factor: float, state: dict | None = None):
        if factor < 0:
            raise ValueError(f"optim.clip_grad_factor: expected >= 0 (0 = off), got {factor}")
        self.factor, self.ema = float(factor), (state or {}).get("ema")

    def state(self) -> dict:
        return {"ema": self.ema}

    def __call__(self, params) -> float:
        """Clip the gradients of ``params`` in place; returns the norm before clipping."""
        params = [p for p in params if p.grad is not None]
        norm = float(torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in params])))
        if not self.factor:
            return norm
        limit = math.inf if self.ema is None else self.factor * self.ema
        if norm > limit:
            for p in params:
                p.grad.mul_(limit / norm)
        kept = min(norm, limit)
        self.ema = kept if self.ema is None else 0.99 * self.ema + 0.01 * kept
        return norm


def save_checkpoint(path: Path, net, opt, step: int, cfg: dict, best: float, history: list, wall_s: float,
                    clip: AdaptiveGradClip | None = None) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "step": step, "net_config": net.config(),
                "train_config": json.dumps(cfg), "best_val_cpsnr": best, "history": json.dumps(history),
                "wall_s": wall_s, "grad_clip": json.dumps(clip.state() if clip else {})}, tmp)
    tmp.replace(path)


def describe_data(cfg: dict) -> str:
    """One line saying what the network was trained on (for the model card)."""
    d, n = cfg.get("data", {}), cfg.get("noise", {})
    src = d.get("source", "natural")
    if src == "camera_pairs":
        what = "isettorch.data.camera_pairs (scene -> optics -> isettorch sensor, its noise model)"
    elif src == "stream":
        what = (f"isettorch.data.PairStream on {d.get('device') or 'the training device'} (scene -> optics -> "
                f"isettorch sensor, its noise model)")
    elif src == "natural":
        off = list(d.get("disable") or [])
        what = (f"isettorch.data.natural scenes ({'all components' if not off else 'without ' + ', '.join(off)}; "
                f"overrides {d.get('natural') or {}}), random camera sensitivities, white-balanced")
    else:
        what = "isettorch.data.generate_scene scenes, random camera sensitivities, white-balanced"
    dom = d.get("domain", "mixed")
    dom_txt = f"{dom} domain" + (f" ({d.get('encoded_fraction', 0.8)} encoded)" if dom == "mixed" else "")
    noise = (f"; Poisson-Gaussian noise at gains {n.get('gain_min', 1.0)}-{n.get('gain_max', 32.0)}"
             if n.get("enabled") else "; noise-free")
    return (f"{what}; {d.get('patch', 80)} px patches, batch {d.get('batch', 16)}, {dom_txt}{noise}; selected on "
            f"held-out synthetic scenes; never Kodak/McMaster")


def write_model_card(path: Path, record: dict, net) -> None:
    """A short markdown model card beside the checkpoints: command, config, data, steps, wall time, hardware."""
    lines = ["# DemosaicNet model card", "", f"- command: `{record['command']}`",
             f"- network: DemosaicNet {net.config()}, {sum(p.numel() for p in net.parameters())} parameters",
             f"- data: {record['data']}", f"- steps: {record['steps']} (world size {record['world_size']})",
             f"- wall time: {record['wall_s']} s", f"- hardware: `{json.dumps(record['hardware'])}`",
             f"- best held-out synthetic validation CPSNR: {record['best_val_cpsnr']}",
             f"- last evaluation: `{json.dumps(record['final'], default=str)}`", "",
             "## Config", "", "```json", json.dumps(record["config"], indent=2, default=str), "```", ""]
    path.write_text("\n".join(lines))


def init_state(ck: dict, net: DemosaicNet, name: str = "init") -> dict:
    """The state dict that starts ``net`` from checkpoint ``ck``, computing the same function as ``ck``'s network:

    - equal configs: its weights as they are;
    - more ``noise_inputs`` (a noise-free checkpoint starting a joint network of the same width and depth): the extra
      input channels of the first convolution zeroed, so the joint network starts as the noise-free one;
    - a deeper residual network of the same width (``depth`` larger, both ``residual``): the checkpoint's blocks,
      then new blocks whose second convolution is zero, each an exact identity at the start (Net2DeeperNet, Chen,
      Goodfellow & Shlens, ICLR 2016, for residual blocks), while their first convolutions keep ``net``'s He
      initialisation so the new blocks train from the first step.
    """
    old, new = {"noise_inputs": 0, **ck["net_config"]}, net.config()
    state = {k: v.float() for k, v in ck["model"].items()}
    if old == new:
        return state

    def but(cfg: dict, key: str) -> dict:
        return {k: v for k, v in cfg.items() if k != key}

    if old.get("residual") and new["depth"] > old["depth"] and but(old, "depth") == but(new, "depth"):
        for key, value in net.state_dict().items():
            if key not in state:  # a new block: body.<i>.conv1 as initialised, body.<i>.conv2 zero
                state[key] = torch.zeros_like(value) if ".conv2." in key else value.detach().clone().float()
        return state
    if but(old, "noise_inputs") != but(new, "noise_inputs") or old["noise_inputs"] > new["noise_inputs"]:
        raise ValueError(f"{name}: net_config {old} cannot start a network {new} (expected the same channels and "
                         f"depth, and at most its noise_inputs; or a deeper residual network of the same channels "
                         f"and noise_inputs)")
    w = state["body.0.weight"]
    extra = new["noise_inputs"] - old["noise_inputs"]
    state["body.0.weight"] = torch.cat([w, w.new_zeros(w.shape[0], extra, *w.shape[2:])], 1)
    return state


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--out", default=None, help="output folder (default: config 'out')")
    ap.add_argument("--steps", type=int, default=None, help="override optim.steps")
    ap.add_argument("--resume", default=None, help="checkpoint to resume from (default: OUT/last.pt if present)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads per process")
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    ap.add_argument("--set", nargs="*", default=[], help="config overrides key.sub=value")
    ap.add_argument("--stop-after", type=int, default=None,
                    help="stop (with a checkpoint) after this many steps in this invocation; resume later")
    add_quiet_argument(ap, "--no-progress")
    args = ap.parse_args(argv)

    cfg = common.load_config(args.config, args.set)
    if args.steps is not None:
        cfg.setdefault("optim", {})["steps"] = args.steps
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    rank, world, is_dist = common.dist_setup(device)
    threads = args.threads or int(cfg.get("threads", 0))
    if threads:
        torch.set_num_threads(threads)
    if device.type == "cuda" and is_dist:
        local, n_gpu = int(os.environ.get("LOCAL_RANK", rank)), torch.cuda.device_count()
        if local >= n_gpu:  # NCCL cannot share one GPU between processes
            raise ValueError(f"--device cuda: torchrun started {world} processes, each needs a GPU of its own and "
                             f"this node has {n_gpu}; use --device cpu or --nproc_per_node {n_gpu}")
        device = torch.device("cuda", local)
    out = Path(args.out or cfg.get("out", "out/train_demosaic"))
    out.mkdir(parents=True, exist_ok=True)
    seed = int(cfg.get("seed", 0))

    net_cfg = dict(cfg.get("net", {}))
    if cfg.get("noise", {}).get("enabled", False):
        net_cfg["noise_inputs"] = 2
    torch.manual_seed(seed)  # identical initial weights on every rank
    net = DemosaicNet(**net_cfg).to(device)
    precision = str(cfg["optim"].get("precision", "fp32"))
    if precision not in PRECISIONS:
        raise ValueError(f"optim.precision: expected one of {PRECISIONS}, got {precision!r}")
    if precision == "bf16":  # oneDNN's bfloat16 convolutions are fastest on channels-last weights
        net = net.to(memory_format=torch.channels_last)
    opt = torch.optim.Adam(net.parameters(), lr=float(cfg["optim"]["lr"]))
    step, best, history, wall0 = 0, -math.inf, [], 0.0
    clip_state = None
    resume = Path(args.resume) if args.resume else out / "last.pt"
    init = cfg.get("init")
    if init and not resume.is_file():  # start from another checkpoint's weights (fresh optimizer and schedule)
        ck = torch.load(init, map_location="cpu", weights_only=True)
        net.load_state_dict(init_state(ck, net, str(init)))
        if rank == 0:
            print(f"initialised from {init}", flush=True)
    if resume.is_file():
        ck = torch.load(resume, map_location="cpu", weights_only=True)
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step, best = int(ck["step"]), float(ck["best_val_cpsnr"])
        history, wall0 = json.loads(ck["history"]), float(ck.get("wall_s", 0.0))
        clip_state = json.loads(ck.get("grad_clip", "{}"))
        old = json.loads(ck["train_config"])
        if (old.get("data"), old.get("val"), old.get("noise")) != (cfg.get("data"), cfg.get("val"), cfg.get("noise")):
            best = -math.inf  # the validation set changed: earlier best scores are not comparable
            if rank == 0:
                print("data/val config changed since the checkpoint: best-model selection restarts", flush=True)
        if rank == 0:
            print(f"resumed from {resume} at step {step}", flush=True)
    clip = AdaptiveGradClip(float(cfg["optim"].get("clip_grad_factor", 0.0) or 0.0), clip_state)
    model = net
    if is_dist:
        model = torch.nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda"
                                                          else None)

    # each rank renders its own scenes; data.scene_seed (default: the run's seed) lets runs share scenes (a bank)
    scene_seed = int(cfg.get("data", {}).get("scene_seed", seed))
    sampler = make_sampler(cfg, seed=scene_seed * 1_000_003 + rank, progress=rank == 0 and not args.quiet,
                           device=device, batch=int(cfg["data"].get("batch", 16)) // world)
    val = make_validation(cfg) if rank == 0 else None
    teacher, distill_w, distill_ens = load_teacher(cfg, device)
    total = int(cfg["optim"]["steps"])
    batch = int(cfg["data"].get("batch", 16)) // world
    loss_kind = cfg["optim"].get("loss", "l2")
    val_every = int(cfg.get("val", {}).get("every", 200))
    ckpt_every = int(cfg.get("checkpoint_every", 100))
    bench = cfg.get("eval", {}).get("benchmarks", {}) or {}
    bench_every = int(cfg.get("eval", {}).get("every", 0))
    t_start = time.time()
    # the bar on stderr (rank 0 only); the validation rows go to stdout through pbar.write (kept under --quiet)
    pbar = progress_bar(total=total, initial=step, desc="train", unit="step", quiet=rank != 0 or args.quiet)
    run_loss, run_n = 0.0, 0
    frac = progress(step, wall0, cfg)
    stop_at = step + args.stop_after if args.stop_after else None
    while frac < 1.0 and (stop_at is None or step < stop_at):
        lr = lr_at(step, frac, cfg)
        for grp in opt.param_groups:
            grp["lr"] = lr
        raw, rgb, feats = make_batch(sampler, cfg, seed * 1_000_003 + step * 1009 + rank, batch, step)
        raw, rgb = raw.to(device), rgb.to(device)
        if teacher is not None:  # the teacher in the run's precision: its bf16 outputs differ from float32 by an
            # MSE of 1.3e-7 on held-out v5 scenes, 1/55 of the one-pass - ensemble MSE the student is taught (7.2e-6)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
                rgb = distill_target(raw, rgb, None if feats is None else feats.to(device), teacher, distill_w,
                                     distill_ens)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            outp = model(raw, None if feats is None else feats.to(device))
        outp = outp.float()
        loss = F.l1_loss(outp, rgb) if loss_kind == "l1" else F.mse_loss(outp, rgb)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        clip(net.parameters())
        opt.step()
        step += 1
        run_loss = run_loss + loss.detach()  # on the device: read back only when logging (no sync per step)
        run_n += 1
        pbar.update(1)
        if step % LOG_EVERY == 0:
            pbar.set_postfix(loss=f"{loss.item():.4f}", lr=f"{lr:.1e}")
        frac = progress(step, wall0 + time.time() - t_start, cfg)
        if is_dist:  # every rank stops at the same step
            import torch.distributed as dist

            f = torch.tensor([frac], dtype=torch.float64)
            dist.all_reduce(f, op=dist.ReduceOp.MAX)
            frac = float(f)
        last = frac >= 1.0 or step == stop_at
        if rank == 0 and (step % val_every == 0 or last):
            row = {"step": step, "wall_s": round(wall0 + time.time() - t_start, 1), "lr": lr,
                   "train_loss": float(run_loss) / max(run_n, 1)}
            run_loss, run_n = 0.0, 0
            row.update(validate(net, val, device))
            if bench and bench_every and (step % bench_every == 0 or last):
                for name, folder in bench.items():
                    row[f"{name}_crop10"] = benchmark(net, data_path(folder), device)
            history.append(row)
            msg = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
            pbar.write(msg, file=sys.stdout)
            if row["val_cpsnr"] > best:
                best = row["val_cpsnr"]
                save_checkpoint(out / "best.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start,
                                clip)
            common.write_csv(out / "history.csv", history)
            cols = [("train_loss", f"train {loss_kind} loss"), ("val_cpsnr", "val CPSNR (dB)"),
                    ("val_gain_db", "val CPSNR - MHC (dB)")]
            cols += [(f"{k}_crop10", f"{k} CPSNR crop10 (dB)") for k in bench if any(f"{k}_crop10" in r
                                                                                   for r in history)]
            common.plot_curves(out / "curves.png", history, cols, f"DemosaicNet {net.config()}")
        if rank == 0 and (step % ckpt_every == 0 or last):
            save_checkpoint(out / "last.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start,
                            clip)
    pbar.close()
    if rank == 0:
        record = {"command": " ".join(["python training/train_demosaic.py", *sys.argv[1:]]) if argv is None else argv,
                  "config": cfg, "world_size": world, "steps": step, "best_val_cpsnr": best,
                  "wall_s": round(wall0 + time.time() - t_start, 1), "hardware": common.hardware(),
                  "final": history[-1] if history else {}}
        record["data"] = describe_data(cfg)
        (out / "record.json").write_text(json.dumps(record, indent=2, default=str))
        write_model_card(out / "MODEL_CARD.md", record, net)
    common.dist_cleanup(is_dist)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
