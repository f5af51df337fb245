"""Output paths of the subcommands, checked before any work and written so that a failed command leaves nothing:
``check_dir`` / ``check_file`` (the place exists or can be made, is writable, is not an input), and
``Outputs``, which writes each file under a temporary name beside it and moves them all into place only when
the command succeeds (a folder it had to make is removed on failure)."""

from __future__ import annotations

import os
from pathlib import Path

from .._files import Outputs  # noqa: F401 (Outputs: the commands' import)
from .._files import missing_folders as _missing


def _writable_ancestor(path: Path, name: str, what: str) -> None:
    """The nearest existing folder above ``path`` (to be made) is a folder we may write in."""
    missing = _missing(path.parent)
    parent = missing[-1].parent if missing else path.parent
    if not parent.is_dir():
        raise ValueError(f"{name}: cannot create {what} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"{name}: cannot create {what} {path}: no permission to write in {parent}")


def check_dir(path, name: str = "out") -> Path:
    """``path`` is a writable folder or can be made: ValueError / PermissionError naming ``name`` otherwise."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise ValueError(f"{name}: expected a folder, {path} is a file")
        if not os.access(p, os.W_OK | os.X_OK):
            raise PermissionError(f"{name}: no permission to write in the folder {path}")
        return p
    _writable_ancestor(p, name, "the folder")
    made = _missing(p)  # and try: permissions alone do not tell (root on a read-only mount, /sys)
    try:
        p.mkdir(parents=True)
    except OSError as err:
        raise OSError(f"{name}: cannot create the folder {path} ({err.strerror or err})") from err
    finally:
        for folder in made:
            try:
                folder.rmdir()
            except OSError:
                break
    return p


def check_file(path, name: str = "out", *, inputs=(), make_parents: bool = False) -> Path:
    """``path`` can be written as a file (not a folder, its folder writable or, with ``make_parents``, makeable)
    and is none of ``inputs`` (never overwrite an input): ValueError / PermissionError naming ``name``."""
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{name}: expected a file name, {path} is a folder")
    check_not_input(p, inputs, name)
    if p.exists():
        if not os.access(p, os.W_OK) or not os.access(p.parent, os.W_OK | os.X_OK):
            raise PermissionError(f"{name}: no permission to write {path}")
        return p
    if p.parent.exists() or make_parents:
        _writable_ancestor(p, name, "the file")
    else:
        raise FileNotFoundError(f"{name}: cannot write {path}: no such folder {str(p.parent)!r}")
    return p


def check_not_input(path, inputs, name: str = "out") -> None:
    """``path`` is none of the files ``inputs`` (resolved: links and ``..`` followed)."""
    target = Path(path).resolve()
    for f in inputs:
        if Path(f).resolve() == target:
            raise ValueError(f"{name}: {path} is the input {f}; expected an output that does not overwrite an input")


def strict_json(obj, **kwargs) -> str:
    """``json.dumps`` of ``obj`` with every non-finite float as null (JSON has no NaN or Infinity: a bare ``NaN``
    breaks strict parsers such as jq and JavaScript)."""
    import json
    import math

    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(obj), allow_nan=False, **kwargs)
