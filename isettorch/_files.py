"""Files written so that a failure leaves nothing half-written: :class:`Outputs` writes each file under a temporary
name beside it and moves them all into place (``os.replace``, atomic on POSIX) only when the block succeeds;
:func:`write_atomic` is the one-file form."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path


def missing_folders(path: Path) -> list[Path]:
    """``path`` and those of its ancestors that do not exist, deepest first (what ``mkdir(parents=True)`` makes)."""
    out = []
    while not path.exists() and path != path.parent:
        out.append(path)
        path = path.parent
    return out


class Outputs:
    """Files of one command or one writer call (a batch of images), written under temporary names and moved into
    place by :meth:`commit`; on an error (``with`` block left by an exception) the temporary files and the folder
    made for them are removed, and no file of that name is touched.

    Example::

        with Outputs(out_dir) as outputs:
            np.save(outputs.temporary(out_dir / "a.npy"), a)
        # a.npy is in place only if the block succeeded

    ``durable=True`` flushes each file to disk (``os.fsync``) before it is moved into place, so that a crash of the
    machine (not only of the process) cannot leave a renamed but empty file: for shards and checkpoints that a resumed
    run trusts.
    """

    def __init__(self, folder=None, *, durable: bool = False):
        self.folder = None if folder is None else Path(folder)
        self.durable = durable
        self.made: list[Path] = []
        self.pending: list[tuple[Path, Path]] = []

    def __enter__(self):
        if self.folder is not None and not self.folder.is_dir():
            missing = missing_folders(self.folder)
            self.folder.mkdir(parents=True, exist_ok=True)
            self.made = missing  # deepest first
        return self

    def temporary(self, path) -> Path:
        """A temporary name beside ``path`` (same suffix, so writers that go by the suffix still work)."""
        path = Path(path)
        if path.is_dir():  # (found at the final move: the other outputs were in place, a temporary file left)
            raise ValueError(f"out: {path} is a folder; an output file of that name cannot replace it")
        tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
        self.pending.append((tmp, path))
        return tmp

    def commit(self) -> None:
        if self.durable:
            for tmp, _ in self.pending:
                with open(tmp, "rb+") as f:
                    os.fsync(f.fileno())
        for tmp, path in self.pending:
            os.replace(tmp, path)
        self.pending = []

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
            return
        for tmp, _ in self.pending:
            try:
                tmp.unlink()
            except OSError:
                pass
        for folder in self.made:
            try:
                folder.rmdir()
            except OSError:
                break


def write_atomic(path, write: Callable[[Path], object], *, durable: bool = False) -> None:
    """Write one file through :class:`Outputs`: ``write(temporary_path)`` writes it, and it replaces ``path`` only if
    that succeeded (``durable``: flushed to disk first). Example: ``write_atomic(p, lambda t: torch.save(obj, t))``."""
    with Outputs(durable=durable) as outputs:
        write(outputs.temporary(path))


def torch_save_atomic(obj, path, *, durable: bool = True) -> None:
    """``torch.save(obj)`` to ``path`` through :func:`write_atomic`, into an open file: given a path, ``torch.save``
    names the archive's inner folder after the file (here the temporary name, with the process id), so the bytes,
    and a shard's checksum, would differ between runs; given a file it names it ``archive``."""
    import torch

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            torch.save(obj, f)

    write_atomic(path, save, durable=durable)
