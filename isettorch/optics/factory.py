"""`build_optics(config)`: every optics type from a config mapping (camera YAML ``optics:`` section).

Types: ``diffraction_limited`` (DiffractionLimitedOptics), ``wavefront`` / ``zernike`` (WavefrontOptics),
``psf_file`` (ShiftInvariantOptics from an ``.npz`` with ``psf`` [(L,) K, K], ``psf_spacing_m`` and optionally
``psf_wavelengths_nm``), ``lens`` (LensOptics from a ``.zmx``/``.yaml`` prescription or a bundled lens name;
``focus_distance_m`` sets the focus, ``object_distance: scene`` images each scene at its ``distance_m``).
Keys are checked against each constructor's arguments; a mistyped key names the closest valid one. In a YAML file,
a relative file path (``psf_file``'s ``path``, a ``lens`` file) is relative to that file's folder
(:func:`resolve_config_paths`), wherever the command runs.
"""

from __future__ import annotations

import difflib
import functools
import inspect
from pathlib import Path

from torch import nn

__all__ = ["build_optics", "OPTICS_TYPES", "resolve_config_paths"]


def resolve_config_paths(optics, base_dir):
    """``optics`` (a config's ``optics:`` mapping, read from a YAML file in ``base_dir``) with its relative file
    paths taken relative to ``base_dir``: a ``psf_file``'s ``path`` and a ``lens`` given as a file (a name with a
    folder or a suffix: ``my_lens.zmx``; a bundled lens name such as ``cooke_triplet`` stays a name). They were
    relative to the current folder: the same config failed from another folder, or read another file of that
    name. Anything else is returned as it is (the builder checks it)."""
    if not isinstance(optics, dict):
        return optics
    key = {"psf_file": "path", "lens": "lens"}.get(optics.get("type"))
    value = optics.get(key)
    if key is None or not isinstance(value, str) or not value:
        return optics
    p = Path(value).expanduser()
    if p.is_absolute() or (key == "lens" and not p.suffix and len(p.parts) == 1):
        return optics
    return {**optics, key: str(Path(base_dir) / p)}

OPTICS_TYPES = ("diffraction_limited", "wavefront", "zernike", "psf_file", "lens")


def _inits(cls) -> list:
    """The ``__init__`` of an optics class and of its bases up to ``nn.Module`` (the class's own first)."""
    out = []
    for c in cls.__mro__:
        if c is nn.Module or c is object:
            break
        if "__init__" in c.__dict__:
            out.append(c.__init__)
    return out


@functools.cache
def _keys(cls) -> frozenset[str]:
    """The constructor keywords of an optics class and its bases (memoised: a camera-pair stream builds an optics
    module per group and batch)."""
    keys = set()
    for init in _inits(cls):
        keys |= {n for n, p in inspect.signature(init).parameters.items()
                 if n != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
    keys.discard("dtype")
    return frozenset(keys)


def _check_values(cfg: dict, cls) -> None:
    """The values' types against the constructors' annotations (booleans are YAML booleans, numbers real and finite;
    :func:`isettorch.camera.check_config_values`, the one check of every config section)."""
    from ..camera import check_config_values

    check_config_values(cfg, _inits(cls), "optics")


def _check(cfg: dict, valid: set[str], kind: str) -> None:
    for k in cfg:
        if k not in valid:
            close = difflib.get_close_matches(str(k), sorted(valid), n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"config: unknown key {k!r} in optics (type {kind}){hint} (valid keys: {sorted(valid)})")


def build_optics(config: dict) -> nn.Module:
    """Build an optics module from ``config`` (``type`` + the constructor's keyword arguments).

    Example:
        >>> build_optics({"type": "lens", "lens": "cooke_triplet", "components": 8})  # doctest: +SKIP
        >>> build_optics({"type": "lens", "lens": "cooke_triplet", "focus_distance_m": 2.0,
        ...               "object_distance": "scene"})  # doctest: +SKIP
    """
    if not isinstance(config, dict):
        raise TypeError(f"config: optics must be a mapping, got {type(config).__name__}")
    cfg = dict(config)
    kind = cfg.pop("type", "diffraction_limited")
    if kind not in OPTICS_TYPES:
        close = difflib.get_close_matches(str(kind), OPTICS_TYPES, n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"config: unknown optics.type {kind!r}{hint} (valid: {list(OPTICS_TYPES)})")
    if kind == "diffraction_limited":
        from .diffraction import DiffractionLimitedOptics as cls
    elif kind in ("wavefront", "zernike"):
        from .wavefront import WavefrontOptics as cls
    elif kind == "lens":
        from .lens.optics import LensOptics as cls
    else:
        return _psf_file(cfg)
    _check(cfg, _keys(cls), kind)
    _check_values(cfg, cls)
    return cls(**cfg)


def _psf_file(cfg: dict) -> nn.Module:
    import numpy as np

    from .shift_invariant import ShiftInvariantOptics

    path = cfg.pop("path", None)
    if path is None:
        raise ValueError("config: optics type psf_file needs 'path' (an .npz with psf, psf_spacing_m and optionally "
                         "psf_wavelengths_nm)")
    _check(cfg, _keys(ShiftInvariantOptics) - {"psf", "psf_spacing_m", "psf_wavelengths_nm"}, "psf_file")
    _check_values(cfg, ShiftInvariantOptics)
    p = Path(path)
    if p.suffix != ".npz" or not p.is_file():
        raise FileNotFoundError(f"config: optics.path {str(path)!r}: expected an existing .npz file")
    with np.load(p, allow_pickle=False) as d:
        missing = {"psf", "psf_spacing_m"} - set(d.files)
        if missing:
            raise ValueError(f"config: optics.path {str(path)!r}: missing arrays {sorted(missing)} (has {d.files})")
        kw = {"psf": d["psf"], "psf_spacing_m": d["psf_spacing_m"]}
        if "psf_wavelengths_nm" in d.files:
            kw["psf_wavelengths_nm"] = d["psf_wavelengths_nm"]
    return ShiftInvariantOptics(**kw, **cfg)
