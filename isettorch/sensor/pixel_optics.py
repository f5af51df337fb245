"""Pixel vignetting: the fraction of the light reaching a pixel that lands on its photodetector, as a function of
the chief-ray angle, the lens's f-number, the optical-stack height and the microlens (geometric optics).

Model (Catrysse & Wandell, "Optical efficiency of image sensor pixels", JOSA A 19(8), 2002, and "Roadmap for CMOS
image sensors: Moore meets Planck and Sommerfeld", Proc. SPIE 5678, 2005; ISETCam ``mlAnalyzeArrayEtendue``,
``mlRadiance``): the lens delivers a uniform disk of directions in direction-cosine space (the image-space
beam, radius sin(alpha) = 1 / (2 N)) centred on the chief ray; each direction refracts into the stack
(index n, Snell: sin(theta') = sin(theta) / n) and travels the stack height h:

* no microlens: light enters uniformly across the pixel aperture p and is displaced by h tan(theta') at the
  detector (width d, centred): efficiency = overlap(x) overlap(y) / p^2;
* ideal microlens (fills the pixel, focuses at the detector depth): a direction focuses to the point
  o + h tan(theta') (o = microlens offset); it is collected when that point lies on the detector. This is the
  etendue (acceptance-angle) argument of the ISET model: the pixel accepts ``|h tan(theta')| <= d / 2``.

Directions are averaged with a uniform grid over the beam's disk (``samples`` per side).

ISET's own microlens model (1-D phase space, a microlens of finite focal length, ISETCam's layered stack, optional
diffraction; ``mlRadiance``) is :mod:`isettorch.sensor.microlens`, which also puts the etendue into the camera
(``Sensor(pixel_optics=...)``); its docstring says how the two models differ. This 2-D geometric model is its
``model='geometric'`` option.
"""

from __future__ import annotations

import math

import torch

from .._checks import check_bool, is_integer

__all__ = ["pixel_vignetting", "microlens_offset_m"]


def _check_pos(v, name):
    if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):  # (True was f/1)
        raise ValueError(f"{name}: expected a positive number, got {v!r}")


def _check_index(n) -> None:
    """A stack's refractive index, at least 1 (below it Snell's law has no refracted ray past sin(theta) = n: a NaN
    efficiency at 40 deg for n = 0.5, and math's unnamed domain error)."""
    _check_pos(n, "stack_index")
    if n < 1:
        raise ValueError(f"stack_index: expected a refractive index >= 1, got {n!r}")


def microlens_offset_m(chief_ray_angle_deg: float, stack_height_m: float, stack_index: float = 1.5) -> float:
    """Microlens shift (m, towards the optical axis is negative) that centres the chief ray's focus on the
    detector: -h tan(asin(sin(theta_c) / n))."""
    _check_pos(stack_height_m, "stack_height_m")
    _check_index(stack_index)
    if isinstance(chief_ray_angle_deg, bool) or not isinstance(chief_ray_angle_deg, (int, float)) \
            or not abs(chief_ray_angle_deg) < 90:  # (NaN fails too: it gave a NaN offset)
        raise ValueError(f"chief_ray_angle_deg: expected a number with |angle| < 90, got {chief_ray_angle_deg!r}")
    t = math.asin(math.sin(math.radians(chief_ray_angle_deg)) / stack_index)
    return -stack_height_m * math.tan(t)


def pixel_vignetting(chief_ray_angle_deg, f_number: float, stack_height_m: float, pixel_size_m: float,
                     detector_size_m: float, *, stack_index: float = 1.5, microlens: bool = True,
                     microlens_offset_m: float = 0.0, samples: int = 201) -> torch.Tensor:
    """Fraction of the pixel's incident light that reaches its detector (0..1), per chief-ray angle.

    Args:
        chief_ray_angle_deg: chief-ray angle(s) (deg), along the pixel's x axis (scalar or tensor).
        f_number: the lens's image-space f-number (beam half-angle asin(1 / (2 N))).
        stack_height_m: height of the optical stack from the microlens (or pixel top) to the detector.
        pixel_size_m, detector_size_m: pixel pitch and (square) photodetector width.
        stack_index: refractive index of the stack.
        microlens: with an ideal microlens (True) or a bare aperture (False).
        microlens_offset_m: lateral shift of the microlens along x (see :func:`microlens_offset_m`); for a bare
            aperture it shifts the entrance aperture.
    """
    for v, n in ((f_number, "f_number"), (stack_height_m, "stack_height_m"), (pixel_size_m, "pixel_size_m"),
                 (detector_size_m, "detector_size_m")):
        _check_pos(v, n)
    _check_index(stack_index)
    if f_number < 0.5:
        raise ValueError(f"f_number: expected >= 0.5 (beam half-angle below 90 deg), got {f_number}")
    if detector_size_m > pixel_size_m:
        raise ValueError(f"detector_size_m: expected at most pixel_size_m={pixel_size_m}, got {detector_size_m}")
    check_bool(microlens, "microlens")  # ('no' took the microlens branch)
    if isinstance(microlens_offset_m, bool) or not isinstance(microlens_offset_m, (int, float)) \
            or not math.isfinite(microlens_offset_m):
        raise ValueError(f"microlens_offset_m: expected a finite number, got {microlens_offset_m!r}")
    if not (is_integer(samples) and samples >= 16):  # (1, 2 or 2.5 samples gave 1.0 against the true 0.678)
        raise ValueError(f"samples: expected an integer >= 16 (pupil samples a side), got {samples!r}")
    cra = torch.as_tensor(chief_ray_angle_deg, dtype=torch.float64)
    if not bool((cra.abs() < 90).all()):  # (NaN fails too: it gave 0)
        raise ValueError(f"chief_ray_angle_deg: expected |angle| < 90, got {cra.tolist()}")
    rad = 1.0 / (2.0 * f_number)
    u = (torch.arange(samples, dtype=torch.float64) - (samples - 1) / 2) * (2.0 / samples)
    gy, gx = torch.meshgrid(u, u, indexing="ij")
    inside = gx * gx + gy * gy <= 1
    dl, dm = gx[inside] * rad, gy[inside] * rad  # [S] offsets in direction-cosine space
    L = torch.sin(torch.deg2rad(cra)).reshape(-1, 1) + dl  # [A, S]
    M = dm.expand_as(L)
    if (L * L + M * M >= 1).any():
        raise ValueError("chief_ray_angle_deg/f_number: the beam reaches grazing incidence (direction cosines >= 1)")
    n = stack_index
    nz = torch.sqrt(n * n - L * L - M * M)
    tx, ty = L / nz, M / nz  # tan of the in-stack angle, per axis
    h, p, d = stack_height_m, pixel_size_m, detector_size_m
    if microlens:
        ok = ((microlens_offset_m + h * tx).abs() <= d / 2) & ((h * ty).abs() <= d / 2)
        eff = ok.to(torch.float64)
    else:
        def overlap(shift):
            lo = torch.maximum(-p / 2 + shift, torch.full_like(shift, -d / 2))
            hi = torch.minimum(p / 2 + shift, torch.full_like(shift, d / 2))
            return (hi - lo).clamp_min(0) / p
        eff = overlap(microlens_offset_m + h * tx) * overlap(h * ty)
    return eff.mean(-1).reshape(cra.shape)
