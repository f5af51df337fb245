"""Where data lives: the ``ISETTORCH_DATA`` folder and paths relative to it.

``ISETTORCH_DATA`` names the folder holding datasets a user supplies (benchmark images such as Kodak and
McMaster, hyperspectral sets, synthetic shards). Configs name data by paths *relative* to it (``kodak24``), so
one config works on every machine; absolute paths and ``~`` or ``$VARS`` are used as given. Unset, it is
``./data`` (the current directory's ``data`` folder).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["DATA_ENV", "data_root", "data_path"]

DATA_ENV = "ISETTORCH_DATA"


def data_root() -> Path:
    """The data folder: ``$ISETTORCH_DATA``, or ``./data`` when it is unset or empty."""
    return Path(os.path.expanduser(os.environ.get(DATA_ENV) or "data"))


def data_path(path: str | os.PathLike, must_exist: bool = True) -> Path:
    """Resolve a data path from a config: ``~`` and ``$VARS`` expanded; a relative path is under :func:`data_root`.

    Raises FileNotFoundError naming the path, the resolved location and ``ISETTORCH_DATA`` when ``must_exist``
    and nothing is there.

    Example:
        >>> import os
        >>> os.environ["ISETTORCH_DATA"] = "/datasets"
        >>> str(data_path("kodak24", must_exist=False)), str(data_path("/abs/kodak", must_exist=False))
        ('/datasets/kodak24', '/abs/kodak')
        >>> del os.environ["ISETTORCH_DATA"]
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ValueError(f"path: expected a non-empty path, got {path!r}")
    p = Path(os.path.expandvars(os.path.expanduser(os.fspath(path))))
    if not p.is_absolute():
        p = data_root() / p
    if must_exist and not p.exists():
        where = os.environ.get(DATA_ENV)
        raise FileNotFoundError(f"path: {os.fspath(path)!r} -> {str(p)!r} does not exist (relative data paths are "
                                f"under ${DATA_ENV}, {'set to ' + repr(where) if where else 'unset, so ./data'})")
    return p
