"""Write camera-pair datasets to disk as shards: resumable, atomic, checksummed, rank-aware.

Layout of ``out/``:

* ``shard-00000.pt`` ...: ``torch.save`` of a dict of plain tensors (load with ``torch.load(weights_only=True)``):
  ``raw``, ``noise_free_raw [n, 1, H, W]``, ``camera_rgb``, ``xyz``, ``linear_srgb``, ``srgb [n, 3, H, W]`` and
  ``meta`` (a dict of ``[n, ...]`` tensors, see ``camera_pairs.META_KEYS``). Shard ``f`` holds items
  ``f * shard_size`` ... ``min((f + 1) * shard_size, count) - 1`` in order.
* ``shard-00000.json``: sidecar with the shard's sha256, item range and the config hash; written (atomically)
  only after its shard file is complete, so a shard with a valid sidecar and matching checksum is complete.
* ``manifest.json``: the config, its hash, ``count``, ``shard_size`` and every finished shard's record;
  ``"complete": true`` when all shards are there.

Each file is written to a temporary name, flushed to disk and renamed (``isettorch._files.write_atomic``), so a run
killed at any point leaves only complete shards (and possibly a stale ``.*.partial-*`` file). Items depend only on
``(seed, index)``, so a resumed run writes byte-identical shards.

Reading back: :class:`ShardDataset` (map-style; item ``i`` equals ``CameraPairDataset(...)[i]`` of the same
config, bitwise), e.g. ``DataLoader(ShardDataset(out), batch_size=16, collate_fn=collate_pairs, shuffle=True)``.

Work split: files are dealt round-robin to ``num_shards x world_size`` processes; process
``shard * world_size + rank`` takes files ``f`` with ``f % (num_shards * world_size) == that``. Under
``torchrun`` the rank and world size come from the ``RANK`` / ``WORLD_SIZE`` environment variables.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import torch

from .._checks import dataset_index
from .._files import torch_save_atomic, write_atomic
from .camera_pairs import GENERATOR_VERSION, CameraPairDataset, collate_pairs
from .config import check_integer, merge_config

MAX_SHARD_FILES = 10_000_000  # shard files of one dataset (a typo's count is refused before any work)

__all__ = ["write_dataset", "config_hash", "sha256_file", "verify_dataset", "ShardDataset", "FORMAT_VERSION"]

FORMAT_VERSION = 1


def config_hash(config: dict, count: int, generator_version: int | None = None, *, legacy: bool = False) -> str:
    """sha256 of the canonical JSON of the (validated) config, the item count, the file format and the generator
    version (``camera_pairs.GENERATOR_VERSION``: shards written by a generator that draws other items never match;
    a manifest's own ``generator_version`` to check the manifest). ``legacy``: the hash of manifests written before
    the generator version was recorded (without it)."""
    fields = {"config": config, "count": int(count), "format": FORMAT_VERSION}
    if not legacy:
        fields["generator"] = GENERATOR_VERSION if generator_version is None else int(generator_version)
    blob = json.dumps(fields, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def sha256_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _write_json(path: Path, obj) -> None:
    text = json.dumps(obj, indent=1, sort_keys=True)
    write_atomic(path, lambda tmp: tmp.write_text(text), durable=True)


def _shard_names(f: int) -> tuple[str, str]:
    return f"shard-{f:05d}.pt", f"shard-{f:05d}.json"


def _sidecars(out: Path) -> list[dict]:
    """The readable shard sidecar records in ``out`` (``shard-*.json``)."""
    recs = []
    for js in sorted(out.glob("shard-*.json")):
        try:
            rec = json.loads(js.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(rec, dict):
            recs.append(rec)
    return recs


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
    count = check_integer(count, "count", 1)
    # integers, not truncated (shard=0.5 matched no file and wrote nothing; num_shards=1.5 wrote half)
    shard, num_shards = check_integer(shard, "shard", 0), check_integer(num_shards, "num_shards", 1)
    workers = check_integer(workers, "workers", 0)
    from_env = [name for name, given in (("RANK", rank), ("WORLD_SIZE", world_size)) if given is None]
    rank = _env_int("RANK", 0) if rank is None else check_integer(rank, "rank", 0)
    world_size = _env_int("WORLD_SIZE", 1) if world_size is None else check_integer(world_size, "world_size", 1)
    if not shard < num_shards:
        raise ValueError(f"shard: expected 0 <= shard < num_shards ({num_shards}), got {shard}")
    if not (world_size >= 1 and 0 <= rank < world_size):
        where = (f" (from the environment: {', '.join(f'{n}={os.environ.get(n)!r}' for n in from_env)}; "
                 f"torchrun sets both)") if from_env else ""
        raise ValueError(f"rank: expected 0 <= rank < world_size ({world_size}), got {rank}{where}")
    size = int(cfg["shard_size"])
    if size < 1:
        raise ValueError(f"shard_size: expected a positive number of items per shard, got {size}")
    n_files = math.ceil(count / size)
    procs, me = num_shards * world_size, shard * world_size + rank
    if n_files > MAX_SHARD_FILES:  # (count 1e15 listed every shard in memory before any output: a silent hang)
        raise ValueError(f"count: {count} items are {n_files} shard files of {size}; at most {MAX_SHARD_FILES} "
                         f"(raise shard_size, or split the dataset)")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    chash = config_hash(cfg, count)
    old = out / "manifest.json"
    if old.is_file():
        try:
            prev = json.loads(old.read_text())
        except ValueError:
            prev = {}
        if not isinstance(prev, dict):
            prev = {}
        if prev.get("config_sha256") not in (None, chash):
            differs = [f"{key} {prev.get(key, default)!r} there, {mine!r} here" for key, default, mine in
                       (("count", None, count), ("generator_version", 1, GENERATOR_VERSION), ("config", None, cfg))
                       if prev.get(key, default) != mine]
            what = "; ".join(d if not d.startswith("config ") else "the config" for d in differs) or "its hash"
            raise ValueError(f"out: {str(out)!r} holds a dataset made with another config, count or generator "
                             f"version ({what}); use a new folder")
    # shards of another config (their sidecars' hashes): refused when the manifest cannot tell (an aborted run writes
    # none, and an unreadable one was taken as empty: another config's shards were rewritten without a word)
    foreign = sorted({str(rec.get("config_sha256")) for rec in _sidecars(out)} - {chash, "None"})
    if foreign:
        raise ValueError(f"out: {str(out)!r} holds shards made with another config, count or generator version "
                         f"(their sidecars' config_sha256 {foreign[0][:12]}...); use a new folder")
    mine = range(me, n_files, procs)
    todo = [f for f in mine if _shard_complete(out, f, chash) is None]

    dtype = torch.float64 if cfg["dtype"] == "float64" else torch.float32
    ds = CameraPairDataset(count, seed=int(cfg["seed"]), scene=cfg["scene"], camera=cfg["camera"], dtype=dtype,
                           targets=cfg["targets"])
    batches = [list(range(f * size, min((f + 1) * size, count))) for f in todo]
    if batches:
        # each shard is generated as one batch (CameraPairDataset.get_batch; bitwise the collated items)
        loader = torch.utils.data.DataLoader(ds, sampler=batches, batch_size=None, num_workers=workers)
        from .._progress import progress as progress_bar

        with progress_bar(total=len(todo), unit="shard", desc=f"synth rank {me}/{procs}", quiet=not progress) as bar:
            for i, (f, batch) in enumerate(zip(todo, loader)):
                pt, js = _shard_names(f)
                torch_save_atomic(batch, out / pt)
                rec = {"file": pt, "sha256": sha256_file(out / pt), "first_index": f * size,
                       "count": int(batch["raw"].shape[0]), "config_sha256": chash, "format_version": FORMAT_VERSION}
                _write_json(out / js, rec)
                bar.update(1)
                if on_shard_written is not None:
                    on_shard_written(f)
                left = len(todo) - i - 1
                need, free = left * (out / pt).stat().st_size, shutil.disk_usage(out).free
                if need > free:  # stop at once, not when the disk is full mid-shard
                    raise OSError(f"out: the {left} shards left need about {need / 1e9:.3g} GB, {str(out)!r} has "
                                  f"{free / 1e9:.3g} GB free (the shards written so far are kept; free space or "
                                  f"lower count)")
    return _write_manifest(out, cfg, chash, count, size, n_files)


def _write_manifest(out: Path, cfg: dict, chash: str, count: int, size: int, n_files: int) -> dict:
    """Scan the sidecars and write ``manifest.json``, under an exclusive lock on ``out/.manifest.lock`` where the
    platform has one (``fcntl.flock``): two ranks finishing together wrote their scans in either order, so a
    finished dataset could be left marked incomplete (8 of 12 shards) by the rank that scanned first."""
    try:
        import fcntl
    except ImportError:  # (Windows: no ranks sharing a folder there)
        fcntl = None
    with open(out / ".manifest.lock", "a") as lock:
        if fcntl is not None:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX)
            except OSError:  # a file system without locks (Lustre without -o flock): unlocked, as before
                pass
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
        _write_json(out / "manifest.json", manifest)
    return manifest


def _manifest_index(manifest) -> tuple[int, int, dict, dict]:
    """``(count, shard_size, {file: name}, {file: sha256})`` of a manifest (file = first index // shard_size): its
    structure checked, else a ValueError saying what is malformed (a list, a record without ``file``, a null
    count gave tracebacks). Read by :func:`verify_dataset` and :class:`ShardDataset`."""
    if not isinstance(manifest, dict):
        raise ValueError(f"a JSON {type(manifest).__name__}, expected an object")
    if manifest.get("format_version") != FORMAT_VERSION:  # (a format_version 99 was read as this one)
        raise ValueError(f"format_version {manifest.get('format_version')!r}, this isettorch reads {FORMAT_VERSION}")
    try:
        count, size = int(manifest["count"]), int(manifest["shard_size"])
        if count < 0 or size < 1:
            raise ValueError(f"count {count}, shard_size {size}: expected >= 0 and >= 1")
        # the hash of its own config and count (a count edited from 8 to 9 gave 9 items, the last an IndexError)
        if config_hash(manifest["config"], count, manifest.get("generator_version"),
                       legacy="generator_version" not in manifest) != manifest["config_sha256"]:
            raise ValueError("config_sha256 is not the hash of its config and count (edited?)")
        records = manifest["shards"]
        if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
            raise TypeError(f"shards: expected a list of records, got {type(records).__name__}")
        if not all(isinstance(rec["file"], str) for rec in records):  # (null was read as the file "None")
            raise TypeError("shards: a record's file is not a name")
        files = {int(rec["first_index"]) // size: rec["file"] for rec in records}
        sha = {int(rec["first_index"]) // size: rec.get("sha256") for rec in records}
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{type(err).__name__}: {err}") from err
    return count, size, files, sha


def unfinished(out) -> str:
    """``"; ... unfinished ..."`` where ``out`` holds shard sidecars but no manifest.json (a run stopped before its
    end, which writes the manifest), else ``""``: the words to add to a missing manifest's message."""
    out = Path(out)
    n = len(list(out.glob("shard-*.json")))
    if n == 0 or (out / "manifest.json").is_file():
        return ""
    return (f"; it holds {n} shard(s) of an unfinished isettorch synth run: run the same synth command again to "
            f"finish it")


def verify_dataset(out) -> list[str]:
    """Check every shard listed in ``out/manifest.json`` against its sha256, and that a complete dataset lists a
    shard for every file (``"complete": true`` with shards missing was 'ok'); returns the problems found."""
    out = Path(out)
    try:
        manifest = json.loads((out / "manifest.json").read_text())
    except (OSError, ValueError) as err:
        return [f"manifest.json: unreadable ({err}){unfinished(out)}"]
    try:
        count, size, files, sha = _manifest_index(manifest)
    except ValueError as err:
        return [f"manifest.json: malformed ({err})"]
    problems = []
    for f, name in sorted(files.items()):
        p = out / name
        if not p.is_file():
            problems.append(f"{name}: missing")
        elif sha256_file(p) != sha[f]:
            problems.append(f"{name}: checksum mismatch")
    if not manifest.get("complete"):
        problems.append(f"incomplete: {len(files)} of {manifest.get('num_files')} shards")
    else:
        unlisted = _unlisted(count, size, files)
        if unlisted:
            problems.append(f"manifest.json: complete, but lists no shard for files {unlisted[:8]} (of "
                            f"{-(-count // size)})")
    return problems


def _unlisted(count: int, size: int, files: dict) -> list[int]:
    """The file numbers a dataset of ``count`` items in shards of ``size`` needs and ``files`` does not list."""
    return sorted(set(range(-(-count // size))) - set(files))


class ShardDataset(torch.utils.data.Dataset):
    """The items of a dataset written by :func:`write_dataset` / ``isettorch synth``, read back from its shards.

    Item ``i`` is item ``i % shard_size`` of shard ``i // shard_size``: the same dict (images, ``meta``) as
    ``CameraPairDataset(count, seed, scene, camera, targets=..., dtype=...)[i]`` with the dataset's config, bitwise
    (its ``targets`` and ``dtype`` too). Shards are opened lazily, memory-mapped (``torch.load(weights_only=True,
    mmap=True)``), and the last ``cache_shards`` opened are kept per process: an item reads its own bytes, not the
    whole shard, so a shuffled loader (which finds an item's shard open about ``cache_shards / num_files`` of the
    time) reads about what it uses, after each shard's checksum (below). Items are copies: editing one in place
    changes nothing else.

    Args:
        root: the dataset folder (with ``manifest.json``).
        verify: check every shard's sha256 against the manifest first (reads everything once); without it each
            shard's is checked the first time this process reads the shard (a changed shard is a ValueError).
        cache_shards: shards kept in memory per process (DataLoader workers each have their own).

    Raises ValueError when the manifest is missing or unreadable, the dataset is incomplete (resume the ``synth``
    run first), or (``verify=True``) a shard is missing or corrupt; a shard that fails to load names its file.

    Example (a tiny dataset: 3 items of 16 x 16 pixels in shards of 2):
        >>> import tempfile
        >>> cfg = {"seed": 5, "shard_size": 2, "targets": ["srgb"],
        ...        "scene": {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}}
        >>> out = tempfile.mkdtemp()
        >>> write_dataset(cfg, out, 3, progress=False)["complete"]
        True
        >>> ds = ShardDataset(out, verify=True)
        >>> len(ds), tuple(ds[2]["srgb"].shape)
        (3, (3, 16, 16))
        >>> loader = torch.utils.data.DataLoader(ds, batch_size=2, shuffle=True, collate_fn=collate_pairs)
        >>> tuple(next(iter(loader))["raw"].shape)
        (2, 1, 16, 16)
        >>> import shutil; shutil.rmtree(out)
    """

    def __init__(self, root, *, verify: bool = False, cache_shards: int = 2):
        self.root = Path(root)
        try:
            manifest = json.loads((self.root / "manifest.json").read_text())
        except (OSError, ValueError) as err:
            raise ValueError(f"root: {str(self.root)!r} has no readable manifest.json ({err}){unfinished(self.root)}"
                             ) from err
        try:
            self.count, self.shard_size, self.files, self.sha256 = _manifest_index(manifest)
        except ValueError as err:
            raise ValueError(f"root: {str(self.root)!r} has a malformed manifest.json ({err})") from err
        if not manifest.get("complete"):
            raise ValueError(f"root: {str(self.root)!r} holds an incomplete dataset ({len(manifest.get('shards', []))}"
                             f" of {manifest.get('num_files')} shards); run the same synth command again to finish it")
        if verify:
            problems = verify_dataset(self.root)
            if problems:
                raise ValueError(f"root: {str(self.root)!r} failed verification: {'; '.join(problems[:5])}")
        cache_shards = check_integer(cache_shards, "cache_shards", 1)
        self.manifest = manifest
        missing = _unlisted(self.count, self.shard_size, self.files)
        if missing:
            raise ValueError(f"root: {str(self.root)!r}'s manifest.json is complete but lists no shard for files "
                             f"{missing[:8]}; run isettorch synth --verify, or the same synth command again")
        self.cache_shards = cache_shards
        self._cache: dict[int, dict] = {}
        self._checked: set[int] = set(self.files) if verify else set()  # shards whose sha256 was checked

    def __len__(self) -> int:
        return self.count

    def _shard(self, f: int) -> dict:
        shard = self._cache.pop(f, None)
        if shard is None:
            path = self.root / self.files[f]
            # the manifest's checksum, the first time a process reads a shard (an edited or swapped shard was served
            # as training data without a word); once per shard and process, not per reload from the cache
            if f not in self._checked and self.sha256.get(f) is not None:
                try:
                    digest = sha256_file(path)
                except OSError as err:
                    raise ValueError(f"{path}: not a readable shard ({type(err).__name__}: {err})") from err
                if digest != self.sha256[f]:
                    raise ValueError(f"{path}: the shard's sha256 differs from manifest.json's; the file was changed "
                                     f"after it was written (isettorch synth --verify lists every such shard)")
                self._checked.add(f)
            try:  # memory-mapped: an item reads its own pages, not the whole shard
                shard = torch.load(path, weights_only=True, mmap=True)
            except Exception as err:  # torch raises several types for truncated / foreign files
                raise ValueError(f"{path}: not a readable shard ({type(err).__name__}: {err})") from err
            while len(self._cache) >= self.cache_shards:
                self._cache.pop(next(iter(self._cache)))  # least recently used first
        self._cache[f] = shard  # most recently used last
        return shard

    def __getitem__(self, index):
        """Item ``index``: copies (an in-place edit of a view changed the cached shard, so every later read of its
        items; and a view kept the whole shard alive)."""
        f, j = divmod(dataset_index(index, self.count), self.shard_size)
        shard = self._shard(f)
        return {k: ({m: t[j].clone() for m, t in v.items()} if isinstance(v, dict) else v[j].clone())
                for k, v in shard.items()}

    def get_batch(self, indices) -> dict:
        """Items ``indices`` collated (:func:`camera_pairs.collate_pairs` format)."""
        return collate_pairs([self[i] for i in indices])
