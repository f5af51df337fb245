"""Random physical spectra for synthetic scenes: surface reflectances and illuminants.

Reflectances (values in [0, 1], smooth):

* ``"pca"``: a linear model (mean + 8 principal components) fitted to measured reflectances that
  colour-science ships (ColorChecker sets of BabelColor, Ohta and ISO 17321-1, the PMC chart, the CIE
  test colour samples and the NIST CQS samples, 8 components); coefficients are drawn from the fitted Gaussian and
  a spectrum that would leave [0, 1] is contracted towards the mean (never clipped).
  Source: Maloney, "Evaluation of linear models of surface spectral reflectance", JOSA A 3 (1986).
* ``"sigmoid"``: sigmoid-polynomial spectra ``S(c0 u^2 + c1 u + c2)``, ``S(x) = 1/2 + x / (2 sqrt(1 + x^2))``.
  Source: Jakob & Hanika, "A low-dimensional function space for efficient spectral upsampling",
  Computer Graphics Forum 38(2), 2019, eq. 2.

Illuminants (relative spectral power in **energy** units on the given grid, all batched in torch):
CIE daylight by CCT, Planckian (blackbody), CIE F1-F12 fluorescent tables, and LED-like white
(blue InGaN pump + broad phosphor, mixed to reach the asked CCT).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from .. import spectral
from .._autograd import records_grad, tensor_cache
from .._checks import check_float_dtype, check_wavelengths
from .config import WAVELENGTH_RANGE_NM, randint_scalar, uniform01

__all__ = [
    "measured_reflectances",
    "recovery_reflectances",
    "srgb_basis_spectra",
    "camera_sensitivities",
    "random_sensitivities",
    "CAMERA_SENSITIVITY_NAMES",
    "reflectance_basis",
    "random_reflectances",
    "sigmoid_polynomial_reflectance",
    "dye_concentration",
    "daylight_spd",
    "blackbody_spd",
    "fluorescent_spd",
    "led_spd",
    "chromaticity_xy",
    "cct_mccamy",
    "ILLUMINANT_KINDS",
    "random_illuminant",
]

ILLUMINANT_KINDS = ("daylight", "blackbody", "fluorescent", "led")

# Implementation note: the synthetic-scene generator calls these functions once per scene on tiny inputs
# (1 CCT, 8 reflectances, ~31 wavelengths), where each torch op costs ~3-5 us of dispatch and numpy ~0.5-1 us.
# The float64 maths therefore runs in numpy on per-grid constants cached as numpy arrays, and converts to torch
# once, at the end. When an input tensor requires grad, the same formulas run in torch instead (``xp`` below is
# ``numpy`` or ``torch``), so the spectra stay differentiable with respect to CCTs and LED parameters.


_GRIDS: dict = {}


def _grid(wavelengths_nm) -> tuple[torch.Tensor, tuple]:
    """``(w, key)``: the grid as a tensor, validated (``check_wavelengths``) once per distinct grid, and its values
    as a tuple of floats (the key of the per-grid caches). A scene calls the spectra functions ~8 times on the same
    grid; each full check costs ~40 us of small tensor ops. A grid is remembered by its exact values, dtype and
    device, so an invalid grid (NaN never equals itself) is always checked, and raises."""
    w = torch.as_tensor(wavelengths_nm)
    if w.dim() != 1:
        w = check_wavelengths(w)  # raises, or gives a 0-d grid its length-1 shape
    values = tuple(w.tolist())
    key = _GRIDS.get((w.dtype, w.device, values))
    if key is None:
        check_wavelengths(w)
        if len(_GRIDS) > 256:  # bounded
            _GRIDS.clear()
        key = tuple(float(x) for x in values)
        _GRIDS[(w.dtype, w.device, values)] = key
    return w, key


def _checked(wavelengths_nm) -> torch.Tensor:
    return _grid(wavelengths_nm)[0]


def _out_dtype(w: torch.Tensor) -> torch.dtype:
    return spectral.table_dtype(w)


def _to_torch(a: np.ndarray, dtype: torch.dtype, device) -> torch.Tensor:
    """The one numpy -> torch conversion at the end of each call (``a`` is a fresh array, never a cached one)."""
    return torch.from_numpy(a).to(dtype=dtype, device=device)


def _f64(value, xp) -> np.ndarray | torch.Tensor:
    """A float64 vector ``[N]`` on the CPU: numpy for ``xp is np``, else a torch tensor (keeps the autograd graph)."""
    if xp is np and isinstance(value, torch.Tensor):
        return value.detach().to(device="cpu", dtype=torch.float64).reshape(-1).numpy()
    if xp is np and isinstance(value, np.ndarray) and value.dtype == np.float64:
        return value.reshape(-1)
    t = torch.as_tensor(value, dtype=torch.float64).reshape(-1)
    return t.cpu() if xp is torch else t.numpy()


def _const(a: np.ndarray, xp, like=None):
    """A cached numpy constant for the array module ``xp`` (shared memory, never written to); on the torch path, on
    the device of the tensor ``like`` (the batched generator draws on the training device)."""
    if xp is np:
        return a
    t = torch.from_numpy(a)
    return t if like is None or like.device == t.device else t.to(like.device)


# ------------------------------------------------------------------------------------------------
# Reflectances


@functools.cache
def _measured_reflectances() -> tuple[np.ndarray, np.ndarray]:
    """Measured reflectances shipped by colour-science, on 400:5:700 nm: (wavelengths [M], R [N, M])."""
    import colour
    from colour.quality.datasets import SDS_TCS, SDS_VS

    wave = np.arange(400.0, 700.1, 5.0)
    rows = []
    sets = [colour.SDS_COLOURCHECKERS[k] for k in ("BabelColor Average", "ColorChecker N Ohta", "ISO 17321-1",
                                                   "PMC")]
    sets += [SDS_TCS["CIE 1995"], SDS_VS["NIST CQS 9.0"]]
    for s in sets:
        for sd in s.values():
            rows.append(np.interp(wave, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)))
    return wave, np.clip(np.asarray(rows), 0.0, 1.0)


@functools.cache
def _pca_native(n_components: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    wave, r = _measured_reflectances()
    mean = r.mean(axis=0)
    _, s, vt = np.linalg.svd(r - mean, full_matrices=False)
    basis = vt[:n_components]
    std = s[:n_components] / math.sqrt(r.shape[0] - 1)
    return wave, mean, basis, std


@tensor_cache(maxsize=64)
def _pca_on_grid(n_components: int, grid: tuple, dtype, device: str):
    wave, mean, basis, std = _pca_native(n_components)
    src = torch.from_numpy(wave)
    dst = torch.tensor(grid, dtype=torch.float64)
    m = spectral.resample(torch.from_numpy(mean), src, dst)
    b = spectral.resample(torch.from_numpy(basis), src, dst)
    return (m.to(dtype=dtype, device=device), b.to(dtype=dtype, device=device),
            torch.from_numpy(std).to(dtype=dtype, device=device))


def reflectance_basis(wavelengths_nm, n_components: int = 8, *, dtype=None, device=None):
    """Linear model of measured reflectances on a grid: ``(mean [L], basis [K, L], coefficient std [K])``.

    The basis is fitted (SVD) on 400-700 nm; outside that range it is 0 (see `spectral.resample`). The tensors are
    the caller's copies (an in-place edit leaves the cached model, and the PCA reflectances drawn from it, alone).
    """
    w, key = _grid(wavelengths_nm)
    if not 1 <= n_components <= 12:
        raise ValueError(f"n_components: expected 1..12 principal components, got {n_components}")
    dtype = spectral.table_dtype(w, dtype)
    return tuple(x.clone() for x in _pca_on_grid(int(n_components), key, dtype, str(device or w.device)))


_NP_DTYPES = {torch.float32: np.float32, torch.float64: np.float64}
_SIGMOID_SCALE = {d: np.array([3.0, 2.5, 1.5], dtype=nd) for d, nd in _NP_DTYPES.items()}  # see random_reflectances


@functools.lru_cache(maxsize=64)
def _reflectance_model(grid: tuple, dtype: torch.dtype, margin: float = 1e-3) -> tuple[np.ndarray, ...]:
    """numpy constants of both reflectance models on a grid, in ``dtype`` (float32 or float64): PCA mean [L],
    basis [K, L], std [K], the room to the upper / lower bound ``1 - margin - mean``, ``mean - margin`` [L], and the
    Jakob-Hanika normalised wavelength ``u = (lambda - 550) / 150`` [L]."""
    mean, basis, std = (x.numpy() for x in _pca_on_grid(8, grid, dtype, "cpu"))
    u = ((torch.tensor(grid, dtype=torch.float64).to(dtype) - 550.0) / 150.0).numpy()
    return mean, basis, std, 1 - margin - mean, mean - margin, u


def _pca_reflectances(coef: np.ndarray, mean, basis, std, room_up, room_down, spread: float = 1.0, xp=np):
    """PCA spectra from standard-normal draws ``coef`` [..., n, K] (numpy, or torch tensors with ``xp=torch``: the
    batched generator), contracted towards the mean to stay in [margin, 1 - margin]."""
    dev = (coef * std * spread) @ basis  # [n, L]
    # Largest alpha <= 1 keeping mean + alpha * dev inside [margin, 1 - margin] (mean is strictly inside).
    # Per sample: room / |dev| towards the side dev points to (dev = 0 gives inf); |dev| < 1e-12 gives a ratio > 1
    # (the rooms are >= 1e-3 wide), which the cap at 1 removes, as clamping |dev| at 1e-12 did.
    ratio = xp.where(dev > 0, room_up, room_down) / xp.abs(dev)
    if xp is np:
        alpha = np.minimum(ratio.min(axis=-1, keepdims=True), 1.0)
    else:
        alpha = ratio.amin(dim=-1, keepdim=True).clamp(max=1.0)
    return mean + alpha * dev


def _sigmoid_polynomial(c, u, xp):
    """Jakob & Hanika (2019) ``S(c0 u^2 + c1 u + c2)`` for coefficients ``c`` [N, 3] and ``u`` [L] in ``xp``."""
    x = c[:, :1] * u**2 + c[:, 1:2] * u + c[:, 2:3]
    return 0.5 + x / (2 * xp.sqrt(1 + x * x))  # Jakob & Hanika 2019, eq. 2


def sigmoid_polynomial_reflectance(coefficients: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """Jakob & Hanika (2019) reflectance ``S(c0 u^2 + c1 u + c2)`` with ``u = (lambda - 550) / 150``.

    Args:
        coefficients: ``[N, 3]`` polynomial coefficients (c0, c1, c2) in the normalised wavelength u.
    Returns:
        ``[N, L]`` reflectances, strictly inside (0, 1).
    """
    w = _checked(wavelengths_nm)
    c = coefficients
    u = ((w.to(c.device, c.dtype) - 550.0) / 150.0)
    return _sigmoid_polynomial(c, u, torch)


def random_reflectances(n: int, wavelengths_nm, generator: torch.Generator, *, model: str = "mixed",
                        pca_fraction: float = 0.5) -> torch.Tensor:
    """``n`` random smooth reflectances ``[n, L]`` in [0, 1].

    Args:
        model: ``"pca"``, ``"sigmoid"`` or ``"mixed"`` (each spectrum draws PCA with probability ``pca_fraction``).
        generator: the only source of randomness (CPU generator); results are moved to the grid's device.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> r = random_reflectances(4, torch.arange(400., 701., 10.), g)
        >>> bool((r >= 0).all() and (r <= 1).all())
        True
    """
    w, key = _grid(wavelengths_nm)
    if model not in ("pca", "sigmoid", "mixed"):
        raise ValueError(f"model: expected 'pca', 'sigmoid' or 'mixed', got {model!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n: expected a number of spectra >= 0, got {n!r}")
    if not (isinstance(pca_fraction, (int, float)) and 0 <= pca_fraction <= 1):
        raise ValueError(f"pca_fraction: expected a probability in [0, 1], got {pca_fraction!r}")
    lo_nm, hi_nm = WAVELENGTH_RANGE_NM
    if model != "sigmoid" and (float(w.min()) < lo_nm or float(w.max()) > hi_nm):
        # the PCA basis (measured reflectances) exists on 400-700 nm only: outside, its draws were NaN and +-inf
        raise ValueError(f"wavelengths_nm: model {model!r} draws from a basis of measured reflectances on "
                         f"{lo_nm:g}-{hi_nm:g} nm, got {float(w.min()):g}-{float(w.max()):g} nm; use model='sigmoid' "
                         "or a grid inside that range")
    dtype = _out_dtype(w)
    calc = dtype if dtype in _NP_DTYPES else torch.float64  # numpy has no bfloat16: other dtypes work in float64
    mean, basis, std, room_up, room_down, u = _reflectance_model(key, calc)
    # Every model makes the same draws, in this order, so a generator state gives the same spectra in all of them.
    pca_coef = torch.randn(n, std.size, generator=generator, dtype=dtype)
    # Coefficient scales chosen so spectra range from flat greys to saturated, single-peaked colours.
    sig_coef = torch.randn(n, 3, generator=generator, dtype=dtype)
    pick = torch.rand(n, 1, generator=generator, dtype=dtype)
    if dtype != calc:
        pca_coef, sig_coef, pick = pca_coef.to(calc), sig_coef.to(calc), pick.to(calc)
    pca_coef, sig_coef, pick = pca_coef.numpy(), sig_coef.numpy() * _SIGMOID_SCALE[calc], pick.numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        if model == "pca":
            out = _pca_reflectances(pca_coef, mean, basis, std, room_up, room_down)
        elif model == "sigmoid":
            out = _sigmoid_polynomial(sig_coef, u, np)
        else:
            out = np.where(pick < pca_fraction, _pca_reflectances(pca_coef, mean, basis, std, room_up, room_down),
                           _sigmoid_polynomial(sig_coef, u, np))
    return _to_torch(out, dtype, w.device)


def dye_concentration(reflectance: torch.Tensor, concentration) -> torch.Tensor:
    """The reflectance of the same colorant at ``concentration`` times its amount: ``r_peak (r / r_peak)^c``.

    Beer-Lambert law: a colorant's absorbance is proportional to its concentration, so its transmittance (and,
    through a diffuse substrate, the reflectance relative to the substrate) is raised to the power ``c``. The
    substrate is taken as the spectrum's peak (the least absorbed wavelength keeps its reflectance), so ``c > 1``
    makes the colour purer at the same peak, ``c < 1`` paler, ``c = 1`` is the identity; zero stays zero.
    Source: the Beer-Lambert law for colorant layers (Wyszecki & Stiles, *Color Science*, 2nd ed., 1982; Berns,
    *Billmeyer and Saltzman's Principles of Color Technology*, 3rd ed., 2000).

    Args:
        reflectance: ``[..., L]`` in [0, 1] (wavelength last).
        concentration: > 0; a scalar, or a tensor ``[..., 1]`` (one per spectrum).

    Example:
        >>> dye_concentration(torch.tensor([0.8, 0.4, 0.2]), 2.0)
        tensor([0.8000, 0.2000, 0.0500])
    """
    r = torch.as_tensor(reflectance)
    if not r.is_floating_point() or r.ndim < 1 or not bool(((r >= 0) & (r <= 1)).all()):
        raise ValueError(f"reflectance: expected a float tensor [..., L] with values in [0, 1], got "
                         f"{tuple(r.shape)} {r.dtype}")
    c = torch.as_tensor(concentration, dtype=r.dtype, device=r.device)
    if not bool((c > 0).all()) or not bool(torch.isfinite(c).all()):
        raise ValueError(f"concentration: expected finite values > 0, got {concentration!r}")
    peak = r.amax(-1, keepdim=True)
    return peak * (r / peak.clamp_min(torch.finfo(r.dtype).tiny)).pow(c)  # an all-zero spectrum stays zero


# ------------------------------------------------------------------------------------------------
# Illuminants (energy units, relative)


def _daylight(t, grid: tuple, xp):
    """CIE daylight [N, L] for CCTs ``t`` [N] (float64, numpy or torch ``xp``): :func:`isettorch.spectral.
    daylight_curves`, the library's one daylight formula."""
    return spectral.daylight_curves(t, grid, xp)


def daylight_spd(cct_k: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE daylight ``[N, L]`` for CCTs ``[N]`` in [4000, 25000] K (energy, S(560) ~ 100).

    Source: CIE 015:2018 eqs. 4.7-4.12 (x_D polynomials in 1/T, y_D = -3 x^2 + 2.87 x - 0.275, M1, M2),
    the same convention as ``colour.temperature.CCT_to_xy_CIE_D`` (6504 K gives D65).
    """
    w, key = _grid(wavelengths_nm)
    xp = torch if records_grad(cct_k) else np
    t = _f64(cct_k, xp)
    spd = _daylight(t, key, xp)
    return (_to_torch(spd, _out_dtype(w), w.device) if xp is np
            else spd.to(dtype=_out_dtype(w), device=w.device))


@functools.lru_cache(maxsize=64)
def _planck_grid(grid: tuple) -> np.ndarray:
    """A grid's wavelengths in metres, float64 [L]."""
    return np.asarray(grid, dtype=np.float64) * 1e-9


def _blackbody(t, grid: tuple, xp):
    """Planck spectra [N, L] for temperatures ``t`` [N, 1], 100 at 560 nm (float64, numpy or torch ``xp``;
    :func:`isettorch.spectral.planck_relative`)."""
    return 100.0 * spectral.planck_relative(_const(_planck_grid(grid), xp, t), t, 560e-9)


def blackbody_spd(temperature_k: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """Planck spectra ``[N, L]`` (energy, 100 at 560 nm). Source: Planck's law (CODATA h, c, k)."""
    w, key = _grid(wavelengths_nm)
    xp = torch if records_grad(temperature_k) else np
    t = _f64(temperature_k, xp).reshape(-1, 1)
    if (t <= 0).any() or not xp.isfinite(t).all():
        raise ValueError(f"temperature_k: expected positive temperatures, got {t.flatten().tolist()}")
    if xp is torch:
        out = _blackbody(t, key, xp).to(dtype=_out_dtype(w), device=w.device)
    else:
        with np.errstate(over="ignore"):  # exp overflow (a cold body, short wavelengths) gives 0 power, as in torch
            out = _to_torch(_blackbody(t, key, xp), _out_dtype(w), w.device)
    return _check_planck_range(out, "temperature_k", t.flatten().tolist())


def _check_planck_range(spd: torch.Tensor, name: str, temperatures) -> torch.Tensor:
    """``spd`` if finite; a blackbody too cold for its dtype (Planck's ratio to 560 nm overflows at the long
    wavelengths: inf, as :func:`isettorch.spectral.blackbody` refuses) is a ValueError naming ``name``."""
    if not bool(torch.isfinite(spd.detach()).all()):
        raise ValueError(f"{name}: the blackbody spectrum relative to 560 nm overflows {spd.dtype} at "
                         f"{[round(float(v), 6) for v in temperatures][:4]} K (Planck's ratio exceeds the format's "
                         f"range); use a higher temperature, a shorter grid or float64")
    return spd


@functools.lru_cache(maxsize=16)
def _fluorescent_table(grid: tuple) -> np.ndarray:
    """CIE F1-F12 on a grid, float64 [12, L]."""
    w = torch.tensor(grid, dtype=torch.float64)
    return torch.stack([spectral.illuminant(f"F{i}", w, dtype=torch.float64) for i in range(1, 13)]).numpy()


def fluorescent_spd(numbers: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE fluorescent illuminants F<n> (n in 1..12) ``[N, L]`` (colour-science tables)."""
    w, key = _grid(wavelengths_nm)
    raw = torch.as_tensor(numbers).reshape(-1).tolist()
    bad = [x for x in raw if not (math.isfinite(float(x)) and float(x) == int(x) and 1 <= int(x) <= 12)]
    if bad:
        raise ValueError(f"numbers: expected CIE fluorescent numbers 1..12, got {bad}")
    return _to_torch(_fluorescent_table(key)[np.asarray(raw, dtype=np.intp) - 1], _out_dtype(w), w.device)


_FINE = torch.arange(380.0, 781.0, 5.0, dtype=torch.float64)
_FINE_KEY = tuple(_FINE.tolist())


def _led_parts(lam, pump_nm, phosphor_nm, phosphor_fwhm_nm, xp):
    """Pump and phosphor emission [N, L] on wavelengths ``lam`` [L] (nm), both peaking at 1."""
    lam = lam[None]
    # Blue InGaN pump ~20 nm FWHM; YAG-like phosphor modelled as a broad Gaussian (Schubert, "Light-Emitting
    # Diodes", 2nd ed., ch. 21: phosphor-converted white LEDs).
    pump = xp.exp(-4 * math.log(2) * ((lam - pump_nm[:, None]) / 20.0) ** 2)
    phos = xp.exp(-4 * math.log(2) * ((lam - phosphor_nm[:, None]) / phosphor_fwhm_nm[:, None]) ** 2)
    return pump, phos


def chromaticity_xy(spd_energy: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE 1931 xy ``[N, 2]`` of spectra ``[N, L]`` (energy units)."""
    w = _checked(wavelengths_nm)
    cm = spectral.cmfs(w, dtype=spd_energy.dtype, device=spd_energy.device)
    xyz = spectral.spectral_integral(spd_energy, cm, w, dim=-1)
    return xyz[..., :2] / xyz.sum(dim=-1, keepdim=True)


def cct_mccamy(xy: torch.Tensor) -> torch.Tensor:
    """Correlated colour temperature (K) from xy ``[..., 2]``. Source: McCamy, Color Res. Appl. 17 (1992)."""
    n = (xy[..., 0] - 0.3320) / (0.1858 - xy[..., 1])
    return 449.0 * n**3 + 3525.0 * n**2 + 6823.3 * n + 5520.33


@functools.lru_cache(maxsize=8)
def _cmf_weights(grid: tuple) -> np.ndarray:
    """CIE 1931 CMFs times the integration weights on a grid, float64 [L, 3] (for fast repeated integrals)."""
    w = torch.tensor(grid, dtype=torch.float64)
    return np.ascontiguousarray((spectral.cmfs(w, dtype=torch.float64) * spectral.wavelength_weights(w)).numpy().T)


def _uv(xyz):
    """CIE 1960 UCS (u, v), each [N], of XYZ [N, 3]: u = 4X / (X + 15Y + 3Z), v = 6Y / (X + 15Y + 3Z)
    (CIE 015:2018)."""
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    d = x + 15 * y + 3 * z
    return 4 * x / d, 6 * y / d


@functools.lru_cache(maxsize=16)
def _led_grid(grid: tuple) -> np.ndarray:
    """The scene's grid followed by the fine 5 nm grid of the CCT condition, float64 [L + 81] (nm)."""
    return np.asarray(grid + _FINE_KEY, dtype=np.float64)


def _led_params(t, pump_nm, phosphor_nm, phosphor_fwhm_nm, xp):
    """``led_spd``'s pump, phosphor peak and phosphor FWHM (nm), float64 [N] (a scalar broadcasts), defaults set."""
    n = t.shape[0]

    def per(v, default, name):
        if v is None:
            if xp is np:
                return np.full(n, default)
            return torch.full((n,), default, dtype=torch.float64, device=t.device)
        if xp is np or not isinstance(v, torch.Tensor):
            v = _f64(v, xp)
        # on the torch path on the CCTs' device (the batched generator draws on the training device)
        v = v if xp is np else v.to(device=t.device, dtype=torch.float64).reshape(-1)
        if v.shape[0] not in (1, n):
            raise ValueError(f"{name}: expected 1 or {n} values (one per CCT), got {v.shape[0]}")
        return xp.broadcast_to(v, (n,))

    if phosphor_nm is None:
        if pump_nm is None and phosphor_fwhm_nm is None:  # the phosphor that puts the LED on the Planckian locus
            phosphor_nm = _on_locus_phosphor(t, xp)
        else:  # warm-white LEDs use red-shifted phosphors
            phosphor_nm = xp.clip(560.0 + 0.012 * (6500.0 - t), 555.0, 610.0)
    return (per(pump_nm, 450.0, "pump_nm"), per(phosphor_nm, 565.0, "phosphor_nm"),
            per(phosphor_fwhm_nm, 120.0, "phosphor_fwhm_nm"))


@functools.cache
def _on_locus_table() -> tuple[np.ndarray, np.ndarray]:
    """``(mired [M], phosphor peak nm [M])``: for the default pump (450 nm, 20 nm FWHM) and phosphor width (120 nm),
    the phosphor peak whose chromaticity is collinear in CIE 1960 uv with the pump and the Planckian locus point at
    1e6 / mired K, so that the pump + phosphor mixture on that CCT's isotemperature line lies on the locus (Duv 0,
    as ANSI C78.377 asks of white LEDs within +-0.006). Solved on a 0.25 nm grid of peaks (480-700 nm) with linear
    interpolation of the sign change; where no peak in that range reaches the locus, the nearest end."""
    cw = _cmf_weights(_FINE_KEY)
    lam = np.asarray(_FINE_KEY)
    peaks = np.arange(480.0, 700.01, 0.25)
    up, vp = _uv(_led_parts(lam, np.array([450.0]), np.array([565.0]), np.array([120.0]), np)[0] @ cw)
    uf, vf = _uv(_led_parts(lam, np.full(peaks.size, 450.0), peaks, np.full(peaks.size, 120.0), np)[1] @ cw)
    mired = np.arange(40.0, 1000.01, 1.0)
    ut, vt = _uv(_blackbody(1e6 / mired[:, None], _FINE_KEY, np) @ cw)
    cross = (uf[None] - up) * (vt[:, None] - vp) - (vf[None] - vp) * (ut[:, None] - up)  # [M, peaks]
    sign = np.signbit(cross)
    change = sign[:, 1:] != sign[:, :-1]
    first = np.where(change.any(axis=1), change.argmax(axis=1), -1)
    out = np.empty(mired.size)
    for i, j in enumerate(first):
        if j < 0:  # unreachable: the end whose cross product is smaller
            out[i] = peaks[0] if abs(cross[i, 0]) < abs(cross[i, -1]) else peaks[-1]
        else:
            c0, c1 = cross[i, j], cross[i, j + 1]
            out[i] = peaks[j] + (peaks[j + 1] - peaks[j]) * c0 / (c0 - c1)
    return mired, out


def _on_locus_phosphor(t, xp):
    """Default phosphor peak (nm) [N] for CCTs ``t`` [N] (K): :func:`_on_locus_table` interpolated linearly in mired
    (differentiable in ``t`` on the torch path)."""
    mired, peak = _on_locus_table()
    if xp is np:
        return np.interp(1e6 / t, mired, peak)
    m = (1e6 / t).clamp(float(mired[0]), float(mired[-1]))
    grid, val = torch.from_numpy(mired).to(t.device), torch.from_numpy(peak).to(t.device)
    j = torch.searchsorted(grid, m.detach()).clamp(1, grid.numel() - 1)
    m0, m1, p0, p1 = grid[j - 1], grid[j], val[j - 1], val[j]
    return p0 + (p1 - p0) * (m - m0) / (m1 - m0)


def _led(t, pump_nm, phosphor_nm, phosphor_fwhm_nm, grid: tuple, iterations, xp):
    """LED spectra [N, L] (peak 100) for CCTs ``t`` and LED parameters [N] (float64, numpy or torch ``xp``)."""
    # pump and phosphor on the scene's grid and, after it, on the fine grid (one evaluation for both)
    both_pump, both_phos = _led_parts(_const(_led_grid(grid), xp, t), pump_nm, phosphor_nm, phosphor_fwhm_nm, xp)
    n_scene = len(grid)
    pump, phos = both_pump[:, :n_scene], both_phos[:, :n_scene]
    fpump, fphos = both_pump[:, n_scene:], both_phos[:, n_scene:]
    # The CCT is defined by the isotemperature line: the normal to the Planckian locus in CIE 1960 uv
    # through the locus point at T (CIE 015:2018 sec. 9.5). Mixing is linear in XYZ, so the LED's uv moves on
    # a straight segment from pump to phosphor and the signed distance along the locus tangent is monotone
    # in the ratio: bisection in log(phosphor / pump), evaluated on a fine 5 nm grid (independent of the scene's).
    cw = _const(_cmf_weights(_FINE_KEY), xp, t)  # [81, 3]
    # Planckian locus at T and, for its tangent, at T * 1.001 and T / 1.001 (one evaluation for the three)
    n = t.shape[0]
    u, v = _uv(_blackbody((np.concatenate if xp is np else torch.cat)([t, t * 1.001, t / 1.001])[:, None],
                          _FINE_KEY, xp) @ cw)
    u_t, v_t = u[:n], v[:n]
    tan_u, tan_v = u[n:2 * n] - u[2 * n:], v[n:2 * n] - v[2 * n:]
    if iterations is None:
        # Closed form. With XYZ_s = cmf . spd_s (s = pump, phosphor) and D = X + 15 Y + 3 Z, the mixture
        # pump + r phosphor has uv = (4 X, 6 Y) / D with X = X_p + r X_f, ... (CIE 015:2018), so
        # D(r) ((uv(r) - uv_t) . tangent) = A_p + r A_f, A_s = (4 X_s - u_t D_s) t_u + (6 Y_s - v_t D_s) t_v:
        # D > 0, hence the isotemperature condition is linear in r and r = -A_p / A_f (exact). As the
        # bisection did, log r is kept in [-8, 10] (an unreachable CCT gives the nearest end).
        xyz_p, xyz_f = fpump @ cw, fphos @ cw  # [N, 3]

        def lin(xyz):
            d = xyz[:, 0] + 15 * xyz[:, 1] + 3 * xyz[:, 2]
            return (4 * xyz[:, 0] - u_t * d) * tan_u + (6 * xyz[:, 1] - v_t * d) * tan_v

        a_p, a_f = lin(xyz_p), lin(xyz_f)
        r = -a_p / a_f
        # too hot (A_p + r A_f > 0) for every r > 0 -> the upper end; never too hot -> the lower end
        hot_everywhere = (a_f >= 0) & (a_p + a_f > 0) | (r <= 0) & (a_p > 0)
        log_r = xp.where(r > 0, xp.log(xp.clip(r, 1e-300, None)), -math.inf)
        log_r = xp.clip(xp.where(hot_everywhere, 10.0, log_r), -8.0, 10.0)
    else:
        lo = xp.zeros_like(t) - 8.0
        hi = xp.zeros_like(t) + 10.0
        for _ in range(int(iterations)):
            mid = (lo + hi) / 2
            u, v = _uv((fpump + xp.exp(mid)[:, None] * fphos) @ cw)
            too_hot = (u - u_t) * tan_u + (v - v_t) * tan_v > 0  # need more phosphor
            lo = xp.where(too_hot, mid, lo)
            hi = xp.where(too_hot, hi, mid)
        log_r = (lo + hi) / 2
    spd = pump + xp.exp(log_r)[:, None] * phos
    return 100 * spd / xp.amax(spd, axis=1, keepdims=True)


def led_spd(cct_k: torch.Tensor, wavelengths_nm, *, pump_nm=None, phosphor_nm=None, phosphor_fwhm_nm=None,
            iterations: int | None = None) -> torch.Tensor:
    """Phosphor-converted white LED ``[N, L]`` (energy, peak 100) whose CCT is ``cct_k`` [N].

    The pump : phosphor ratio ``r`` puts the LED on the isotemperature line of ``cct_k`` (more phosphor lowers
    the CCT). Defaults: pump 450 nm, phosphor FWHM 120 nm, and the phosphor peak that puts the LED on the
    Planckian locus (|Duv| <= 3e-5 over 1800-20000 K by colour-science's Ohno 2013; ANSI C78.377 allows
    +-0.006 for white LEDs): ~564 nm at 6500 K to ~598 nm at 2700 K (:func:`_on_locus_table`). With a custom
    pump or width and no phosphor peak, the peak is ``560 + 0.012 (6500 - T)`` nm (555-610).
    ``iterations=None`` (default) solves for ``r`` in closed form (exact: the condition is linear in ``r``, see
    the comment below); an integer runs the former bisection in ``log r`` with that many steps (26 gave
    ``|d log r| <= 1.3e-7``).
    """
    w, key = _grid(wavelengths_nm)
    xp = torch if records_grad(cct_k, pump_nm, phosphor_nm, phosphor_fwhm_nm) else np
    t = _f64(cct_k, xp)
    if not bool(((t >= 1000) & (t <= 25000)).all()):  # the on-locus table spans 1000-25000 K (NaN fails too)
        raise ValueError(f"cct_k: expected LED CCTs in [1000, 25000] K, got {t.tolist()}")
    if phosphor_fwhm_nm is not None and not bool((_f64(phosphor_fwhm_nm, xp) > 0).all()):
        raise ValueError(f"phosphor_fwhm_nm: expected a positive width (nm), got {phosphor_fwhm_nm!r}")
    params = _led_params(t, pump_nm, phosphor_nm, phosphor_fwhm_nm, xp)
    if xp is torch:
        return _led(t, *params, key, iterations, xp).to(dtype=_out_dtype(w), device=w.device)
    with np.errstate(all="ignore"):  # as in torch: inf / nan follow IEEE rules silently
        return _to_torch(_led(t, *params, key, iterations, xp), _out_dtype(w), w.device)


@functools.cache
def _fluorescent_cct(num: int) -> float:
    return float(cct_mccamy(chromaticity_xy(fluorescent_spd(torch.tensor([num]), _FINE), _FINE))[0])


def random_illuminant(kind: str, wavelengths_nm, generator: torch.Generator, cct_range_k=None):
    """One random illuminant of ``kind``: returns ``(spd [L] energy, cct_k float, name str)``.

    ``cct_range_k`` (lo, hi) is sampled uniformly in mired (1e6 / T), the perceptually even scale;
    ``fluorescent`` draws one of F1-F12 and reports its McCamy CCT.
    """
    defaults = {"daylight": (4000.0, 25000.0), "blackbody": (2000.0, 10000.0), "led": (2700.0, 6500.0)}
    if kind not in ILLUMINANT_KINDS:
        raise ValueError(f"kind: expected one of {ILLUMINANT_KINDS}, got {kind!r}")
    w, key = _grid(wavelengths_nm)
    dtype = _out_dtype(w)
    u = uniform01(generator)
    if kind == "fluorescent":
        num = randint_scalar(1, 13, generator)
        spd = _fluorescent_table(key)[num - 1].copy()
        return _to_torch(spd, dtype, w.device), _fluorescent_cct(num), f"F{num}"
    lo, hi = cct_range_k if cct_range_k is not None else defaults[kind]
    if not 0 < lo <= hi:
        raise ValueError(f"cct_range_k: expected 0 < lo <= hi, got {(lo, hi)}")
    mired = 1e6 / hi + u * (1e6 / lo - 1e6 / hi)
    cct = 1e6 / mired
    # The public functions' numpy path, called directly on the CCT. The spectrum is computed for the CCT rounded
    # to torch's default dtype (float32 by default), as ``torch.tensor([cct])`` did before; the rounding moves the
    # CCT by < 1e-7 relative.
    t = np.array([cct], dtype=_NP_DTYPES.get(torch.get_default_dtype(), np.float64)).astype(np.float64)
    with np.errstate(all="ignore"):
        if kind == "daylight":
            spd = _daylight(t, key, np)
        elif kind == "blackbody":
            spd = _blackbody(t[:, None], key, np)
        else:
            spd = _led(t, *_led_params(t, None, None, None, np), key, None, np)
    out = _to_torch(spd[0], dtype, w.device)
    return (_check_planck_range(out, "cct_range_k", [cct]) if kind == "blackbody" else out), cct, kind


# ------------------------------------------------------------------------------------------------
# Natural palettes and camera sensitivities (the natural-scene generator, :mod:`.natural`)


def measured_reflectances(wavelengths_nm, *, dtype=torch.float64) -> torch.Tensor:
    """The measured reflectances shipped by colour-science (ColorCheckers: BabelColor, N Ohta, ISO 17321-1, PMC;
    CIE 1995 TCS; NIST CQS 9.0 VS) resampled to the grid: ``[N, L]`` in [0, 1]."""
    check_float_dtype(dtype)
    w, _ = _grid(wavelengths_nm)
    wave, r = _measured_reflectances()
    out = spectral.resample(torch.from_numpy(r), torch.from_numpy(wave), w.to(torch.float64))
    return out.clamp(0.0, 1.0).to(dtype)


@tensor_cache(maxsize=16)  # (outside inference mode: a basis first made under it refused every later gradient)
def _srgb_basis(grid: tuple) -> torch.Tensor:
    from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as basis

    b = torch.from_numpy(np.asarray(basis.values, dtype=np.float64)).T  # [3, M], columns R, G, B
    src = torch.from_numpy(np.asarray(basis.wavelengths, dtype=np.float64))
    return spectral.resample(b, src, torch.tensor(grid, dtype=torch.float64))


def srgb_basis_spectra(wavelengths_nm) -> torch.Tensor:
    """Mallett & Yuksel's sRGB basis spectra ``[3, L]`` (``colour.recovery``, "Spectral primary decomposition for
    rendering with sRGB reflectance", EGSR 2019): a linear sRGB triplet ``c`` in [0, 1] is the reflectance
    ``c @ basis``, in [0, 1] at every wavelength, whose sRGB under D65 is ``c`` (the decomposition is linear, so
    an RGB image lifts to a factored spectral image of three maps)."""
    _, key = _grid(wavelengths_nm)
    return _srgb_basis(key).clone()  # (the caller's own: an in-place edit changed every later call's basis)


#: the default saturation Beta(a, b) and albedo range of :func:`recovery_reflectances` (and its batched draw)
RECOVERY_CHROMA_BETA, RECOVERY_ALBEDO_RANGE = (1.2, 4.0), (0.03, 0.9)


def hsv_reflectances(hue: torch.Tensor, sat: torch.Tensor, val: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """Reflectances ``[..., L]`` of linear-sRGB colours given in HSV (hue, saturation, value ``[...]`` in [0, 1]; the
    HSV -> RGB of Smith 1978) lifted by Mallett & Yuksel's basis (:func:`srgb_basis_spectra`), clipped to [0, 1],
    float64 on the colours' device."""
    h6 = hue * 6.0
    k = torch.stack([(5.0 + h6) % 6, (3.0 + h6) % 6, (1.0 + h6) % 6], -1)
    rgb = val[..., None] * (1 - sat[..., None] * torch.clamp(torch.minimum(k, 4 - k), 0, 1))
    w, _ = _grid(wavelengths_nm)
    return (rgb @ srgb_basis_spectra(w.cpu()).to(rgb.device)).clamp(0.0, 1.0)


def recovery_reflectances(n: int, wavelengths_nm, generator: torch.Generator, *,
                          chroma_beta=RECOVERY_CHROMA_BETA, albedo_range=RECOVERY_ALBEDO_RANGE) -> torch.Tensor:
    """``n`` reflectances ``[n, L]`` of natural chromaticities upsampled with ``colour.recovery`` (the linear
    Mallett & Yuksel 2019 sRGB basis, :func:`srgb_basis_spectra`).

    Colours are drawn in HSV of linear sRGB: hue uniform, saturation ~ Beta(``chroma_beta``) (most natural
    surfaces are weakly saturated; the default's mean is 0.23), value (albedo) log-uniform in ``albedo_range``.
    """
    if not 0 < albedo_range[0] < albedo_range[1] <= 1:
        raise ValueError(f"albedo_range: expected 0 < lo < hi <= 1, got {albedo_range}")
    if len(chroma_beta) != 2 or not all(math.isfinite(float(v)) and float(v) > 0 for v in chroma_beta):
        raise ValueError(f"chroma_beta: expected two positive Beta parameters (a, b), got {chroma_beta!r} (the "
                         f"inverse CDF is NaN otherwise)")
    hue = torch.rand(n, generator=generator, dtype=torch.float64)
    from scipy.stats import beta as _beta

    # Beta by inverse CDF of a uniform draw: every random number comes from the generator
    u = torch.rand(n, generator=generator, dtype=torch.float64).numpy()
    sat = torch.from_numpy(_beta.ppf(u, float(chroma_beta[0]), float(chroma_beta[1])))
    lo, hi = (math.log(v) for v in albedo_range)
    val = torch.exp(lo + (hi - lo) * torch.rand(n, generator=generator, dtype=torch.float64))
    w, _ = _grid(wavelengths_nm)
    return hsv_reflectances(hue, sat, val, w).to(_out_dtype(w))


#: measured camera sensitivities shipped by colour-science (NPL measurements) usable by name
CAMERA_SENSITIVITY_NAMES = ("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)")


def camera_sensitivities(name: str, wavelengths_nm) -> torch.Tensor:
    """Channel sensitivities ``[3, L]`` (peak 1) of a measured camera (``CAMERA_SENSITIVITY_NAMES``), or
    ``"srgb"``: the CIE 1931 CMFs through the IEC 61966-2-1 XYZ -> linear sRGB matrix (a camera whose
    white-balanced output is linear sRGB; negative lobes kept)."""
    w, key = _grid(wavelengths_nm)
    if name == "srgb":
        from ..image import XYZ_TO_LINEAR_SRGB

        return torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ spectral.cmfs(w.to(torch.float64),
                                                                                   dtype=torch.float64)
    if name not in CAMERA_SENSITIVITY_NAMES:
        raise ValueError(f"name: expected one of {CAMERA_SENSITIVITY_NAMES + ('srgb',)}, got {name!r}")
    import colour

    m = colour.characterisation.MSDS_CAMERA_SENSITIVITIES[name]
    s = spectral.resample(torch.tensor(np.asarray(m.values), dtype=torch.float64).T,
                          torch.tensor(np.asarray(m.wavelengths), dtype=torch.float64), w.to(torch.float64))
    return s / s.max()


def random_sensitivities(wavelengths_nm, generator: torch.Generator, kinds: dict | None = None) -> torch.Tensor:
    """Channel sensitivities ``[3, L]`` of a random camera: a measured one (:data:`CAMERA_SENSITIVITY_NAMES`),
    the sRGB CMF camera, or a random Gaussian triplet (peaks 455/540/605 nm +- 15 nm, widths 25-50 nm), chosen
    with ``kinds`` weights (default measured 0.35, srgb 0.35, gaussian 0.3)."""
    kinds = dict(kinds or {"measured": 0.35, "srgb": 0.35, "gaussian": 0.3})
    bad = set(kinds) - {"measured", "srgb", "gaussian"}
    if bad or not kinds or min(kinds.values()) < 0 or sum(kinds.values()) <= 0:
        raise ValueError(f"kinds: expected non-negative weights of 'measured', 'srgb', 'gaussian', got {kinds}")
    names = list(kinds)
    w = torch.tensor([float(kinds[k]) for k in names], dtype=torch.float64)
    kind = names[int(torch.multinomial(w / w.sum(), 1, generator=generator))]
    wl, _ = _grid(wavelengths_nm)
    if kind == "measured":
        i = int(torch.randint(0, len(CAMERA_SENSITIVITY_NAMES), (), generator=generator))
        return camera_sensitivities(CAMERA_SENSITIVITY_NAMES[i], wl)
    if kind == "srgb":
        return camera_sensitivities("srgb", wl)
    peaks = torch.tensor([455.0, 540.0, 605.0], dtype=torch.float64) + 15 * torch.randn(3, generator=generator,
                                                                                         dtype=torch.float64)
    widths = 25.0 + 25.0 * torch.rand(3, generator=generator, dtype=torch.float64)
    return torch.exp(-0.5 * ((wl.to(torch.float64)[None] - peaks[:, None]) / widths[:, None]) ** 2)
