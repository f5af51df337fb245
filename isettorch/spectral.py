"""Wavelength grids, spectral resampling, photons <-> energy, CIE colour matching functions,
luminosity and illuminants, and luminance / XYZ of spectral images.

Conventions
-----------
* Wavelengths are 1-D tensors in nm, strictly increasing; non-uniform grids are allowed.
* Spectral integrals use the grid's own sample widths (:func:`wavelength_weights`): on a uniform
  grid every sample has the weight of the step (ISETCam's rectangle rule, ``binwidth * sum``);
  on a non-uniform grid a sample's weight is half the distance between its neighbours (the
  end samples take the full width to their single neighbour, which equals the uniform rule).
  A single-wavelength grid has a weight of 1 nm (ISETCam's ``sceneGet(scene, 'binwidth')``).
  ``wavelength_weights(w, rule='isetcam')`` gives ISETCam's rule instead: ``w[1] - w[0]`` for every sample,
  also on a non-uniform grid (for ISETCam parity only).
* :func:`resample` interpolates linearly and returns **0 outside the data's range**
  (as ISETCam's ``interp1(..., 'linear', 0)``), so a filter never invents response where it
  was not measured.
* Tabulated CIE data come from colour-science, converted to tensors once and cached per
  (grid, dtype, device); returned tensors are fresh copies.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from . import constants
from ._autograd import tensor_cache
from ._checks import as_tensor, check_float_dtype, check_rank, check_wavelengths, is_integer, is_real

__all__ = [
    "default_wavelengths",
    "wavelength_weights",
    "resample",
    "resample_rows",
    "resample_held",
    "band_average",
    "photons_to_energy",
    "planck_relative",
    "energy_to_photons",
    "cmfs",
    "luminosity",
    "illuminant",
    "illuminant_names",
    "blackbody",
    "daylight",
    "luminance",
    "xyz",
    "spectral_integral",
]

OBSERVERS = {
    "1931": "CIE 1931 2 Degree Standard Observer",
    "1931_2": "CIE 1931 2 Degree Standard Observer",
    "1964": "CIE 1964 10 Degree Standard Observer",
    "1964_10": "CIE 1964 10 Degree Standard Observer",
}


#: the most samples a wavelength grid of :func:`default_wavelengths` may have (1 pm steps over 400-700 nm: 300,001)
MAX_WAVELENGTHS = 1_000_000


def default_wavelengths(start_nm: float = 400.0, stop_nm: float = 700.0, step_nm: float = 10.0,
                        *, dtype=None, device=None) -> torch.Tensor:
    """The grid ``start:step:stop`` in nm (inclusive), ISETCam's default is 400:10:700 (at most
    :data:`MAX_WAVELENGTHS` samples)."""
    for name, v in (("start_nm", start_nm), ("stop_nm", stop_nm), ("step_nm", step_nm)):
        if not is_real(v):  # (NaN: int() error)
            raise ValueError(f"{name}: expected a finite number of nm, got {v!r}")
    if step_nm <= 0:
        raise ValueError(f"step_nm: expected a positive step, got {step_nm}")
    if stop_nm < start_nm:
        raise ValueError(f"stop_nm: expected stop_nm >= start_nm ({start_nm}), got {stop_nm}")
    n = int(math.floor((stop_nm - start_nm) / step_nm + 1e-9)) + 1
    if n > MAX_WAVELENGTHS:  # (a step of 1e-12 nm asked for 1.2 PB)
        raise ValueError(f"step_nm: {step_nm} nm gives {n} samples from {start_nm} to {stop_nm} nm; expected at most "
                         f"{MAX_WAVELENGTHS}")
    return start_nm + step_nm * torch.arange(n, dtype=dtype or torch.get_default_dtype(), device=device)


WEIGHT_RULES = ("midpoint", "isetcam")


def wavelength_weights(wavelengths_nm: torch.Tensor, rule: str = "midpoint") -> torch.Tensor:
    """Integration weight (nm) of each sample of a wavelength grid.

    ``rule='midpoint'`` (default): each sample's own width, half the distance between its neighbours (the end
    samples take the full width to their single neighbour); see the module notes. ``rule='isetcam'``: ISETCam's
    plain rectangle rule, the bin width ``w[1] - w[0]`` for every sample, ends included (``sceneGet(scene,
    'binwidth')``; isetcam-parity/FORMAT.md 4.1). The two agree on a uniform grid; on a non-uniform one only the
    midpoint rule is a quadrature of the spectrum, so use ``'isetcam'`` only to reproduce ISETCam. A single
    wavelength has a weight of 1 nm under both.
    """
    if rule not in WEIGHT_RULES:
        raise ValueError(f"rule: expected one of {WEIGHT_RULES}, got {rule!r}")
    w = check_wavelengths(wavelengths_nm)
    if not w.is_floating_point():  # (an integer grid's midpoint weights were truncated: 1.5 nm became 1)
        w = w.to(torch.get_default_dtype())
    if w.numel() == 1:
        return torch.ones_like(w)
    if rule == "isetcam":
        return (w[1] - w[0]).expand_as(w).clone()
    d = w[1:] - w[:-1]
    out = torch.empty_like(w)
    out[0] = d[0]
    out[-1] = d[-1]
    if w.numel() > 2:
        out[1:-1] = 0.5 * (d[1:] + d[:-1])
    return out


def resample(values: torch.Tensor, src_nm, dst_nm, dim: int = -1) -> torch.Tensor:
    """Linear interpolation of spectra from grid ``src_nm`` to ``dst_nm`` along ``dim``; 0 outside.

    Differentiable with respect to ``values``.

    Example:
        >>> resample(torch.tensor([0., 1.]), torch.tensor([400., 500.]), torch.tensor([450., 600.]))
        tensor([0.5000, 0.0000])
    """
    _check_float_values(values)
    _check_dim(values, dim, "values")
    src = check_wavelengths(torch.as_tensor(src_nm), "src_nm").to(values.device, torch.float64)
    dst = check_wavelengths(torch.as_tensor(dst_nm), "dst_nm").to(values.device, torch.float64)
    if values.shape[dim] != src.numel():
        raise ValueError(
            f"values: expected {src.numel()} samples along dim {dim} to match src_nm, got {values.shape[dim]}"
        )
    v = values.movedim(dim, -1)
    if src.numel() == dst.numel() and torch.equal(src, dst):
        return values.clone()
    if src.numel() == 1:
        hit = (dst == src[0]).to(v.dtype)
        return (v[..., :1] * hit).movedim(-1, dim)
    idx, t, inside = _linear_weights(src, dst, v.dtype)
    out = (v[..., idx] * (1 - t) + v[..., idx + 1] * t) * inside
    return out.movedim(-1, dim)


def resample_held(values: torch.Tensor, src_nm, dst_nm, dim: int = -1) -> torch.Tensor:
    """:func:`resample` with the end values held outside ``src_nm`` instead of 0: for measured reflectances, which do
    not drop to 0 beyond their data (CIE 015:2018 section 7.2.2, extrapolation by the nearest measured value;
    colour-science's default constant extrapolation).

    Example:
        >>> resample_held(torch.tensor([0.2, 0.4]), torch.tensor([400., 500.]), torch.tensor([380., 450., 600.]))
        tensor([0.2000, 0.3000, 0.4000])
    """
    src = check_wavelengths(torch.as_tensor(src_nm), "src_nm").to(torch.float64)
    dst = check_wavelengths(torch.as_tensor(dst_nm), "dst_nm").detach().to(device=src.device, dtype=torch.float64)
    # resample() needs a strictly increasing grid; clamping can repeat the end points, so interpolate on the unique
    # values and scatter back
    uniq, inverse = torch.unique(dst.clamp(float(src[0]), float(src[-1])), return_inverse=True)
    out = resample(values, src, uniq.to(values.device), dim=dim)
    return out.index_select(dim, inverse.to(out.device))


def _check_dim(x: torch.Tensor, dim, name: str) -> None:
    """``dim`` names one of ``x``'s axes (an IndexError deep in a shape lookup otherwise)."""
    if not (is_integer(dim) and -x.dim() <= dim < x.dim()):
        raise ValueError(f"dim: expected the spectral axis of {name} (an integer in [-{x.dim()}, {x.dim() - 1}]), got "
                         f"{dim!r} for shape {tuple(x.shape)}")


def _check_float_values(values: torch.Tensor) -> None:
    """Spectra to interpolate are floating point: the interpolation weights are cast to their dtype, which rounded
    an integer spectrum's to 0 (every sample between two knots took the left one's value)."""
    if not values.is_floating_point():
        raise ValueError(f"values: expected floating-point spectra, got {values.dtype} (convert them, e.g. "
                         f".double(): integer values would round the interpolation weights to 0)")


def _linear_weights(src: torch.Tensor, dst: torch.Tensor, dtype: torch.dtype):
    """Linear interpolation from ``src [..., Ls]`` (float64, increasing, >= 2 samples) to ``dst [..., Ld]`` (the same
    leading dims, or 1-D with a 1-D ``src``): the left neighbour's index ``[..., Ld]``, its weight ``t`` and the
    inside-the-grid mask (0 outside), both in ``dtype``; shared by :func:`resample` and :func:`resample_rows`."""
    idx = (torch.searchsorted(src, dst, right=True) - 1).clamp(0, src.shape[-1] - 2)
    x0, x1 = src.gather(-1, idx), src.gather(-1, idx + 1)
    t = ((dst - x0) / (x1 - x0)).to(dtype)
    inside = ((dst >= src[..., :1]) & (dst <= src[..., -1:])).to(dtype)
    return idx, t, inside


def resample_rows(values: torch.Tensor, src_nm: torch.Tensor, dst_nm: torch.Tensor) -> torch.Tensor:
    """:func:`resample` (linear, 0 outside) with a source grid per row: ``values [..., Ls]`` on ``src_nm [..., Ls]``
    (increasing along the last dim) to ``dst_nm [Ld]``, ``[..., Ld]``: the same arithmetic, element by element, as
    ``resample(values[i], src_nm[i], dst_nm)`` for every row ``i``, in one batched search (e.g. a per-item QE whose
    curves are shifted along the wavelength axis, :func:`isettorch.sensor.filters.shifted_qe`)."""
    _check_float_values(values)
    if src_nm.shape[-1] != values.shape[-1]:  # (3 values on 2 knots gave 0.5)
        raise ValueError(f"src_nm: expected {values.shape[-1]} knots per row like values, got {src_nm.shape[-1]}")
    if src_nm.shape[:-1] != values.shape[:-1]:  # one grid for every row (a [Ls] grid failed in a reshape)
        try:
            src_nm = src_nm.expand(values.shape)
        except RuntimeError:
            raise ValueError(f"src_nm: expected one grid per row of values {tuple(values.shape)} (or one for all), "
                             f"got shape {tuple(src_nm.shape)}") from None
    knots = src_nm.detach()
    if not bool(torch.isfinite(knots).all() & (knots[..., 1:] > knots[..., :-1]).all()):  # (decreasing: 0)
        raise ValueError("src_nm: expected finite, strictly increasing knots in every row")
    lead = values.shape[:-1]
    v = values.reshape(-1, values.shape[-1])
    src = src_nm.to(torch.float64).reshape(-1, src_nm.shape[-1]).contiguous()
    dst = dst_nm.to(device=src.device, dtype=torch.float64).expand(src.shape[0], -1).contiguous()
    idx, t, inside = _linear_weights(src, dst, v.dtype)
    out = (v.gather(-1, idx) * (1 - t) + v.gather(-1, idx + 1) * t) * inside
    return out.reshape(*lead, -1)


def _spectral_shape(wavelengths_nm: torch.Tensor, x: torch.Tensor, dim: int) -> torch.Tensor:
    shape = [1] * x.dim()
    shape[dim] = -1
    return wavelengths_nm.to(x.device, x.dtype).reshape(shape)


def photons_to_energy(photons: torch.Tensor, wavelengths_nm, dim: int = -3, *, h: float | None = None,
                      c: float | None = None) -> torch.Tensor:
    """Photon spectral quantity (photons/s/...) to energy (W/...): ``E = N h c / lambda``.

    Source: Planck-Einstein relation; h, c from CODATA 2018 unless given (ISETCam ``Quanta2Energy``).
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    _check_dim(photons, dim, "photons")
    if photons.shape[dim] != w.numel():
        raise ValueError(f"photons: expected {w.numel()} wavelengths along dim {dim}, got {photons.shape[dim]}")
    h, c = _planck_constants(h, c)
    return photons * (h * c) / (_spectral_shape(w, photons, dim) * 1e-9)


def energy_to_photons(energy: torch.Tensor, wavelengths_nm, dim: int = -3, *, h: float | None = None,
                      c: float | None = None) -> torch.Tensor:
    """Energy spectral quantity (W/...) to photons (photons/s/...): ``N = E lambda / (h c)``."""
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    _check_dim(energy, dim, "energy")
    if energy.shape[dim] != w.numel():
        raise ValueError(f"energy: expected {w.numel()} wavelengths along dim {dim}, got {energy.shape[dim]}")
    h, c = _planck_constants(h, c)
    return energy * (_spectral_shape(w, energy, dim) * 1e-9) / (h * c)


def _planck_constants(h, c) -> tuple[float, float]:
    """``(h, c)``: CODATA 2018's unless given (ISETCam passes its own), each a finite number > 0 (h = 0 gave zero
    energy or infinite photons)."""
    h = constants.PLANCK_J_S if h is None else h
    c = constants.SPEED_OF_LIGHT_M_PER_S if c is None else c
    for name, v in (("h", h), ("c", c)):
        if not (is_real(v) and v > 0):
            raise ValueError(f"{name}: expected a finite constant > 0, got {v!r}")
    return h, c


# ---------------------------------------------------------------------------------------------
# Tabulated data from colour-science (loaded once, numpy on the native grid)


@functools.cache
def _native_cmfs(observer: str) -> tuple[np.ndarray, np.ndarray]:
    import colour

    key = OBSERVERS.get(str(observer))
    if key is None:
        raise ValueError(f"observer: expected one of {sorted(OBSERVERS)}, got {observer!r}")
    m = colour.MSDS_CMFS[key]
    return np.asarray(m.wavelengths, float), np.asarray(m.values, float).T.copy()


@functools.cache
def _native_vlambda() -> tuple[np.ndarray, np.ndarray]:
    import colour

    sd = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    return np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)


_FLUORESCENT = {f"F{i}": f"FL{i}" for i in range(1, 13)}
#: the CIE D illuminants' correlated colour temperatures on the modern c2 scale (CIE 015:2018 note: D65 is 6504 K)
_D_SERIES_CCT = {"D50": 5003.0, "D55": 5503.0, "D65": 6504.0, "D75": 7504.0}


def illuminant_names() -> list[str]:
    """Names accepted by :func:`illuminant` (besides ``D<cct>`` and ``blackbody<cct>``)."""
    return ["D65", "D50", "D55", "D75", "A", "E", "equal_energy", "equal_photon", *_FLUORESCENT]


@functools.cache
def _native_illuminant(name: str) -> tuple[np.ndarray, np.ndarray]:
    import colour

    if name in ("D65", "D50", "D55", "D75", "A"):
        sd = colour.SDS_ILLUMINANTS[name]
        w, v = np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)
        if w[-1] < 830.0:  # colour-science's tables end at 780 nm; CIE 015:2018 defines these to 830 nm
            ext = np.arange(w[-1] + 5.0, 830.0 + 1e-9, 5.0)
            if name == "A":  # Planck at 2856 K (CIE 015:2018 eq. 2.1), the definition the table rounds
                more = colour.sd_CIE_standard_illuminant_A(colour.SpectralShape(ext[0], ext[-1], 5.0)).values
            else:  # the CIE daylight model at the name's CCT (modern c2 scale), joined at the table's last value
                cct = _D_SERIES_CCT[name]
                model = daylight(cct, torch.tensor([w[-1], *ext], dtype=torch.float64)).numpy()
                more = model[1:] * (v[-1] / model[0])
            w, v = np.concatenate([w, ext]), np.concatenate([v, np.asarray(more, float)])
        return w, v
    elif name in _FLUORESCENT:
        sd = colour.SDS_ILLUMINANTS[_FLUORESCENT[name]]
    else:  # pragma: no cover - guarded by illuminant()
        raise KeyError(name)
    return np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)


def _key(w: torch.Tensor) -> tuple:
    return tuple(float(x) for x in w.detach().double().cpu().tolist())


@tensor_cache(maxsize=256)
def _cached_on_grid(kind: str, arg, grid: tuple, dtype: torch.dtype, device: str) -> torch.Tensor:
    dst = torch.tensor(grid, dtype=torch.float64)
    if kind == "cmfs":
        src, vals = _native_cmfs(arg)
    elif kind == "vlambda":
        src, vals = _native_vlambda()
    elif kind == "illuminant":
        src, vals = _native_illuminant(arg)
        if arg in _FLUORESCENT:  # line spectra: the power in each sample's band, not the value at its centre
            # (CIE 015 tabulates F1-F12 at 5 nm; point samples at 10 nm miss the 435 and 545 nm mercury lines:
            # F2's white 0.024 from its CIE chromaticity in xy, F11's 0.029; an audit of 2026-11-30)
            if dst.numel() == src.size and np.allclose(dst.numpy(), src, rtol=0, atol=1e-9):
                return torch.from_numpy(vals).to(dtype=dtype, device=device)  # the table's own grid: the table
            out = band_average(torch.from_numpy(vals)[None], torch.from_numpy(src), dst)[0]
            return out.to(dtype=dtype, device=device)
    else:  # pragma: no cover
        raise KeyError(kind)
    out = resample(torch.from_numpy(vals), torch.from_numpy(src), dst, dim=-1)
    return out.to(dtype=dtype, device=device)


def band_average(values: torch.Tensor, src_nm: torch.Tensor, dst_nm: torch.Tensor) -> torch.Tensor:
    """Spectra ``values [K, N]`` on knots ``src_nm`` (piecewise linear) on the grid ``dst_nm [L]``, each sample the
    mean over its band (its integration weight, :func:`wavelength_weights`: edges halfway to its neighbours; the
    data's end values held where the band of a sample inside them overhangs their ends; a sample outside them is 0),
    so the power in every band is kept: narrow emission lines (fluorescent lamps' mercury lines, CRT phosphors)
    survive a coarse grid, where point samples (:func:`resample`) miss them. On a finer grid it is linear
    interpolation smoothed over the band."""
    src = check_wavelengths(torch.as_tensor(src_nm), "src_nm").to(values.dtype)  # (a decreasing grid gave zeros)
    dst = check_wavelengths(torch.as_tensor(dst_nm), "dst_nm").to(values.dtype)
    if values.dim() != 2 or values.shape[-1] != src.numel():
        raise ValueError(f"values: expected [K, {src.numel()}] on src_nm, got {tuple(values.shape)}")
    # the bands tile the grid: edges at the midpoints between samples, the end samples' half a step beyond them (each
    # band as wide as its wavelength_weights). A band of that width centred on its sample overlapped its neighbour on
    # one side and left a gap on the other on a non-uniform grid: a line in the gap was lost (F11 -2.1 % of its power)
    if dst.numel() == 1:
        lo, hi = dst - 0.5, dst + 0.5
    else:
        mid = 0.5 * (dst[1:] + dst[:-1])
        lo = torch.cat([dst[:1] - 0.5 * (dst[1] - dst[0]), mid])
        hi = torch.cat([mid, dst[-1:] + 0.5 * (dst[-1] - dst[-2])])
    seg = src[1:] - src[:-1]
    slope = (values[:, 1:] - values[:, :-1]) / seg
    cum = torch.cat([torch.zeros_like(values[:, :1]),
                     torch.cumsum(0.5 * (values[:, 1:] + values[:, :-1]) * seg, dim=1)], dim=1)  # exact: linear

    def primitive(x):  # integral from src[0] to x, clamped to the data's range (0 outside)
        x = x.clamp(src[0], src[-1])
        k = (torch.searchsorted(src, x, right=True) - 1).clamp(0, src.numel() - 2)
        dx = x - src[k]
        return cum[:, k] + values[:, k] * dx + 0.5 * slope[:, k] * dx**2

    def held(x):  # the primitive with the end values held beyond the data (CIE 015:2018, 7.2.2: extrapolate by the
        # nearest value): a sample on the data's range whose band overhangs its end (380 nm's 377.5-382.5 nm on
        # 380:5:785 for a 380-780 nm table) was the mean with 0 beyond it, about half the table's value (F2 at 380
        # nm: 0.63 for 1.18), and then depended on whether the grid had a sample beyond the table
        return primitive(x) + values[:, :1] * (x - src[0]).clamp(max=0) + values[:, -1:] * (x - src[-1]).clamp(min=0)

    inside = (dst >= src[0]) & (dst <= src[-1])  # a sample beyond the data is 0, as resample's
    return torch.where(inside, (held(hi) - held(lo)) / (hi - lo), torch.zeros_like(dst))


def table_dtype(w: torch.Tensor, dtype=None) -> torch.dtype:
    """The dtype of a table computed on grid ``w``: ``dtype``, else the grid's if floating, else torch's default;
    float32 or float64 (:func:`~isettorch._checks.check_float_dtype`: an integer dtype truncated the tables to 0 and
    1). The one rule of the library's spectral tables (CMFs, illuminants, filters, reflectance sets and models)."""
    return check_float_dtype(dtype or (w.dtype if w.is_floating_point() else torch.get_default_dtype()))


def _grid_args(wavelengths_nm, dtype, device):
    w = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm"))
    return w, table_dtype(w, dtype), device or w.device


def cmfs(wavelengths_nm, observer: str = "1931", *, dtype=None, device=None) -> torch.Tensor:
    """CIE colour matching functions [3, L] (x-bar, y-bar, z-bar) on the given grid.

    Source: CIE 015:2018 tables as shipped by colour-science (``colour.MSDS_CMFS``); ``observer`` is
    ``"1931"`` (2 degree) or ``"1964"`` (10 degree). Zero outside 360-830 nm.
    """
    if str(observer) not in OBSERVERS:
        raise ValueError(f"observer: expected one of {sorted(OBSERVERS)}, got {observer!r}")
    w, dtype, device = _grid_args(wavelengths_nm, dtype, device)
    return _cached_on_grid("cmfs", str(observer), _key(w), dtype, str(device)).clone()


def luminosity(wavelengths_nm, *, dtype=None, device=None) -> torch.Tensor:
    """Photopic luminous efficiency V(lambda) [L] (CIE 1924, colour.SDS_LEFS_PHOTOPIC)."""
    w, dtype, device = _grid_args(wavelengths_nm, dtype, device)
    return _cached_on_grid("vlambda", None, _key(w), dtype, str(device)).clone()


def planck_relative(wavelength_m, temperature_k, reference_m):
    """``B(lambda, T) / B(reference, T)`` of Planck's law ``B = 2 h c^2 / lambda^5 / (exp(h c / (lambda k T)) - 1)``
    (CODATA h, c, k; :mod:`isettorch.constants`), computed in log space so that a cold body's ratio is not 0 / 0 where
    both radiances underflow (below about 36 K, 560 nm: NaN), though the ratio itself can exceed the float range (in
    float64 below about 7 K at 700 nm: inf; :func:`blackbody` refuses that): ``(ref / lambda)^5 exp(L(c2 / (ref T)) -
    L(c2 / (lambda T)))``, ``L(x) = log(exp(x) - 1)``, ``c2 = h c / k``. The library's one Planck formula
    (:func:`blackbody`, the scene generator's lights). NumPy arrays or tensors that broadcast (a tensor temperature
    keeps its gradient)."""
    h, c, k = constants.PLANCK_J_S, constants.SPEED_OF_LIGHT_M_PER_S, constants.BOLTZMANN_J_PER_K
    xp = torch if any(isinstance(v, torch.Tensor) for v in (wavelength_m, temperature_k, reference_m)) else np

    def log_expm1(x):  # both branches finite for x > 0 (no NaN in the discarded one's gradient)
        return xp.where(x < 1, xp.log(xp.expm1(xp.minimum(x, xp.ones_like(x)))),
                        x + xp.log1p(-xp.exp(-xp.maximum(x, xp.ones_like(x)))))

    a = h * c / (k * temperature_k * reference_m) + 0 * wavelength_m
    b = h * c / (k * temperature_k * wavelength_m)
    return xp.exp(5 * xp.log(reference_m / wavelength_m) + log_expm1(a) - log_expm1(b))


def _is_number(v) -> bool:
    """A finite real number: a Python, NumPy or Decimal number, or a one-value (0-d) array or tensor; not a bool or
    text."""
    if isinstance(v, (bool, str, bytes)) or (hasattr(v, "dtype") and getattr(v, "ndim", 0) != 0):
        return False
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def blackbody(temperature_k: float, wavelengths_nm, *, dtype=None, device=None) -> torch.Tensor:
    """Planck spectral radiance (energy units), normalised to 100 at 560 nm [L] (:func:`planck_relative`)."""
    if not _is_number(temperature_k) or not float(temperature_k) > 0:  # ('6500' raised a bare TypeError)
        raise ValueError(f"temperature_k: expected a positive temperature in kelvin, got {temperature_k!r}")
    w, dtype, device = _grid_args(wavelengths_nm, dtype, device)
    spd = (100.0 * planck_relative(w.to(torch.float64) * 1e-9, float(temperature_k), 560e-9)).to(dtype)
    if not bool(torch.isfinite(spd).all()):  # (inf at the long wavelengths, named later as 'illuminant')
        raise ValueError(f"temperature_k: at {float(temperature_k):g} K the spectrum relative to 560 nm overflows "
                         f"{dtype} at {float(w[~torch.isfinite(spd)].min()):g} nm (Planck's ratio exceeds the "
                         f"format's range); use a higher temperature, a shorter grid, or float64")
    return spd.to(device=device)


def daylight(cct_k: float, wavelengths_nm, *, dtype=None, device=None) -> torch.Tensor:
    """CIE D-series daylight at correlated colour temperature ``cct_k`` (4000-25000 K) [L].

    Source: CIE 015:2018 daylight model (``colour.sd_CIE_illuminant_D_series``). The CCT is on the
    current (ITS-90) scale, so 6504 K gives D65's chromaticity.
    """
    if not _is_number(cct_k) or not (4000 <= float(cct_k) <= 25000):
        raise ValueError(f"cct_k: expected a daylight CCT in [4000, 25000] K, got {cct_k!r}")
    w, dtype, device = _grid_args(wavelengths_nm, dtype, device)
    return _daylight_cached(float(cct_k), _key(w), dtype, str(device)).clone()


@tensor_cache(maxsize=256)
def _daylight_cached(cct_k: float, grid: tuple, dtype, device: str) -> torch.Tensor:
    return torch.from_numpy(daylight_curves(np.array([cct_k]), grid, np, cie_rounding=True)[0]).to(dtype=dtype,
                                                                                                     device=device)


@functools.lru_cache(maxsize=64)
def _daylight_basis(grid: tuple) -> np.ndarray:
    """CIE daylight basis S0, S1, S2 (colour-science's tables) on a grid, float64 [3, L]."""
    from colour.colorimetry import SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES as S

    src = torch.tensor(np.asarray(S["S0"].wavelengths, float))
    vals = torch.tensor(np.stack([np.asarray(S[k].values, float) for k in ("S0", "S1", "S2")]))
    return resample(vals, src, torch.tensor(grid, dtype=torch.float64)).numpy()


def daylight_curves(t, grid: tuple, xp=np, cie_rounding: bool = False):
    """CIE daylight ``[N, L]`` (energy, S(560) ~ 100) for CCTs ``t`` ``[N]`` in [4000, 25000] K on the wavelengths
    ``grid`` (a tuple of nm): float64, a NumPy array (``xp=np``) or a tensor (``xp=torch``, differentiable in ``t``).
    The library's one daylight formula: :func:`daylight` (named daylights, ``cie_rounding=True``) and the scene
    generator's per-item daylights (smooth in the CCT, so differentiable).

    Source: CIE 015:2018 eqs. 4.7-4.12 (x_D polynomials in 1/T, y_D = -3 x^2 + 2.87 x - 0.275, M1, M2; 6504 K gives
    D65's chromaticity). ``cie_rounding``: M1 and M2 rounded to three decimals as CIE 015 prescribes for its tables
    and colour-science does (``sd_CIE_illuminant_D_series``, equal to it); unrounded the curve is smooth in the CCT
    and differs from the rounded one by up to 2e-4 of S(560) (0.022 at 6504 K)."""
    if not ((t >= 4000) & (t <= 25000)).all():  # NaN fails this too
        raise ValueError(f"cct_k: expected daylight CCTs in [4000, 25000] K, got {t.tolist()}")
    xd = xp.where(t <= 7000,
                  -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063,
                  -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040)
    yd = -3.0 * xd**2 + 2.870 * xd - 0.275
    m = 0.0241 + 0.2562 * xd - 0.7341 * yd
    m1 = (-1.3515 - 1.7703 * xd + 5.9114 * yd) / m
    m2 = (0.0300 - 31.4424 * xd + 30.0717 * yd) / m
    if cie_rounding:
        m1, m2 = (np.round(m1, 3), np.round(m2, 3)) if xp is np else (torch.round(m1, decimals=3),
                                                                       torch.round(m2, decimals=3))
    b = _daylight_basis(grid)
    if xp is not np:
        b = torch.from_numpy(b).to(t.device)
    return b[0] + m1[:, None] * b[1] + m2[:, None] * b[2]


def illuminant(name: str, wavelengths_nm, *, dtype=None, device=None) -> torch.Tensor:
    """Relative spectral power (energy units) of a named illuminant on the given grid [L].

    Names: ``D65``, ``D50``, ``D55``, ``D75``, ``A``, ``F1``..``F12`` (CIE tables via colour-science),
    ``D<cct>`` (e.g. ``D5000``, CIE daylight at that CCT), ``blackbody<T>`` / ``BB<T>`` (Planck),
    ``E`` / ``equal_energy`` (flat in energy, 100) and ``equal_photon`` (flat in photons, energy
    proportional to 1/lambda, 100 at 560 nm).
    """
    w, dtype, device = _grid_args(wavelengths_nm, dtype, device)
    if not isinstance(name, str):
        raise TypeError(f"name: expected an illuminant name (str), got {type(name).__name__}")
    key = name.strip()
    up = key.upper()
    if up in ("E", "EQUAL_ENERGY", "EE"):
        return torch.full((w.numel(),), 100.0, dtype=dtype, device=device)
    if up in ("EQUAL_PHOTON", "EP"):
        return (560.0 / w.to(torch.float64) * 100.0).to(dtype=dtype, device=device)
    if up in ("D65", "D50", "D55", "D75", "A") or up in _FLUORESCENT:
        return _cached_on_grid("illuminant", up, _key(w), dtype, str(device)).clone()
    if up.startswith("FL") and f"F{up[2:]}" in _FLUORESCENT:
        return _cached_on_grid("illuminant", f"F{up[2:]}", _key(w), dtype, str(device)).clone()
    for prefix in ("BLACKBODY", "BB"):
        if up.startswith(prefix):
            try:
                return blackbody(float(key[len(prefix):]), w, dtype=dtype, device=device)
            except ValueError as err:
                raise ValueError(f"name: could not read a temperature from {name!r}: {err}") from err
    if up.startswith("D"):
        try:
            cct = float(key[1:])
        except ValueError:
            cct = None
        if cct is not None:
            return daylight(cct, w, dtype=dtype, device=device)
    raise ValueError(
        f"name: unknown illuminant {name!r}; expected one of {illuminant_names()}, 'D<cct>' or 'blackbody<T>'"
    )


def spectral_integral(x: torch.Tensor, weights: torch.Tensor, wavelengths_nm, dim: int = -3) -> torch.Tensor:
    """``sum_lambda x(lambda) * weights[k](lambda) * dlambda`` -> the spectral axis becomes K channels.

    ``weights`` is [K, L] (or [L], giving K = 1).
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    check_float_dtype(x.dtype, "x")  # (integer data rounded the weights to 0; half underflowed)
    dim = dim % x.dim()
    if x.shape[dim] != w.numel():
        raise ValueError(f"x: expected {w.numel()} wavelengths along dim {dim}, got {x.shape[dim]}")
    wts = weights if weights.dim() == 2 else weights.reshape(1, -1)
    check_rank(wts, 2, "weights", "[K, L]")
    if wts.shape[-1] != w.numel():  # (a bare broadcasting error)
        raise ValueError(f"weights: expected [K, {w.numel()}] on the {w.numel()} wavelengths, got shape "
                         f"{tuple(weights.shape)}")
    dl = wavelength_weights(w).to(x.device, x.dtype)
    m = wts.to(x.device, x.dtype) * dl
    out = torch.tensordot(x.movedim(dim, -1), m, dims=([-1], [1]))
    return out.movedim(-1, dim)


def luminance(photons: torch.Tensor, wavelengths_nm, dim: int = -3, *, h: float | None = None,
              c: float | None = None) -> torch.Tensor:
    """Photometric quantity of a spectral photon image: ``683 * sum E(l) V(l) dl`` with E in W/...

    Radiance in photons/s/sr/m^2/nm gives luminance in cd/m^2; irradiance in photons/s/m^2/nm gives
    illuminance in lux. The spectral axis ``dim`` becomes size 1. Source: CIE 015:2018, Km = 683 lm/W.
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    check_float_dtype(photons.dtype, "photons")  # (integer photons gave 0: V(lambda) cast to int64)
    e = photons_to_energy(photons, w, dim, h=h, c=c)
    v = luminosity(w, dtype=photons.dtype, device=photons.device)
    return constants.KM_LM_PER_W * spectral_integral(e, v, w, dim)


def xyz(photons: torch.Tensor, wavelengths_nm, dim: int = -3, *, observer: str = "1931") -> torch.Tensor:
    """CIE XYZ (absolute: Y in cd/m^2 for radiance, lux for irradiance) of a photon image.

    ``X = 683 sum E(l) xbar(l) dl`` etc. (CIE 015:2018). The spectral axis becomes 3 channels.
    """
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    check_float_dtype(photons.dtype, "photons")
    return xyz_of_energy(photons_to_energy(photons, w, dim), w, dim, observer=observer)


def xyz_of_energy(energy: torch.Tensor, wavelengths_nm, dim: int = -3, *, observer: str = "1931") -> torch.Tensor:
    """CIE XYZ of a spectral power (W/...: a radiance in W/sr/m^2/nm gives Y in cd/m^2): ``X = 683 sum E(l)
    xbar(l) dl`` etc. (CIE 015:2018; :data:`constants.KM_LM_PER_W`). The spectral axis becomes 3 channels."""
    w = check_wavelengths(torch.as_tensor(wavelengths_nm))
    check_float_dtype(energy.dtype, "energy")
    return constants.KM_LM_PER_W * spectral_integral(energy, cmfs(w, observer, dtype=energy.dtype,
                                                                  device=energy.device), w, dim)
