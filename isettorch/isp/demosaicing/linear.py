"""Linear demosaicing: nearest-neighbour replication, bilinear, normalised convolution for any CFA, and
Malvar-He-Cutler (2004)."""

from __future__ import annotations

import contextlib

import torch
import torch.nn.functional as F

from ..._autograd import tensor_cache
from ..._checks import check_bool
from ._cfa import (
    bayer_index_map,
    channel_masks,
    check_bayer_pattern,
    check_index_map,
    check_raw,
    correlate,
    idx_key,
    pad,
)

__all__ = ["demosaic_nearest", "demosaic_bilinear", "demosaic_generic", "demosaic_malvar2004",
           "demosaic_nearest_cfa"]


def _nearest_sources(index_map: torch.Tensor, num_channels: int) -> torch.Tensor:
    """For each channel and CFA phase, the (dy, dx) offset to the nearest sample of that channel in the period-sized
    window above and to the left (dy in (-ph, 0], dx in (-pw, 0]); ties prefer the same row. Offsets depend only
    on the CFA phase, not on where periods start, so the method is shift-consistent. Returns long [C, ph, pw, 2]."""
    ph, pw = index_map.shape
    out = torch.zeros(num_channels, ph, pw, 2, dtype=torch.long)
    window = sorted(((dy, dx) for dy in range(-ph + 1, 1) for dx in range(-pw + 1, 1)),
                    key=lambda d: (abs(d[0]) + abs(d[1]), abs(d[0]), -d[0], -d[1]))
    for py in range(ph):
        for px in range(pw):
            for c in range(num_channels):
                out[c, py, px] = torch.tensor(next(d for d in window
                                                   if index_map[(py + d[0]) % ph, (px + d[1]) % pw] == c))
    return out


def demosaic_nearest_cfa(raw: torch.Tensor, index_map: torch.Tensor, num_channels: int | None = None
                         ) -> torch.Tensor:
    """Nearest-neighbour replication for any periodic CFA: every pixel takes, for each channel, the value of the
    closest sample of that channel above and to its left, within one CFA period (Losson et al. 2010);
    on the top/left border, the sample one period further in.

    Args:
        raw: mosaic (B, 1, H, W).
        index_map: long tensor [ph, pw] of channel indices (row-major, top-left first).
        num_channels: C (default: max index + 1).

    Returns:
        (B, C, H, W).
    """
    raw = check_raw(raw)
    bsz, _, h, w = raw.shape
    idx, c = check_index_map(index_map, num_channels, h, w)
    ph, pw = idx.shape
    offsets = _nearest_sources(idx, c).tolist()
    # Pad top/left by one period minus one with the same phase one period further in (raw row -k <- row ph - k).
    xp = torch.cat([raw[..., 1:ph, :], raw], dim=-2)
    xp = torch.cat([xp[..., 1:pw], xp], dim=-1)
    out = raw.new_empty(bsz, c, h, w)
    for py in range(ph):
        ny = len(range(py, h, ph))
        for px in range(pw):
            nx = len(range(px, w, pw))
            for ch in range(c):
                dy, dx = offsets[ch][py][px]
                y0, x0 = py + dy + ph - 1, px + dx + pw - 1
                out[:, ch, py::ph, px::pw] = xp[:, 0, y0:y0 + (ny - 1) * ph + 1:ph, x0:x0 + (nx - 1) * pw + 1:pw]
    return out


def demosaic_nearest(raw: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """Nearest-neighbour replication demosaic of a Bayer mosaic (Losson et al. 2010): each missing
    value is copied from the closest site of that colour to the left, above, or above-left (G from the left).

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device.
        pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (row-major, top-left first).

    Returns:
        RGB (B, 3, H, W).

    Example:
        >>> demosaic_nearest(torch.rand(1, 1, 4, 6), "RGGB").shape
        torch.Size([1, 3, 4, 6])
    """
    return demosaic_nearest_cfa(raw, bayer_index_map(check_bayer_pattern(pattern)), 3)


def _tent(ph: int, pw: int) -> list[list[float]]:
    """Separable triangle kernel of size (2ph-1, 2pw-1): bilinear interpolation weights for period (ph, pw)."""
    return [[float((ph - abs(dy)) * (pw - abs(dx))) for dx in range(-pw + 1, pw)] for dy in range(-ph + 1, ph)]


def demosaic_generic(raw: torch.Tensor, index_map: torch.Tensor, num_channels: int | None = None) -> torch.Tensor:
    """Demosaic any periodic CFA by normalised convolution (Knutsson & Westin 1993): for each channel c,
    ``(K * (raw m_c)) / (K * m_c)`` at the sites where c is missing, the measured value where it is sampled.
    K is the separable triangle of size (2ph-1, 2pw-1), so every channel has a sample in its support; the
    image and masks are padded by half-sample symmetric reflection, so borders need no special case. On a
    Bayer CFA this is bilinear interpolation (equal to ``demosaic_bilinear`` away from the one-pixel border).

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device; H >= ph, W >= pw.
        index_map: long tensor [ph, pw] of channel indices in [0, num_channels) (row-major, top-left first);
            every channel must appear at least once.
        num_channels: C (default: max index + 1).

    Returns:
        (B, C, H, W).

    Example:
        >>> rgbw = torch.tensor([[0, 1], [3, 2]])  # R G / W B
        >>> demosaic_generic(torch.rand(2, 1, 6, 6), rgbw, 4).shape
        torch.Size([2, 4, 6, 6])
    """
    raw = check_raw(raw)
    h, w = raw.shape[-2:]
    idx, c = check_index_map(index_map, num_channels, h, w)
    masks = channel_masks(idx, c, h, w, dtype=raw.dtype, device=raw.device)
    kernel = [_tent(*idx.shape)]
    num = correlate(raw * masks, kernel, "symmetric")
    den = correlate(masks, kernel, "symmetric")
    return torch.where(masks > 0, raw, num / den)


# Bilinear kernels (Losson, Macaire & Yang 2010, "Comparison of color demosaicing methods"; as colour-demosaicing).
_H_G = [[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]]
_H_RB = [[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]]


def demosaic_bilinear(raw: torch.Tensor, pattern: str = "RGGB", *, normalize_border: bool = True) -> torch.Tensor:
    """Bilinear demosaic of a Bayer mosaic (Losson et al. 2010): each channel's samples convolved
    with a 3x3 kernel, the image extended by half-sample symmetric reflection (scipy 'reflect').

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device.
        pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (row-major, top-left first).
        normalize_border: divide by the kernel weight that fell on samples of the channel. Inside the image this
            weight is exactly 1, so the result is bit-identical to colour-demosaicing; on the one-pixel border the
            reflection brings fewer samples of a channel, and colour-demosaicing (``False``) returns a too-dark
            value there (e.g. G = G/2 at an R corner), while ``True`` averages the samples it has and keeps a
            constant image constant.

    Returns:
        RGB (B, 3, H, W), not clipped.

    Example:
        >>> demosaic_bilinear(torch.rand(1, 1, 4, 6), "GRBG").shape
        torch.Size([1, 3, 4, 6])
    """
    raw = check_raw(raw)
    h, w = raw.shape[-2:]
    idx = bayer_index_map(check_bayer_pattern(pattern))
    if h < 2 or w < 2:
        raise ValueError(f"raw: expected at least 2x2 pixels for a Bayer mosaic, got {h}x{w}")
    masks = channel_masks(idx, 3, h, w, dtype=raw.dtype, device=raw.device)
    kernel = [_H_RB, _H_G, _H_RB]
    out = correlate(raw * masks, kernel, "symmetric")
    if check_bool(normalize_border, "normalize_border"):
        out = out / _bilinear_weight(idx_key(idx), h, w, raw.dtype, raw.device)
    return out


@tensor_cache(maxsize=4)  # full-size masks: keep few (a 24 MP frame is ~0.1-0.3 GB)
def _bilinear_weight(key: tuple, h: int, w: int, dtype, device) -> torch.Tensor:
    """Kernel weight that falls on samples of each channel: exactly 1 away from the one-pixel border."""
    masks = channel_masks(torch.tensor(key), 3, h, w, dtype=dtype, device=device)
    return correlate(masks, [_H_RB, _H_G, _H_RB], "symmetric")


# Malvar, He & Cutler (2004), Fig. 2: gradient-corrected bilinear kernels (x 1/8).
_G_AT_RB = [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]]
_RB_AT_G_ROW = [[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]]
_RB_AT_BR = [[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]]


def _scaled(kernel, factor: float) -> list[list[float]]:
    return [[v * factor for v in row] for row in kernel]


_MALVAR = [_scaled(_G_AT_RB, 1 / 8), _scaled(_RB_AT_G_ROW, 1 / 8), _scaled(list(zip(*_RB_AT_G_ROW)), 1 / 8),
           _scaled(_RB_AT_BR, 1 / 8)]


@tensor_cache(maxsize=16)
def _malvar_polyphase(pattern: str, dtype, device) -> tuple[torch.Tensor, tuple, tuple]:
    """:func:`demosaic_malvar2004`'s kernels on the polyphase planes of the mosaic padded by 2: a (8, 4, 3, 3) weight
    (each cell position's two estimates), for each output channel the colour and cell position it fills, and each
    cell position's sampled colour ``((colour, py, px), ...)``. Tap
    (ky, kx) of 0..4 at position (py, px) reads padded pixel (py + ky, px + kx): plane 2 (y % 2) + x % 2 at cell
    offset (y // 2, x // 2). (Cached, by tensor_cache: outside inference mode, so autograd may use it.)"""
    idx = bayer_index_map(pattern).tolist()
    weight, writes = [[[[0.0] * 3 for _ in range(3)] for _ in range(4)] for _ in range(8)], []
    for py, px in ((0, 0), (0, 1), (1, 0), (1, 1)):
        site = idx[py][px]
        if site == 1:  # green: the colour of its row by the row kernel, of its column by the column kernel
            kernels = ((idx[py][1 - px], _MALVAR[1]), (idx[1 - py][px], _MALVAR[2]))
        else:  # red or blue: green, and the other of the two by the diagonal kernel
            kernels = ((1, _MALVAR[0]), (2 - site, _MALVAR[3]))
        for c, kernel in kernels:
            for ky, row in enumerate(kernel):
                for kx, wt in enumerate(row):
                    y, x = py + ky, px + kx
                    weight[len(writes)][2 * (y % 2) + x % 2][y // 2][x // 2] = float(wt)
            writes.append((c, py, px))
    samples = tuple((idx[py][px], py, px) for py, px in ((0, 0), (0, 1), (1, 0), (1, 1)))
    return torch.tensor(weight, dtype=dtype, device=device), tuple(writes), samples


def demosaic_malvar2004(raw: torch.Tensor, pattern: str = "RGGB", boundary: str = "symmetric") -> torch.Tensor:
    """Malvar-He-Cutler high-quality linear demosaic of a Bayer mosaic: bilinear interpolation corrected by the
    Laplacian of the channel sampled at the site, as four fixed 5x5 kernels (Malvar et al. 2004, Fig. 2). The
    image is extended by half-sample symmetric reflection (scipy 'reflect', as colour-demosaicing does).
    Differentiable; :class:`isettorch.isp.learned.DemosaicNet` corrects this estimate.

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device.
        pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (row-major, top-left first).
        boundary: 'symmetric' (default, scipy 'reflect': d c b a | a b c d) or 'mirror' (scipy 'mirror' = torch
            'reflect': d c b | a b c d), the extension the shipped learned networks were trained with. The
            half-sample reflection moves a Bayer mosaic's colour phase at the border, so with 'symmetric' a constant
            colour field is not reproduced in the outer two rows and columns (errors up to 0.55 of a (0.1, 0.5, 0.9)
            field, 0.70 on a mosaic two pixels high); 'mirror' keeps the phase and reproduces it exactly (2e-16).
            The pipeline's demosaic stage (:class:`isettorch.isp.pipeline.DemosaicStage`) and the learned networks'
            base use 'mirror'; the default stays colour-demosaicing's, so that the benchmark numbers match it.

    Returns:
        RGB (B, 3, H, W), not clipped.

    Example:
        >>> demosaic_malvar2004(torch.rand(2, 1, 8, 8), "BGGR").shape
        torch.Size([2, 3, 8, 8])

    Reference:
        H. S. Malvar, L.-W. He, R. Cutler, "High-quality linear interpolation for demosaicing of Bayer-patterned
        color images", ICASSP 2004.
    """
    raw = check_raw(raw)
    if boundary not in ("symmetric", "mirror"):
        raise ValueError(f"boundary: expected 'symmetric' or 'mirror', got {boundary!r}")
    pattern = check_bayer_pattern(pattern)
    b, _, h, w = raw.shape
    if h < 2 or w < 2:  # as the other methods: a mosaic without a whole 2 x 2 cell lacks a colour
        raise ValueError(f"raw: expected at least 2x2 pixels for a Bayer mosaic, got {h}x{w}")
    if b == 0:  # an empty batch, as the other methods return it (pixel_unshuffle kept the empty input's shape)
        return raw.new_zeros(0, 3, h, w)
    # Each 2 x 2 cell position holds one colour and needs the other two, each one of the four kernels at that
    # position only. On the mosaic's four polyphase planes a 5 x 5 kernel at one position is a 3 x 3 kernel over the
    # planes, so the eight estimates are one convolution (4 planes in, 8 out) at a quarter of the pixels, written
    # with the samples into their positions: no full-resolution kernel pass and no selection, and ~10 operations a
    # call instead of ~60 (8.2-8.8 against 10.4-13.4 ms/MP on Kodak and McMaster sizes, 2 threads, AVX2).
    hc, wc = (h + 1) // 2, (w + 1) // 2
    xp = pad(raw, 2, 2, boundary)
    if h % 2 or w % 2:  # an even padded size; the extra row/column is read only by outputs cropped away
        xp = F.pad(xp, (0, w % 2, 0, h % 2), mode="replicate")
    planes = F.pixel_unshuffle(xp, 2)  # plane 2 qy + qx holds xp[qy::2, qx::2]
    weight, writes, samples = _malvar_polyphase(pattern, raw.dtype, raw.device)
    device_type = raw.device.type
    with (torch.autocast(device_type, enabled=False) if torch.amp.is_autocast_available(device_type)
          else contextlib.nullcontext()):  # at the mosaic's precision under autocast too, as the other methods are
        estimates = F.conv2d(planes, weight)
    out = raw.new_empty(b, 3, 2 * hc, 2 * wc)
    cells = out.view(b, 3, hc, 2, wc, 2)
    for k, (c, py, px) in enumerate(writes):
        cells[:, c, :, py, :, px] = estimates[:, k]
    for c, py, px in samples:  # the samples (the planes' interior: xp is padded by one cell)
        cells[:, c, :, py, :, px] = planes[:, 2 * py + px, 1:1 + hc, 1:1 + wc]
    return out if (h, w) == out.shape[-2:] else out[..., :h, :w].contiguous()
