"""Write camera-pair datasets to disk as shards: resumable, atomic, checksummed, rank-aware.

Layout of ``out/``:

* ``shard-00000.pt`` ...: ``torch.save`` of a dict of plain tensors (load with ``torch.load(weights_only=True)``):
  ``raw [n, 1, H, W]``, ``noise_free_raw``, ``camera_rgb``, ``xyz``, ``linear_srgb``, ``srgb [n, 3, H, W]`` and
  ``meta`` (a dict of ``[n, ...]`` tensors, see ``camera_pairs.META_KEYS``). Shard ``f`` holds items
  ``f * shard_size`` ... ``min((f + 1) * shard_size, count) - 1`` in order.
* ``shard-00000.json``: sidecar with the shard's sha256, item range and the config hash; written (atomically)
  only after its shard file is complete, so a shard with a valid sidecar and matching checksum is complete.
* ``manifest.json``: the config, its hash, ``count``, ``shard_size`` and every finished shard's record;
  ``"complete": true`` when all shards are there.

Each file is written to a temporary name and renamed (``os.replace``, atomic on POSIX), so a run killed at
any point leaves only complete shards (and possibly a stale ``*.tmp*`` file). Items depend only on
``(seed, index)``, so a resumed run writes byte-identical shards.

Work split: files are dealt round-robin to ``num_shards x world_size`` processes; process
``shard * world_size + rank`` takes files ``f`` with ``f % (num_shards * world_size) == that``. Under
``torchrun`` the rank and world size come from the ``RANK`` / ``WORLD_SIZE`` environment variables.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable
from pathlib import Path

import torch

from .camera_pairs import GENERATOR_VERSION, CameraPairDataset
from .config import merge_config

__all__ = ["write_dataset", "config_hash", "sha256_file", "verify_dataset", "FORMAT_VERSION"]

FORMAT_VERSION = 1


def config_hash(config: dict, count: int) -> str:
    """sha256 of the canonical JSON of the (validated) config, the item count, the file format and the generator
    version (``camera_pairs.GENERATOR_VERSION``: shards written by a generator that draws other items never match)."""
    blob = json.dumps({"config": config, "count": int(count), "format": FORMAT_VERSION,
                       "generator": GENERATOR_VERSION}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _atomic_save(obj, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    torch.save(obj, tmp)
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _shard_names(f: int) -> tuple[str, str]:
    return f"shard-{f:05d}.pt", f"shard-{f:05d}.json"


def _shard_complete(out: Path, f: int, chash: str) -> dict | None:
    """The sidecar record if shard ``f`` is complete and matches the config, else None."""
    pt, js = _shard_names(f)
    try:
        rec = json.loads((out / js).read_text())
    except (OSError, ValueError):
        return None
    if rec.get("config_sha256") != chash or not (out / pt).is_file():
        return None
    if sha256_file(out / pt) != rec.get("sha256"):
        return None
    return rec


def _env_int(name: str, default: int) -> int:
    v = os.environ.get(name)
    if v is None or v == "":
        return default
    try:
        return int(v)
    except ValueError as err:
        raise ValueError(f"{name}: expected an integer environment variable, got {v!r}") from err


def write_dataset(config: dict | None, out, count: int, *, shard: int = 0, num_shards: int = 1, workers: int = 0,
                  rank: int | None = None, world_size: int | None = None, progress: bool = True,
                  on_shard_written: Callable[[int], None] | None = None) -> dict:
    """Generate ``count`` camera pairs from ``config`` (keys of ``SYNTH_DEFAULTS``) into shards under ``out``.

    Args:
        shard, num_shards: this invocation's part of the files (``--shard i --num-shards K``).
        workers: DataLoader worker processes (each builds whole shards).
        rank, world_size: default from the ``RANK`` / ``WORLD_SIZE`` environment variables (torchrun), else 0 / 1.
        on_shard_written: called with the file number after each shard is committed (tests use it to abort).
    Returns:
        the manifest dict (also written to ``out/manifest.json``).
    """
    cfg = merge_config(config)
    count = int(count)
    if count < 1:
        raise ValueError(f"count: expected a positive number of items, got {count}")
    rank = _env_int("RANK", 0) if rank is None else int(rank)
    world_size = _env_int("WORLD_SIZE", 1) if world_size is None else int(world_size)
    if not (num_shards >= 1 and 0 <= shard < num_shards):
        raise ValueError(f"shard: expected 0 <= shard < num_shards ({num_shards}), got {shard}")
    if not (world_size >= 1 and 0 <= rank < world_size):
        raise ValueError(f"rank: expected 0 <= rank < world_size ({world_size}), got {rank}")
    if workers < 0:
        raise ValueError(f"workers: expected a non-negative number of worker processes, got {workers}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    chash = config_hash(cfg, count)
    old = out / "manifest.json"
    if old.is_file():
        try:
            prev = json.loads(old.read_text())
        except ValueError:
            prev = {}
        if prev.get("config_sha256") not in (None, chash):
            raise ValueError(f"out: {str(out)!r} holds a dataset made with another config, count or generator "
                             f"version (config_sha256 {prev.get('config_sha256')}, generator version "
                             f"{prev.get('generator_version', 1)}, this one {GENERATOR_VERSION}); use a new folder")
    size = int(cfg["shard_size"])
    if size < 1:
        raise ValueError(f"shard_size: expected a positive number of items per shard, got {size}")
    n_files = math.ceil(count / size)
    procs, me = num_shards * world_size, shard * world_size + rank
    mine = [f for f in range(n_files) if f % procs == me]
    todo = [f for f in mine if _shard_complete(out, f, chash) is None]

    dtype = torch.float64 if cfg["dtype"] == "float64" else torch.float32
    ds = CameraPairDataset(count, seed=int(cfg["seed"]), scene=cfg["scene"], camera=cfg["camera"], dtype=dtype,
                           targets=cfg["targets"])
    batches = [list(range(f * size, min((f + 1) * size, count))) for f in todo]
    if batches:
        # each shard is generated as one batch (CameraPairDataset.get_batch; bitwise the collated items)
        loader = torch.utils.data.DataLoader(ds, sampler=batches, batch_size=None, num_workers=workers)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(todo), unit="shard", desc=f"synth rank {me}/{procs}", dynamic_ncols=True)
        try:
            for f, batch in zip(todo, loader):
                pt, js = _shard_names(f)
                _atomic_save(batch, out / pt)
                rec = {"file": pt, "sha256": sha256_file(out / pt), "first_index": f * size,
                       "count": int(batch["raw"].shape[0]), "config_sha256": chash, "format_version": FORMAT_VERSION}
                _atomic_write_bytes(out / js, json.dumps(rec, indent=1, sort_keys=True).encode())
                if bar is not None:
                    bar.update(1)
                if on_shard_written is not None:
                    on_shard_written(f)
        finally:
            if bar is not None:
                bar.close()
    return _write_manifest(out, cfg, chash, count, size, n_files)


def _write_manifest(out: Path, cfg: dict, chash: str, count: int, size: int, n_files: int) -> dict:
    shards = []
    for f in range(n_files):
        try:
            rec = json.loads((out / _shard_names(f)[1]).read_text())
        except (OSError, ValueError):
            continue
        if rec.get("config_sha256") == chash:
            shards.append(rec)
    manifest = {"format_version": FORMAT_VERSION, "generator_version": GENERATOR_VERSION, "config": cfg,
                "config_sha256": chash, "count": count,
                "shard_size": size, "num_files": n_files, "shards": shards, "complete": len(shards) == n_files}
    _atomic_write_bytes(out / "manifest.json", json.dumps(manifest, indent=1, sort_keys=True).encode())
    return manifest


def verify_dataset(out) -> list[str]:
    """Check every shard listed in ``out/manifest.json`` against its sha256; returns the problems found."""
    out = Path(out)
    try:
        manifest = json.loads((out / "manifest.json").read_text())
    except (OSError, ValueError) as err:
        return [f"manifest.json: unreadable ({err})"]
    problems = []
    for rec in manifest.get("shards", []):
        p = out / rec["file"]
        if not p.is_file():
            problems.append(f"{rec['file']}: missing")
        elif sha256_file(p) != rec["sha256"]:
            problems.append(f"{rec['file']}: checksum mismatch")
    if not manifest.get("complete"):
        problems.append(f"incomplete: {len(manifest.get('shards', []))} of {manifest.get('num_files')} shards")
    return problems
