"""Thin-lens geometry, the camera equation and relative illumination (off-axis fall-off).

All functions are batched: scalars may be Python numbers or tensors that broadcast (typically ``[B]``).
"""

from __future__ import annotations

import math

import torch

from .._checks import is_integer

__all__ = [
    "image_distance",
    "magnification",
    "image_sample_spacing",
    "camera_equation_factor",
    "cos4th",
    "cos4th_isetcam",
    "relative_illumination",
]


def _t(x, like: torch.Tensor | None = None) -> torch.Tensor:
    """A tensor; Python numbers become float64 (or ``like``'s dtype/device) so no precision is lost."""
    if isinstance(x, torch.Tensor):
        return x
    if like is not None and like.is_floating_point():
        return torch.as_tensor(x, dtype=like.dtype, device=like.device)
    return torch.as_tensor(x, dtype=torch.float64)


def _check_range(t: torch.Tensor, name: str, what: str, lo: float | None = 0.0, hi: float | None = None
                 ) -> torch.Tensor:
    """``t`` when every value is finite, above ``lo`` and below ``hi`` (one host read), else a ValueError naming
    ``name`` (a negative distance gave a negative spacing, f/0 NaN: the sibling helpers' rule)."""
    ok = torch.isfinite(t)
    if lo is not None:
        ok = ok & (t > lo)
    if hi is not None:
        ok = ok & (t < hi)
    if not bool(ok.all()):
        raise ValueError(f"{name}: expected {what}, got {t.detach().reshape(-1).tolist()}")
    return t


def image_distance(focal_length_m, object_distance_m) -> torch.Tensor:
    """Thin-lens image distance ``d_i = 1 / (1/f - 1/d_o)`` (m); Gaussian lens equation (Hecht, Optics, 5.17).

    Raises ValueError when the object is at or inside the focal length (no real image).

    Example:
        >>> image_distance(torch.tensor(0.05), torch.tensor(1.0))
        tensor(0.0526)
    """
    f = _t(focal_length_m, object_distance_m if isinstance(object_distance_m, torch.Tensor) else None)
    s = _t(object_distance_m, f)
    ok_f = (f > 0) & torch.isfinite(f)  # (NaN gave NaN, f <= 0 a negative distance)
    if not bool((ok_f & (s > f)).all()):  # one host read; NaN fails too
        if not bool(ok_f.all()):
            raise ValueError(f"focal_length_m: expected finite positive focal lengths, got {f.tolist()} m")
        raise ValueError(f"object_distance_m: expected a distance beyond the focal length {f.tolist()} m, "
                         f"got {s.tolist()} m (no real image)")
    return 1.0 / (1.0 / f - 1.0 / s)


def magnification(focal_length_m, object_distance_m) -> torch.Tensor:
    """Lateral magnification ``m = -d_i / d_o`` (negative: the image is inverted); ISETCam ``opticsGet 'mag'``."""
    d_i = image_distance(focal_length_m, object_distance_m)
    return -d_i / _t(object_distance_m, d_i)


def image_sample_spacing(hfov_deg, n_cols: int, image_distance_m) -> torch.Tensor:
    """Image-plane pitch (m) of ``n_cols`` samples spanning the horizontal FOV: ``2 d_i tan(hfov/2) / W``.

    Equal to the scene-plane pitch times ``|m|`` (the scene at ``d_o`` maps to ``d_i``); ISETCam ``oiGet 'width'``.
    """
    if not (is_integer(n_cols) and n_cols >= 1):  # (0 gave inf, 2.7 and negative counts were taken)
        raise ValueError(f"n_cols: expected an integer number of samples >= 1, got {n_cols!r}")
    d = _check_range(_t(image_distance_m, hfov_deg if isinstance(hfov_deg, torch.Tensor) else None),
                     "image_distance_m", "finite distances > 0 (m)")
    hfov = _check_range(_t(hfov_deg, d), "hfov_deg", "finite fields of view in (0, 180) degrees", hi=180.0)
    return 2 * d * torch.tan(torch.deg2rad(hfov) / 2) / n_cols


def camera_equation_factor(f_number, magnification_=0.0, *, paraxial: bool = False) -> torch.Tensor:
    """Irradiance per unit radiance ``E / L`` (sr) on the axis of a lens of f-number ``N``.

    Both are ``E / L = pi sin^2(theta)`` for the cone of half-angle ``theta`` the pupil subtends at the image
    (Smith, Modern Optical Engineering, ch. 9; Hecht, Optics, 5th ed., section 5.3), with the working f-number
    ``N_w = N (1 + |m|)``; they differ in how ``theta`` follows from ``N_w``:

    * ``paraxial=False`` (ISETCam ``oiCalculateIrradiance``, the default): ``pi / (1 + 4 N_w^2)``, ``tan(theta) =
      1 / (2 N_w)``: the pupil's diameter seen from the image distance (a thin lens);
    * ``paraxial=True``: ``pi / (4 N_w^2)``, ``sin(theta) = 1 / (2 N_w)``: an aplanatic lens (Abbe sine condition,
      the relation behind ``MIN_F_NUMBER``), also the small-aperture limit of both.

    The paraxial value is larger by ``1 / (4 N_w^2)`` relative: 6.25 % at f/2, 3.2 % at f/2.8, 1.56 % at f/4.

    Multiply by the lens transmittance ``T(lambda)`` for the full camera equation.
    """
    n = _check_range(_t(f_number), "f_number", "finite f-numbers > 0")
    m = _check_range(_t(magnification_, n), "magnification_", "finite magnifications", lo=None)
    nw2 = 4 * n**2 * (1 + m.abs()) ** 2
    return math.pi / nw2 if paraxial else math.pi / (1 + nw2)


def cos4th(y_m: torch.Tensor, x_m: torch.Tensor, image_distance_m) -> torch.Tensor:
    """Natural vignetting ``cos^4(phi)`` with ``cos(phi) = d / sqrt(d^2 + r^2)`` (Slater & Klein, the cos^4 law).

    ``y_m [B, H]``, ``x_m [B, W]`` are sample positions from the axis; ``image_distance_m`` ``[B]``.
    Returns ``[B, 1, H, W]``.
    """
    d = torch.as_tensor(image_distance_m, dtype=x_m.dtype, device=x_m.device)
    d2 = _check_range(d, "image_distance_m", "finite distances > 0 (m)").reshape(-1, 1, 1, 1) ** 2
    r2 = y_m[:, None, :, None] ** 2 + x_m[:, None, None, :] ** 2
    return (d2 / (d2 + r2)) ** 2


def cos4th_isetcam(y_m: torch.Tensor, x_m: torch.Tensor, image_distance_m, f_number, magnification_=0.0,
                   ) -> torch.Tensor:
    """ISETCam's relative illumination (``cos4th.m``): a finite-aperture formula for close images.

    If ``d > 10 * diagonal`` it is ``cos^4``; otherwise, with ``cos(phi) = d / sqrt(d^2 + r^2)`` and
    ``sin(theta) = 1 / (1 + 4 (N (1 - m))^2)``, ``fall = (pi/2) (1 - (1 - tan^2 theta + tan^2 phi) /
    sqrt(tan^4 phi + 2 tan^2 phi (1 - tan^2 theta) + 1 / cos^4 theta)) / (pi sin^2 theta)``. The
    diagonal is ``hypot(H dx, W dx)``, taken from the sample positions (``dx = x[1] - x[0]``).
    Returns ``[B, 1, H, W]``.
    """
    dt = x_m.dtype
    d = _check_range(torch.as_tensor(image_distance_m, dtype=dt, device=x_m.device), "image_distance_m",
                     "finite distances > 0 (m)").reshape(-1, 1, 1, 1)
    # (f/0 gave NaN everywhere: sin(theta) = 1)
    n = _check_range(torch.as_tensor(f_number, dtype=dt, device=x_m.device), "f_number",
                     "finite f-numbers > 0").reshape(-1, 1, 1, 1)
    m = _check_range(torch.as_tensor(magnification_, dtype=dt, device=x_m.device), "magnification_",
                     "finite magnifications", lo=None).reshape(-1, 1, 1, 1)
    h, w = y_m.shape[-1], x_m.shape[-1]
    dx = (x_m[:, 1] - x_m[:, 0]) if w > 1 else (y_m[:, 1] - y_m[:, 0]) if h > 1 else torch.zeros_like(x_m[:, 0])
    diagonal = torch.hypot(h * dx, w * dx).reshape(-1, 1, 1, 1)
    r2 = y_m[:, None, :, None] ** 2 + x_m[:, None, None, :] ** 2
    s2 = d**2 + r2
    simple = (d**2 / s2) ** 2
    tan2_phi = r2 / d**2  # tan^2 = sin^2 / cos^2 = r^2 / d^2
    q4 = 4 * (n * (1 - m)) ** 2
    sin_t = 1 / (1 + q4)
    cos2_t = q4 / (1 + q4) * (1 + sin_t)  # 1 - sin^2 as (1 - sin)(1 + sin): no cancellation for a small sin
    tan2_t = sin_t**2 / cos2_t
    # ISETCam's fall = (1 - a / sqrt(b)) / (2 sin^2 theta), a = 1 - tan^2 theta + tan^2 phi, b the root's argument,
    # cancels catastrophically for a slow lens (sin^2 theta below the float's epsilon from about f/16 in float32:
    # 0.5 on axis at f/32, negative irradiance at f/64). Since b - a^2 = 4 sin^2 theta / cos^2 theta exactly, for
    # a >= 0 it equals 2 / (cos^2 theta sqrt(b) (sqrt(b) + a)), a sum of positive terms (1 on axis exactly); for
    # a < 0 (a fast lens far off axis) the original form has no cancellation
    a = 1 - tan2_t + tan2_phi
    root = torch.sqrt(tan2_phi**2 + 2 * tan2_phi * (1 - tan2_t) + 1 / cos2_t**2)
    full = torch.where(a >= 0, 2 / (cos2_t * root * (root + a)), (1 - a / root) / (2 * sin_t**2))
    return torch.where(d > 10 * diagonal, simple, full)


def relative_illumination(method: str | None, y_m, x_m, image_distance_m, f_number, magnification_=0.0):
    """Dispatch: ``None``/``'none'`` -> 1, ``'cos4th'`` -> :func:`cos4th`, ``'isetcam'`` -> :func:`cos4th_isetcam`."""
    if method is None or method == "none":
        return None
    if method == "cos4th":
        return cos4th(y_m, x_m, image_distance_m)
    if method == "isetcam":
        return cos4th_isetcam(y_m, x_m, image_distance_m, f_number, magnification_)
    raise ValueError(f"relative_illumination: expected None, 'none', 'cos4th' or 'isetcam', got {method!r}")
