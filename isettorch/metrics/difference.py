"""Colour differences dE76, dE94 and dE2000, and a colour-accuracy report for a rendered Macbeth chart.

All functions are batched and differentiable; square roots and ``atan2`` are guarded so that identical
colours and neutral colours (a = b = 0) give finite (zero) gradients instead of NaN.
"""

from __future__ import annotations

import dataclasses

import torch

from .._checks import check_bool, check_finite, check_float_dtype, is_real, warn_caller
from .color import _channel_last, working_dtype, xyz_to_lab  # noqa: F401 (working_dtype re-exported)


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """sqrt with gradient 0 (not inf/NaN) at x <= 0; negative round-off is treated as 0; NaN stays NaN (a NaN
    colour scored dE 0, a perfect match). Values below the dtype's smallest normal number count as 0 too: a chroma
    of 1e-21 in float32 squares into the subnormals, where the chain of gradients turned into NaN and -inf."""
    pos = x > torch.finfo(x.dtype).tiny
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.where(x.isnan(), x, 0.0))


def _safe_atan2_deg(y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Hue angle in degrees in [0, 360); 0 where x = y = 0 (Sharma et al. 2005, eq. 4), with finite gradients. As
    in :func:`_safe_sqrt`, a chroma whose square is below the dtype's smallest normal number counts as 0 (atan2's
    gradient divides by x^2 + y^2, which underflowed to 0: NaN)."""
    zero = (x * x + y * y) <= torch.finfo(x.dtype).tiny
    h = torch.rad2deg(torch.atan2(torch.where(zero, torch.zeros_like(y), y), torch.where(zero, torch.ones_like(x), x)))
    h = torch.where(h < 0, h + 360.0, h)
    return torch.where(zero, torch.zeros_like(h), h)


def _split(lab1: torch.Tensor, lab2: torch.Tensor, dim: int):
    """The L, a, b components of both colours (broadcast, in their promoted dtype), and the dtype to return.
    Half-precision input (float16, bfloat16) is computed in float32 and returned in its own dtype: dE2000's 25^7 and
    7th powers of chroma overflow
    float16 (max 65504: every difference NaN), and dE94's hue term subtracts nearly equal squares."""
    a, _ = _channel_last(lab1, dim, "lab1")
    b, _ = _channel_last(lab2, dim, "lab2")
    check_finite(a.detach(), "lab1")  # a NaN or Inf colour gave a NaN difference without a word
    check_finite(b.detach(), "lab2")
    try:
        a, b = torch.broadcast_tensors(a, b)
    except RuntimeError as err:
        raise ValueError(f"lab2: shape {tuple(lab2.shape)} does not broadcast with lab1 {tuple(lab1.shape)}") from err
    # the dtype to return: the inputs' own (promoted; integers as torch's default), though _channel_last computes
    # half precision in float32
    out = torch.promote_types(*(t.dtype if t.is_floating_point() else torch.get_default_dtype()
                                for t in (lab1, lab2)))
    # both in the working precision: a half colour beside a float64 one was computed in float16 (dE2000 NaN, dE94 inf
    # once |a| or |b| passed ~181)
    a, b = a.to(working_dtype(out)), b.to(working_dtype(out))
    return a.unbind(-1), b.unbind(-1), out


def _as(de: torch.Tensor, dtype) -> torch.Tensor:
    return de if dtype is None or de.dtype == dtype else de.to(dtype)


def delta_e_76(lab1: torch.Tensor, lab2: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """CIE 1976 colour difference: Euclidean distance in CIELAB (CIE 15:2004 eq. 8.8)."""
    (L1, a1, b1), (L2, a2, b2), out = _split(lab1, lab2, dim)
    return _as(_safe_sqrt((L1 - L2) ** 2 + (a1 - a2) ** 2 + (b1 - b2) ** 2), out)


def delta_e_94(lab1: torch.Tensor, lab2: torch.Tensor, dim: int = -3, textiles: bool = False) -> torch.Tensor:
    """CIE 1994 colour difference (CIE 116-1995), ``lab1`` is the reference (S_C, S_H use its chroma).

    Graphic-arts weights (k_L = 1, K1 = 0.045, K2 = 0.015) by default, textiles (2, 0.048, 0.014) on request,
    as in colour-science's ``delta_E_CIE1994``.
    """
    (L1, a1, b1), (L2, a2, b2), out = _split(lab1, lab2, dim)
    k_L, K1, K2 = (2.0, 0.048, 0.014) if check_bool(textiles, "textiles") else (1.0, 0.045, 0.015)
    C1 = _safe_sqrt(a1**2 + b1**2)
    C2 = _safe_sqrt(a2**2 + b2**2)
    dL = L1 - L2
    dC = C1 - C2
    dH2 = ((a1 - a2) ** 2 + (b1 - b2) ** 2 - dC**2).clamp_min(0.0)
    s_C = 1.0 + K1 * C1
    s_H = 1.0 + K2 * C1
    return _as(_safe_sqrt((dL / k_L) ** 2 + (dC / s_C) ** 2 + dH2 / s_H**2), out)


def _c7_ratio(c: torch.Tensor) -> torch.Tensor:
    """CIEDE2000's ``C^7 / (C^7 + 25^7)`` (Sharma et al. 2005, eqs. 4 and 20) without overflow: above C = 25 as
    ``1 / (1 + (25 / C)^7)`` (C^7 overflowed float32 from C = 3.1e5: dE2000 NaN), below as written; each branch
    sees only its own range, so neither gives an infinite gradient."""
    big = c > 25.0
    high = 1.0 / (1.0 + (25.0 / torch.where(big, c, torch.full_like(c, 25.0))) ** 7)
    c7 = torch.where(big, torch.full_like(c, 25.0), c) ** 7
    return torch.where(big, high, c7 / (c7 + 25.0**7))


def delta_e_2000(lab1: torch.Tensor, lab2: torch.Tensor, dim: int = -3, k_L: float = 1.0, k_C: float = 1.0,
                 k_H: float = 1.0) -> torch.Tensor:
    """CIEDE2000 colour difference (CIE 142-2001), implemented as in Sharma, Wu and Dalal, "The CIEDE2000
    color-difference formula: implementation notes, supplementary test data, and mathematical observations",
    Color Res. Appl. 30(1), 2005, eqs. 1-22 (hue rules for C' = 0 and abs(dh') > 180 included). The parametric
    factors ``k_L``, ``k_C``, ``k_H`` are positive numbers (1 for the reference conditions).

    At an exactly neutral colour (a = b = 0) the chroma has a kink and its gradient in a, b is taken as 0 (finite,
    but a neutral output gets no chroma gradient from dE2000 or dE94; dE76's is the direction to the target).
    Half-precision input is computed in float32 and returned in its dtype (the 7th powers overflow float16)."""
    for name, k in (("k_L", k_L), ("k_C", k_C), ("k_H", k_H)):
        if not is_real(k) or not k > 0:
            raise ValueError(f"{name}: expected a positive parametric factor (a number), got {k!r}")
    (L1, a1, b1), (L2, a2, b2), out = _split(lab1, lab2, dim)
    C1 = _safe_sqrt(a1**2 + b1**2)
    C2 = _safe_sqrt(a2**2 + b2**2)
    G = 0.5 * (1.0 - _safe_sqrt(_c7_ratio((C1 + C2) / 2.0)))
    a1p, a2p = (1.0 + G) * a1, (1.0 + G) * a2
    C1p, C2p = _safe_sqrt(a1p**2 + b1**2), _safe_sqrt(a2p**2 + b2**2)
    h1p, h2p = _safe_atan2_deg(b1, a1p), _safe_atan2_deg(b2, a2p)

    dLp = L2 - L1
    dCp = C2p - C1p
    chroma_zero = (C1p * C2p) == 0
    dh = h2p - h1p
    dhp = torch.where(dh > 180.0, dh - 360.0, torch.where(dh < -180.0, dh + 360.0, dh))
    dhp = torch.where(chroma_zero, torch.zeros_like(dhp), dhp)
    dHp = 2.0 * _safe_sqrt(C1p * C2p) * torch.sin(torch.deg2rad(dhp / 2.0))

    Lbp = (L1 + L2) / 2.0
    Cbp = (C1p + C2p) / 2.0
    hsum = h1p + h2p
    hbp = torch.where((h1p - h2p).abs() <= 180.0, hsum / 2.0,
                      torch.where(hsum < 360.0, (hsum + 360.0) / 2.0, (hsum - 360.0) / 2.0))
    hbp = torch.where(chroma_zero, hsum, hbp)
    rad = torch.deg2rad
    T = (1.0 - 0.17 * torch.cos(rad(hbp - 30.0)) + 0.24 * torch.cos(rad(2.0 * hbp))
         + 0.32 * torch.cos(rad(3.0 * hbp + 6.0)) - 0.20 * torch.cos(rad(4.0 * hbp - 63.0)))
    dtheta = 30.0 * torch.exp(-(((hbp - 275.0) / 25.0) ** 2))
    R_C = 2.0 * _safe_sqrt(_c7_ratio(Cbp))
    Lm2 = (Lbp - 50.0) ** 2
    S_L = 1.0 + 0.015 * Lm2 / torch.sqrt(20.0 + Lm2)
    S_C = 1.0 + 0.045 * Cbp
    S_H = 1.0 + 0.015 * Cbp * T
    R_T = -torch.sin(rad(2.0 * dtheta)) * R_C
    tL, tC, tH = dLp / (k_L * S_L), dCp / (k_C * S_C), dHp / (k_H * S_H)
    return _as(_safe_sqrt(tL**2 + tC**2 + tH**2 + R_T * tC * tH), out)


METHODS = {"76": delta_e_76, "94": delta_e_94, "2000": delta_e_2000}


def delta_e(lab1: torch.Tensor, lab2: torch.Tensor, method: str = "2000", dim: int = -3) -> torch.Tensor:
    """Colour difference between two CIELAB tensors.

    Args:
        lab1: reference L*a*b*, 3 components along ``dim`` (e.g. :math:`(B, 3, H, W)` or :math:`(N, 3)` with dim=-1).
        lab2: test L*a*b*, broadcastable with ``lab1``.
        method: "76" (CIE 1976), "94" (CIE 1994, graphic arts, lab1 is the reference) or "2000" (CIEDE2000).
        dim: the colour dimension.

    Returns:
        the colour difference with ``dim`` removed, e.g. :math:`(B, H, W)`.

    Example:
        >>> delta_e(torch.tensor([[50., 2.6772, -79.7751]]), torch.tensor([[50., 0., -82.7485]]), dim=-1)
        tensor([2.0425])

    Reference: Sharma, Wu and Dalal, Color Res. Appl. 30(1) 21-30, 2005; CIE 15:2004.
    """
    key = str(method).lower().removeprefix("cie").removeprefix("de")
    if key not in METHODS:
        raise ValueError(f"method: expected one of {sorted(METHODS)}, got {method!r}")
    return METHODS[key](lab1, lab2, dim=dim)


class DeltaE(torch.nn.Module):
    """Module form of :func:`delta_e`."""

    def __init__(self, method: str = "2000", dim: int = -3) -> None:
        super().__init__()
        self.method, self.dim = method, dim

    def forward(self, lab1: torch.Tensor, lab2: torch.Tensor) -> torch.Tensor:
        return delta_e(lab1, lab2, self.method, self.dim)


# ---------------------------------------------------------------------------------------------------------------
# Colour-accuracy report of a rendered Macbeth (ColorChecker) chart


@dataclasses.dataclass
class ColorAccuracy:
    """Per-patch colour differences of a rendered chart against reference values."""

    delta_e: torch.Tensor  # [..., P] per-patch dE
    mean: torch.Tensor  # [...]
    max: torch.Tensor  # [...]
    median: torch.Tensor  # [...]
    lab_rendered: torch.Tensor  # [..., P, 3]
    lab_reference: torch.Tensor  # [..., P, 3]
    method: str = "2000"
    patch_names: tuple[str, ...] | None = None

    def report(self) -> str:
        de = self.delta_e.detach().reshape(-1, self.delta_e.shape[-1]).cpu()
        lines = [f"colour accuracy (dE{self.method}), {de.shape[-1]} patches"]
        for i, row in enumerate(de):
            lines.append(f"  sample {i}: mean {row.mean():.3f}  median {row.quantile(0.5):.3f}  max {row.max():.3f} "
                         f"(patch {int(row.argmax()) + 1})")
        return "\n".join(lines)

    def plot(self, ax=None):
        """Bar chart of per-patch dE (first sample); returns the Figure."""
        from ..plot import _fig_ax

        fig, ax = _fig_ax(ax)
        de = self.delta_e.detach().reshape(-1, self.delta_e.shape[-1])[0].cpu().numpy()
        ref = self.lab_reference.detach().reshape(-1, *self.lab_reference.shape[-2:])[0]
        colours = _lab_to_display(ref)
        ax.bar(range(1, len(de) + 1), de, color=colours, edgecolor="k", linewidth=0.5)
        ax.axhline(float(de.mean()), color="r", ls="--", lw=1, label=f"mean {de.mean():.2f}")
        ax.set_xlabel("patch")
        ax.set_ylabel(f"dE{self.method}")
        ax.legend(fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
        return fig


def _lab_to_display(lab: torch.Tensor):
    from .color import lab_to_xyz, xyz_to_srgb

    return xyz_to_srgb(lab_to_xyz(lab.double(), "D50", dim=-1), dim=-1).clamp(0, 1).cpu().numpy()


def color_accuracy(rendered: torch.Tensor, reference: torch.Tensor, white="D65", method: str = "2000",
                   space: str = "xyz", patch_names=None) -> ColorAccuracy:
    """Colour accuracy of a rendered chart: per-patch dE, mean, median and max.

    Compare like with like: the reference must be the chart under the illuminant the scene was rendered with,
    and ``white`` that illuminant's white (:func:`macbeth_reference_xyz` with ``illuminant=``). For a
    24-patch ColorChecker in XYZ (white patch 19 the brightest), a reference whose white patch does not have
    the chromaticity of ``white`` raises, and a rendered white patch far (> 0.02 in xy) from the reference's
    warns: a D65 render scored against the D50 chart values reads mean dE2000 7.2 instead of 3.7 (issue 18).

    Args:
        rendered: rendered patch values :math:`(..., P, 3)` (P patches, 24 for a Macbeth chart), XYZ on the
            scale of ``white`` (``space="xyz"``) or CIELAB (``space="lab"``).
        reference: reference patch values, same layout and space, broadcastable (e.g. :math:`(P, 3)`).
        white: reference white XYZ (:math:`(3)` or :math:`(B, 3)` or a name) used for both when space="xyz".
        method: "76", "94" or "2000".
        space: "xyz" or "lab".

    Example:
        >>> ref, names = macbeth_reference_xyz("D65")  # [24, 3]: the chart under D65, Y_white = 1
        >>> acc = color_accuracy(ref * torch.tensor([1.02, 1.0, 0.98], dtype=ref.dtype), ref, white="D65")
        >>> round(float(acc.mean), 2), names[18]
        (1.75, 'white 9.5 (.05 D)')

    Reference: ISO 17321-1:2012 (colour-accuracy evaluation with a colour target); McCamy et al. 1976 (chart).
    """
    if space not in ("xyz", "lab"):
        raise ValueError(f"space: expected 'xyz' or 'lab', got {space!r}")
    for name, t in (("rendered", rendered), ("reference", reference)):
        if not isinstance(t, torch.Tensor) or t.dim() < 2 or t.shape[-1] != 3:
            raise ValueError(f"{name}: expected a tensor of shape (..., P, 3), got "
                             f"{tuple(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__}")
    if rendered.shape[-2] != reference.shape[-2]:
        raise ValueError(f"reference: expected {rendered.shape[-2]} patches like rendered, got {reference.shape[-2]}")
    check_finite(rendered.detach(), "rendered")  # (named here: xyz_to_lab's error would name 'xyz')
    check_finite(reference.detach(), "reference")
    # both in their promoted dtype (half precision in float32: its median raised in torch.quantile)
    out = torch.promote_types(rendered.dtype, reference.dtype)
    work = working_dtype(out)
    rendered, reference = rendered.to(work), reference.to(work)
    try:  # one shape for both: a shared reference [P, 3] against a batch [B, P, 3] with a white per item [B, 3]
        # took white i for patch i of the reference (B = P), not white b for item b
        shape = torch.broadcast_shapes(rendered.shape, reference.shape)
    except RuntimeError as err:
        raise ValueError(f"reference: expected a shape that broadcasts with rendered's {tuple(rendered.shape)}, got "
                         f"{tuple(reference.shape)}") from err
    rendered, reference = rendered.expand(shape), reference.expand(shape)
    if space == "xyz":
        lab_r = xyz_to_lab(rendered, white, dim=-1)
        lab_ref = xyz_to_lab(reference, white, dim=-1)
    else:
        lab_r, lab_ref = rendered, reference
    de = delta_e(lab_ref, lab_r, method, dim=-1)
    if space == "xyz":
        _check_chart_whites(rendered, reference, white)
    out = out if out.is_floating_point else work  # returned in the inputs' (promoted) dtype, as delta_e does
    return ColorAccuracy(delta_e=de.to(out), mean=de.mean(-1).to(out), max=de.amax(-1).to(out),
                         median=de.quantile(0.5, dim=-1).to(out), lab_rendered=lab_r.to(out),
                         lab_reference=lab_ref.to(out), method=str(method), patch_names=patch_names)


#: Index of the ColorChecker's white patch (row 4, column 1) in reading order.
_WHITE_PATCH = 18
#: Largest xy distance between a chart's white patch and the white it is scored against (D65-D50: 0.044;
#: the published D50 white patch against D50 and the reflectance chart's under D65 against D65: < 0.004).
_WHITE_XY_TOLERANCE = 0.02


def _xy(xyz: torch.Tensor) -> torch.Tensor:
    return xyz[..., :2] / xyz.sum(-1, keepdim=True).clamp_min(torch.finfo(xyz.dtype).tiny)


def _check_chart_whites(rendered: torch.Tensor, reference: torch.Tensor, white) -> None:
    """Reference white patch vs ``white`` (error) and rendered vs reference white patch (warning), 24 patches."""
    from .color import _white

    if reference.shape[-2] != 24 or not bool((reference.detach()[..., 1].argmax(-1) == _WHITE_PATCH).all()):
        return
    ref_xy = _xy(reference.detach()[..., _WHITE_PATCH, :])
    w = _white(white, reference.detach()[..., _WHITE_PATCH, :].reshape(-1, 3)).reshape(-1, 3)
    d_ref = float((ref_xy - _xy(w)).norm(dim=-1).max())
    if d_ref > _WHITE_XY_TOLERANCE:
        raise ValueError(
            f"white: the reference chart's white patch has chromaticity (x, y) = "
            f"{[round(v, 4) for v in ref_xy.reshape(-1, 2)[0].tolist()]}, {d_ref:.3f} from white {white!r} "
            f"{[round(v, 4) for v in _xy(w)[0].tolist()]}: reference and white describe different illuminants "
            "(e.g. the published D50 chart values with white='D65'); use macbeth_reference_xyz(illuminant=...) "
            "and white=... of the render's illuminant")
    d_r = float((_xy(rendered.detach()[..., _WHITE_PATCH, :]) - ref_xy).norm(dim=-1).max())
    if d_r > _WHITE_XY_TOLERANCE:
        warn_caller(
            f"rendered: the white patch's chromaticity is {d_r:.3f} (xy) from the reference's: if the scene was "
            "rendered under another illuminant than the reference's, compare with "
            "macbeth_reference_xyz(illuminant=<the render's>) and its white (a D65 render scored against the D50 "
            "chart reads mean dE2000 7.2 instead of 3.7)")


def macbeth_reference_xyz(illuminant=None, dtype=torch.float64,
                          wavelengths_nm=None) -> tuple[torch.Tensor, tuple[str, ...]]:
    """ColorChecker 24 reference XYZ (24, 3), Y_white = 1, patches in reading order (dark skin ... black), and
    the patch names.

    ``illuminant=None``: the published X-Rite values (after November 2014) under D50, from colour-science; use
    ``white="D50"`` with them. ``illuminant`` given (a name such as ``"D65"`` or an energy SPD): the chart's
    reflectances (the ones :func:`isettorch.scene.macbeth` renders) under that illuminant, computed spectrally
    (:func:`isettorch.isp.chart.macbeth_true_xyz`); use ``white=illuminant`` with them. Score a render against
    the chart under the illuminant it was rendered with.
    """
    import colour

    check_float_dtype(dtype)  # (an integer dtype truncated every value to 0)
    cc = colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    names = tuple(cc.data.keys())
    if illuminant is not None:
        from ..isp.chart import macbeth_true_xyz

        return macbeth_true_xyz(illuminant, wavelengths_nm).to(dtype), names
    xyz = colour.xyY_to_XYZ(list(cc.data.values()))
    return torch.as_tensor(xyz, dtype=dtype), names


__all__ = ["delta_e", "delta_e_76", "delta_e_94", "delta_e_2000", "DeltaE", "ColorAccuracy", "color_accuracy",
           "macbeth_reference_xyz", "METHODS"]
