"""DDFAPD: demosaicing with directional filtering and a posteriori decision (Menon, Andriani & Calvagno 2007)."""

from __future__ import annotations

import torch

from ..._checks import check_bool
from ._cfa import bayer_masks, check_bayer_pattern, check_raw, correlate, correlate_hv, pad

__all__ = ["demosaic_menon2007"]

# Menon et al. (2007): directional green filter h0 (bilinear) + h1 (Laplacian correction), applied separately
# as colour-demosaicing does (the rounding then matches, and so do its direction decisions).
_H0 = (0.0, 0.5, 0.0, 0.5, 0.0)
_H1 = (-0.25, 0.0, 0.5, 0.0, -0.25)
# Menon et al. (2007): decision window over the current and the two previous columns (horizontal direction),
# written as a correlation kernel (colour-demosaicing applies it by convolution, i.e. flipped).
_K_DECISION = ((1.0, 0.0, 1.0, 0.0, 0.0),
               (0.0, 1.0, 0.0, 0.0, 0.0),
               (3.0, 0.0, 3.0, 0.0, 0.0),
               (0.0, 1.0, 0.0, 0.0, 0.0),
               (1.0, 0.0, 1.0, 0.0, 0.0))
_K_DECISION_T = tuple(zip(*_K_DECISION))
_K_PAIR = (0.5, 0.0, 0.5)
_K_MEAN3 = (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)


def _hv(x, taps):
    return correlate_hv(x, taps, "mirror")


def demosaic_menon2007(raw: torch.Tensor, pattern: str = "RGGB", *, refine: bool = True) -> torch.Tensor:
    """DDFAPD demosaic of a Bayer mosaic (Menon et al. 2007): green is interpolated horizontally and vertically
    with a 5-tap filter, the direction with the smaller local colour-difference gradient wins (a posteriori
    decision), red and blue are reconstructed on the colour differences along the chosen direction, and an
    optional refining step filters the colour differences again.

    Boundary handling follows colour-demosaicing 0.2 (whole-sample mirror for the 1-D filters and the gradient,
    zeros for the decision window), so results agree with ``demosaicing_CFA_Bayer_Menon2007`` to rounding, except
    where the two directional criteria tie exactly (common on quantised, e.g. 8-bit, data): there the summation
    order of the decision window breaks the tie, and the other direction's green spreads through the refining
    step (up to 0.12 % of the pixels of an 8-bit photograph, up to ~0.03 of full scale there).
    Differentiable almost everywhere (the directional choice is a hard selection, as in the paper).

    Args:
        raw: mosaic (B, 1, H, W), float32 or float64, any device; H, W >= 2.
        pattern: 'RGGB', 'BGGR', 'GRBG' or 'GBRG' (row-major, top-left first).
        refine: apply the paper's refining step (colour differences smoothed again along the chosen direction).

    Returns:
        RGB (B, 3, H, W), not clipped.

    Example:
        >>> demosaic_menon2007(torch.rand(1, 1, 16, 16), "RGGB").shape
        torch.Size([1, 3, 16, 16])

    Reference:
        D. Menon, S. Andriani, G. Calvagno, "Demosaicing with directional filtering and a posteriori decision",
        IEEE Trans. Image Processing 16(1):132-141, 2007. doi:10.1109/TIP.2006.884928
    """
    raw = check_raw(raw)
    check_bool(refine, "refine")
    h, w = raw.shape[-2:]
    if h < 2 or w < 2:
        raise ValueError(f"raw: expected at least 2x2 pixels for a Bayer mosaic, got {h}x{w}")
    m = bayer_masks(check_bayer_pattern(pattern), h, w, raw.device)
    is_r, is_g, is_b = m["R"], m["G"], m["B"]
    zero = raw.new_zeros(())

    # Directional green estimates and the colour differences at R/B sites.
    h0_h, h0_v = _hv(raw, _H0)
    h1_h, h1_v = _hv(raw, _H1)
    g_h = torch.where(is_g, raw, h0_h + h1_h)
    g_v = torch.where(is_g, raw, h0_v + h1_v)
    c_h = torch.where(is_g, zero, raw - g_h)
    c_v = torch.where(is_g, zero, raw - g_v)
    # Gradients of the colour differences between sites two apart, summed over the decision window.
    d_h = (c_h - pad(c_h, 0, 2, "mirror")[..., 4:]).abs()
    d_v = (c_v - pad(c_v, 2, 0, "mirror")[..., 4:, :]).abs()
    delta_h = correlate(d_h, [_K_DECISION], "zeros")
    delta_v = correlate(d_v, [_K_DECISION_T], "zeros")
    horizontal = delta_v >= delta_h
    g = torch.where(horizontal, g_h, g_v)

    # Red and blue at green sites: bilinear on R-G / B-G along the row or column holding that colour.
    r = torch.where(is_r, raw, zero)
    b = torch.where(is_b, raw, zero)
    rbg = torch.cat([r, b, g], dim=1)
    hh, vv = _hv(rbg, _K_PAIR)
    g_in_r_row, g_in_b_row = m["G_in_R_row"], m["G_in_B_row"]
    r = torch.where(g_in_r_row, g + hh[:, 0:1] - hh[:, 2:3], r)
    r = torch.where(g_in_b_row, g + vv[:, 0:1] - vv[:, 2:3], r)
    b = torch.where(g_in_b_row, g + hh[:, 1:2] - hh[:, 2:3], b)
    b = torch.where(g_in_r_row, g + vv[:, 1:2] - vv[:, 2:3], b)
    # Red at blue sites and blue at red sites, along the chosen direction. The neighbours used are green
    # sites, so both updates read the planes as they are now.
    rb = torch.cat([r, b], dim=1)
    hh, vv = _hv(rb, _K_PAIR)
    r_at_b = torch.where(horizontal, b + hh[:, 0:1] - hh[:, 1:2], b + vv[:, 0:1] - vv[:, 1:2])
    b_at_r = torch.where(horizontal, r + hh[:, 1:2] - hh[:, 0:1], r + vv[:, 1:2] - vv[:, 0:1])
    r = torch.where(is_b, r_at_b, r)
    b = torch.where(is_r, b_at_r, b)
    if refine:
        r, g, b = _refine(r, g, b, m, horizontal)
    return torch.cat([r, g, b], dim=1)


def _refine(r, g, b, m, horizontal):
    """Refining step (Menon et al. 2007): smooth the colour differences along the chosen direction."""
    is_r, is_b = m["R"], m["B"]
    # Green at R/B sites from the 3-tap mean of R-G (B-G) along the chosen direction.
    diff = torch.cat([r - g, b - g], dim=1)
    smooth = torch.where(horizontal, *_hv(diff, _K_MEAN3))
    g = torch.where(is_r, r - smooth[:, 0:1], g)
    g = torch.where(is_b, b - smooth[:, 1:2], g)
    # Red and blue at green sites from the refreshed colour differences.
    diff = torch.cat([r - g, b - g], dim=1)
    hh, vv = _hv(diff, _K_PAIR)
    g_in_b_row, g_in_r_row = m["G_in_B_row"], m["G_in_R_row"]
    # (a green site in a row of B is in a column of R, and vice versa)
    r = torch.where(g_in_b_row, g + vv[:, 0:1], r)
    r = torch.where(g_in_r_row, g + hh[:, 0:1], r)
    b = torch.where(g_in_r_row, g + vv[:, 1:2], b)
    b = torch.where(g_in_b_row, g + hh[:, 1:2], b)
    # Red at blue sites and blue at red sites from the R-B difference.
    r_b = r - b
    smooth = torch.where(horizontal, *_hv(r_b, _K_MEAN3))
    r = torch.where(is_b, b + smooth, r)
    b = torch.where(is_r, r - smooth, b)
    return r, g, b
