"""Input validation helpers: every error names the argument, the value and what was expected."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np
import torch


def as_tensor(value, name: str, *, dtype=None, device=None) -> torch.Tensor:
    """Convert a number, sequence or tensor to a tensor, with a clear error otherwise."""
    if isinstance(value, torch.Tensor):
        t = value
        if dtype is not None or device is not None:
            t = t.to(dtype=dtype or t.dtype, device=device or t.device)
        return t
    if isinstance(value, (bool, np.bool_)):  # (mean_luminance_cd_m2=True was a 1 cd/m^2 scene, data_range=True 1)
        raise TypeError(f"{name}: expected a number or tensor, got {value!r}")
    if np.iscomplexobj(value):  # (torch dropped the imaginary part with a warning)
        raise TypeError(f"{name}: expected real numbers, got complex values")
    if isinstance(value, np.ndarray):  # (a reversed view's negative strides were refused as 'not a number')
        value = np.ascontiguousarray(value)
    try:
        return torch.as_tensor(value, dtype=dtype or torch.get_default_dtype(), device=device)
    except (TypeError, ValueError, RuntimeError) as err:
        raise TypeError(f"{name}: expected a number or tensor, got {type(value).__name__} ({value!r})") from err


def tensor_version(t: torch.Tensor):
    """``t``'s in-place version counter, for cache keys; a tensor made under ``torch.inference_mode`` has none (reading
    it raised, so a camera failed on a scene built there): a new object each call, so a key holding it never hits."""
    return object() if t.is_inference() else t._version


def is_real(v) -> bool:
    """A finite real number: int or float (or a NumPy scalar), not a bool (``True`` is no pixel size) or a string."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def tensor_hint(v) -> str:
    """What to add to a "got {v!r}" message when ``v`` is a tensor where a plain number is taken (a positive tensor
    had been told it was not positive)."""
    return "; a number, not a tensor (pass float(...))" if torch.is_tensor(v) else ""


def is_integer(v) -> bool:
    """An integer (Python or NumPy), not a bool and not a float (``1.5`` is no seed or bit depth, ``True`` none)."""
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


_SMALL = 64  # a CPU tensor this small is checked on its Python values (no tensor ops: ~10x less per-call work)


def _small_values(t: torch.Tensor) -> list | None:
    """The values of a small real CPU tensor as a flat Python list, else None."""
    if t.numel() <= _SMALL and t.device.type == "cpu" and not t.is_complex():
        if t.dim() == 1:  # the common case (a [B] parameter): one call
            return t.tolist()
        return t.detach().reshape(-1).tolist()
    return None


def check_finite(t: torch.Tensor, name: str) -> None:
    if t.device.type == "meta":  # shapes only: no values to check
        return
    vals = _small_values(t)
    if vals is not None:
        bad = sum(not math.isfinite(v) for v in vals)
        if bad:
            raise ValueError(f"{name}: expected finite values, found {bad} NaN/Inf entries")
        return
    if not torch.isfinite(t).all():
        bad = (~torch.isfinite(t)).sum().item()
        raise ValueError(f"{name}: expected finite values, found {bad} NaN/Inf entries")


def check_nonnegative(t: torch.Tensor, name: str) -> None:
    check_finite(t, name)
    if (t < 0).any():
        raise ValueError(f"{name}: expected non-negative values, minimum is {t.min().item():.6g}")


#: the precisions the library computes in
FLOAT_DTYPES = (torch.float32, torch.float64)


def first_line(err: BaseException) -> str:
    """An exception's message, first line only (torch lists signatures or advice below it), or its type's name."""
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def check_window(window, height: int, width: int, name: str, min_pixels: int = 1) -> tuple[int, int, int, int]:
    """An end-exclusive ``(row0, row1, col0, col1)`` of integers inside a ``height x width`` image holding at least
    ``min_pixels`` pixels (a region of interest; 0.5 was truncated to 0 and 2.7 to 2), else a ValueError naming
    ``name``."""
    if not (isinstance(window, (tuple, list)) and len(window) == 4 and all(is_integer(v) for v in window)):
        raise ValueError(f"{name}: expected (row0, row1, col0, col1) integers, got {window!r}")
    r0, r1, c0, c1 = (int(v) for v in window)
    if not (0 <= r0 < r1 <= height and 0 <= c0 < c1 <= width) or (r1 - r0) * (c1 - c0) < min_pixels:
        at_least = f" holding at least {min_pixels} pixels" if min_pixels > 1 else ""
        raise ValueError(f"{name}: expected (row0, row1, col0, col1), end-exclusive, with 0 <= row0 < row1 <= "
                         f"{height} and 0 <= col0 < col1 <= {width}{at_least}, got {window!r}")
    return r0, r1, c0, c1


def check_float_dtype(dtype, name: str = "dtype") -> torch.dtype:
    """``dtype`` if it is torch.float32 or torch.float64 (the precisions the library computes in), else a
    ValueError naming ``name``."""
    if dtype not in FLOAT_DTYPES:
        raise ValueError(f"{name}: expected torch.float32 or torch.float64, got {dtype}")
    return dtype


def check_bool(value, name: str) -> bool:
    """``value`` if it is True or False (a string such as 'no', a number or None is not read as a flag): else a
    TypeError naming ``name``."""
    if not isinstance(value, bool):
        raise TypeError(f"{name}: expected True or False, got {value!r}")
    return value


def check_positive(value, name: str) -> torch.Tensor:
    t = as_tensor(value, name)
    check_finite(t, name)
    if (t <= 0).any():
        raise ValueError(f"{name}: expected a positive value, got {t.min().item():.6g}")
    return t


def check_rank(t: torch.Tensor, ranks: int | Sequence[int], name: str, layout: str) -> None:
    ranks = (ranks,) if isinstance(ranks, int) else tuple(ranks)
    if t.dim() not in ranks:
        raise ValueError(f"{name}: expected a tensor of shape {layout}, got shape {tuple(t.shape)}")


def check_wavelengths(w: torch.Tensor, name: str = "wavelengths_nm") -> torch.Tensor:
    """Wavelength grids are 1-D, finite, positive and strictly increasing (nm)."""
    if not isinstance(w, torch.Tensor):
        w = torch.as_tensor(w, dtype=torch.get_default_dtype())
    if w.dim() == 0:
        w = w.reshape(1)
    check_rank(w, 1, name, "[L]")
    if w.numel() == 0:
        raise ValueError(f"{name}: expected at least one wavelength, got an empty grid")
    check_finite(w, name)
    if (w <= 0).any():
        raise ValueError(f"{name}: expected positive wavelengths in nm, got minimum {w.min().item():.6g}")
    if w.numel() > 1 and not (w[1:] > w[:-1]).all():
        raise ValueError(f"{name}: expected a strictly increasing wavelength grid, got {w.tolist()}")
    return w


def check_nanometres(w, name: str) -> None:
    """Wavelengths read from a file are nanometres: a grid outside 100-100,000 nm (0.4-0.7: micrometres; 4e-7:
    metres) is refused naming ``name`` (such files loaded as scenes of 0.4-0.7 nm light without a word)."""
    a = torch.as_tensor(w, dtype=torch.float64).reshape(-1)
    if a.numel() and (float(a.min()) < 100 or float(a.max()) > 1e5):
        raise ValueError(f"{name}: expected wavelengths in nm, got {float(a.min()):g}-{float(a.max()):g} "
                         f"(micrometres? times 1000; metres? times 1e9)")


def check_in_dtype_range(value: float, name: str, dtype) -> None:
    """ValueError unless a nonzero Python number keeps its value in ``dtype`` (the data's): no overflow to inf, no
    underflow of a positive level to 0 (an analog gain of 1e-50 in float32 is 0, and a division by it NaN)."""
    if value != 0 and dtype.is_floating_point:
        fi = torch.finfo(dtype)
        if not fi.tiny <= abs(value) <= fi.max:
            raise ValueError(f"{name}: {value:.6g} is outside the range of {dtype} (the data's dtype: magnitudes "
                             f"{fi.tiny:.3g} to {fi.max:.3g}); use float64 data or a value in range")


def narrow_float(a: np.ndarray, dtype, name: str, *, underflow: bool = False) -> np.ndarray:
    """``a`` cast to the float ``dtype`` of a file (float32, float16), checked after the cast: ValueError naming
    ``name`` if a value overflows to inf (1e40 in float32, 1e5 in half) or, with ``underflow``, a nonzero value
    becomes 0 (the file would hold values that differ from the data's without a word)."""
    with np.errstate(over="ignore", under="ignore"):
        out = a.astype(dtype, copy=False)
    if not np.isfinite(out).all():
        raise ValueError(f"{name}: values up to {float(np.abs(a).max()):.4g} overflow {np.dtype(dtype).name} (largest "
                         f"{float(np.finfo(dtype).max):.4g}); scale the data or write a wider float")
    if underflow and bool(((a != 0) & (out == 0)).any()):
        small = float(np.abs(a[(a != 0) & (out == 0)]).max())
        raise ValueError(f"{name}: nonzero values as small as {small:.4g} underflow to 0 in {np.dtype(dtype).name} "
                         f"(smallest {float(np.finfo(dtype).smallest_subnormal):.4g}); scale the data")
    return out


def batch_param(value, name: str, batch: int, *, dtype, device, positive: bool = False) -> torch.Tensor:
    """A per-sample scalar as a tensor of shape [B] (a scalar broadcasts). A bool (``exposure_s=True`` was 1 s) is
    a TypeError naming ``name``, and so is a non-float ``dtype`` (an integer one truncated 0.0123 s to 0)."""
    if isinstance(value, bool) or isinstance(value, torch.Tensor) and value.dtype == torch.bool:
        raise TypeError(f"{name}: expected a number or a [B] tensor of numbers, got {value!r}")
    if dtype is not None and not dtype.is_floating_point:
        raise TypeError(f"{name}: the data's dtype {dtype} is not a float dtype; give float32 or float64 data")
    if isinstance(value, (int, float)):  # fast path: checked as a Python number
        if not math.isfinite(value):
            raise ValueError(f"{name}: expected finite values, found 1 NaN/Inf entries")
        if positive and value <= 0:
            raise ValueError(f"{name}: expected positive values, got {value:.6g}")
        dtype = dtype or torch.get_default_dtype()
        check_in_dtype_range(value, name, dtype)
        return torch.full((batch,), value, dtype=dtype, device=device)
    t = as_tensor(value, name, dtype=dtype, device=device)
    if t.dim() > 1:
        raise ValueError(f"{name}: expected a scalar or a [B] tensor, got shape {tuple(t.shape)}")
    t = t.reshape(-1)
    if t.numel() not in (1, batch):
        want = "1 value (the batch has one sample)" if batch == 1 else f"1 or {batch} values (one per batch sample)"
        raise ValueError(f"{name}: expected {want}, got {t.numel()}")
    vals = _small_values(t)
    if vals is None:
        check_finite(t, name)
        if positive and (t <= 0).any():
            raise ValueError(f"{name}: expected positive values, got {t.min().item():.6g}")
    else:
        bad = sum(not math.isfinite(v) for v in vals)
        if bad:
            raise ValueError(f"{name}: expected finite values, found {bad} NaN/Inf entries")
        if positive and min(vals) <= 0:
            raise ValueError(f"{name}: expected positive values, got {min(vals):.6g}")
    return t.expand(batch) if t.numel() == 1 else t


def isclose_grid(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.shape == b.shape and bool(torch.allclose(a.double().cpu(), b.double().cpu(), rtol=0, atol=1e-6))


def round_half_away(x: float) -> int:
    """MATLAB ``round``: halves away from zero."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def _integer_tensor_as_int(index):
    """A 0-d integer tensor (as a sampler gives) as a Python int; anything else (a bool, floating or complex tensor
    included) unchanged, for the caller's check to refuse. Shared by :func:`item_index` and :func:`dataset_index`."""
    if isinstance(index, torch.Tensor) and index.dim() == 0 and not (
            index.is_floating_point() or index.is_complex() or index.dtype == torch.bool):
        return int(index)
    return index


def item_index(index, name: str = "index") -> int:
    """An item's identity index: a non-negative integer (Python, NumPy, or a 0-d integer tensor as a sampler gives);
    ValueError naming ``name`` otherwise (1.5 was item 1)."""
    return check_integer(_integer_tensor_as_int(index), name, 0)


def dataset_index(index, length: int) -> int:
    """A map-style dataset's item index as an int in ``[0, length)`` (negative indices count from the end):
    TypeError unless an integer (Python, numpy or a 0-d integer tensor; a bool tensor was item 0 or 1), IndexError
    outside ``[-length, length)``."""
    index = _integer_tensor_as_int(index)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise TypeError(f"index: expected an integer, got {index!r}")
    index = int(index)
    if not -length <= index < length:
        raise IndexError(f"index: expected 0 <= index < {length}, got {index}")
    return index % length


def check_device(device) -> torch.device:
    """``device`` (a name or a :class:`torch.device`) as a device this torch can compute on here: ValueError naming
    ``device`` for a malformed name, a device type this build of torch lacks (``mps`` on Linux, ``cuda`` without
    CUDA), an absent device (``cuda:3`` on a one-GPU machine; a tiny allocation is the test) or ``meta`` (shapes
    only, no values to compute or score). Shared by the demosaic benchmark
    (:mod:`isettorch.isp.evaluation`) and :class:`isettorch.data.PairStream`."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as err:
        raise ValueError(f"device: {device!r} is not a torch device ({first_line(err)})") from err
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device: {str(device)!r}, but CUDA is not available on this machine")
    if dev.type == "meta":
        raise ValueError("device: 'meta' holds no values (shapes only); expected a device that computes, e.g. cpu")
    try:
        torch.zeros(1, device=dev)
    except Exception as err:  # noqa: BLE001 - torch raises RuntimeError, AssertionError, NotImplementedError, ...
        raise ValueError(f"device: cannot compute on {str(device)!r} with this torch build on this machine "
                         f"({first_line(err).split('. ')[0]})") from err
    return dev


def check_zip_crc(path, name: str) -> None:
    """A ``torch.save`` file (a zip archive) whose members fail their CRC-32 is refused naming ``name``:
    ``torch.load`` does not check them, so a damaged file loaded with changed weights. Files that are not zip
    archives are left to ``torch.load``'s own message."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError):
        return
    except Exception as err:  # noqa: BLE001 - zlib errors of a damaged compressed member
        bad = f"({type(err).__name__})"
    if bad is not None:
        raise ValueError(f"{name}: {str(path)!r} is damaged (member {bad} fails its CRC-32 check)")


def check_integer(value, name: str, minimum: int | None = None) -> int:
    """``value`` if it is an integer (>= ``minimum``); a float such as 1.7 is not truncated, a bool is not an
    integer: ValueError naming ``name``."""
    if not is_integer(value) or (minimum is not None and value < minimum):
        what = {None: "an integer", 0: "a non-negative integer", 1: "a positive integer"}.get(
            minimum, f"an integer >= {minimum}")
        raise ValueError(f"{name}: expected {what}, got {value!r}")
    return int(value)


#: seeds are reduced modulo 2^64 by :func:`seed_for` (SplitMix64 state): seeds outside ``[0, 2^64)`` would alias
SEED_LIMIT = 2 ** 64


def check_seed(seed, name: str = "seed") -> int:
    """A seed (the data sets and streams, ``isettorch synth``, sensors, scene generators, evaluations): an integer in
    ``[0, 2^64)``, the 64-bit word :func:`seed_for` mixes it as (outside it, seeds alias: ``2^64`` draws what ``0``
    draws, ``-1`` what ``2^64 - 1`` draws); ValueError naming ``seed`` otherwise."""
    seed = check_integer(seed, name)
    if not 0 <= seed < SEED_LIMIT:
        raise ValueError(f"{name}: expected an integer in [0, 2**64) (seeds are mixed as 64-bit words: {seed} would "
                         f"repeat the items of seed {seed % SEED_LIMIT}), got {seed!r}")
    return seed


_MASK64 = (1 << 64) - 1


def seed_for(seed: int, index: int, stream: int = 0) -> int:
    """A 63-bit seed for item ``index`` of a dataset seeded with ``seed`` (SplitMix64 finaliser, Steele et al.,
    "Fast splittable pseudorandom number generators", OOPSLA 2014). Depends only on its arguments, so an item
    is identical on any worker or rank. ``seed`` as :func:`check_seed` (1.5, "1" or True read as seed 1, -1 as
    2^64 - 1); ``index`` and ``stream`` integers (of any sign: the library's own streams use index -1)."""
    seed = check_seed(seed)
    for name, v in (("index", index), ("stream", stream)):
        if not is_integer(v):
            raise ValueError(f"{name}: expected an integer, got {v!r}")
    return splitmix64(int(seed) * 0x9E3779B97F4A7C15 + int(index) * 0xD1B54A32D192ED03
                      + int(stream) * 0x8CB92BA72F3D8DD7 + 0x632BE59BD9B4E019)


def splitmix64(z: int) -> int:
    """SplitMix64's finaliser of the 64-bit word ``z mod 2^64``, to 63 bits (a torch seed of every sign)."""
    z &= _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return (z ^ (z >> 31)) & ((1 << 63) - 1)


def warn_caller(message: str, category=UserWarning) -> None:
    """``warnings.warn`` attributed to the first frame outside isettorch and torch: the user's line that called the
    library (a fixed ``stacklevel`` pointed into the library, the more so behind wrappers such as
    ``_autograd.full_precision`` and ``Module.__call__``)."""
    import sys
    import warnings

    frame, level = sys._getframe(1), 2
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in ("isettorch", "torch"):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)
