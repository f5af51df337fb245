"""Linear demosaicing: nearest-neighbour replication, bilinear, normalised convolution for any CFA, and
Malvar-He-Cutler (2004)."""

from __future__ import annotations

import torch

from ._cfa import (
    bayer_index_map,
    bayer_masks,
    channel_masks,
    check_bayer_pattern,
    check_index_map,
    check_raw,
    correlate,
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
    closest sample of that channel above and to its left, within one CFA period (Losson et al. 2010, section 3.1);
    on the top/left border, the sample one period further in.

    Args:
        raw: mosaic (B, 1, H, W).
        index_map: long tensor [ph, pw] of channel indices (row-major, top-left first).
        num_channels: C (default: max index + 1).

    Returns:
        (B, C, H, W).
    """
    raw = check_raw(raw)
    h, w = raw.shape[-2:]
    idx, c = check_index_map(index_map, num_channels, h, w)
    ph, pw = idx.shape
    off = _nearest_sources(idx, c)[:, torch.arange(h)[:, None] % ph, torch.arange(w)[None, :] % pw]  # C,H,W,2
    sy = torch.arange(h)[:, None] + off[..., 0]
    sx = torch.arange(w)[None, :] + off[..., 1]
    # On the top/left border the sample can fall outside the image: use the same phase one period further in.
    sy = torch.where(sy < 0, sy + ph, sy)
    sx = torch.where(sx < 0, sx + pw, sx)
    src = (sy * w + sx).reshape(-1).to(raw.device)
    return raw.flatten(1).index_select(1, src).reshape(raw.shape[0], c, h, w)


def demosaic_nearest(raw: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """Nearest-neighbour replication demosaic of a Bayer mosaic (Losson et al. 2010, section 3.1): each missing
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


def _tent(ph: int, pw: int, dtype, device) -> torch.Tensor:
    """Separable triangle kernel of size (2ph-1, 2pw-1): bilinear interpolation weights for period (ph, pw)."""
    ty = ph - torch.arange(-(ph - 1), ph, dtype=dtype, device=device).abs()
    tx = pw - torch.arange(-(pw - 1), pw, dtype=dtype, device=device).abs()
    return ty[:, None] * tx[None, :]


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
    kernel = _tent(*idx.shape, raw.dtype, raw.device).expand(c, -1, -1)
    num = correlate(raw * masks, kernel, "symmetric")
    den = correlate(masks, kernel, "symmetric")
    return torch.where(masks > 0, raw, num / den)


# Losson et al. (2010) eq. 3.3-3.4 (the kernels of colour-demosaicing's bilinear method).
_H_G = [[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]]
_H_RB = [[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]]


def demosaic_bilinear(raw: torch.Tensor, pattern: str = "RGGB", *, normalize_border: bool = True) -> torch.Tensor:
    """Bilinear demosaic of a Bayer mosaic (Losson et al. 2010, section 3.2): each channel's samples convolved
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
    kernel = torch.tensor([_H_RB, _H_G, _H_RB], dtype=raw.dtype, device=raw.device)
    out = correlate(raw * masks, kernel, "symmetric")
    if normalize_border:
        weight = correlate(masks, kernel, "symmetric")  # exactly 1 away from the border
        out = out / weight
    return out


# Malvar, He & Cutler (2004), Fig. 2: gradient-corrected bilinear kernels (x 1/8).
_G_AT_RB = [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]]
_RB_AT_G_ROW = [[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]]
_RB_AT_BR = [[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]]


def _malvar_kernels(dtype, device) -> torch.Tensor:
    row = torch.tensor(_RB_AT_G_ROW, dtype=dtype, device=device)
    k = torch.stack([torch.tensor(_G_AT_RB, dtype=dtype, device=device), row, row.T,
                     torch.tensor(_RB_AT_BR, dtype=dtype, device=device)])
    return k / 8


def demosaic_malvar2004(raw: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """Malvar-He-Cutler high-quality linear demosaic of a Bayer mosaic: bilinear interpolation corrected by the
    Laplacian of the channel sampled at the site, as four fixed 5x5 kernels (Malvar et al. 2004, Fig. 2). The
    image is extended by half-sample symmetric reflection (scipy 'reflect', as colour-demosaicing does).

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device.
        pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (row-major, top-left first).

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
    bsz, _, h, w = raw.shape
    m = bayer_masks(check_bayer_pattern(pattern), h, w, raw.device)
    k = _malvar_kernels(raw.dtype, raw.device)
    # candidates: 0 raw, 1 G at R/B, 2 R/B at G in a row of that colour, 3 ... in a column of it, 4 R at B / B at R
    cand = torch.cat([raw, correlate(raw.expand(-1, 4, -1, -1), k, "symmetric")], dim=1)
    g_in_r_row, g_in_b_row = m["G"] & m["R_row"], m["G"] & m["B_row"]
    zero = torch.zeros_like(m["R"], dtype=torch.long)
    sel_r = zero + 2 * g_in_r_row + 3 * g_in_b_row + 4 * m["B"]
    sel_g = zero + 1 * (m["R"] | m["B"])
    sel_b = zero + 2 * g_in_b_row + 3 * g_in_r_row + 4 * m["R"]
    sel = torch.cat([sel_r, sel_g, sel_b], dim=1).expand(bsz, 3, h, w)
    return cand.gather(1, sel)
