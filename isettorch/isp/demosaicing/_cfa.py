"""CFA helpers shared by the demosaic methods: pattern parsing, channel masks, boundary padding that matches
scipy.ndimage's modes, small separable/2-D convolutions, and mosaicking (sampling an image through a CFA)."""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from ..._autograd import tensor_cache
from ..._checks import FLOAT_DTYPES, check_finite
from ...sensor.cfa import BAYER_PATTERNS, CFA, tile  # the one CFA-pattern table and its tiling


def check_raw(raw, name: str = "raw") -> torch.Tensor:
    """A mosaic is a floating tensor of shape (B, 1, H, W)."""
    if not isinstance(raw, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor of shape (B, 1, H, W), got {type(raw).__name__}")
    if raw.dim() != 4 or raw.shape[1] != 1:
        raise ValueError(f"{name}: expected a tensor of shape (B, 1, H, W), got shape {tuple(raw.shape)}")
    if raw.dtype not in FLOAT_DTYPES:  # (float16 / bfloat16: Menon's decisions flipped, 0.27 off)
        raise TypeError(f"{name}: expected a floating-point tensor (float32 or float64), got dtype {raw.dtype}")
    # a NaN or Inf sample is refused, not spread (called directly, bilinear spread one NaN sample to 23 outputs,
    # MHC to 73, Menon to 40; demosaic() refused it)
    check_finite(raw.detach(), name)
    return raw


def check_bayer_pattern(pattern) -> str:
    """Normalise a Bayer pattern string ('RGGB', 'BGGR', 'GRBG', 'GBRG'; row-major, top-left first)."""
    if not isinstance(pattern, str):
        raise TypeError(f"pattern: expected one of {BAYER_PATTERNS} as a string, got {type(pattern).__name__}")
    p = pattern.upper()
    if p not in BAYER_PATTERNS:
        raise ValueError(f"pattern: expected one of {BAYER_PATTERNS}, got {pattern!r}")
    return p


def bayer_index_map(pattern: str, device=None) -> torch.Tensor:
    """The 2x2 channel-index map (0 = R, 1 = G, 2 = B) of a Bayer pattern, as a long tensor [2, 2].

    Example:
        >>> bayer_index_map("GRBG").tolist()
        [[1, 0], [2, 1]]
    """
    return CFA(check_bayer_pattern(pattern)).index_map.to(device)


def check_index_map(index_map, num_channels: int | None, height: int, width: int) -> tuple[torch.Tensor, int]:
    """Validate a CFA index map [ph, pw] of channel indices; returns it (long, CPU) and the channel count."""
    if not isinstance(index_map, torch.Tensor):
        raise TypeError(f"index_map: expected a long tensor [ph, pw] of channel indices, "
                        f"got {type(index_map).__name__}")
    if index_map.dim() != 2 or index_map.numel() == 0:
        raise ValueError(f"index_map: expected a non-empty tensor of shape [ph, pw], "
                         f"got shape {tuple(index_map.shape)}")
    if index_map.is_floating_point() or index_map.is_complex() or index_map.dtype == torch.bool:
        raise TypeError(f"index_map: expected an integer (long) tensor of channel indices, "
                        f"got dtype {index_map.dtype}")
    idx = index_map.detach().to("cpu", torch.long)
    if num_channels is None:
        num_channels = int(idx.max()) + 1
    if not isinstance(num_channels, int) or num_channels < 1:
        raise ValueError(f"num_channels: expected a positive integer, got {num_channels!r}")
    if idx.min() < 0 or idx.max() >= num_channels:
        raise ValueError(f"index_map: expected channel indices in [0, {num_channels - 1}], got {idx.tolist()}")
    missing = sorted(set(range(num_channels)) - set(idx.flatten().tolist()))
    if missing:
        raise ValueError(f"index_map: every channel must be sampled at least once, channels {missing} are absent "
                         f"from {idx.tolist()}")
    ph, pw = idx.shape
    if height < ph or width < pw:
        raise ValueError(f"raw: expected at least one full CFA period ({ph}x{pw}), got an image of {height}x{width}")
    return idx, num_channels


def idx_key(index_map: torch.Tensor) -> tuple:
    """A hashable copy of an index map (for caches)."""
    return tuple(map(tuple, index_map.tolist()))


@tensor_cache(maxsize=4)  # full-size masks: keep few (a 24 MP frame is ~0.1-0.3 GB)
def _channel_masks(key: tuple, num_channels: int, height: int, width: int, dtype, device) -> torch.Tensor:
    full = tile(torch.tensor(key, device=device), height, width)
    return (full[None] == torch.arange(num_channels, device=device)[:, None, None]).to(dtype)[None]


def channel_masks(index_map: torch.Tensor, num_channels: int, height: int, width: int, *, dtype, device
                  ) -> torch.Tensor:
    """One-hot sampling masks (1, C, H, W) of a CFA tiled over the image (cached; do not modify in place)."""
    return _channel_masks(idx_key(index_map), num_channels, height, width, dtype, torch.device(device))


@tensor_cache(maxsize=4)  # full-size masks: keep few (a 24 MP frame is ~0.1-0.3 GB)
def bayer_masks(pattern: str, height: int, width: int, device) -> dict[str, torch.Tensor]:
    """Boolean masks (1, 1, H, W) of a Bayer mosaic: R, G, B sites and the rows/columns that hold R or B
    (cached; do not modify in place)."""
    full = tile(bayer_index_map(pattern, device=device), height, width)[None, None]
    r, g, b = full == 0, full == 1, full == 2
    m = {
        "R": r, "G": g, "B": b,
        "R_row": r.any(dim=-1, keepdim=True).expand_as(r), "R_col": r.any(dim=-2, keepdim=True).expand_as(r),
        "B_row": b.any(dim=-1, keepdim=True).expand_as(b), "B_col": b.any(dim=-2, keepdim=True).expand_as(b),
    }
    m["G_in_R_row"], m["G_in_B_row"] = g & m["R_row"], g & m["B_row"]
    return m


def _fold(n: int, before: int, after: int, mode: str, device) -> torch.Tensor:
    """Source indices for padding an axis of length n, like scipy.ndimage's boundary modes."""
    idx = torch.arange(-before, n + after, device=device)
    if mode == "symmetric":  # scipy 'reflect' (half-sample symmetric): d c b a | a b c d | d c b a
        period = 2 * n
        idx = idx % period
        return torch.where(idx >= n, period - 1 - idx, idx)
    if mode == "mirror":  # scipy 'mirror', torch 'reflect' (whole-sample): d c b | a b c d | c b a
        if n == 1:
            return torch.zeros_like(idx)
        period = 2 * n - 2
        idx = idx % period
        return torch.where(idx >= n, period - idx, idx)
    raise ValueError(f"mode: expected 'symmetric', 'mirror' or 'zeros', got {mode!r}")


def pad(x: torch.Tensor, py: int, px: int, mode: str) -> torch.Tensor:
    """Pad the last two dims by (py, px) on each side. mode: 'symmetric' (scipy 'reflect'), 'mirror' (scipy
    'mirror' = torch 'reflect') or 'zeros' (scipy 'constant')."""
    if py == 0 and px == 0:
        return x
    if mode == "zeros":
        return F.pad(x, (px, px, py, py))
    h, w = x.shape[-2:]
    if mode == "mirror" and py < h and px < w:
        return F.pad(x, (px, px, py, py), mode="reflect")
    if mode == "symmetric" and py <= h and px <= w:
        if py:
            x = torch.cat([x[..., :py, :].flip(-2), x, x[..., h - py:, :].flip(-2)], dim=-2)
        if px:
            x = torch.cat([x[..., :px].flip(-1), x, x[..., w - px:].flip(-1)], dim=-1)
        return x
    if py:
        x = x.index_select(-2, _fold(h, py, py, mode, x.device))
    if px:
        x = x.index_select(-1, _fold(w, px, px, mode, x.device))
    return x


@functools.lru_cache(maxsize=256)
def _weight_groups(kernel: tuple) -> tuple:
    """A constant kernel's taps grouped by weight, ``((weight, ((dy, dx), ...)), ...)`` in first-seen order
    (cached: the grouping is Python work that every call of a demosaic repeated, ~40 us per kernel)."""
    by_weight: dict[float, list[tuple[int, int]]] = {}
    for dy, row in enumerate(kernel):
        for dx, wt in enumerate(row):
            if wt != 0:
                by_weight.setdefault(float(wt), []).append((dy, dx))
    return tuple((wt, tuple(offsets)) for wt, offsets in by_weight.items())


def _shift_add(xp: torch.Tensor, kernel, h: int, w: int, oy: int = 0, ox: int = 0) -> torch.Tensor:
    """Correlate a padded plane with a small constant kernel (nested sequences of floats) by summing shifted
    slices ``xp[..., oy + dy : oy + dy + h, ox + dx : ox + dx + w]``, one multiply per distinct weight: cheaper
    than conv2d for the sparse 3x3/5x5 kernels here, in any dtype."""
    acc = None
    for wt, offsets in _weight_groups(tuple(map(tuple, kernel))):
        slices = [xp[..., oy + y:oy + y + h, ox + x:ox + x + w] for y, x in offsets]
        if len(slices) == 1:
            if acc is None:
                acc = slices[0] * wt
            else:
                acc.add_(slices[0], alpha=wt)
            continue
        part = slices[0] + slices[1]
        for sl in slices[2:]:
            part.add_(sl)
        if acc is None:
            acc = part.mul_(wt) if wt != 1.0 else part
        else:
            acc.add_(part, alpha=wt)
    return xp.new_zeros(xp.shape[:-2] + (h, w)) if acc is None else acc


def correlate_hv(x: torch.Tensor, taps, mode: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Correlate every channel with the same constant 1-D taps along the width and along the height (one pad)."""
    r = len(taps) // 2
    h, w = x.shape[-2:]
    xp = pad(x, r, r, mode)
    return (_shift_add(xp, [list(taps)], h, w, oy=r), _shift_add(xp, [[t] for t in taps], h, w, ox=r))


def correlate(x: torch.Tensor, kernels, mode: str) -> torch.Tensor:
    """Depthwise 2-D correlation, same-size output: channel c of x (N, C, H, W) with kernels[c], a constant
    odd-sized kernel given as nested sequences of floats (one kernel may serve all C channels)."""
    kernels = list(kernels)
    c = x.shape[1]
    if len(kernels) not in (1, c):
        raise ValueError(f"kernels: expected 1 or {c} kernels, got {len(kernels)}")
    kh, kw = len(kernels[0]), len(kernels[0][0])
    h, w = x.shape[-2:]
    xp = pad(x, kh // 2, kw // 2, mode)
    if len(kernels) == 1:
        return _shift_add(xp, kernels[0], h, w)
    return torch.cat([_shift_add(xp[:, i:i + 1], k, h, w) for i, k in enumerate(kernels)], dim=1)


def correlate_h(x: torch.Tensor, taps, mode: str) -> torch.Tensor:
    """Correlate every channel along the width with the same constant 1-D taps (odd length)."""
    return correlate(x, [[list(taps)]], mode)


def correlate_v(x: torch.Tensor, taps, mode: str) -> torch.Tensor:
    """Correlate every channel along the height with the same constant 1-D taps (odd length)."""
    return correlate(x, [[[t] for t in taps]], mode)


def mosaic(image: torch.Tensor, pattern="RGGB") -> torch.Tensor:
    """Sample an image through a CFA: (B, C, H, W) -> (B, 1, H, W), noise-free.

    Args:
        image: (B, C, H, W); C = 3 (R, G, B) for a Bayer pattern string.
        pattern: a Bayer pattern string ('RGGB', 'BGGR', 'GRBG', 'GBRG') or a long index map [ph, pw] of
            channel indices into C.

    Example:
        >>> mosaic(torch.rand(2, 3, 8, 8), "RGGB").shape
        torch.Size([2, 1, 8, 8])
    """
    if not isinstance(image, torch.Tensor) or image.dim() != 4:
        raise ValueError(f"image: expected a tensor of shape (B, C, H, W), got "
                         f"{tuple(image.shape) if isinstance(image, torch.Tensor) else type(image).__name__}")
    h, w = image.shape[-2:]
    if isinstance(pattern, str):
        idx = bayer_index_map(pattern)
        if image.shape[1] != 3:
            raise ValueError(f"image: a Bayer pattern needs 3 channels (R, G, B), got shape {tuple(image.shape)}")
        idx, _ = check_index_map(idx, 3, h, w)
    else:
        idx, _ = check_index_map(pattern, image.shape[1], h, w)
    full = tile(idx.to(image.device), h, w)[None, None].expand(image.shape[0], 1, h, w)
    return image.gather(1, full)
