"""Camera-pair batch sources of the demosaic trainer: ``data.source: camera_pairs``
(:class:`CameraPairSource`, :class:`isettorch.data.camera_pairs.CameraPairDataset`) and ``data.source: stream``
(:class:`StreamSource`, :class:`isettorch.data.PairStream` on a device); items cropped to RGGB (:func:`pair_batch`).
Part of ``training/train_demosaic.py``."""

from __future__ import annotations

import torch

from training.demosaic_noise import noise_features

TEST_SEED_OFFSET = 2_000_006_000  # held-out camera-pair items for evaluation (dataset seed = seed + this)


def rggb_offset(index_map: torch.Tensor) -> tuple[int, int]:
    """(dy, dx) of the R pixel (channel 0) in a 2x2 Bayer cell ``index_map`` (R, G, B = 0, 1, 2)."""
    im = index_map.tolist()
    for dy in (0, 1):
        for dx in (0, 1):
            if im[dy][dx] == 0 and im[1 - dy][1 - dx] == 2:
                return dy, dx
    raise ValueError(f"cfa: expected a 2x2 Bayer cell (R, G, G, B), got {im}")


def _source_config(cfg: dict) -> tuple[int, bool, dict]:
    """``(patch, noisy, data.camera)`` of a camera-pair source, checked: an even patch >= 4, Bayer CFA patterns."""
    d = cfg.get("data", {})
    patch = int(d.get("patch", 80))
    if patch < 4 or patch % 2:
        raise ValueError(f"data.patch: expected an even size >= 4, got {patch}")
    return patch, bool(cfg.get("noise", {}).get("enabled", False)), dict(d.get("camera") or {})


def _check_bayer_patterns(camera: dict) -> None:
    from isettorch.data.config import CAMERA_DEFAULTS
    from isettorch.isp.learned import BAYER_PATTERNS

    pats = camera.get("cfa_patterns", CAMERA_DEFAULTS["cfa_patterns"])
    bad = [p for p in pats if str(p).upper() not in BAYER_PATTERNS]
    if bad:
        raise ValueError(f"data.camera.cfa_patterns: expected Bayer patterns {BAYER_PATTERNS}, got {bad}")


def _meta_noise_features(meta: dict) -> torch.Tensor:
    """``noise_features((a, b))`` with ``a = meta['noise_gain']``, ``b = meta['noise_floor_var']`` (``var = a x +
    b`` in normalised units, the dataset's Poisson-Gaussian model)."""
    return noise_features(torch.stack([meta["noise_gain"], meta["noise_floor_var"]], 1).float())


class CameraPairSource:
    """Training batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` (source ``camera_pairs``).

    ``batch(batch_seed, n)`` renders items ``batch_seed * n + i`` (i < n) of one dataset (seed ``cfg.seed +
    seed_offset``), so a batch depends only on (seed, step, rank) like the other sources, and crops each to
    ``patch x patch`` RGGB. Returns (raw [B,1,P,P], camera_rgb [B,3,P,P], noise features [B,2] or None).
    """

    LENGTH = 2**62

    def __init__(self, cfg: dict, seed_offset: int = 0):
        from isettorch.data.camera_pairs import CameraPairDataset

        d = cfg.get("data", {})
        self.patch, self.noisy, camera = _source_config(cfg)
        scene = dict(d.get("scene") or {}, height=self.patch + 2, width=self.patch + 2)
        _check_bayer_patterns(camera)
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
    :class:`CameraPairSource`: (raw [B,1,P,P], camera_rgb [B,3,P,P], noise features [B,2] or None).
    ``data.camera_config`` (instead of ``data.camera``): one camera for every item (:func:`stream_camera`), e.g. a
    calibrated sensor (``isettorch calibrate --out``), for a camera-specific joint model.

    ``data.stream_chunk`` (default 4 on a CPU, 64 on an accelerator): the stream renders ``chunk`` training batches
    at once, as one stream batch of ``chunk x batch`` items, and step ``s`` takes slice ``s % chunk`` of chunk ``s //
    chunk`` (stream batch ``(s // chunk) * world + rank``), the chunk kept until its last slice is used. A stream
    batch costs a few thousand torch calls whatever its size (``docs/training_in_the_loop.md``): on a GPU a training
    step of 16 items would otherwise wait for the launches of a whole stream batch, and on 2 CPU cores a
    ``train_demosaic`` step (batch 16, 80 px) took 72 ms with chunk 4 against 78 ms with chunk 1 and 89 ms fed by
    ``camera_pairs`` (``benchmarks/THROUGHPUT.md``, 2026-11-29). A step's batch still depends only on (seed, step,
    rank, chunk), so a resumed run gets the batches it would have had."""

    #: the default ``data.stream_chunk`` by device type
    CPU_CHUNK, ACCELERATOR_CHUNK = 4, 64

    def __init__(self, cfg: dict, seed_offset: int = 0, device=None, batch: int | None = None):
        from isettorch.data import PairStream

        d = cfg.get("data", {})
        self.patch, self.noisy, camera = _source_config(cfg)
        if d.get("camera_config") is not None:  # one given camera (camera-specific training), not drawn cameras
            if camera:
                raise ValueError("data.camera, data.camera_config: give one of them (drawn cameras or one camera "
                                 "config), got both")
            camera = stream_camera(d["camera_config"], self.patch + 2)
        else:
            _check_bayer_patterns(camera)
        dev = torch.device(d.get("device") or device or "cpu")
        if dev.type == "cpu":  # large temporaries and the stream's threads stay in this process's main heap
            from isettorch.data.config import tune_allocator

            tune_allocator()
        self.batch_size = int(batch or d.get("batch", 16))
        chunk = d.get("stream_chunk")
        if chunk is None:
            chunk = self.CPU_CHUNK if dev.type == "cpu" else self.ACCELERATOR_CHUNK
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise ValueError(f"data.stream_chunk: expected a positive integer (training batches per stream batch), "
                             f"got {chunk!r}")
        self.chunk = chunk
        # a step takes one stream batch with batch(k): on a CPU in at least two parts, on two threads (72 ms a step
        # against 89 ms fed by the stream's iterator, whose rendering threads then compete with the step's)
        n = self.batch_size * chunk
        parts = None if dev.type != "cpu" or n < 8 or isinstance(camera, torch.nn.Module) else max(2, n // 32)
        self.stream = PairStream(n, seed=int(cfg.get("seed", 0)) + int(seed_offset),
                                 scene=dict(d.get("scene") or {}, height=self.patch + 2, width=self.patch + 2),
                                 camera=camera, targets=("noise_free_raw", "camera_rgb"), device=dev, parts=parts)
        self._chunk_cache: tuple | None = None  # (stream batch index, (raw, camera_rgb, features or None))

    def batch(self, step: int, n: int):
        if n != self.batch_size:
            raise ValueError(f"data.batch: the stream draws batches of {self.batch_size}, asked for {n}")
        c, j = divmod(int(step), self.chunk)
        k = c * self.stream.world_size + self.stream.rank
        if self._chunk_cache is None or self._chunk_cache[0] != k:
            self._chunk_cache = (k, self._crops(self.stream.batch(k)))
        sl = slice(j * n, (j + 1) * n)
        raw, rgb, feats = self._chunk_cache[1]
        return raw[sl], rgb[sl], None if feats is None else feats[sl]

    def _crops(self, b: dict):
        """(raw, camera_rgb, noise features or None) of a stream batch, each item cropped to ``patch`` RGGB."""
        n = b["raw"].shape[0]
        src = b["raw"] if self.noisy else b["noise_free_raw"]
        # the offset (dy, dx) of the R pixel in each item's 2x2 cell, read on the device; the four shifted crops
        # are gathered, so every Bayer order reaches the network as RGGB
        pos = (b["meta"]["cfa"].reshape(n, 4) == 0).float().argmax(1)  # R is channel 0

        def crop(img):
            shifts = torch.stack([img[:, :, dy:dy + self.patch, dx:dx + self.patch] for dy in (0, 1) for dx in (0, 1)])
            return shifts[pos, torch.arange(n, device=img.device)]

        feats = _meta_noise_features(b["meta"]) if self.noisy else None
        return crop(src).float(), crop(b["camera_rgb"]).float(), feats


def stream_camera(config, size: int):
    """The :class:`isettorch.Camera` of ``data.camera_config`` (a camera YAML path, a built-in name or a mapping, as
    :meth:`isettorch.Camera.from_config` takes; e.g. a ``sensor:`` section written by ``isettorch calibrate``) with a
    ``size x size`` sensor (the stream's item size), for :class:`StreamSource`: every item is rendered through this
    camera as configured (its sensor's exposure, auto-exposure, analog gain and noise). Its CFA must be Bayer."""
    import copy

    from isettorch.camera import Camera, load_config
    from isettorch.isp.learned import BAYER_PATTERNS

    cfg = copy.deepcopy(config) if isinstance(config, dict) else load_config(config)
    if not isinstance(cfg.get("sensor"), dict):
        raise ValueError(f"data.camera_config: expected a camera config with a sensor: section, got {config!r}")
    cfg["sensor"] = dict(cfg["sensor"], rows=int(size), cols=int(size))
    camera = Camera.from_config(cfg)
    pattern = "".join("".join(r) for r in camera.sensor.cfa.cell)
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"data.camera_config: the sensor's CFA must be a Bayer pattern {BAYER_PATTERNS}, got "
                         f"{pattern!r}")
    return camera


def pair_batch(b: dict, patch: int, noisy: bool):
    """(raw, camera_rgb, noise features or None) cropped to ``patch`` RGGB from a camera-pair batch (noise features
    from the metadata, :func:`_meta_noise_features`)."""
    src = b["raw"] if noisy else b["noise_free_raw"]
    raws, rgbs = [], []
    for i in range(src.shape[0]):
        dy, dx = rggb_offset(b["meta"]["cfa"][i])
        raws.append(src[i, :, dy:dy + patch, dx:dx + patch])
        rgbs.append(b["camera_rgb"][i, :, dy:dy + patch, dx:dx + patch])
    feats = _meta_noise_features(b["meta"]) if noisy else None
    return torch.stack(raws).float(), torch.stack(rgbs).float(), feats
