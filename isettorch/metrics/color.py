"""Colorimetry: XYZ <-> CIELAB (any white), chromaticity xy and u'v', sRGB <-> XYZ.

Tensors carry the three colour components along ``dim`` (default ``-3``: images ``(B, 3, H, W)`` or
``(3, H, W)``; pass ``dim=-1`` for tables ``(N, 3)``). Everything is elementwise, batched, on any device,
float32/float64, and differentiable (the CIELAB cube root switches to its linear segment before 0, so no
infinite slopes).
"""

from __future__ import annotations

import torch

from .._autograd import tensor_cache
from .._checks import as_tensor, check_finite
from ..image import D65_XY, SRGB_PRIMARIES_XY, XYZ_TO_LINEAR_SRGB, rgb_to_xyz_matrix  # noqa: F401 (re-exported)

# CIE 15:2004 eq. 8.3: the CIELAB function f(t) is t^(1/3) above (6/29)^3 and linear below.
_DELTA = 6.0 / 29.0
_EPS = _DELTA**3  # 216 / 24389
_KAPPA_LIN = 1.0 / (3.0 * _DELTA**2)  # 841 / 108

# White points from their CIE 1931 xy (CIE 15:2004 table T.3, 2-degree observer; the values of colour-science's
# CCS_ILLUMINANTS), as XYZ with Y = 1.
_WHITE_XY = {"D65": D65_XY, "D50": (0.3457, 0.3585), "A": (0.44758, 0.40745), "E": (1 / 3, 1 / 3)}
WHITE_POINTS = {k: (x / y, 1.0, (1.0 - x - y) / y) for k, (x, y) in _WHITE_XY.items()}


@tensor_cache(maxsize=None)
def _srgb_matrices() -> tuple[torch.Tensor, torch.Tensor]:
    """The sRGB -> XYZ matrix and its inverse, float64: the library's one definition (isettorch.image)."""
    inv = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64)
    return torch.linalg.inv(inv), inv


def _srgb_matrix(inverse: bool, like: torch.Tensor) -> torch.Tensor:
    """The sRGB -> XYZ matrix (or its inverse) in ``like``'s dtype and device."""
    return _srgb_matrices()[int(inverse)].to(dtype=like.dtype, device=like.device)


def working_dtype(dtype: torch.dtype) -> torch.dtype:
    """The precision a colour metric or conversion computes in for inputs of (promoted) ``dtype``: float32 for half
    precision (float16, bfloat16), torch's default for integers, else the dtype itself."""
    if not dtype.is_floating_point:
        return torch.get_default_dtype()
    return torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype


def _in_dtype(out: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A conversion's result (computed in :func:`working_dtype`) in the input's floating dtype."""
    return out.to(like.dtype) if like.is_floating_point() else out


def _channel_last(x: torch.Tensor, dim: int, name: str) -> tuple[torch.Tensor, int]:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    if x.dim() == 0:
        raise ValueError(f"{name}: expected a tensor with 3 colour components along dim={dim}, got a scalar")
    if not -x.dim() <= dim < x.dim() or x.shape[dim % x.dim()] != 3:
        raise ValueError(f"{name}: expected 3 colour components along dim={dim}, got shape {tuple(x.shape)}")
    d = dim % x.dim()
    if x.is_complex() or x.dtype == torch.bool:  # (a complex value lost its imaginary part in the cast below)
        raise TypeError(f"{name}: expected a real tensor, got {x.dtype}")
    # half precision computes in float32 and returns in its own dtype (in bfloat16 throughout, Lab was 3.7 off the
    # float64 value of the same bfloat16 input, 3.7x the output's rounding; integers in torch's default)
    x = x.to(working_dtype(x.dtype))
    return x.movedim(d, -1), d


def _white(white, ref: torch.Tensor, channel_dim: int | None = None) -> torch.Tensor:
    """White as [..., 3] broadcastable against ``ref`` moved to channel-last.

    ``white`` is a name in WHITE_POINTS, a [3] tensor, or [B, 3] (one white per leading batch sample).
    ``channel_dim``: where the colour axis was in the input; a [B, 3] white needs one before it (a (3, H, W) image
    has none: its whites were paired with its rows).
    """
    if isinstance(white, str):
        if white.upper() not in WHITE_POINTS:
            raise ValueError(f"white: expected one of {sorted(WHITE_POINTS)} or an XYZ tensor, got {white!r}")
        white = WHITE_POINTS[white.upper()]
    w = as_tensor(white, "white", dtype=ref.dtype, device=ref.device)
    check_finite(w, "white")
    if w.shape[-1:] != (3,) or w.dim() > 2:
        raise ValueError(f"white: expected XYZ of shape [3] or [B, 3], got shape {tuple(w.shape)}")
    if (w <= 0).any():
        raise ValueError(f"white: expected positive XYZ, got {w.tolist()}")
    if w.dim() == 2:
        if channel_dim == 0 and w.shape[0] != 1:
            raise ValueError(f"white: a [B, 3] white needs a leading batch dimension before the colour axis, and "
                             f"the input's colours are its first dimension (shape {tuple(ref.movedim(-1, 0).shape)}); "
                             f"give a [3] white, or a batched input")
        if ref.dim() < 2 or (ref.shape[0] != w.shape[0] and w.shape[0] != 1):
            raise ValueError(
                f"white: a [B, 3] white needs a leading batch dimension of {w.shape[0]}, got input shape "
                f"{tuple(ref.shape)} (channel-last)"
            )
        w = w.reshape(w.shape[0], *([1] * (ref.dim() - 2)), 3)
    return w


def _lab_f(t: torch.Tensor) -> torch.Tensor:
    # CIE 15:2004 eq. 8.3; the cube root sees only t > eps, so its gradient stays finite.
    return torch.where(t > _EPS, t.clamp_min(_EPS) ** (1.0 / 3.0), _KAPPA_LIN * t + 4.0 / 29.0)


def _lab_f_inv(f: torch.Tensor) -> torch.Tensor:
    return torch.where(f > _DELTA, f**3, (f - 4.0 / 29.0) / _KAPPA_LIN)


def xyz_to_lab(xyz: torch.Tensor, white="D65", dim: int = -3) -> torch.Tensor:
    r"""CIE XYZ to CIELAB (CIE 15:2004 section 8.2.1) relative to any white.

    Args:
        xyz: tristimulus values with 3 components along ``dim``, e.g. :math:`(B, 3, H, W)`, on the same
            scale as ``white`` (both with Y_white = 1, or both in cd/m^2, ...).
        white: the reference white's XYZ, shape :math:`(3)` or :math:`(B, 3)`, or a name ("D65", "D50", "A", "E",
            Y = 1).
        dim: the colour dimension.

    Returns:
        L*, a*, b* along ``dim``, same shape as ``xyz``.

    Example:
        >>> xyz_to_lab(torch.tensor([WHITE_POINTS["D65"]]), "D65", dim=-1)  # doctest: +SKIP
        tensor([[100., 0., 0.]])
    """
    x, d = _channel_last(xyz, dim, "xyz")
    check_finite(x.detach(), "xyz")
    w = _white(white, x, d)
    f = _lab_f(x / w)
    fx, fy, fz = f.unbind(-1)
    lab = torch.stack((116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)), dim=-1)
    return _in_dtype(lab.movedim(-1, d), xyz)


def lab_to_xyz(lab: torch.Tensor, white="D65", dim: int = -3) -> torch.Tensor:
    """CIELAB to CIE XYZ (inverse of :func:`xyz_to_lab`, CIE 15:2004 section 8.2.1 / CIE 015 note 8)."""
    x, d = _channel_last(lab, dim, "lab")
    check_finite(x.detach(), "lab")
    w = _white(white, x, d)
    L, a, b = x.unbind(-1)
    fy = (L + 16.0) / 116.0
    f = torch.stack((fy + a / 500.0, fy, fy - b / 200.0), dim=-1)
    return _in_dtype((_lab_f_inv(f) * w).movedim(-1, d), lab)


def _safe_denominator(s: torch.Tensor) -> torch.Tensor:
    tiny = torch.finfo(s.dtype).tiny
    return torch.where(s.abs() > tiny, s, torch.ones_like(s))


def xyz_to_xy(xyz: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """CIE 1931 chromaticity x = X / (X + Y + Z), y = Y / (X + Y + Z) (CIE 15:2004 eq. 7.3).

    Returns 2 components along ``dim``. Black (X + Y + Z = 0) gives (0, 0) (colour-science returns the
    illuminant's chromaticity there; here no value is invented and the gradient stays finite).
    """
    x, d = _channel_last(xyz, dim, "xyz")
    check_finite(x.detach(), "xyz")
    s = _safe_denominator(x.sum(-1, keepdim=True))
    return _in_dtype((x[..., :2] / s).movedim(-1, d), xyz)


def xyz_to_uv(xyz: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """CIE 1976 UCS chromaticity u' = 4X / (X + 15Y + 3Z), v' = 9Y / (X + 15Y + 3Z) (CIE 15:2004 eq. 8.1)."""
    x, d = _channel_last(xyz, dim, "xyz")
    check_finite(x.detach(), "xyz")
    X, Y, Z = x.unbind(-1)
    s = _safe_denominator(X + 15.0 * Y + 3.0 * Z)
    return _in_dtype(torch.stack((4.0 * X / s, 9.0 * Y / s), dim=-1).movedim(-1, d), xyz)


def xy_to_xyz(xy: torch.Tensor, Y=1.0, dim: int = -3) -> torch.Tensor:
    """Chromaticity (x, y) plus luminance Y to XYZ (CIE 15:2004 eq. 7.3 inverted)."""
    if not isinstance(xy, torch.Tensor):
        raise TypeError(f"xy: expected a torch.Tensor, got {type(xy).__name__}")
    if xy.dim() == 0 or not -xy.dim() <= dim < xy.dim():
        raise ValueError(f"dim: expected a dimension of xy's {xy.dim()}, got {dim}")
    d = dim % xy.dim()
    if xy.shape[d] != 2:
        raise ValueError(f"xy: expected 2 components along dim={dim}, got shape {tuple(xy.shape)}")
    check_finite(xy.detach(), "xy")  # (NaN passed the y > 0 test and came out as NaN XYZ)
    c = xy.movedim(d, -1)
    x, y = c.unbind(-1)
    if (y <= 0).any():
        raise ValueError(f"xy: expected y > 0, got minimum {y.min().item():.6g}")
    Yt = as_tensor(Y, "Y", dtype=c.dtype, device=c.device)
    check_finite(Yt.detach(), "Y")
    try:
        Yt = Yt.expand_as(x)
    except RuntimeError:
        raise ValueError(f"Y: expected a luminance broadcastable to xy's {tuple(x.shape)} points, got shape "
                         f"{tuple(Yt.shape)}") from None
    return torch.stack((x * Yt / y, Yt, (1 - x - y) * Yt / y), dim=-1).movedim(-1, d)


def srgb_to_xyz(srgb: torch.Tensor, dim: int = -3) -> torch.Tensor:
    """Encoded sRGB (IEC 61966-2-1) to XYZ (D65, Y_white = 1): :func:`isettorch.image.srgb_decode`, then the matrix
    of the sRGB primaries and D65 (:func:`rgb_to_xyz_matrix`; colour-science's ``normalised_primary_matrix``), so
    that sRGB white is the D65 of :data:`WHITE_POINTS` exactly (CIELAB (100, 0, 0)). IEC 61966-2-1's rounded
    4-decimal matrix (colour-science's ``sRGB_to_XYZ``) differs from it by up to 4e-5; kornia's 6-decimal one,
    used here before 2026-11-30, by up to 3e-4 (white at b* = 0.019).
    """
    from ..image import srgb_decode

    if isinstance(srgb, torch.Tensor) and not srgb.is_floating_point():  # (8-bit codes read as [0, 1]: grey 200 at
        raise TypeError(f"srgb: expected a floating-point tensor in [0, 1] units (8-bit codes: divide by 255 "  # Y 3e5)
                        f"first), got {srgb.dtype}")
    x, d = _channel_last(srgb, dim, "srgb")
    check_finite(x.detach(), "srgb")
    return _in_dtype((srgb_decode(x) @ _srgb_matrix(False, x).T).movedim(-1, d), srgb)


def xyz_to_srgb(xyz: torch.Tensor, dim: int = -3, clip: bool = True) -> torch.Tensor:
    """XYZ (D65, Y_white = 1) to encoded sRGB (IEC 61966-2-1): the inverse of :func:`srgb_to_xyz`'s matrix, then
    :func:`isettorch.image.srgb_encode`. ``clip``: linear values above 1 become 1 (else they follow the power law);
    negative linear values (out of gamut) always encode to 0, the library's one sRGB clipping rule."""
    from ..image import srgb_encode

    x, d = _channel_last(xyz, dim, "xyz")
    check_finite(x.detach(), "xyz")
    return _in_dtype(srgb_encode(x @ _srgb_matrix(True, x).T, clip=clip).movedim(-1, d), xyz)
