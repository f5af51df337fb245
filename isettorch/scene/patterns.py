"""Uniform fields and spatial test patterns (ISETCam ``sceneCreate`` patterns), as spectral scenes.

Every pattern is a spectrally neutral relative reflectance map in [0, 1] lit by ``illuminant`` (default D65),
so the scene carries ``illuminant_photons`` and ``scene.reflectance()`` returns the map. Each generator
returns a batch of one, scaled to ``mean_luminance_cd_m2`` (default 100 cd/m^2; None keeps the raw scale),
on the wavelength grid ``wavelengths`` (default 400:10:700 nm). Pixel coordinates are measured from the
image centre, ``(n - 1) / 2``, with rows growing downwards.

The defaults are this library's, not ``sceneCreate``'s: every pattern is lit by D65 at a 10 degree field of view,
where ISETCam lights the slanted bar with equal energy at 2 degrees, the zone plate with equal photons at 4, the
point array with D65 at 40 and the sweep, checkerboard, grid lines and star with equal photons. ISETCam's slanted
bar of slope ``s`` (``sceneSlantedBar``: ``Y > s X``) is ``slanted_edge(angle_deg=degrees(atan(1 / s)))`` mirrored
left to right (to its anti-aliased edge pixels). Pass ``illuminant``, ``hfov_deg`` and the pattern's own arguments
to reproduce those ISETCam scenes. The frequency sweep is not ISETCam's: ``imgSweep`` has the phase
``2 pi f x^3`` (local frequency ``3 f x^2`` cycles per image, ``3 f`` at the right edge), this one a phase
quadratic in ``x`` (frequency rising linearly, :func:`frequency_sweep`).
"""

from __future__ import annotations

import math

import torch

from .. import spectral
from .._checks import check_bool
from ._common import (
    DEFAULT_DISTANCE_M,
    DEFAULT_HFOV_DEG,
    DEFAULT_MEAN_LUMINANCE_CD_M2,
    check_float,
    check_int,
    check_size,
    illuminant_energy,
    pattern_scene,
    pixel_coords,
    resolve_dtype,
    resolve_grid,
)
from .scene import Scene

__all__ = [
    "uniform",
    "monochromatic",
    "ramp",
    "frequency_sweep",
    "slanted_edge",
    "point_array",
    "grid_lines",
    "star",
    "checkerboard",
    "zone_plate",
    "hdr_chart",
]

_M = DEFAULT_MEAN_LUMINANCE_CD_M2


def _common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2):
    return {"hfov_deg": hfov_deg, "distance_m": distance_m, "mean_luminance_cd_m2": mean_luminance_cd_m2}


def _grid_and_dtype(wavelengths, dtype, device):
    w = resolve_grid(wavelengths, resolve_dtype(dtype, wavelengths), device)
    return w, w.dtype, w.device


def _check_level(dark_level) -> float:
    return check_float(dark_level, "dark_level", low=0.0, high=1.0, high_open=True)


# ---------------------------------------------------------------------------------------------
# Uniform fields


def uniform(spectrum="D65", size=32, wavelengths=None, *, mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG,
            distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """A uniform field whose radiance has the shape of ``spectrum`` (a perfect white under that light).

    ISETCam: ``sceneCreate('uniform d65' | 'uniform ee' | 'uniform ep' | 'uniform bb', size)``.

    Args:
        spectrum: illuminant name (``"D65"``, ``"equal_energy"``, ``"equal_photon"``, ``"blackbody5000"``,
            ``"D5000"``, ``"A"``, ``"F2"``, ...; see :func:`isettorch.spectral.illuminant`) or energy SPD [L].
        size: rows and cols (int) or (rows, cols).

    Returns:
        Scene (1, L, H, W), ``illuminant_photons`` equal to the radiance.

    Example:
        >>> s = uniform("equal_photon", size=4)
        >>> p = s.photons[0, :, 0, 0]
        >>> bool(torch.allclose(p, p.mean().expand_as(p))), round(s.mean_luminance().item(), 3)
        (True, 100.0)
    """
    rows, cols = check_size(size)
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    pattern = torch.ones(rows, cols, dtype=dt, device=dev)
    name = f"uniform {spectrum}" if isinstance(spectrum, str) else "uniform"
    return pattern_scene(pattern, illuminant_energy(spectrum, w, "spectrum"), w, name=name,
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def monochromatic(wavelength_nm: float = 550.0, size=32, wavelengths=None, *, mean_luminance_cd_m2=_M,
                  hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """A uniform field of monochromatic light at ``wavelength_nm``.

    With ``wavelengths=None`` the scene has the single band ``[wavelength_nm]`` (ISETCam
    ``sceneCreate('uniform monochromatic', wavelength, size)``; its luminance uses a 1 nm bin width);
    with a grid, ``wavelength_nm`` must be one of its samples and all other bands are zero.

    Example:
        >>> s = monochromatic(550.0, size=4)
        >>> s.wavelengths_nm.tolist(), round(s.mean_luminance().item(), 4)
        ([550.0], 100.0)
    """
    lam = check_float(wavelength_nm, "wavelength_nm", low=0.0, low_open=True)
    rows, cols = check_size(size)
    if wavelengths is None:
        w = resolve_grid(torch.tensor([lam], dtype=torch.float64), resolve_dtype(dtype), device)
    else:
        w = resolve_grid(wavelengths, dtype, device)
    # to the grid's precision: 632.8 nm in float32 is 632.79999 (a 1e-6 nm tolerance refused it at the default dtype)
    tol = max(1e-6, 4 * torch.finfo(w.dtype).eps * lam)
    hit = (w.double() - lam).abs() < tol
    if not hit.any():
        raise ValueError(f"wavelength_nm: expected one of the grid's samples {w.tolist()}, got {lam}")
    if spectral.luminosity(w.double()[hit]).item() <= 0:
        raise ValueError(f"wavelength_nm: {lam} nm is invisible (V(lambda) = 0), so the field has no luminance")
    spd = hit.to(w.dtype)
    pattern = torch.ones(rows, cols, dtype=w.dtype, device=w.device)
    return pattern_scene(pattern, spd, w, name=f"monochromatic {lam:g} nm",
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


# ---------------------------------------------------------------------------------------------
# Ramps, sweeps, edges


def ramp(size=64, kind: str = "linear", *, dynamic_range: float = 1000.0, dark_level: float = 0.0,
         illuminant="D65", wavelengths=None, mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG,
         distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """Intensity ramp increasing from left to right, constant down the columns.

    ``kind="linear"``: reflectance ``dark_level + (1 - dark_level) x / (W - 1)``
    (ISETCam ``sceneCreate('linear intensity ramp')``); ``kind="exponential"``: reflectance
    ``dynamic_range ** (x / (W - 1) - 1)``, from ``1 / dynamic_range`` to 1, equal ratios per column
    (ISETCam ``sceneCreate('exponential intensity ramp', size, dynamicRange)``).

    Example:
        >>> s = ramp((2, 8), "exponential", dynamic_range=100.0)
        >>> lum = s.luminance()[0, 0, 0]
        >>> round((lum[-1] / lum[0]).item(), 3)
        100.0
    """
    rows, cols = check_size(size)
    if cols < 2:
        raise ValueError(f"size: a ramp needs at least 2 columns, got {cols}")
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    t = torch.arange(cols, dtype=torch.float64) / (cols - 1)
    # both checked whatever the kind (the kind's unused one had been taken unchecked: dark_level=5 refused for a
    # linear ramp and accepted for an exponential one)
    dark = _check_level(dark_level)
    dr = check_float(dynamic_range, "dynamic_range", low=1.0, low_open=True)
    if kind == "linear":
        profile = dark + (1 - dark) * t
    elif kind == "exponential":
        profile = dr ** (t - 1)
    else:
        raise ValueError(f"kind: expected 'linear' or 'exponential', got {kind!r}")
    pattern = profile.to(dt).to(dev).expand(rows, cols).clone()
    return pattern_scene(pattern, illuminant, w, name=f"{kind} ramp",
                         metadata={"kind": kind}, **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def frequency_sweep(size=128, max_frequency_cpi: float | None = None, *, contrast: float = 1.0,
                    contrast_ramp: bool = True, illuminant="D65", wavelengths=None, mean_luminance_cd_m2=_M,
                    hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """Sinusoid whose spatial frequency rises linearly from 0 (left) to ``max_frequency_cpi`` (right edge).

    Reflectance ``0.5 (1 + c(y) cos(pi f_max u^2))`` with ``u = col / W``: the phase derivative gives the local
    frequency ``f_max u`` cycles per image width. ``c(y)`` falls linearly from ``contrast`` (top row) to
    ``contrast / H`` (bottom row) when ``contrast_ramp``, else is constant.
    Like ISETCam's ``sceneCreate('sweep frequency', size, maxFreq)`` (frequency along x, contrast along y) but not
    the same pattern: ISETCam's ``imgSweep`` phase ``2 pi maxFreq x^3`` (``x`` in [0, 1]) has the local frequency
    ``3 maxFreq x^2``, rising quadratically to ``3 maxFreq`` cycles per image.

    Args:
        max_frequency_cpi: local frequency at the right edge, cycles per image width; default W / 4
            (half the Nyquist limit); at most W / 2.

    Example:
        >>> frequency_sweep(32, 8.0).photons.shape
        torch.Size([1, 31, 32, 32])
    """
    rows, cols = check_size(size)
    f_max = cols / 4 if max_frequency_cpi is None else check_float(
        max_frequency_cpi, "max_frequency_cpi", low=0.0, high=cols / 2, low_open=True)
    c = check_float(contrast, "contrast", low=0.0, high=1.0)
    check_bool(contrast_ramp, "contrast_ramp")  # ('no' was True)
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    u = torch.arange(cols, dtype=torch.float64) / cols
    carrier = torch.cos(math.pi * f_max * u**2)
    if contrast_ramp:
        cy = c * (rows - torch.arange(rows, dtype=torch.float64)) / rows
    else:
        cy = torch.full((rows,), c, dtype=torch.float64)
    pattern = 0.5 * (1 + cy[:, None] * carrier[None, :])
    return pattern_scene(pattern.to(dt).to(dev), illuminant, w, name="frequency sweep",
                         metadata={"max_frequency_cpi": f_max, "contrast": c},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def _halfplane_coverage(s: torch.Tensor, a: float, b: float) -> torch.Tensor:
    """Area of a unit pixel on the positive side of a line at signed distance ``s`` from its centre.

    ``a >= b >= 0`` are |cos|, |sin| of the line normal. The projection of the square on the normal is the sum
    of two uniform variables of widths a and b, so the coverage is their (trapezoidal) CDF.
    """
    if b < 1e-12:
        return (s / a + 0.5).clamp(0, 1)
    t = (s + 0.5 * (a + b)).clamp(0, a + b)
    low = t**2 / (2 * a * b)
    mid = (t - 0.5 * b) / a
    high = 1 - (a + b - t) ** 2 / (2 * a * b)
    return torch.where(t < b, low, torch.where(t <= a, mid, high))


def slanted_edge(size=64, angle_deg: float = 5.0, *, dark_level: float = 0.25, illuminant="D65",
                 wavelengths=None, mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG,
                 distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """A straight edge through the image centre, dark on the left and bright (reflectance 1) on the right.

    ``angle_deg`` is the edge's tilt from vertical, positive when its top leans to the right
    (the edge is the line ``x = -y tan(angle)`` with y downwards); allowed in (-90, 90). Pixels on the edge
    take the exact area fraction of the pixel on the bright side (box pixels). The default ``dark_level``
    0.25 is the 4:1 edge contrast of ISO 12233:2017; ISETCam: ``sceneCreate('slanted edge', size, slope)``.

    Example:
        >>> s = slanted_edge(16, 0.0)
        >>> s.reflectance()[0, 0, 0, 7].item(), s.reflectance()[0, 0, 0, 8].item()
        (0.25, 1.0)
    """
    rows, cols = check_size(size, minimum=2)
    theta = check_float(angle_deg, "angle_deg", low=-90.0, high=90.0, low_open=True, high_open=True)
    dark = _check_level(dark_level)
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    y, x = pixel_coords(rows, cols, torch.float64, "cpu")
    ct, st = math.cos(math.radians(theta)), math.sin(math.radians(theta))
    s = x * ct + y * st  # signed distance (pixels) from the edge, positive on the bright side
    a, b = max(abs(ct), abs(st)), min(abs(ct), abs(st))
    cover = _halfplane_coverage(s, a, b)
    pattern = dark + (1 - dark) * cover
    return pattern_scene(pattern.to(dt).to(dev), illuminant, w, name="slanted edge",
                         metadata={"angle_deg": theta, "dark_level": dark},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


# ---------------------------------------------------------------------------------------------
# Periodic patterns


def _first_position(spacing: int) -> int:
    """ISETCam scenePointArray / sceneGridLines: the first point or line at MATLAB's round(spacing / 2), 1-based
    (halves away from zero): 0-based (spacing + 1) // 2 - 1 (7 for spacing 16; it was spacing // 2, one pixel off
    for even spacings)."""
    return (spacing + 1) // 2 - 1


def _periodic_positions(n: int, spacing: int) -> torch.Tensor:
    return torch.arange(_first_position(spacing), n, spacing)


def point_array(size=128, spacing: int = 16, *, point_size: int = 1, illuminant="D65", wavelengths=None,
                mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None,
                device=None) -> Scene:
    """Bright square points of ``point_size`` pixels on a black background, every ``spacing`` pixels.

    The first point is at ((spacing + 1) // 2 - 1, (spacing + 1) // 2 - 1) (0-based), a point of ``point_size``
    pixels spans ``point_size // 2`` pixels before it (centred for odd sizes), as ISETCam's ``sceneCreate('point
    array', size, spacing)`` places them (``round(spacing / 2)``, 1-based, widened by ``conv2(.., ones(k),
    'same')``).

    Example:
        >>> int((point_array(32, 8).reflectance()[0, 0] > 0.5).sum())
        16
    """
    rows, cols = check_size(size)
    spacing = check_int(spacing, "spacing")
    point_size = check_int(point_size, "point_size")
    if point_size > spacing:
        raise ValueError(f"point_size: expected at most spacing ({spacing}) pixels, got {point_size}")
    if _first_position(spacing) >= min(rows, cols):
        raise ValueError(f"spacing: expected (spacing + 1) // 2 - 1 < the image size {min(rows, cols)}, got "
                         f"{spacing}")
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    pattern = torch.zeros(rows, cols, dtype=dt, device=dev)
    for r in _periodic_positions(rows, spacing).tolist():
        for c in _periodic_positions(cols, spacing).tolist():
            r0, c0 = r - point_size // 2, c - point_size // 2
            pattern[max(r0, 0):r0 + point_size, max(c0, 0):c0 + point_size] = 1
    return pattern_scene(pattern, illuminant, w, name="point array",
                         metadata={"spacing": spacing, "point_size": point_size},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def grid_lines(size=128, spacing: int = 16, line_width: int = 1, *, illuminant="D65", wavelengths=None,
               mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None,
               device=None) -> Scene:
    """Bright horizontal and vertical lines ``line_width`` wide every ``spacing`` pixels on black.

    Lines start at row/col ``(spacing + 1) // 2 - 1`` (0-based) and grow ``line_width`` pixels down / right, as
    ISETCam's ``sceneCreate('grid lines', size, spacing)`` places them (``round(spacing / 2)``, 1-based).

    Example:
        >>> grid_lines(16, 8).reflectance()[0, 0, 3].tolist() == [1.0] * 16
        True
    """
    rows, cols = check_size(size)
    spacing = check_int(spacing, "spacing", minimum=2)
    line_width = check_int(line_width, "line_width")
    if line_width >= spacing:
        raise ValueError(f"line_width: expected fewer than spacing ({spacing}) pixels, got {line_width}")
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    off = _first_position(spacing)
    on_r = ((torch.arange(rows) - off) % spacing < line_width) & (torch.arange(rows) >= off)
    on_c = ((torch.arange(cols) - off) % spacing < line_width) & (torch.arange(cols) >= off)
    if not (on_r.any() or on_c.any()):
        raise ValueError(f"spacing: no line fits in a {rows}x{cols} image with spacing {spacing}")
    pattern = (on_r[:, None] | on_c[None, :]).to(dtype=dt, device=dev)
    return pattern_scene(pattern, illuminant, w, name="grid lines",
                         metadata={"spacing": spacing, "line_width": line_width},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def checkerboard(size=64, square_size: int = 8, *, dark_level: float = 0.0, illuminant="D65", wavelengths=None,
                 mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None,
                 device=None) -> Scene:
    """Checkerboard of ``square_size``-pixel squares, dark square top-left (MATLAB ``checkerboard``).

    ISETCam: ``sceneCreate('checkerboard', pixelsPerCheck, numberOfChecks)``.

    Example:
        >>> checkerboard(4, 2).reflectance()[0, 0].tolist()
        [[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 1.0, 1.0], [1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]]
    """
    rows, cols = check_size(size)
    sq = check_int(square_size, "square_size")
    dark = _check_level(dark_level)
    if sq >= max(rows, cols):
        raise ValueError(f"square_size: expected less than the image size {max(rows, cols)}, got {sq}")
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    parity = (torch.arange(rows)[:, None] // sq + torch.arange(cols)[None, :] // sq) % 2
    pattern = (dark + (1 - dark) * parity.to(torch.float64)).to(dtype=dt, device=dev)
    return pattern_scene(pattern, illuminant, w, name="checkerboard", metadata={"square_size": sq},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


# ---------------------------------------------------------------------------------------------
# Radial patterns


def star(size=128, num_spokes: int = 24, *, profile: str = "square", dark_level: float = 0.0, illuminant="D65",
         wavelengths=None, mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M,
         dtype=None, device=None) -> Scene:
    """Siemens star: ``num_spokes`` bright and ``num_spokes`` dark sectors around the image centre.

    The angular profile is ``sin(N theta)`` (theta counter-clockwise from +x): ``"sine"`` gives the sinusoidal
    star of ISO 12233:2017 (``0.5 (1 + sin)``); ``"square"`` the binary star, antialiased by the arc distance
    to the nearest sector border (``clamp(0.5 + r sin(N theta) / N, 0, 1)``, exact near the borders),
    so it is mirror-antisymmetric and sub-pixel spokes near the centre average to 0.5.
    ISETCam: ``sceneCreate('star pattern')`` / ``'rings rays'``.

    Example:
        >>> s = star(16, 8).reflectance()[0, 0]
        >>> bool(torch.allclose(s, s.rot90(1, (0, 1)), atol=1e-6))
        True
    """
    rows, cols = check_size(size)
    n = check_int(num_spokes, "num_spokes", minimum=2)
    dark = _check_level(dark_level)
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    y, x = pixel_coords(rows, cols, torch.float64, "cpu")
    theta = torch.atan2(-y, x)
    sn = torch.sin(n * theta)
    if profile == "sine":
        v = 0.5 * (1 + sn)
    elif profile == "square":
        v = (0.5 + torch.hypot(x, y) * sn / n).clamp(0, 1)
    else:
        raise ValueError(f"profile: expected 'square' or 'sine', got {profile!r}")
    pattern = dark + (1 - dark) * v
    return pattern_scene(pattern.to(dt).to(dev), illuminant, w, name="star",
                         metadata={"num_spokes": n, "profile": profile},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


def zone_plate(size=128, max_frequency_cpp: float = 0.5, *, illuminant="D65", wavelengths=None,
               mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG, distance_m=DEFAULT_DISTANCE_M, dtype=None,
               device=None) -> Scene:
    """Circular zone plate ``0.5 (1 + cos(pi f_max r^2 / R))``, R = min(H, W) / 2, r from the centre (pixels).

    The local radial frequency is ``f_max r / R`` cycles per pixel: 0 at the centre and ``max_frequency_cpp``
    (default the Nyquist limit, 0.5) at the middle of the nearest border; towards the corners it exceeds that
    (up to sqrt(2) f_max) and aliases, as ISETCam's does. ISETCam: ``sceneCreate('zone plate')``.

    Example:
        >>> zone_plate(16).photons.shape
        torch.Size([1, 31, 16, 16])
    """
    rows, cols = check_size(size, minimum=2)
    f = check_float(max_frequency_cpp, "max_frequency_cpp", low=0.0, high=0.5, low_open=True)
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    y, x = pixel_coords(rows, cols, torch.float64, "cpu")
    radius = min(rows, cols) / 2
    pattern = 0.5 * (1 + torch.cos(math.pi * f * (x**2 + y**2) / radius))
    return pattern_scene(pattern.to(dt).to(dev), illuminant, w, name="zone plate",
                         metadata={"max_frequency_cpp": f, "radius_px": radius},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))


# ---------------------------------------------------------------------------------------------
# High dynamic range


def hdr_chart(decades: int = 6, steps_per_decade: int = 2, patch_size: int = 16, *, illuminant="D65",
              wavelengths=None, mean_luminance_cd_m2=_M, hfov_deg=DEFAULT_HFOV_DEG,
              distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """A row of square patches whose luminance falls by equal ratios over ``decades`` decades.

    Patch k (left to right, k = 0 .. decades * steps_per_decade) has reflectance
    ``10 ** (-k / steps_per_decade)``, so the brightest / darkest luminance ratio is ``10 ** decades``.
    ISETCam: ``sceneCreate('hdr chart')`` (sceneHDRChart).

    Example:
        >>> s = hdr_chart(decades=2, steps_per_decade=1, patch_size=2)
        >>> lum = s.luminance()[0, 0, 0, ::2]
        >>> round((lum[0] / lum[-1]).item(), 3)
        100.0
    """
    d = check_int(decades, "decades")
    steps = check_int(steps_per_decade, "steps_per_decade")
    p = check_int(patch_size, "patch_size")
    w, dt, dev = _grid_and_dtype(wavelengths, dtype, device)
    if 10.0 ** -d < torch.finfo(dt).tiny:  # (46 decades in float32 made the darkest patches exactly 0)
        raise ValueError(f"decades: {d} decades reach below {dt}'s smallest normal number; expected at most "
                         f"{math.floor(-math.log10(torch.finfo(dt).tiny))} in {dt}")
    levels = 10.0 ** (-torch.arange(d * steps + 1, dtype=torch.float64) / steps)
    pattern = levels.repeat_interleave(p)[None, :].expand(p, -1)
    return pattern_scene(pattern.to(dt).to(dev).clone(), illuminant, w, name="hdr chart",
                         metadata={"decades": d, "steps_per_decade": steps, "patch_size": p,
                                   "levels": levels.tolist()},
                         **_common_kwargs(hfov_deg, distance_m, mean_luminance_cd_m2))

