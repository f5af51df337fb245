"""Demosaicing: Bayer methods behind one entry point with a registry, a generic method for any CFA, and a
plug-in point for learned methods. The entry point is the function :func:`demosaic` and its module
:class:`Demosaic` (exported by :mod:`isettorch.isp`: ``from isettorch.isp import demosaic, Demosaic``).

    >>> raw = mosaic(torch.full((1, 3, 8, 8), 0.25), "RGGB")   # a Bayer mosaic (B, 1, H, W)
    >>> demosaic(raw, "RGGB", method="malvar2004").shape          # -> (B, 3, H, W)
    torch.Size([1, 3, 8, 8])
    >>> Demosaic("menon2007")(raw, "RGGB").unique()               # a constant colour field stays constant
    tensor([0.2500])
    >>> class Grey(nn.Module):                                    # any callable / nn.Module (raw, pattern) -> RGB
    ...     def forward(self, raw, pattern):
    ...         return raw.expand(-1, 3, -1, -1)
    >>> register_method("grey_example", Grey())
    >>> demosaic(raw, "RGGB", method="grey_example").shape
    torch.Size([1, 3, 8, 8])
    >>> del METHODS["grey_example"]
    >>> demosaic(raw, torch.tensor([[0, 1], [1, 2]]), method="bilinear").shape  # any CFA as an index map
    torch.Size([1, 3, 8, 8])
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Callable

import torch
from torch import nn

from ..._checks import check_finite
from ._cfa import BAYER_PATTERNS, bayer_index_map, mosaic
from .linear import demosaic_bilinear, demosaic_generic, demosaic_malvar2004, demosaic_nearest, demosaic_nearest_cfa
from .menon2007 import demosaic_menon2007

__all__ = ["BAYER_PATTERNS", "METHODS", "Demosaic", "bayer_index_map", "demosaic", "demosaic_bilinear",
           "demosaic_bilinear_colour", "demosaic_generic", "demosaic_malvar2004", "demosaic_menon2007",
           "demosaic_nearest", "demosaic_nearest_cfa", "get_method", "mosaic", "register_method"]

def demosaic_bilinear_colour(raw: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """Bilinear exactly as colour-demosaicing 0.2 computes it, border included (``normalize_border=False``): the
    reference for its published CPSNR at crop 0; the border is biased (a constant image is not kept constant)."""
    return demosaic_bilinear(raw, pattern, normalize_border=False)


#: Bayer demosaic methods: name -> callable(raw (B, 1, H, W), pattern: str) -> RGB (B, 3, H, W).
METHODS: dict[str, Callable] = {
    "nearest": demosaic_nearest,
    "bilinear": demosaic_bilinear,
    "malvar2004": demosaic_malvar2004,
    "menon2007": demosaic_menon2007,
    "bilinear_colour": demosaic_bilinear_colour,
}

# Methods that live in optional modules, imported on first use (the module registers itself).
_LAZY_METHODS = {name: "isettorch.isp.learned" for name in ("learned", "learned_small", "learned_tiny")}

# Methods that also work on any CFA given as an index map.
_GENERIC = {"nearest": demosaic_nearest_cfa, "bilinear": demosaic_generic, "generic": demosaic_generic}


def register_method(name: str, fn: Callable, *, overwrite: bool = False) -> None:
    """Add a demosaic method to ``METHODS``: any callable ``fn(raw, pattern) -> (B, 3, H, W)``, e.g. an
    ``nn.Module`` whose ``forward(raw, pattern)`` runs a network."""
    if not isinstance(name, str) or not name:
        raise TypeError(f"name: expected a non-empty string, got {name!r}")
    if not callable(fn):
        raise TypeError(f"fn: expected a callable (raw, pattern) -> RGB, got {type(fn).__name__}")
    if name in METHODS and not overwrite and METHODS[name] is not fn:
        raise ValueError(f"name: method {name!r} is already registered (pass overwrite=True to replace it)")
    METHODS[name] = fn


def get_method(name: str) -> Callable:
    """Look a method up in ``METHODS``, importing its module first if it is a lazily registered one."""
    if not isinstance(name, str):
        raise TypeError(f"method: expected a method name (str), got {type(name).__name__}")
    if name not in METHODS and name in _LAZY_METHODS:
        try:
            importlib.import_module(_LAZY_METHODS[name])
        except ModuleNotFoundError as err:
            if err.name != _LAZY_METHODS[name]:
                raise
            raise ValueError(f"method: {name!r} needs module {_LAZY_METHODS[name]}, which is not installed") from err
    if name not in METHODS:
        raise ValueError(f"method: expected one of {sorted(set(METHODS) | set(_LAZY_METHODS))}, got {name!r}")
    return METHODS[name]


def demosaic(raw: torch.Tensor, pattern="RGGB", method: str | Callable = "bilinear", **kwargs) -> torch.Tensor:
    """Demosaic a raw mosaic.

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device, finite (a NaN or Inf sample is a ValueError).
        pattern: a Bayer pattern 'RGGB', 'BGGR', 'GRBG', 'GBRG' (row-major, top-left first), or a long index map
            [ph, pw] of channel indices for any other CFA (methods 'nearest', 'bilinear' / 'generic' only).
        method: a name in ``METHODS`` ('nearest', 'bilinear', 'malvar2004', 'menon2007', or a registered one such
            as 'learned'), or a callable (raw, pattern) -> RGB.
        **kwargs: passed to the method (e.g. ``refine=False`` for menon2007).

    Returns:
        (B, 3, H, W) for a Bayer pattern; (B, C, H, W) for an index map (``num_channels`` may be given in kwargs).

    Example:
        >>> raw = torch.rand(2, 1, 32, 32)
        >>> demosaic(raw, "RGGB", method="menon2007").shape
        torch.Size([2, 3, 32, 32])
    """
    if isinstance(raw, torch.Tensor) and raw.is_floating_point():
        # a NaN or Inf sample is refused, not spread: MHC carries it over 5 x 5 pixels, a learned method over the
        # whole image (its guard's local means)
        check_finite(raw, "raw")
    if isinstance(pattern, torch.Tensor):
        if callable(method) or method not in _GENERIC:
            raise ValueError(f"method: an index-map CFA supports {sorted(_GENERIC)}, got {method!r}")
        return _GENERIC[method](raw, pattern, **kwargs)
    fn = method if callable(method) else get_method(method)
    if kwargs and not callable(method):
        _check_options(method, fn, kwargs)
    return fn(raw, pattern, **kwargs)


@functools.lru_cache(maxsize=64)
def _option_names(fn: Callable) -> tuple[str, ...] | None:
    """The keyword options a method takes after ``(raw, pattern)`` (None: it takes any, or has no signature and
    checks its own); once per method (a pipeline stage passes Malvar's boundary on every call)."""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    named = [p for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    return tuple(p.name for p in named[2:] if not p.name.startswith("_"))


def _check_options(name: str, fn: Callable, kwargs: dict) -> None:
    """A method's keyword options: an unknown one is a TypeError naming the method and what it takes (Python's own
    named an internal function, e.g. ``_register.<locals>._learned()``)."""
    takes = _option_names(fn)
    if takes is None:
        return
    unknown = sorted(set(kwargs) - set(takes))
    if unknown:
        raise TypeError(f"method {name!r}: unknown option(s) {unknown}; it takes {takes or 'none'}")


class Demosaic(nn.Module):
    """Demosaic stage: ``Demosaic(method)(raw, pattern) -> RGB``. ``method`` is a registered name, or any
    ``nn.Module`` / callable with the signature ``(raw, pattern)`` (a learned demosaic), which then becomes a
    submodule so its parameters move with ``.to()`` and appear in ``state_dict()``.

    Example:
        >>> stage = Demosaic("malvar2004", pattern="GRBG")
        >>> stage(torch.rand(1, 1, 8, 8)).shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(self, method: str | Callable = "bilinear", pattern="RGGB", **kwargs):
        super().__init__()
        if isinstance(method, str):
            if not isinstance(pattern, torch.Tensor):
                get_method(method)  # fail early on an unknown name
            self.method_name, self.fn = method, None
        elif callable(method):
            self.method_name, self.fn = type(method).__name__, method  # an nn.Module is registered as a child
        else:
            raise TypeError(f"method: expected a method name or a callable, got {type(method).__name__}")
        self.pattern = pattern
        self.kwargs = kwargs

    def forward(self, raw: torch.Tensor, pattern=None) -> torch.Tensor:
        pattern = self.pattern if pattern is None else pattern
        return demosaic(raw, pattern, self.fn if self.fn is not None else self.method_name, **self.kwargs)

    def extra_repr(self) -> str:
        return f"method={self.method_name!r}, pattern={self.pattern!r}"
