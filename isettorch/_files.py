"""Files written so that a failure leaves nothing half-written: :class:`Outputs` writes each file under a temporary
name beside it and moves them all into place (``os.replace``, atomic on POSIX) only when the block succeeds."""

from __future__ import annotations

import os
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
    """

    def __init__(self, folder=None):
        self.folder = None if folder is None else Path(folder)
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
