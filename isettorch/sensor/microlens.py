"""Microlens and pixel-stack optics: the fraction of a pixel's light that reaches its photodiode (the etendue of
ISET), per chief-ray angle, with no microlens, a centred microlens or a microlens at the optimal offset.

Model (Catrysse & Wandell, "Optical efficiency of image sensor pixels", JOSA A 19(8), 2002; ISETCam
``mlRadiance``, ``mlAnalyzeArrayEtendue``, ``mlensCreate``, ``mlensGet('optimal offset')``): 1-D ray phase space
(position x, direction sine p = n sin(theta), conserved across the flat layers of the stack):

1. source: a box of rays, ``|x| < D / 2`` (the microlens aperture D) and p in sin(CRA) +- NA with
   NA = sin(atan(1 / (2 N_source))) (a Lambertian exit pupil of f-number N_source seen from the pixel);
2. microlens (when present): p -> p + sin(atan(x / f_air)), f_air = f_ml / 1.52 (ISETCam's ``rStack``: the
   microlens focal length is given in the stack; in air-momentum units its power is n / f_ml);
3. offset: x -> x + o (positive o compensates a positive CRA);
4. each layer (thickness t_i, index n_i): x -> x - t_i tan(asin(p / n_i));
5. etendue = (rays inside the photodiode, ``|x| < d / 2``) / (source rays over the pixel aperture,
   ``|x| < p_pixel / 2``).

The optimal offset is the chief ray's walk through the stack, ``sum_i t_i tan(asin(sin(CRA) / n_i))``
(``mlensGet(ml, 'optimal offset')``).

Defaults follow the pixel, as ISETCam builds a microlens from a sensor (``mlensCreate(sensor)`` /
``mlImportParams``): the microlens focal length is the pixel depth (the stack height, ``sum(t_i)`` or
``stack_height_m``), its diameter the pixel width, and the photodiode ``sqrt(0.75)`` x the pixel width (the 75 %
fill of ``pixelCreate``). ISETCam's default pixel (``pixelCreate('default')``) is 2.8 um wide with a 2.42487 um
photodiode under a 7 um stack of two layers, 2 um at n = 2.0 and 5 um at n = 1.46, hence a microlens of f = 7 um at
f/2.5, refractive index 1.5 (used only for the array's optimal offsets, ``mlOptimalOffsets``); the source is the
default optics, f/4 with f = 3.8628 mm; the wavelength 500 nm (:data:`ISETCAM_PIXEL`). Explicit values win; a
microlens or a photodiode wider than the pixel is an error.

Two ways to count the rays (``sampling``):

* ``'isetcam'`` (default): ISETCam's own 255 x 255 phase-space grid over x in +-2 D and p in +-0.99
  (``mlCoordinates``), each transform a forward map of the grid points re-binned to the nearest cell with the
  cell's mean (``ffndgrid``), so the rays that leave that window (``|x| > 2 D`` or ``|p| > 0.99``) at any step are
  dropped.
  Its numbers are ISETCam's (an independent NumPy port of ``mlRadiance`` agrees to 0 on 750 pixel / stack /
  f-number / angle cases); no gradients (a tensor that requires grad is refused).
* ``'continuous'``: the same ray model integrated exactly along x for a fine grid of directions (the inside-length of
  each segment between x samples follows the crossing of the photodiode edge, linearly): no grid averaging and no
  finite x window (only the ``|p| < 0.99`` cut at the microlens: a segment with an end beyond it counts as outside, so
  the etendue reads up to 7.6e-3 low at ``samples=(64, 128)`` and 2.3e-3 at (128, 256) against a 3000 x 3000 midpoint
  integral, over pixels of 1-6 um, f/1.4-f/16, stacks of 3-12 um and CRA 0-45 deg). Its gradient in the source's
  f-number, and in the chief-ray angle for ``'none'`` and ``'centred'``, is Leibniz's rule for the span of directions
  (0.154 against 0.154 for d/dN at f/2, any sample count): the derivative of the exact integral, so it differs from
  the midpoint sum's own derivative by the quadrature error (1.2e-4 relative with ``diffraction=True`` at the default
  samples, 7e-6 at (256, 128)). In the CRA of ``'optimal'`` (whose offset follows the CRA),
  the stack height, the offset and the microlens focal length it is the gradient of the direction samples' sum, as
  before 2026-11-30: without ``diffraction`` a focused beam makes each direction's share a near-step that moves with
  them, and the gradient errs by 10-40 % (ISETCam's pixel, d/dh at f/2, CRA 3-22 deg: -0.194 per um at the default 64
  directions against -0.218 by finite differences; d/d(offset) at f/1.4, 2.8 um, 22 deg: 0.222 against 0.313), and is
  noise where the true slope is near zero; with ``diffraction=True`` (each ray a Gaussian) the integrand is smooth and
  these gradients agree to 1e-4 at 64 directions, except where the beam reaches the cut at 0.99 (whose share the
  moving samples miss): the CRA's of ``'optimal'`` (0 against -0.0126 at f/2.8, a 6 um pixel, 35 deg) and, for
  ``'optimal'`` with the microlens focal length following the stack height, d/dh and d/d(f_ml) at steep beams
  (an audit, per um, autograd against central differences: 45 deg f/1.4 -0.0835 / -0.0754 and -0.0041 / +0.0040;
  50 deg f/2 -0.0733 / -0.0599 and +0.0036 / +0.0171; with f_ml fixed, as ``PixelOptics`` has it, they agree). It is the
  integral that ISETCam's grid approximates, not ISETCam's number. Measured against ISETCam's grid: on ISETCam's
  default pixel (CRA 0-35 deg, source f/2-f/8) up to 0.030 (centred microlens, f/8, CRA 13.5 deg: the grid's averaging
  blurs the hard edge of the focused beam; 0.015 at f/4); over 4148 (pixel 1.4-5.6 um, stack 3-12 um, f/2-f/8, CRA
  0-30 deg) cases whose beam stays inside ISETCam's window up to 0.052, 99 % within 0.018; and up to 1 where ISETCam's
  +-2 D window clips the beam (a large optimal offset or a long stack at a large CRA, e.g. the 1.4 um pixel's optimal
  microlens at 30 deg: 0.92 vs ISETCam's 0.78; ISETCam drops those rays, down to 0, the integral keeps them).

``diffraction=True`` adds what the ray model leaves out: each ray lands as a Gaussian approximation to the
Fraunhofer pattern of the aperture (microlens width D, or the pixel without a microlens) after the stack,
sigma = 0.886 lambda_medium z / (2.355 D) with lambda_medium = lambda / n_mean (Goodman, *Introduction to Fourier
Optics*, 3rd ed., section 4.4: the rectangular aperture's FWHM 0.886 lambda z / D). The etendue then depends on the
wavelength (red light spreads more than blue), which ISETCam's ray model (its ``'angle'`` coordinates) does not.

How this differs from :func:`isettorch.sensor.pixel_optics.pixel_vignetting` (the geometric model, kept as
``model='geometric'``): that model is 2-D (a disk of directions over a square pixel), with an *ideal* microlens
(every direction focuses to one point at the photodiode depth) and no diffraction; this one is ISET's 1-D phase
space (separable in x and y, as ISETCam's pixel irradiance), with a microlens of finite focal length and aperture
(its focus may lie above or below the photodiode; a beam of finite NA makes a spot of finite width), ISETCam's
layered stack, and optional diffraction. The geometric model is the better physics for a 2-D beam at a large CRA
when the microlens focuses on the photodiode; this one matches ISET and models defocused or small microlenses.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .._autograd import records_grad
from .._checks import check_bool, is_real

__all__ = ["ISETCAM_PIXEL", "MICROLENS_METHODS", "PixelOptics", "microlens_radiance", "microlens_etendue",
           "microlens_optimal_offset_m", "microlens_array_offsets_m"]

MICROLENS_METHODS = ("none", "centred", "optimal")
_ALIASES = {"centered": "centred", "no microlens": "none", "nomicrolens": "none", "bare": "none",
            "optimized": "optimal"}

# ISETCam's default pixel and microlens (pixelCreate('default'), mlensCreate, oiCreate optics, mlensCreate's 500 nm)
ISETCAM_PIXEL: dict = dict(
    pixel_size_m=2.8e-6, photodiode_size_m=math.sqrt(2.8e-6 ** 2 * 0.75),
    layer_thicknesses_m=(2e-6, 5e-6), layer_indices=(2.0, 1.46),
    microlens_focal_length_m=7e-6, microlens_f_number=2.5, microlens_index=1.5,
    source_f_number=4.0, source_focal_length_m=3.862755099e-3, wavelength_nm=500.0,
)

_ISETCAM_STACK_INDEX = 1.52  # mlRadiance's rStack: the microlens focal length in air is f_ml / 1.52
_P_MAX = 0.99  # mlCoordinates: the direction-sine grid ends at +-0.99


def _method(method: str) -> str:
    if not isinstance(method, str):
        raise ValueError(f"method: expected one of {MICROLENS_METHODS} (or 'centered'), got {method!r}")
    m = _ALIASES.get(method.lower(), method.lower())
    if m not in MICROLENS_METHODS:
        raise ValueError(f"method: expected one of {MICROLENS_METHODS} (or 'centered'), got {method!r}")
    return m


def _pos(v, name: str) -> None:
    if isinstance(v, torch.Tensor):
        if not bool(torch.isfinite(v).all()) or bool((v <= 0).any()):
            raise ValueError(f"{name}: expected positive finite values, got {v.detach().flatten()[:4].tolist()}")
        return
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
        raise ValueError(f"{name}: expected a positive number, got {v!r}")


def _stack(layer_thicknesses_m, layer_indices, stack_height_m, stack_index, dtype, device):
    """(thicknesses [K], indices [K]) in metres. ``stack_index`` replaces the layers by one of that index;
    ``stack_height_m`` scales the layers to that total height (differentiable)."""
    if stack_index is not None:
        _pos(stack_index, "stack_index")
        idx = torch.as_tensor(stack_index, dtype=dtype, device=device).reshape(1)
        t = torch.as_tensor([float(sum(layer_thicknesses_m))], dtype=dtype, device=device)
    else:
        t = torch.as_tensor(layer_thicknesses_m, dtype=dtype, device=device).reshape(-1)
        idx = torch.as_tensor(layer_indices, dtype=dtype, device=device).reshape(-1)
        if t.numel() != idx.numel() or t.numel() == 0:
            raise ValueError(f"layer_thicknesses_m, layer_indices: expected the same number (>= 1) of layers, got "
                             f"{t.numel()} and {idx.numel()}")
        if not bool(torch.isfinite(t).all()) or bool((t <= 0).any()):
            raise ValueError(f"layer_thicknesses_m: expected positive finite thicknesses, got {t.tolist()}")
    if not bool(torch.isfinite(idx).all()) or bool((idx < 1).any()):
        raise ValueError(f"layer_indices/stack_index: expected refractive indices >= 1, got {idx.tolist()}")
    if stack_height_m is not None:
        _pos(stack_height_m, "stack_height_m")
        h = torch.as_tensor(stack_height_m, dtype=dtype, device=device)
        if h.numel() != 1:  # (two heights scaled the two layers each by its own: a 3.14 um stack for [1, 4] um)
            raise ValueError(f"stack_height_m: expected one value (the stack's total height, m), got shape "
                             f"{tuple(h.shape)}")
        t = t * (h.reshape(()) / t.sum())
    return t, idx


def microlens_optimal_offset_m(chief_ray_angle_deg, *, layer_thicknesses_m=ISETCAM_PIXEL["layer_thicknesses_m"],
                               layer_indices=ISETCAM_PIXEL["layer_indices"], stack_height_m=None,
                               stack_index=None) -> torch.Tensor:
    """Microlens offset that centres the chief ray on the photodiode: ``sum_i t_i tan(asin(sin(CRA) / n_i))``
    (ISETCam ``mlensGet(ml, 'optimal offset')``; positive: towards the optical axis' side the chief ray comes
    from, the sign :func:`microlens_radiance` uses). Tensor in, tensor out (metres)."""
    cra = torch.as_tensor(chief_ray_angle_deg, dtype=torch.float64)
    if not torch.is_floating_point(cra):
        cra = cra.double()
    _check_cra(cra)
    t, n = _stack(layer_thicknesses_m, layer_indices, stack_height_m, stack_index, cra.dtype, cra.device)
    s = torch.sin(torch.deg2rad(cra))[..., None]
    return (t * torch.tan(torch.asin(s / n))).sum(-1)


def microlens_array_offsets_m(rows: int, cols: int, pixel_size_m: float, *,
                              source_focal_length_m: float = ISETCAM_PIXEL["source_focal_length_m"],
                              microlens_focal_length_m: float = ISETCAM_PIXEL["microlens_focal_length_m"],
                              microlens_index: float = ISETCAM_PIXEL["microlens_index"]) -> torch.Tensor:
    """Optimal microlens offsets over an array ``[rows, cols]`` (m): ``f_ml tan(asin(sin(CRA) / n_ml))`` with
    ``CRA = atan(r / f_source)`` at each pixel centre (ISETCam ``mlOptimalOffsets``: the microlens focal length
    as the stack height and the microlens index as the stack's)."""
    for v, name in ((pixel_size_m, "pixel_size_m"), (source_focal_length_m, "source_focal_length_m"),
                    (microlens_focal_length_m, "microlens_focal_length_m"), (microlens_index, "microlens_index")):
        _pos(v, name)
    if float(microlens_index) < 1:
        raise ValueError(f"microlens_index: expected a refractive index >= 1, got {microlens_index!r}")
    if not all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in (rows, cols)):  # (True: 1 row)
        raise ValueError(f"rows, cols: expected positive integers, got {rows!r}, {cols!r}")
    y = (torch.arange(rows, dtype=torch.float64) - (rows - 1) / 2) * pixel_size_m
    x = (torch.arange(cols, dtype=torch.float64) - (cols - 1) / 2) * pixel_size_m
    r = torch.hypot(y[:, None], x[None, :])
    cra = torch.atan(r / source_focal_length_m)
    return microlens_focal_length_m * torch.tan(torch.asin(torch.sin(cra) / microlens_index))


def _check_cra(cra: torch.Tensor) -> None:
    if not bool(torch.isfinite(cra).all()) or bool((cra.abs() >= 90).any()):
        raise ValueError(f"chief_ray_angle_deg: expected finite angles with |angle| < 90 deg, got "
                         f"{cra.detach().flatten()[:6].tolist()}")


def _photodiode_m(kw) -> float:
    """The photodiode width (m): the given one (at most the pixel's), else pixelCreate's 75 % fill factor,
    ``sqrt(0.75 w^2)``."""
    pixel = float(kw["pixel_size_m"])
    photodiode = kw["photodiode_size_m"]
    if photodiode is None:
        return math.sqrt(pixel ** 2 * 0.75)
    _pos(photodiode, "photodiode_size_m")
    if float(photodiode) > pixel:
        raise ValueError(f"photodiode_size_m: {float(photodiode):.6g} m is wider than the pixel (pixel_size_m="
                         f"{pixel:.6g} m); give photodiode_size_m <= pixel_size_m, or omit it for ISETCam's 75 % fill "
                         f"(sqrt(0.75) x pixel_size_m)")
    return float(photodiode)


def _microlens_diameter_m(kw, f_ml, pixel: float) -> tuple[float, str | None]:
    """(the microlens diameter (m), the argument that set it, None for the default: the pixel width)."""
    if kw.get("microlens_diameter_m") is not None:
        _pos(kw["microlens_diameter_m"], "microlens_diameter_m")
        return float(kw["microlens_diameter_m"]), "microlens_diameter_m"
    if kw.get("microlens_f_number") is not None:
        _pos(kw["microlens_f_number"], "microlens_f_number")
        return float(f_ml) / float(kw["microlens_f_number"]), "microlens_f_number"
    return pixel, None


def _params(chief_ray_angle_deg, method, offset_m, kw):
    """Shared argument handling: (cra [A], method, thicknesses, indices, offset [A], geometry dict)."""
    method = _method(method)
    tensors = [v for v in (chief_ray_angle_deg, offset_m, kw["stack_height_m"], kw["stack_index"],
                           kw["microlens_focal_length_m"]) if isinstance(v, torch.Tensor)]
    dtype = torch.float64
    device = tensors[0].device if tensors else torch.device("cpu")
    if isinstance(chief_ray_angle_deg, bool) or (isinstance(chief_ray_angle_deg, torch.Tensor)
                                                 and chief_ray_angle_deg.dtype == torch.bool):
        raise ValueError(f"chief_ray_angle_deg: expected angles in degrees, got a boolean {chief_ray_angle_deg!r}")
    cra = torch.as_tensor(chief_ray_angle_deg, dtype=dtype, device=device)
    _check_cra(cra)
    for name in ("pixel_size_m", "source_f_number", "wavelength_nm"):
        _pos(kw[name], name)
    for name in ("photodiode_size_m", "microlens_focal_length_m"):
        if kw[name] is not None:
            _pos(kw[name], name)
    for name in ("pixel_size_m", "source_f_number"):
        if isinstance(kw[name], torch.Tensor) and kw[name].numel() != 1:
            raise ValueError(f"{name}: expected one value (a scalar or one-element tensor), got shape "
                             f"{tuple(kw[name].shape)}")
    if float(torch.as_tensor(kw["source_f_number"]).detach()) < 0.5:  # (no warning on a tensor that requires grad)
        raise ValueError(f"source_f_number: expected >= 0.5, got {kw['source_f_number']}")
    for name in ("pixel_size_m", "photodiode_size_m", "microlens_diameter_m", "microlens_f_number"):
        if records_grad(kw.get(name)):  # read as numbers below: the gradient was dropped without a word
            raise ValueError(f"{name}: the etendue reads it as a number (no gradient); pass a number or a detached "
                             f"tensor (the differentiable geometry: stack_height_m, layer_thicknesses_m, "
                             f"layer_indices, stack_index, microlens_focal_length_m, offset_m)")
    pixel = float(kw["pixel_size_m"])
    photodiode = _photodiode_m(kw)
    t, n = _stack(kw["layer_thicknesses_m"], kw["layer_indices"], kw["stack_height_m"], kw["stack_index"], dtype,
                  device)
    # mlImportParams: the microlens focal length is the pixel depth (the stack height), its diameter the pixel width
    f_ml = t.sum() if kw["microlens_focal_length_m"] is None else torch.as_tensor(
        kw["microlens_focal_length_m"], dtype=dtype, device=device)
    diam, given = _microlens_diameter_m(kw, f_ml, pixel)
    if given is not None and diam > pixel * (1 + 1e-9):
        raise ValueError(f"{given}: the microlens diameter {diam:.6g} m (microlens_diameter_m, or the focal length "
                         f"{float(f_ml):.6g} m / microlens_f_number) is wider than the pixel (pixel_size_m={pixel:.6g} "
                         f"m); give microlens_diameter_m <= pixel_size_m or microlens_f_number >= "
                         f"{float(f_ml) / pixel:.4g}, or neither for a microlens as wide as the pixel")
    if isinstance(offset_m, bool) or (isinstance(offset_m, torch.Tensor) and offset_m.dtype == torch.bool):
        raise ValueError(f"offset_m: expected finite offsets (m), got {offset_m!r}")  # (True was a 1 m offset)
    if method == "optimal":
        s = torch.sin(torch.deg2rad(cra))[..., None]
        off = (t * torch.tan(torch.asin(s / n))).sum(-1)
        if offset_m is not None:
            off = off + torch.as_tensor(offset_m, dtype=dtype, device=device)
    elif method == "centred":
        off = torch.zeros_like(cra) if offset_m is None else torch.as_tensor(offset_m, dtype=dtype, device=device)
    else:
        if offset_m is not None:
            raise ValueError("offset_m: method 'none' has no microlens to offset")
        off = torch.zeros_like(cra)
    if not bool(torch.isfinite(off.detach()).all()):
        raise ValueError(f"offset_m: expected finite offsets (m), got {off.detach().flatten()[:6].tolist()}")
    lam = torch.as_tensor(kw["wavelength_nm"], dtype=dtype, device=device) * 1e-9
    try:  # the rays' geometry; the wavelength only blurs
        shape_geo = torch.broadcast_shapes(cra.shape, off.shape)
    except RuntimeError as err:
        raise ValueError(f"offset_m: shape {tuple(off.shape)} does not broadcast with the chief-ray angles' "
                         f"{tuple(cra.shape)}") from err
    shape = torch.broadcast_shapes(shape_geo, lam.shape)
    cra, off = (v.expand(shape_geo).reshape(-1) for v in (cra, off))
    fnum = kw["source_f_number"]  # a tensor (a learnable f-number) keeps its gradient: the source's NA
    na = (torch.sin(torch.atan(1.0 / (2.0 * torch.as_tensor(fnum, dtype=dtype, device=device))))
          if isinstance(fnum, torch.Tensor) else math.sin(math.atan(1.0 / (2.0 * float(fnum)))))
    geo = dict(D=diam, p=pixel, d=float(photodiode), na=na, f_air=f_ml / _ISETCAM_STACK_INDEX, lam=lam, shape=shape,
               shape_geo=shape_geo)
    return cra, method, t, n, off, geo


def _continuous(cra, method, t, n, off, geo, diffraction, samples, profile=True):
    """Exact x-integration of the phase-space box per direction sample: (etendue [A], x_final [A, U, X],
    weights [A, U, X])."""
    nu, nx = samples
    D, d, na = geo["D"], geo["d"], geo["na"]
    dtype, dev = t.dtype, t.device
    s = torch.sin(torch.deg2rad(cra))  # [A]
    lo = (s - na).clamp(min=-_P_MAX)
    hi = (s + na).clamp(max=_P_MAX)
    if bool((hi <= lo).any()):
        raise ValueError("chief_ray_angle_deg/source_f_number: the source's directions lie outside |p| < 0.99")
    k = (torch.arange(nu, dtype=dtype, device=dev) + 0.5) / nu
    # the direction sines: U midpoints of the source's span [lo, hi], then its two ends (for the gradient below).
    # The span's width (the f-number) enters through Leibniz's rule alone; its centre (the CRA) too, unless the
    # offset follows the CRA ('optimal'), where the samples move with the CRA as the beam and the offset move
    # together (Leibniz's rule there gave -0.061 for -0.0056: the offset's share went through the near-step)
    na_d = na.detach() if isinstance(na, torch.Tensor) else na
    s_u = s if method == "optimal" else s.detach()
    lo_u, hi_u = (s_u - na_d).clamp(min=-_P_MAX), (s_u + na_d).clamp(max=_P_MAX)
    s_l = s.detach() if method == "optimal" else s
    lo_l, hi_l = (s_l - na).clamp(min=-_P_MAX), (s_l + na).clamp(max=_P_MAX)  # the ends Leibniz's rule moves
    u = torch.cat([lo_u[:, None] + (hi_u - lo_u)[:, None] * k, lo_u.detach()[:, None], hi_u.detach()[:, None]],
                  1)  # [A, U + 2]
    x = torch.linspace(-D / 2, D / 2, nx + 1, dtype=dtype, device=dev)  # segment ends
    pu = u[:, :, None].expand(-1, -1, nx + 1)
    if method != "none":
        pu = pu + torch.sin(torch.atan(x / geo["f_air"]))
    valid = pu.abs() < _P_MAX
    pc = pu.clamp(-_P_MAX, _P_MAX)
    walk = (t * torch.tan(torch.asin(pc[..., None] / n))).sum(-1)  # [A, U, X+1]
    xf = x + off[:, None, None] - walk
    shape, shape_geo = geo["shape"], geo["shape_geo"]
    lead = (1,) * (len(shape) - len(shape_geo))
    width = (hi - lo) / (2 * na)  # share of the source's directions inside ISETCam's grid (the profile's weight)

    def full(v):  # [A_geo, ...] -> [A, ...] over the broadcast (geometry x wavelength) shape
        rest = tuple(v.shape[1:])
        return v.reshape((*lead, *shape_geo, *rest)).expand((*shape, *rest)).reshape((-1, *rest))

    if diffraction:
        sigma = _diffraction_sigma_m(t, n, geo, method)[:, None, None]
        xf, valid, width = full(xf), full(valid), full(width)
        half = d / 2
        phi = torch.special.ndtr
        g = phi((half - xf) / sigma) - phi((-half - xf) / sigma)
        g = torch.where(valid, g, torch.zeros_like(g))
        inside = 0.5 * (g[..., 1:] + g[..., :-1])  # trapezoid over each segment
    else:
        sfun = d / 2 - xf.abs()  # > 0 inside the photodiode
        sfun = torch.where(valid, sfun, torch.full_like(sfun, -1.0))
        a, b = sfun[..., :-1], sfun[..., 1:]
        both = (a > 0) & (b > 0)
        cross = (a > 0) != (b > 0)
        pos = torch.where(a > 0, a, b).clamp(min=0)
        denom = (a - b).abs()
        frac_cross = pos / torch.where(cross, denom, torch.ones_like(denom))
        inside = torch.where(both, torch.ones_like(a), torch.where(cross, frac_cross, torch.zeros_like(a)))
    # the fraction of the source (the microlens aperture D <= P, directions inside the grid: mlRadiance's
    # etendueIn) that reaches the photodiode (etendueOut): the mean over the directions of each direction's share,
    # e = 1 / (hi - lo) * integral_lo^hi f(u) du. Its gradient in the span's ends (the source's f-number, and the
    # chief-ray angle but for 'optimal') is Leibniz's, de/dhi = (f(hi) - e) / (hi - lo) and de/dlo = (e - f(lo)) /
    # (hi - lo), not the midpoint sum's: a focused beam makes f(u) a near-step, whose midpoint samples moved with
    # the ends gave gradients off by tens of percent at any sample count (0.196 against 0.155 at 512 directions)
    rows = inside.mean(-1)  # [A, U + 2]
    m, f_lo, f_hi = rows[:, :nu].mean(-1), rows[:, nu].detach(), rows[:, nu + 1].detach()
    lo_a, hi_a = (full(lo_l), full(hi_l)) if diffraction else (lo_l, hi_l)
    span = (hi_a - lo_a).detach()
    md = m.detach()
    e = m + ((f_hi - md) * (hi_a - hi_a.detach()) - (f_lo - md) * (lo_a - lo_a.detach())) / span
    xf, valid = xf[:, :nu], valid[:, :nu]
    if not diffraction:
        e, xf, valid, width = full(e), full(xf), full(valid), full(width)
    if not profile:
        return e, None, None
    xm = 0.5 * (xf[..., 1:] + xf[..., :-1])
    wm = torch.where(valid[..., 1:] & valid[..., :-1], torch.ones_like(xm), torch.zeros_like(xm))
    return e, xm, wm * (width / (nu * nx))[:, None, None]


def _diffraction_sigma_m(t, n, geo, method) -> torch.Tensor:
    """Gaussian width ``[A]`` of the aperture's Fraunhofer pattern after the stack: FWHM 0.886 lambda_medium z / D
    (Goodman, Introduction to Fourier Optics, 4.4), sigma = FWHM / 2.3548; lambda_medium = lambda / mean index."""
    shape = geo["shape"]
    n_mean = (t * n).sum() / t.sum()
    aperture = geo["D"] if method != "none" else geo["p"]
    lam = geo["lam"].reshape((*((1,) * (len(shape) - geo["lam"].dim())), *geo["lam"].shape))
    return 0.886 * (lam.expand(shape).reshape(-1) / n_mean) * t.sum() / (2.3548 * aperture)


def _isetcam_cells(xn, un, x0, dx, u0, du, n):
    """ISETCam ``ffndgrid``'s target cell of each mapped grid point (nearest cell, MATLAB round: half away from
    zero) and whether it lands inside the grid (points beyond it are dropped)."""
    bx = torch.sign((xn - x0) / dx) * torch.floor(((xn - x0) / dx).abs() + 0.5)
    bu = torch.sign((un - u0) / du) * torch.floor(((un - u0) / du).abs() + 0.5)
    ok = (bx >= 0) & (bx < n) & (bu >= 0) & (bu < n)
    return (bu.clamp(0, n - 1) * n + bx.clamp(0, n - 1)).long(), ok


def _isetcam_rebin(w, cell, ok, n):
    """ISETCam ``ffndgrid(z, f, -n, limits, 1)``: the mean of the values landing in each cell, 0 where none (or a
    zero sum) lands. ``w [A, n * n]``; ``cell, ok``: ``[n * n]`` (one map for every row) or ``[A, n * n]``."""
    a = w.shape[0]
    if cell.dim() == 1:
        sel = ok.nonzero().squeeze(1)
        tgt = cell[sel]
        total = w.new_zeros(a, n * n).index_add_(1, tgt, w[:, sel])
        count = torch.bincount(tgt, minlength=n * n).to(w.dtype)[None]
    else:
        tgt = (cell + (torch.arange(a, device=w.device) * n * n)[:, None])[ok]
        total = w.new_zeros(a * n * n).index_add_(0, tgt, w[ok]).reshape(a, n * n)
        count = w.new_zeros(a * n * n).index_add_(0, tgt, torch.ones_like(w[ok])).reshape(a, n * n)
    return torch.where(total != 0, total / count.clamp(min=1), torch.zeros_like(total))


def _numpy_linspace(half: float, n: int, dtype, device) -> torch.Tensor:
    """``linspace(-half, half, n)`` as NumPy builds it, ``-half + k (2 half) / (n - 1)`` with the far end exact (the
    grid of the NumPy port of mlRadiance in the tests; MATLAB's linspace rounds a little differently, and gives the
    same etendue at the tie below). torch.linspace fills from both ends: 141 of 255 values differed in the last bit
    (the middle 2.7e-17, here 0 for the default grid), and where a source cone's edge fell on a grid row (CRA 45
    degrees at f/0.5) ISETCam's strict comparison counted it: a 25 % larger etendue."""
    k = torch.arange(n, dtype=torch.float64)
    g = -half + k * (2 * half / (n - 1))
    g[-1] = half
    return g.to(dtype=dtype, device=device)


def _isetcam_grid(cra, method, t, n, off, geo, n_grid=255, chunk=32):
    """ISETCam ``mlRadiance`` on its own grid (``mlCoordinates``, ``mlSource``, ``mlLens``, ``mlDisplacement``,
    ``mlPropagate``, each re-binned by ``ffndgrid``): (etendue [A], x [N], x-profile at the photodiode [A, N])."""
    D, p, d, na = geo["D"], geo["p"], geo["d"], geo["na"]
    dtype, dev = t.dtype, t.device
    t, n, off, cra = t.detach(), n.detach(), off.detach(), cra.detach()
    x, u = _numpy_linspace(2 * D, n_grid, dtype, dev), _numpy_linspace(_P_MAX, n_grid, dtype, dev)
    dx, du = float(x[1] - x[0]), float(u[1] - u[0])
    X, U = x[None, :].expand(n_grid, -1), u[:, None].expand(-1, n_grid)
    Xf, Uf = X.reshape(-1), U.reshape(-1)
    grid = (float(x[0]), dx, float(u[0]), du, n_grid)
    # the microlens and the layers map every angle's grid alike: one cell map each
    lens = _isetcam_cells(Xf, Uf + torch.sin(torch.atan(Xf / float(geo["f_air"]))), *grid) if method != "none" \
        else None
    layers = [_isetcam_cells(Xf - ti * torch.tan(torch.asin(Uf / ni)), Uf, *grid)
              for ti, ni in zip(t.tolist(), n.tolist())]
    pairs, inverse = torch.unique(torch.stack([cra, off], 1), dim=0, return_inverse=True)
    e_all, prof_all = [cra.new_zeros(0)], [cra.new_zeros(0, n_grid)]
    for i in range(0, pairs.shape[0], chunk):
        c, o = pairs[i:i + chunk, 0], pairs[i:i + chunk, 1]
        s = torch.sin(torch.deg2rad(c))[:, None, None]
        src = ((U > s - na) & (U < s + na) & (X > -D / 2) & (X < D / 2)).to(dtype)  # [a, N, N] mlSource
        w = src.reshape(c.shape[0], -1)
        if lens is not None:
            w = _isetcam_rebin(w, *lens, n_grid)
            shifted = _isetcam_cells(Xf[None] + o[:, None], Uf[None].expand(c.shape[0], -1), *grid)
            w = _isetcam_rebin(w, *shifted, n_grid)
        for cells in layers:
            w = _isetcam_rebin(w, *cells, n_grid)
        prof = w.reshape(-1, n_grid, n_grid).sum(1)  # sum(W_detector, 1)
        e_in = src.sum(1)[:, x.abs() < p / 2].sum(-1)
        if bool((e_in == 0).any()):
            s_bad = s.reshape(-1)[e_in == 0]
            if bool(((s_bad - na >= _P_MAX) | (s_bad + na <= -_P_MAX)).any()):
                raise ValueError(f"chief_ray_angle_deg: the source's cone (NA {float(na):.3g} about sin(CRA)) lies "
                                 f"beyond ISETCam's direction grid (|sin| < {_P_MAX}); use sampling='continuous' or a "
                                 f"smaller angle")
            raise ValueError(f"source_f_number: the source's cone (NA {float(na):.3g} about sin(CRA)) falls between "
                             f"the rows of ISETCam's {n_grid}-point direction grid (step {du:.3g}), so the grid holds "
                             f"none of its light; use sampling='continuous' for so slow a source (or more "
                             f"grid_points)")
        e_all.append(prof[:, x.abs() < d / 2].sum(-1) / e_in)
        prof_all.append(prof)
    return torch.cat(e_all)[inverse], x, torch.cat(prof_all)[inverse]


# None: follows the pixel (mlensCreate(sensor) / mlImportParams): microlens focal length = the stack height,
# diameter = the pixel width; photodiode = sqrt(0.75) x the pixel width (pixelCreate's 75 % fill)
_DEFAULTS = dict(source_f_number=ISETCAM_PIXEL["source_f_number"], microlens_focal_length_m=None,
                 microlens_f_number=None, microlens_diameter_m=None,
                 layer_thicknesses_m=ISETCAM_PIXEL["layer_thicknesses_m"],
                 layer_indices=ISETCAM_PIXEL["layer_indices"], stack_height_m=None, stack_index=None,
                 pixel_size_m=ISETCAM_PIXEL["pixel_size_m"], photodiode_size_m=None,
                 wavelength_nm=ISETCAM_PIXEL["wavelength_nm"],
                 # accepted for ISETCam's microlens structure; a pixel's etendue does not depend on them (they place
                 # an angle on the array: microlens_array_offsets_m, PixelOptics)
                 source_focal_length_m=ISETCAM_PIXEL["source_focal_length_m"],
                 microlens_index=ISETCAM_PIXEL["microlens_index"])
# the and ISETCam's other names for the same parameters
_ALIAS_KEYS = {"pixel_width_m": "pixel_size_m", "photodiode_width_m": "photodiode_size_m"}


def _by_value(v):
    """A cache-key form of a pixel value: a tensor by its values (by identity, an in-place update, an optimiser's
    step, returned the etendue map of the old value)."""
    return ("tensor", tuple(v.detach().reshape(-1).tolist())) if isinstance(v, torch.Tensor) else v


def _pixel_kwargs(pixel: dict) -> dict:
    out = {}
    for k, v in pixel.items():
        key = _ALIAS_KEYS.get(k, k)
        if key in out:
            raise ValueError(f"{k}: given twice (as {key!r} too)")
        out[key] = v
    unknown = set(out) - set(_DEFAULTS)
    if unknown:
        raise ValueError(f"{sorted(unknown)[0]}: not a microlens/pixel parameter; expected one of "
                         f"{sorted(set(_DEFAULTS) | set(_ALIAS_KEYS))}")
    _check_one_aperture(out)
    for key in _SCALAR_PIXEL_KEYS:  # (as PixelOptics checks them: a NaN one the etendue does not read passed)
        if out.get(key) is not None:
            _pos(out[key], key)
    if out.get("microlens_index") is not None and float(torch.as_tensor(out["microlens_index"]).min()) < 1:
        raise ValueError(f"microlens_index: expected a refractive index >= 1, got {out['microlens_index']!r}")
    return {**_DEFAULTS, **out}


def _check_one_aperture(pixel: dict) -> None:
    """The microlens aperture is given once: ``microlens_diameter_m`` or ``microlens_f_number`` (the diameter is the
    focal length / f-number), not both (one would be ignored)."""
    if pixel.get("microlens_diameter_m") is not None and pixel.get("microlens_f_number") is not None:
        raise ValueError(f"microlens_f_number, microlens_diameter_m: give one of them (the diameter is "
                         f"microlens_focal_length_m / microlens_f_number), got both "
                         f"({pixel['microlens_f_number']!r} and {pixel['microlens_diameter_m']!r})")


def _check_samples(samples, name: str = "samples") -> tuple[int, int]:
    """(directions, x segments) of the continuous integral: two positive integers."""
    ok = isinstance(samples, (tuple, list)) and len(samples) == 2 and all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in samples)
    if not ok:
        raise ValueError(f"{name}: expected two positive integers (directions, x segments), got {samples!r}")
    return tuple(samples)


def microlens_radiance(chief_ray_angle_deg=0.0, method: str = "centred", *, offset_m=None,
                       sampling: str = "isetcam", diffraction: bool = False, samples: tuple[int, int] = (128, 256),
                       grid_points: int = 255, **pixel) -> dict:
    """ISET's microlens analysis for one pixel per chief-ray angle (ISETCam ``mlRadiance``).

    Args:
        chief_ray_angle_deg: chief-ray angle(s) of the source at the pixel (deg), scalar or tensor ``(*)``.
        method: ``'none'`` (no microlens: the stack's vignetting), ``'centred'`` (microlens over the pixel centre)
            or ``'optimal'`` (microlens at :func:`microlens_optimal_offset_m`).
        offset_m: microlens offset (m, scalar or ``(*)``), added to the method's (0 when centred); a tensor with
            gradient gives gradients (``sampling='continuous'``).
        sampling: ``'isetcam'`` (default: ISETCam's 255 x 255 grid, its numbers, no gradients) or ``'continuous'``
            (the exact integral of the same model, differentiable; differences in the module docstring).
        diffraction: spread each ray by the aperture's Fraunhofer width (see the module docstring;
            ``sampling='continuous'`` only).
        samples: (directions, x segments) of the continuous integral.
        grid_points: ISETCam's phase-space grid size (``mlCoordinates``: 255); 0 skips the irradiance (continuous
            sampling only).
        pixel: the pixel and microlens (defaults: ISETCam's default pixel, :data:`ISETCAM_PIXEL`, with the microlens
            and photodiode following the pixel as ``mlensCreate(sensor)`` builds them): ``source_f_number``,
            ``microlens_focal_length_m`` (default the stack height), ``microlens_f_number`` or
            ``microlens_diameter_m`` (default: the diameter is the pixel width), ``layer_thicknesses_m`` and
            ``layer_indices`` (the stack, top to photodiode), or ``stack_height_m`` (scales the layers to this
            height; a tensor gives gradients, the default microlens focal length following it) and ``stack_index``
            (one layer of this index), ``pixel_size_m`` (or ``pixel_width_m``), ``photodiode_size_m`` (or
            ``photodiode_width_m``; default ``sqrt(0.75)`` x the pixel width), ``wavelength_nm`` (scalar or a tensor
            broadcasting with the angles); ``source_focal_length_m`` and ``microlens_index`` are accepted (ISETCam's
            microlens fields) but do not change a pixel's etendue; ``microlens_offset_m`` is ``offset_m``.

    Returns:
        dict with ``etendue (*)`` (fraction of the pixel's incident light reaching the photodiode, as ISETCam's
        ``mlensGet(ml, 'etendue')``), ``offset_m (*)`` (the microlens offset used), ``x_m [N]`` and
        ``irradiance (*, N, N)``: the relative irradiance at the photodiode plane (ISETCam's separable
        ``'pixel irradiance'``, the x-profile's outer product, peak 1) over x in +-2 D.

    Example:
        >>> r = microlens_radiance(torch.tensor([0.0, 20.0]), "optimal")
        >>> r["etendue"].shape, r["irradiance"].shape
        (torch.Size([2]), torch.Size([2, 255, 255]))

    Reference: Catrysse & Wandell, JOSA A 19(8), 2002; ISETCam ``mlRadiance``.
    """
    if "microlens_offset_m" in pixel:  # ISETCam's 'ml offset' under its own name
        if offset_m is not None:
            raise ValueError("microlens_offset_m: given together with offset_m (the same parameter)")
        offset_m = pixel.pop("microlens_offset_m")
    kw = _pixel_kwargs(pixel)
    if sampling not in ("continuous", "isetcam"):
        raise ValueError(f"sampling: expected 'isetcam' or 'continuous', got {sampling!r}")
    samples = _check_samples(samples)
    if not (isinstance(grid_points, int) and not isinstance(grid_points, bool) and grid_points >= 0
            and (grid_points >= 2 or sampling == "continuous" and grid_points == 0)):
        raise ValueError(f"grid_points: expected an integer >= 2 (0 with sampling='continuous'), got {grid_points!r}")
    if sampling == "isetcam":
        if diffraction:
            raise ValueError("diffraction: ISETCam's ray grid has none; pass sampling='continuous' with "
                             "diffraction=True")
        layers = [v for k in ("layer_thicknesses_m", "layer_indices") if kw.get(k) is not None
                  for v in (kw[k] if isinstance(kw[k], (list, tuple)) else [kw[k]])]
        if records_grad(chief_ray_angle_deg, offset_m, *layers, *(kw[k] for k in (
                "stack_height_m", "stack_index", "microlens_focal_length_m", "wavelength_nm", "source_f_number"))):
            raise ValueError("sampling: 'isetcam' (the default, ISETCam's grid) has no gradients; pass "
                             "sampling='continuous' to differentiate the etendue")
    cra, method, t, n, off, geo = _params(chief_ray_angle_deg, method, offset_m, kw)
    D = geo["D"]
    x = torch.linspace(-2 * D, 2 * D, grid_points, dtype=t.dtype, device=t.device)
    if sampling == "isetcam":
        e, x, prof = _isetcam_grid(cra, method, t, n, off, geo, grid_points)
        lead = (1,) * (len(geo["shape"]) - len(geo["shape_geo"]))
        e = e.reshape((*lead, *geo["shape_geo"])).expand(geo["shape"]).reshape(-1)
        prof = prof.reshape((*lead, *geo["shape_geo"], -1)).expand((*geo["shape"], -1)).reshape(e.numel(), -1)
    else:
        e, xm, wm = _continuous(cra, method, t, n, off, geo, diffraction, samples, profile=grid_points > 0)
        if xm is None:
            return {"etendue": e.reshape(geo["shape"])}
        with torch.no_grad():  # the irradiance profile: a histogram of where the rays land (ISETCam's grid)
            dx = float(x[1] - x[0])
            b = torch.round((xm - x[0]) / dx).long()
            ok = (b >= 0) & (b < grid_points) & (wm > 0)
            prof = torch.zeros(xm.shape[0], grid_points, dtype=xm.dtype, device=xm.device)
            prof.scatter_add_(1, b.clamp(0, grid_points - 1).reshape(xm.shape[0], -1),
                              (wm * ok).reshape(xm.shape[0], -1))
            if diffraction:  # the landing positions spread by the diffraction pattern
                sig = _diffraction_sigma_m(t, n, geo, method)[:, None, None]
                kern = torch.exp(-0.5 * ((x[:, None] - x[None, :]) / sig) ** 2)
                prof = torch.einsum("aj,aij->ai", prof, kern / kern.sum(1, keepdim=True))
    prof = prof / prof.amax(-1, keepdim=True).clamp(min=torch.finfo(prof.dtype).tiny)
    irr = prof[:, :, None] * prof[:, None, :]
    shape = geo["shape"]
    off = off.reshape((*((1,) * (len(shape) - len(geo["shape_geo"]))), *geo["shape_geo"])).expand(shape)
    return {"etendue": e.reshape(shape), "offset_m": off, "x_m": x,
            "irradiance": irr.reshape(*shape, grid_points, grid_points)}


def microlens_etendue(chief_ray_angle_deg, method: str = "centred", *, model: str = "phase_space", offset_m=None,
                      sampling: str = "isetcam", diffraction: bool = False, samples: tuple[int, int] = (128, 256),
                      **pixel) -> torch.Tensor:
    """Etendue (fraction of the pixel's incident light reaching the photodiode) per chief-ray angle.

    ``model='phase_space'`` (default): ISET's microlens model, :func:`microlens_radiance` (same arguments): by
    default ISETCam's numbers (``sampling='isetcam'``); ``sampling='continuous'`` for gradients.
    ``model='geometric'``: :func:`isettorch.sensor.pixel_optics.pixel_vignetting` (2-D beam, ideal microlens
    focusing at the photodiode depth) on the same stack, with its single index the stack's paraxial equivalent
    ``h / sum(t_i / n_i)``; no gradients.

    Args:
        chief_ray_angle_deg: tensor ``(*)`` or scalar (deg).
        method: ``'none'``, ``'centred'`` or ``'optimal'``.

    Returns:
        ``(*)`` float64 tensor.

    Example:
        >>> microlens_etendue(torch.tensor([0.0, 10.0, 20.0]), "none")  # ISETCam's default pixel, ISETCam's numbers
        tensor([0.8310, 0.6548, 0.3810], dtype=torch.float64)
        >>> microlens_etendue(torch.tensor([0.0, 10.0, 20.0]), "none", sampling="continuous")  # the exact integral
        tensor([0.8234, 0.6559, 0.3767], dtype=torch.float64)
        >>> microlens_etendue(torch.tensor([0.0, 10.0, 20.0]), "centred", pixel_size_m=1.4e-6)  # follows the pixel
        tensor([1.0000, 0.3413, 0.0000], dtype=torch.float64)
    """
    if model == "phase_space":
        return microlens_radiance(chief_ray_angle_deg, method, offset_m=offset_m, sampling=sampling,
                                  diffraction=diffraction, samples=samples,
                                  grid_points=255 if sampling == "isetcam" else 0, **pixel)["etendue"]
    if model != "geometric":
        raise ValueError(f"model: expected 'phase_space' or 'geometric', got {model!r}")
    from .pixel_optics import microlens_offset_m as geometric_offset
    from .pixel_optics import pixel_vignetting

    kw = _pixel_kwargs(pixel)
    method = _method(method)
    if records_grad(chief_ray_angle_deg, offset_m, kw["source_f_number"], kw["stack_height_m"]):
        raise ValueError("model: 'geometric' (Catrysse & Wandell's closed form, in Python floats) has no gradients; "
                         "pass model='phase_space' with sampling='continuous' to differentiate the etendue")
    t, n = _stack(kw["layer_thicknesses_m"], kw["layer_indices"], kw["stack_height_m"], kw["stack_index"],
                  torch.float64, torch.device("cpu"))
    h = float(t.sum())
    n_eq = h / float((t / n).sum())
    # the closed form's microlens is ideal, as wide as the pixel and focused at the stack's depth: another aperture
    # or focal length was accepted and ignored (a microlens half or twice the pixel's width gave the same etendue)
    _pos(kw["pixel_size_m"], "pixel_size_m")
    f_ml = kw.get("microlens_focal_length_m")
    if f_ml is not None and abs(float(f_ml) - h) > 1e-9 * h:
        raise ValueError(f"microlens_focal_length_m: model 'geometric' has an ideal microlens focused at the stack's "
                         f"depth ({h:.6g} m), got {float(f_ml):.6g} m; leave it out, or use model='phase_space'")
    diam, given = _microlens_diameter_m(kw, h if f_ml is None else float(f_ml), float(kw["pixel_size_m"]))
    if given is not None and abs(diam - float(kw["pixel_size_m"])) > 1e-9 * float(kw["pixel_size_m"]):
        raise ValueError(f"{given}: model 'geometric' has a microlens as wide as the pixel "
                         f"({float(kw['pixel_size_m']):.6g} m), got a diameter of {diam:.6g} m; leave it out, or use "
                         f"model='phase_space'")
    cra = torch.as_tensor(chief_ray_angle_deg, dtype=torch.float64)
    _check_cra(cra)
    photodiode = _photodiode_m(kw)
    extra = torch.zeros(()) if offset_m is None else torch.as_tensor(offset_m, dtype=torch.float64).cpu()
    if offset_m is not None:
        if method == "none":
            raise ValueError("offset_m: method 'none' has no microlens to offset")
        if isinstance(offset_m, bool) or not bool(torch.isfinite(extra).all()):
            raise ValueError(f"offset_m: expected finite offsets (m), got {offset_m!r}")
        try:  # one offset per angle (a pixel-optics map's offsets grow with the image height), or one for all
            extra = torch.broadcast_to(extra, cra.shape)
        except RuntimeError as err:
            raise ValueError(f"offset_m: shape {tuple(extra.shape)} does not broadcast with the chief-ray angles' "
                             f"{tuple(cra.shape)}") from err
    extra = extra.expand(cra.shape).reshape(-1).tolist()
    out = []
    for c, ex in zip(cra.reshape(-1).tolist(), extra):
        off = (geometric_offset(c, h, n_eq) if method == "optimal" else 0.0) - ex
        out.append(pixel_vignetting(c, float(kw["source_f_number"]), h, float(kw["pixel_size_m"]),
                                    photodiode, stack_index=n_eq, microlens=method != "none",
                                    microlens_offset_m=off))
    return torch.stack(out).reshape(cra.shape) if out else cra.clone()

PIXEL_OPTICS_KEYS = ("method", "model", "convention", "diffraction", "learnable", "offset_per_image_height",
                     "exit_pupil_distance_m", "angle_samples", "samples")
# the pixel parameters that are one positive number (the layers are lists, checked with the stack)
_SCALAR_PIXEL_KEYS = ("pixel_size_m", "photodiode_size_m", "microlens_focal_length_m", "microlens_f_number",
                      "microlens_diameter_m", "source_f_number", "stack_index", "wavelength_nm",
                      "source_focal_length_m", "microlens_index")


class PixelOptics(nn.Module):
    """The etendue map of a sensor's pixels from each pixel's chief-ray angle (ISETCam ``sensorVignetting`` /
    ``mlAnalyzeArrayEtendue``), for ``Sensor(pixel_optics=...)``.

    Two conventions:

    * ``'physical'`` (default): the chief-ray angle at a pixel a distance r from the optical axis is read from the
      optical image: a ray-traced lens's table (``oi.metadata['chief_ray_angle']``: image heights (m) and traced
      angles (deg)), else ``atan(r / d)`` with d the exit-pupil distance (``exit_pupil_distance_m``, default the image
      distance: the thin lens's pupil is the lens). The etendue is the continuous (differentiable) integral
      (:func:`microlens_etendue` with ``sampling='continuous'``), the 1-D model applied separably along the pixel's
      columns and rows as ISETCam's pixel irradiance is (``mlRadiance``: the x-profile's outer product): the pixel
      at (x, y) gets ``T(|x|) T(|y|)`` (``model='geometric'``, already a 2-D efficiency: ``T(|x|) T(|y|) / T(0)``,
      exact on the axes), ``T(u)`` the 1-D etendue at the chief ray and microlens offset of the image point at
      height u on an axis (for a thin lens, the chief ray's angle projected on the pixel's axes). A pixel
      on a diagonal thus keeps more light than one on an axis at the same chief-ray angle, as a square photodiode
      does (centred microlens, 20 deg, ISETCam's pixel at f/4: a 2-D trace gives 0.355 and 0.123, this model 0.316
      and 0.188; the radially symmetric ``E(CRA) E(0)`` used before 2026-11-30 gave 0.188 for both). The map
      multiplies the light over the whole pixel (the fill factor enters only through the photodiode width), so the
      microlens must be as wide as the pixel (a narrower one is refused: the light between microlenses is not
      modelled); ``T`` is computed at ``angle_samples`` heights (default 33) from 0 to the farthest pixel centre's
      column or row coordinate and interpolated linearly (33 keep the interpolation within 0.01 of the direct value
      for ISETCam's pixel over 0-34 deg, 129 within 0.003).
    * ``'isetcam'``: ISETCam's ``sensorVignetting`` / ``mlAnalyzeArrayEtendue`` exactly: the CRA of each pixel is
      ``atan(r / f)`` with f the optics focal length (``sensorGet(sensor, 'cra degrees')`` with no argument uses
      ``opticsGet(optics, 'focal length')``; a traced lens's table is not used; ``exit_pupil_distance_m``
      replaces f), the etendue is ISETCam's grid (``sampling='isetcam'``) of the radial direction at
      ``cra = (0:nAngles) / nAngles * max(CRA)`` (``angle_samples = nAngles + 1``, default 6: ISETCam's nAngles 5),
      interpolated linearly in the CRA (``interp1``), and the map multiplies the sensor's fill-factor signal
      (``sensorCompute``: volts x etendue). No gradients or diffraction (ISETCam's grid has neither).

    The microlens follows the pixel (ISETCam ``mlensCreate(sensor)``): its focal length is the stack height given
    when this module is built (a learnable stack height then moves the photodiode under that microlens), its
    diameter the sensor's pitch, the photodiode ``sqrt(fill_factor)`` x the pitch, the source f-number the optical
    image's.

    Args:
        method: ``'none'``, ``'centred'`` or ``'optimal'`` (:func:`microlens_etendue`).
        model: ``'phase_space'`` (ISET's microlens model) or ``'geometric'``.
        convention: ``'physical'`` (default) or ``'isetcam'`` (above).
        diffraction: wavelength-dependent etendue (see :func:`microlens_radiance`), applied per wavelength
            (``'physical'`` only).
        stack_height_m: total stack height (scales the layers; default their sum).
        offset_per_image_height: a further microlens offset of this many metres per metre of image height (the
            microlens array's pitch shrink), added to the method's.
        learnable: the stack height (as ``log_stack_height_m``, so it stays positive) and
            ``offset_per_image_height`` as ``nn.Parameter`` s (``'physical'`` only; under method ``'none'`` the
            offset stays a buffer: no microlens to offset).
        exit_pupil_distance_m: overrides the distance of the chief rays' origin (the optical image's image
            distance under ``'physical'``, its focal length under ``'isetcam'``); ``math.inf`` for an image-space
            telecentric lens (every chief ray parallel to the axis, CRA 0).
        angle_samples: image heights on an axis (``'physical'``, default 33) or chief-ray angles (``'isetcam'``,
            default 6) at which the etendue is computed.
        samples: the continuous integral's (directions, x segments).
        pixel: microlens and stack parameters of :func:`microlens_radiance` (``pixel_size_m`` defaults to the
            sensor's pitch, ``photodiode_size_m`` to ``sqrt(fill_factor) x pixel_size_m``, ``microlens_diameter_m``
            to ``pixel_size_m``, ``microlens_focal_length_m`` to the stack height, ``source_f_number`` to the
            optical image's f-number).
    """

    def __init__(self, method: str = "centred", *, model: str = "phase_space", convention: str = "physical",
                 diffraction: bool = False, stack_height_m: float | None = None, offset_per_image_height: float = 0.0,
                 learnable: bool = False, exit_pupil_distance_m: float | None = None,
                 angle_samples: int | None = None, samples: tuple[int, int] = (64, 128), **pixel) -> None:
        super().__init__()
        self.method = _method(method)
        if model not in ("phase_space", "geometric"):
            raise ValueError(f"model: expected 'phase_space' or 'geometric', got {model!r}")
        if convention not in ("physical", "isetcam"):
            raise ValueError(f"convention: expected 'physical' or 'isetcam', got {convention!r}")
        for label, flag in (("diffraction", diffraction), ("learnable", learnable)):
            check_bool(flag, label)
        if model == "geometric" and (learnable or diffraction):
            raise ValueError("model: 'geometric' has no gradients or diffraction; use model='phase_space'")
        if convention == "isetcam" and (learnable or diffraction):
            raise ValueError(f"convention: 'isetcam' (ISETCam's grid) has no gradients or diffraction; use "
                             f"convention='physical' for {'learnable' if learnable else 'diffraction'}=True")
        if angle_samples is None:
            angle_samples = 6 if convention == "isetcam" else 33  # mlAnalyzeArrayEtendue: nAngles = 5
        if not (isinstance(angle_samples, int) and not isinstance(angle_samples, bool) and angle_samples >= 2):
            raise ValueError(f"angle_samples: expected an integer >= 2, got {angle_samples!r}")
        samples = _check_samples(samples)
        if isinstance(exit_pupil_distance_m, torch.Tensor) and exit_pupil_distance_m.requires_grad:
            # (read as a number per call: a learnable distance got no gradient, silently)
            raise ValueError("exit_pupil_distance_m: a fixed number of metres, not a tensor that requires grad (the "
                             "chief-ray angles are not differentiated in it)")
        if exit_pupil_distance_m is not None and exit_pupil_distance_m != math.inf:  # inf: telecentric, CRA 0
            _pos(exit_pupil_distance_m, "exit_pupil_distance_m")
        pixel = {_ALIAS_KEYS.get(k, k): v for k, v in pixel.items()}
        unknown = set(pixel) - set(_DEFAULTS) - {"stack_height_m"}
        if unknown:
            raise ValueError(f"pixel_optics: unknown key {sorted(unknown)[0]!r}; expected one of "
                             f"{sorted(set(_DEFAULTS) | set(PIXEL_OPTICS_KEYS))}")
        _check_one_aperture(pixel)
        for key in _SCALAR_PIXEL_KEYS:  # checked when built, not at the first render
            if pixel.get(key) is not None:
                _pos(pixel[key], key)
        if any(pixel.get(k) is not None for k in ("layer_thicknesses_m", "layer_indices", "stack_index")):
            _stack(pixel.get("layer_thicknesses_m", _DEFAULTS["layer_thicknesses_m"]),
                   pixel.get("layer_indices", _DEFAULTS["layer_indices"]), None, pixel.get("stack_index"),
                   torch.float64, "cpu")
        if pixel.get("photodiode_size_m") is not None and pixel.get("pixel_size_m") is not None:
            _photodiode_m(pixel)
        self.model, self.convention, self.diffraction = model, convention, diffraction
        self.exit_pupil_distance_m = exit_pupil_distance_m
        self.angle_samples, self.samples = angle_samples, samples
        self.pixel = {k: tuple(v) if isinstance(v, list) else v for k, v in pixel.items()}  # hashable (cache)
        layers = self.pixel.get("layer_thicknesses_m", _DEFAULTS["layer_thicknesses_m"])
        h = float(sum(layers)) if stack_height_m is None else stack_height_m
        _pos(h, "stack_height_m")
        if records_grad(stack_height_m):  # (read as a number: its gradient was dropped with a torch warning only)
            raise ValueError("stack_height_m: the starting height, read as a number, not a tensor that requires "
                             "grad; pass a number and learnable=True to learn it (log_stack_height_m)")
        if not is_real(offset_per_image_height):  # (True was read as 1 m per m)
            raise ValueError(f"offset_per_image_height: expected a finite number, got {offset_per_image_height!r}")
        if self.method == "none" and offset_per_image_height != 0:
            raise ValueError("offset_per_image_height: method 'none' has no microlens to offset (it was ignored); "
                             "use method 'centred' or 'optimal'")
        if convention == "isetcam" and exit_pupil_distance_m == math.inf and offset_per_image_height != 0:
            raise ValueError("offset_per_image_height: convention 'isetcam' reads the etendue by chief-ray angle, "
                             "which a telecentric lens (exit_pupil_distance_m inf) makes 0 at every pixel, so an "
                             "offset growing with the image height cannot be placed; use convention='physical'")
        self._microlens_focal_length_m = float(h)  # mlensCreate(sensor): the pixel depth when built
        h_t = torch.tensor(math.log(float(h)), dtype=torch.float64)  # log: a positive height by construction
        o_t = torch.tensor(float(offset_per_image_height), dtype=torch.float64)
        if learnable:
            self.log_stack_height_m = nn.Parameter(h_t)
            if self.method == "none":  # no microlens to offset: the stack height learns alone
                self.register_buffer("offset_per_image_height", o_t)
            else:
                self.offset_per_image_height = nn.Parameter(o_t)
        else:
            self.register_buffer("log_stack_height_m", h_t)
            self.register_buffer("offset_per_image_height", o_t)
        self._memo: dict = {}

    @property
    def wavelength_dependent(self) -> bool:
        return self.diffraction

    def extra_repr(self) -> str:
        return (f"method={self.method!r}, model={self.model!r}, convention={self.convention!r}, "
                f"diffraction={self.diffraction}, stack_height={float(self.stack_height_m.detach()) * 1e6:.4g} um")

    @property
    def stack_height_m(self) -> torch.Tensor:
        """Total stack height (m), ``exp(log_stack_height_m)``."""
        return self.log_stack_height_m.exp()

    def chief_ray_angle_deg(self, oi, rows: int, cols: int, pixel_size_m: float) -> torch.Tensor:
        """Chief-ray angle (deg) at each pixel centre ``[B, rows, cols]`` (the sensor grid centred on the axis)."""
        r = self._radii(rows, cols, pixel_size_m, oi)
        return self._cra_of_radius(oi, r)

    @staticmethod
    def _radii(rows, cols, pitch, oi):
        dev = oi.sample_spacing_m.device
        y = (torch.arange(rows, dtype=torch.float64, device=dev) - (rows - 1) / 2) * pitch
        x = (torch.arange(cols, dtype=torch.float64, device=dev) - (cols - 1) / 2) * pitch
        return torch.hypot(y[:, None], x[None, :])

    def _cra_of_radius(self, oi, r: torch.Tensor) -> torch.Tensor:
        """CRA (deg) ``[B, *r.shape]`` at image heights ``r`` (m)."""
        b = oi.batch_size
        if self.convention == "isetcam":  # sensorGet(sensor, 'cra'): atan(r / opticsGet(optics, 'focal length'))
            if self.exit_pupil_distance_m is not None:
                d = torch.full((b,), float(self.exit_pupil_distance_m), dtype=torch.float64, device=r.device)
            elif oi.focal_length_m is None:
                raise ValueError("oi: pixel_optics with convention='isetcam' needs the optics focal length "
                                 "(sensorGet(sensor, 'cra') uses it): the optical image has no focal_length_m (give "
                                 "pixel_optics exit_pupil_distance_m)")
            else:
                d = torch.as_tensor(oi.focal_length_m, dtype=torch.float64, device=r.device).reshape(-1).expand(b)
            return torch.rad2deg(torch.atan(r[None] / d.reshape(-1, *([1] * r.dim()))))
        table = oi.metadata.get("chief_ray_angle") if isinstance(oi.metadata, dict) else None
        if table is not None and self.exit_pupil_distance_m is None:
            hm = torch.as_tensor(table["image_height_m"], dtype=torch.float64, device=r.device)
            cd = torch.as_tensor(table["cra_deg"], dtype=torch.float64, device=r.device)
            if bool((r > hm[-1] * (1 + 1e-9)).any()):
                raise ValueError(f"oi: the sensor reaches {float(r.max()) * 1e3:.4g} mm off axis, beyond the lens's "
                                 f"traced chief rays ({float(hm[-1]) * 1e3:.4g} mm)")
            out = _interp1(r.reshape(-1), hm, cd).reshape(r.shape)
            return out.expand(b, *r.shape)
        if self.exit_pupil_distance_m is not None:
            d = torch.full((b,), float(self.exit_pupil_distance_m), dtype=torch.float64, device=r.device)
        else:
            d = oi.image_distance_m if oi.image_distance_m is not None else oi.focal_length_m
            if d is None:
                raise ValueError("oi: pixel_optics needs the exit-pupil distance: the optical image has no "
                                 "image_distance_m or focal_length_m (give pixel_optics exit_pupil_distance_m)")
            d = torch.as_tensor(d, dtype=torch.float64, device=r.device).reshape(-1).expand(b)
        return torch.rad2deg(torch.atan(r[None] / d.reshape(-1, *([1] * r.dim()))))

    def _etendue(self, cra, offset, wavelength_nm, pixel, method):
        kw = {**pixel, "wavelength_nm": wavelength_nm}
        if self.model == "geometric":
            kw.setdefault("stack_height_m", float(self.stack_height_m.detach()))
            kw["wavelength_nm"] = 500.0  # the geometric model has no wavelength
            off = None if offset is None else offset.detach().cpu()  # (the per-sample offsets were dropped)
            return microlens_etendue(cra.detach().cpu(), method, model="geometric", offset_m=off, **kw).to(cra)
        sampling = "isetcam" if self.convention == "isetcam" else "continuous"
        return microlens_etendue(cra, method, offset_m=offset, diffraction=self.diffraction, samples=self.samples,
                                 sampling=sampling, stack_height_m=self.stack_height_m.to(cra.device), **kw)

    def etendue_map(self, oi, rows: int, cols: int, pixel_size_m: float, fill_factor: float = 0.75) -> torch.Tensor:
        """The etendue at every pixel: ``[B, rows, cols]``, or ``[B, L, rows, cols]`` on the OI's wavelengths when
        ``diffraction`` (float64; differentiable in ``log_stack_height_m`` and ``offset_per_image_height``)."""
        e, i0, w = self.radial_etendue(oi, rows, cols, pixel_size_m, fill_factor)
        emap = self.interpolate(e, i0, w)  # [B, W, rows, cols]
        return emap if self.diffraction else emap[:, 0]

    def interpolate(self, e: torch.Tensor, i0: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Samples ``e [B, ..., K]`` -> pixels ``[B, ..., rows, cols]``, linear between samples ``i0`` and ``i0 + 1``
        with weight ``w``: ``[2, rows, cols]`` for every batch item (``'physical'``: the pixel's column and row
        coordinates, whose two values multiply) or ``[B, rows, cols]`` per item (the CRA, ``'isetcam'``)."""
        w = w.to(e.dtype)
        k = e.shape[-1]
        if self.convention == "physical":
            # separable: a pixel's column coordinate is its column's (the same down every row) and its row
            # coordinate its row's, so each 1-D profile is interpolated once per column / row and the map is their
            # outer product (the same products as per pixel, without gathering rows x cols values per band twice)
            ix, wx, iy, wy = i0[0, 0], w[0, 0], i0[1, :, 0], w[1, :, 0]
            ex, ey = (e[..., i] * (1 - ww) + e[..., (i + 1).clamp(max=k - 1)] * ww for i, ww in ((ix, wx), (iy, wy)))
            out = ex[..., None, :] * ey[..., :, None]
            if self.model == "geometric":
                # the geometric model is already the 2-D efficiency (pixel_vignetting: both axes' overlaps over the
                # beam's disk): T(|x|) T(|y|) counted the other axis's on-axis share twice (the centre pixel got
                # T(0)^2, 0.485 for a bare pixel instead of 0.696). Separable about the axis: T(|x|) T(|y|) / T(0),
                # exact on the axes
                e0 = e[..., :1]
                out = out / torch.where(e0 > 0, e0, torch.ones_like(e0))[..., None]
            return out
        b, mid = e.shape[0], e.shape[1:-1]
        idx = i0.reshape(b, *([1] * len(mid)), -1).expand(b, *mid, -1)
        ww = w.reshape(b, *([1] * len(mid)), -1)
        out = torch.gather(e, -1, idx) * (1 - ww) + torch.gather(e, -1, (idx + 1).clamp(max=k - 1)) * ww
        return out.reshape(*e.shape[:-1], *i0.shape[1:])

    def radial_etendue(self, oi, rows: int, cols: int, pixel_size_m: float, fill_factor: float = 0.75):
        """The etendue at ``angle_samples`` image heights on an axis, from 0 to the farthest pixel centre's column
        or row coordinate (``'physical'``), or at chief-ray angles from 0 to the largest (``'isetcam'``),
        ``e [B, W, K]`` (W = the OI's wavelengths with ``diffraction``, else 1), and each pixel's interpolation
        indices and weights ``(i0, w)``, ``[2, rows, cols]`` (``'physical'``: at its column and at its row
        coordinate) or ``[B, rows, cols]`` (``'isetcam'``) (memoised per geometry when no gradient is needed);
        :meth:`interpolate` makes the map."""
        if not (is_real(fill_factor) and 0 < fill_factor <= 1):  # (a bad one was reported as photodiode_size_m)
            raise ValueError(f"fill_factor: expected a number in (0, 1], got {fill_factor!r}")
        pixel = dict(self.pixel)
        pixel.setdefault("pixel_size_m", float(pixel_size_m))
        pixel.setdefault("photodiode_size_m", math.sqrt(fill_factor) * float(pixel["pixel_size_m"]))
        if "microlens_diameter_m" not in pixel and "microlens_f_number" not in pixel:
            pixel["microlens_diameter_m"] = float(pixel["pixel_size_m"])
        pixel.setdefault("microlens_focal_length_m", self._microlens_focal_length_m)
        if self.convention == "physical" and self.model == "phase_space":
            # the etendue is the share of the light on the microlens that reaches the photodiode (ISETCam's
            # etendueIn); 'physical' applies it to the light on the whole pixel, which holds only for a microlens
            # as wide as the pixel (a narrower one read 1.33x a bare pixel's signal at any diameter)
            p = float(pixel["pixel_size_m"])
            diam, given = _microlens_diameter_m(pixel, pixel["microlens_focal_length_m"], p)
            if diam < p * (1 - 1e-9):
                raise ValueError(f"{given}: a microlens {diam:.6g} m wide is narrower than the pixel ({p:.6g} m); "
                                 f"convention='physical' models a microlens covering the whole pixel (the light "
                                 f"between narrower microlenses is not modelled). Use a microlens as wide as the "
                                 f"pixel, or convention='isetcam' (ISETCam's etendue of the light on the microlens)")
        if "source_f_number" not in pixel:
            if oi.f_number is None:
                raise ValueError("oi: pixel_optics needs the source f-number: the optical image has none (give "
                                 "pixel_optics source_f_number)")
            fn = torch.as_tensor(oi.f_number).reshape(-1)
            if not bool((fn == fn[0]).all()):
                raise ValueError(f"oi.f_number: pixel_optics needs one f-number per batch, got {fn.tolist()}")
            # a learnable f-number stays a tensor where the etendue is differentiable (the continuous integral);
            # elsewhere its share of the gradient would be dropped without a word
            differentiable = self.convention == "physical" and self.model == "phase_space"
            if records_grad(fn) and not differentiable:
                raise ValueError(f"pixel_optics: the optics' f-number requires grad, but the {self.convention!r} "
                                 f"convention's {self.model!r} etendue has no gradient (its share of d/dN would be "
                                 f"dropped); use convention='physical', model='phase_space'")
            pixel["source_f_number"] = fn[0] if records_grad(fn) else float(fn[0])
        waves = tuple(float(w) for w in oi.wavelengths_nm.reshape(-1).tolist()) if self.diffraction else (None,)
        grad = records_grad(self.log_stack_height_m, self.offset_per_image_height, *pixel.values())
        key = None
        table = oi.metadata.get("chief_ray_angle") if isinstance(oi.metadata, dict) else None
        if not grad:
            geo = tuple(None if g is None else tuple(torch.as_tensor(g).reshape(-1).tolist())
                        for g in (oi.image_distance_m, oi.focal_length_m))
            key = (self.method, self.model, self.convention, self.samples, self.angle_samples,
                   self.exit_pupil_distance_m, rows, cols, float(pixel_size_m), fill_factor, waves,
                   tuple(sorted((k, _by_value(v)) for k, v in pixel.items())), geo,
                   oi.batch_size,
                   id(table),
                   float(self.log_stack_height_m.detach()), float(self.offset_per_image_height.detach()),
                   str(oi.device))
            hit = self._memo.get(key)
            # the entry holds the chief-ray table whose id is in the key: a new table at a freed one's address (a
            # lens swapped on the sensor) got the old table's etendue map
            if hit is not None and hit[0] is table:
                return hit[1]
        if self.convention == "isetcam":
            out = self._isetcam_radial(oi, self._radii(rows, cols, pixel_size_m, oi), pixel)
            if key is not None:
                if len(self._memo) > 8:
                    self._memo.clear()
                self._memo[key] = (table, out)
            return out
        # separable along the pixel's rows and columns (ISETCam's pixel irradiance, mlRadiance: the x-profile's
        # outer product): the pixel at (x, y) gets T(|x|) T(|y|), T(u) the 1-D etendue at image height u on an axis
        dev = oi.sample_spacing_m.device
        ax = [(torch.arange(n, dtype=torch.float64, device=dev) - (n - 1) / 2).abs() * pixel_size_m
              for n in (cols, rows)]
        u_max = (max(rows, cols) - 1) / 2 * pixel_size_m  # the farthest pixel centre's column or row coordinate
        k = self.angle_samples
        rk = torch.linspace(0.0, max(u_max, 1e-12), k, dtype=torch.float64, device=dev)
        cra_k = self._cra_of_radius(oi, rk)  # [B, K]
        b = cra_k.shape[0]
        offset = self.offset_per_image_height.to(rk.device) * rk  # [K]
        offset = offset.expand(b, k).reshape(-1)
        wl = pixel.pop("wavelength_nm", _DEFAULTS["wavelength_nm"])
        if self.diffraction:  # every (wavelength, radius) pair in one batched call
            wl = torch.tensor(waves, dtype=torch.float64, device=dev)[None, :, None].expand(b, -1, k)
        nw = len(waves)
        cra_w = cra_k[:, None, :].expand(b, nw, k)
        off = None if self.method == "none" else offset.reshape(b, 1, k).expand(b, nw, k)
        e = self._etendue(cra_w, off, wl, pixel, self.method).reshape(b, nw, k)  # [B, W, K]
        # linear interpolation in each coordinate (differentiable in the etendue values)
        pos = torch.stack([ax[0][None, :].expand(rows, cols), ax[1][:, None].expand(rows, cols)])  # [2, rows, cols]
        pos = (pos / rk[-1] * (k - 1)).clamp(0, k - 1) if u_max > 0 else torch.zeros_like(pos)
        i0 = pos.floor().long().clamp(max=k - 2)
        out = (e, i0, (pos - i0).to(e.dtype))
        if key is not None:
            if len(self._memo) > 8:
                self._memo.clear()
            self._memo[key] = (table, out)
        return out


    def _isetcam_radial(self, oi, r: torch.Tensor, pixel: dict):
        """ISETCam ``mlAnalyzeArrayEtendue``: the etendue at ``cra = (0:nAngles) / nAngles * max(sensorCRA(:))``
        (``e [B, 1, K]``) and each pixel's ``interp1`` index and weight in the CRA (``[B, rows, cols]``)."""
        k = self.angle_samples
        cra_px = self._cra_of_radius(oi, r)  # [B, rows, cols], sensorGet(sensor, 'cra degrees')
        b = cra_px.shape[0]
        cra_max = cra_px.reshape(b, -1).amax(-1)  # [B]
        cra_k = torch.arange(k, dtype=torch.float64, device=r.device) / (k - 1) * cra_max[:, None]  # [B, K]
        offset = None
        if self.method != "none":  # the array's further offset at each sample's image height (0 by default)
            d = r.new_tensor(float(self.exit_pupil_distance_m)).expand(b) if self.exit_pupil_distance_m is not None \
                else torch.as_tensor(oi.focal_length_m, dtype=torch.float64, device=r.device).reshape(-1).expand(b)
            height = d[:, None] * torch.tan(torch.deg2rad(cra_k))  # each sample's image height
            # a telecentric lens (d inf) has CRA 0 everywhere: inf x 0 made NaN offsets (refused, naming offset_m)
            height = torch.where(cra_k == 0, torch.zeros_like(height), height)
            offset = (self.offset_per_image_height.to(r.device) * height)[:, None, :]
        wl = pixel.pop("wavelength_nm", _DEFAULTS["wavelength_nm"])
        e = self._etendue(cra_k[:, None, :], offset, wl, pixel, self.method).reshape(b, 1, k)
        scale = torch.where(cra_max > 0, (k - 1) / cra_max.clamp(min=1e-300), torch.zeros_like(cra_max))
        pos = (cra_px * scale[:, None, None]).clamp(0, k - 1)
        i0 = pos.floor().long().clamp(max=k - 2)
        return e, i0, (pos - i0).to(e.dtype)


def _interp1(xq: torch.Tensor, xp: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
    """Piecewise-linear interpolation of ``fp(xp)`` (increasing ``xp``) at ``xq``."""
    i = torch.searchsorted(xp, xq).clamp(1, xp.numel() - 1)
    x0, x1 = xp[i - 1], xp[i]
    w = ((xq - x0) / (x1 - x0)).clamp(0, 1)
    return fp[i - 1] * (1 - w) + fp[i] * w
