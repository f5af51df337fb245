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
from .._checks import check_wavelengths

__all__ = [
    "reflectance_basis",
    "random_reflectances",
    "sigmoid_polynomial_reflectance",
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


def _key(w: torch.Tensor) -> tuple:
    return tuple(float(x) for x in w.detach().double().cpu().tolist())


_VALID_GRIDS: set = set()


def _checked(wavelengths_nm) -> torch.Tensor:
    """``check_wavelengths`` once per distinct grid (a scene calls the spectra functions ~8 times on the same
    grid; each full check costs ~40 us of small tensor ops). A grid is remembered by its exact values, dtype and
    device, so an invalid grid (NaN never equals itself) is always checked, and raises."""
    w = torch.as_tensor(wavelengths_nm)
    if w.dim() != 1:
        return check_wavelengths(w)
    key = (w.dtype, str(w.device), tuple(w.detach().cpu().tolist()))
    if key not in _VALID_GRIDS:
        check_wavelengths(w)
        if len(_VALID_GRIDS) > 256:  # bounded
            _VALID_GRIDS.clear()
        _VALID_GRIDS.add(key)
    return w


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


@functools.lru_cache(maxsize=64)
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

    The basis is fitted (SVD) on 400-700 nm; outside that range it is 0 (see `spectral.resample`).
    """
    w = _checked(wavelengths_nm)
    if not 1 <= n_components <= 12:
        raise ValueError(f"n_components: expected 1..12 principal components, got {n_components}")
    dtype = dtype or (w.dtype if w.is_floating_point() else torch.get_default_dtype())
    return _pca_on_grid(int(n_components), _key(w), dtype, str(device or w.device))


def _pca_reflectances(n: int, w: torch.Tensor, generator: torch.Generator, spread: float = 1.0,
                      margin: float = 1e-3) -> torch.Tensor:
    mean, basis, std = reflectance_basis(w, dtype=w.dtype, device=w.device)
    coef = torch.randn(n, std.numel(), generator=generator, dtype=w.dtype).to(w.device) * std * spread
    dev = coef @ basis  # [n, L]
    # Largest alpha <= 1 keeping mean + alpha * dev inside [margin, 1 - margin] (mean is strictly inside).
    up = torch.where(dev > 0, (1 - margin - mean) / dev.clamp_min(1e-12), torch.full_like(dev, math.inf))
    lo = torch.where(dev < 0, (mean - margin) / (-dev).clamp_min(1e-12), torch.full_like(dev, math.inf))
    alpha = torch.minimum(up, lo).amin(dim=1, keepdim=True).clamp(max=1.0)
    return mean + alpha * dev


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
    x = c[:, :1] * u**2 + c[:, 1:2] * u + c[:, 2:3]
    return 0.5 + x / (2 * torch.sqrt(1 + x * x))  # Jakob & Hanika 2019, eq. 2


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
    w = _checked(wavelengths_nm)
    if model not in ("pca", "sigmoid", "mixed"):
        raise ValueError(f"model: expected 'pca', 'sigmoid' or 'mixed', got {model!r}")
    dtype = w.dtype if w.is_floating_point() else torch.get_default_dtype()
    w = w.to(dtype)
    pca = _pca_reflectances(n, w, generator)
    # Coefficient scales chosen so spectra range from flat greys to saturated, single-peaked colours.
    coef = torch.randn(n, 3, generator=generator, dtype=dtype) * torch.tensor([3.0, 2.5, 1.5], dtype=dtype)
    sig = sigmoid_polynomial_reflectance(coef.to(w.device), w)
    pick = torch.rand(n, 1, generator=generator, dtype=dtype).to(w.device)
    if model == "pca":
        return pca
    if model == "sigmoid":
        return sig
    return torch.where(pick < pca_fraction, pca, sig)


# ------------------------------------------------------------------------------------------------
# Illuminants (energy units, relative)


@functools.lru_cache(maxsize=64)
def _daylight_basis(grid: tuple, dtype, device: str) -> torch.Tensor:
    from colour.colorimetry import SDS_BASIS_FUNCTIONS_CIE_ILLUMINANT_D_SERIES as S

    src = torch.tensor(np.asarray(S["S0"].wavelengths, float))
    vals = torch.tensor(np.stack([np.asarray(S[k].values, float) for k in ("S0", "S1", "S2")]))
    return spectral.resample(vals, src, torch.tensor(grid, dtype=torch.float64)).to(dtype=dtype, device=device)


def daylight_spd(cct_k: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE daylight ``[N, L]`` for CCTs ``[N]`` in [4000, 25000] K (energy, S(560) ~ 100).

    Source: CIE 015:2018 eqs. 4.7-4.12 (x_D polynomials in 1/T, y_D = -3 x^2 + 2.87 x - 0.275, M1, M2),
    the same convention as ``colour.temperature.CCT_to_xy_CIE_D`` (6504 K gives D65).
    """
    w = _checked(wavelengths_nm)
    t = torch.as_tensor(cct_k, dtype=torch.float64).reshape(-1)
    if ((t < 4000) | (t > 25000)).any():
        raise ValueError(f"cct_k: expected daylight CCTs in [4000, 25000] K, got {t.tolist()}")
    xd = torch.where(t <= 7000,
                     -4.6070e9 / t**3 + 2.9678e6 / t**2 + 0.09911e3 / t + 0.244063,
                     -2.0064e9 / t**3 + 1.9018e6 / t**2 + 0.24748e3 / t + 0.237040)
    yd = -3.0 * xd**2 + 2.870 * xd - 0.275
    m = 0.0241 + 0.2562 * xd - 0.7341 * yd
    m1 = (-1.3515 - 1.7703 * xd + 5.9114 * yd) / m
    m2 = (0.0300 - 31.4424 * xd + 30.0717 * yd) / m
    b = _daylight_basis(_key(w), torch.float64, "cpu")
    spd = b[0] + m1[:, None] * b[1] + m2[:, None] * b[2]
    dtype = w.dtype if w.is_floating_point() else torch.get_default_dtype()
    return spd.to(dtype=dtype, device=w.device)


def blackbody_spd(temperature_k: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """Planck spectra ``[N, L]`` (energy, 100 at 560 nm). Source: Planck's law (CODATA h, c, k)."""
    from .. import constants

    w = _checked(wavelengths_nm)
    t = torch.as_tensor(temperature_k, dtype=torch.float64).reshape(-1, 1)
    if (t <= 0).any() or not torch.isfinite(t).all():
        raise ValueError(f"temperature_k: expected positive temperatures, got {t.flatten().tolist()}")
    h, c, k = constants.PLANCK_J_S, constants.SPEED_OF_LIGHT_M_PER_S, constants.BOLTZMANN_J_PER_K
    lam = w.to(torch.float64).cpu() * 1e-9
    planck = 2 * h * c**2 / lam**5 / torch.expm1(h * c / (lam * k * t))
    ref = 2 * h * c**2 / 560e-9**5 / torch.expm1(h * c / (560e-9 * k * t))
    dtype = w.dtype if w.is_floating_point() else torch.get_default_dtype()
    return (100.0 * planck / ref).to(dtype=dtype, device=w.device)


@functools.lru_cache(maxsize=16)
def _fluorescent_table(grid: tuple) -> torch.Tensor:
    w = torch.tensor(grid, dtype=torch.float64)
    return torch.stack([spectral.illuminant(f"F{i}", w, dtype=torch.float64) for i in range(1, 13)])


def fluorescent_spd(numbers: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE fluorescent illuminants F<n> (n in 1..12) ``[N, L]`` (colour-science tables)."""
    w = _checked(wavelengths_nm)
    nums = [int(x) for x in torch.as_tensor(numbers).reshape(-1).tolist()]
    bad = [x for x in nums if not 1 <= x <= 12]
    if bad:
        raise ValueError(f"numbers: expected CIE fluorescent numbers 1..12, got {bad}")
    table = _fluorescent_table(_key(w))
    dtype = w.dtype if w.is_floating_point() else torch.get_default_dtype()
    return table[torch.tensor(nums) - 1].to(dtype=dtype, device=w.device)


_FINE = torch.arange(380.0, 781.0, 5.0, dtype=torch.float64)


def _led_parts(w: torch.Tensor, pump_nm: torch.Tensor, phosphor_nm: torch.Tensor, phosphor_fwhm_nm: torch.Tensor):
    lam = w.to(torch.float64).cpu()[None]
    # Blue InGaN pump ~20 nm FWHM; YAG-like phosphor modelled as a broad Gaussian (Schubert, "Light-Emitting
    # Diodes", 2nd ed., ch. 21: phosphor-converted white LEDs).
    pump = torch.exp(-4 * math.log(2) * ((lam - pump_nm[:, None]) / 20.0) ** 2)
    phos = torch.exp(-4 * math.log(2) * ((lam - phosphor_nm[:, None]) / phosphor_fwhm_nm[:, None]) ** 2)
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
def _cmf_weights(grid: tuple) -> torch.Tensor:
    """CIE 1931 CMFs times the integration weights on a grid, float64 [3, L] (for fast repeated integrals)."""
    w = torch.tensor(grid, dtype=torch.float64)
    return spectral.cmfs(w, dtype=torch.float64) * spectral.wavelength_weights(w)


def _uv(spd_energy: torch.Tensor, wavelengths_nm) -> torch.Tensor:
    """CIE 1960 UCS uv ``[N, 2]``: u = 4X / (X + 15Y + 3Z), v = 6Y / (X + 15Y + 3Z) (CIE 015:2018)."""
    x, y, z = (spd_energy.to(torch.float64) @ _cmf_weights(_key(torch.as_tensor(wavelengths_nm))).T).unbind(-1)
    d = x + 15 * y + 3 * z
    return torch.stack([4 * x / d, 6 * y / d], dim=-1)


def led_spd(cct_k: torch.Tensor, wavelengths_nm, *, pump_nm=None, phosphor_nm=None, phosphor_fwhm_nm=None,
            iterations: int | None = None) -> torch.Tensor:
    """Phosphor-converted white LED ``[N, L]`` (energy, peak 100) whose CCT is ``cct_k`` [N].

    The pump : phosphor ratio ``r`` puts the LED on the isotemperature line of ``cct_k`` (more phosphor lowers
    the CCT). Defaults: pump 450 nm, phosphor ``560 + 0.012 (6500 - T)`` nm (555-610) with 120 nm FWHM.
    ``iterations=None`` (default) solves for ``r`` in closed form (exact: the condition is linear in ``r``, see
    the comment below); an integer runs the former bisection in ``log r`` with that many steps (26 gave
    ``|d log r| <= 1.3e-7``).
    """
    w = _checked(wavelengths_nm)
    t = torch.as_tensor(cct_k, dtype=torch.float64).reshape(-1)
    n = t.numel()

    def per(v, default):
        return torch.full((n,), default, dtype=torch.float64) if v is None else \
            torch.as_tensor(v, dtype=torch.float64).reshape(-1).expand(n)

    if phosphor_nm is None:  # warm-white LEDs use red-shifted phosphors
        phosphor_nm = (560.0 + 0.012 * (6500.0 - t)).clamp(555.0, 610.0)
    pump, phos = _led_parts(w, per(pump_nm, 450.0), per(phosphor_nm, 565.0), per(phosphor_fwhm_nm, 120.0))
    # The CCT is defined by the isotemperature line: the normal to the Planckian locus in CIE 1960 uv
    # through the locus point at T (CIE 015:2018 sec. 9.5). Mixing is linear in XYZ, so the LED's uv moves on
    # a straight segment from pump to phosphor and the signed distance along the locus tangent is monotone
    # in the ratio: bisection in log(phosphor / pump), evaluated on a fine 5 nm grid (independent of the scene's).
    fine = _FINE
    fpump, fphos = _led_parts(fine, per(pump_nm, 450.0), per(phosphor_nm, 565.0), per(phosphor_fwhm_nm, 120.0))
    uv_t = _uv(blackbody_spd(t, fine), fine)
    fine_key = _key(fine)
    cw = _cmf_weights(fine_key).T
    tangent = _uv(blackbody_spd(t * 1.001, fine), fine) - _uv(blackbody_spd(t / 1.001, fine), fine)
    if iterations is None:
        # Closed form. With XYZ_s = cmf . spd_s (s = pump, phosphor) and D = X + 15 Y + 3 Z, the mixture
        # pump + r phosphor has uv = (4 X, 6 Y) / D with X = X_p + r X_f, ... (CIE 015:2018), so
        # D(r) ((uv(r) - uv_t) . tangent) = A_p + r A_f, A_s = (4 X_s - u_t D_s) t_u + (6 Y_s - v_t D_s) t_v:
        # D > 0, hence the isotemperature condition is linear in r and r = -A_p / A_f (exact). As the
        # bisection did, log r is kept in [-8, 10] (an unreachable CCT gives the nearest end).
        xyz_p, xyz_f = fpump @ cw, fphos @ cw  # [N, 3]

        def lin(xyz):
            d = xyz[:, 0] + 15 * xyz[:, 1] + 3 * xyz[:, 2]
            return ((4 * xyz[:, 0] - uv_t[:, 0] * d) * tangent[:, 0]
                    + (6 * xyz[:, 1] - uv_t[:, 1] * d) * tangent[:, 1])

        a_p, a_f = lin(xyz_p), lin(xyz_f)
        r = -a_p / a_f
        # too hot (A_p + r A_f > 0) for every r > 0 -> the upper end; never too hot -> the lower end
        hot_everywhere = (a_f >= 0) & (a_p + a_f > 0) | (r <= 0) & (a_p > 0)
        log_r = torch.where(r > 0, torch.log(r.clamp_min(1e-300)), torch.full_like(r, -math.inf))
        log_r = torch.where(hot_everywhere, torch.full_like(r, 10.0), log_r).clamp(-8.0, 10.0)
        spd = pump + torch.exp(log_r)[:, None] * phos
    else:
        lo = torch.full((n,), -8.0, dtype=torch.float64)
        hi = torch.full((n,), 10.0, dtype=torch.float64)
        for _ in range(int(iterations)):
            mid = (lo + hi) / 2
            x, y, z = ((fpump + torch.exp(mid)[:, None] * fphos) @ cw).unbind(-1)
            d = x + 15 * y + 3 * z
            uv = torch.stack([4 * x / d, 6 * y / d], dim=-1)
            too_hot = ((uv - uv_t) * tangent).sum(dim=1) > 0  # need more phosphor
            lo = torch.where(too_hot, mid, lo)
            hi = torch.where(too_hot, hi, mid)
        spd = pump + torch.exp((lo + hi) / 2)[:, None] * phos
    spd = 100 * spd / spd.amax(dim=1, keepdim=True)
    dtype = w.dtype if w.is_floating_point() else torch.get_default_dtype()
    return spd.to(dtype=dtype, device=w.device)


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
    w = _checked(wavelengths_nm)
    u = float(torch.rand((), generator=generator, dtype=torch.float64))
    if kind == "fluorescent":
        num = int(torch.randint(1, 13, (), generator=generator))
        spd = fluorescent_spd(torch.tensor([num]), w)[0]
        cct = _fluorescent_cct(num)
        return spd, cct, f"F{num}"
    lo, hi = cct_range_k if cct_range_k is not None else defaults[kind]
    if not 0 < lo <= hi:
        raise ValueError(f"cct_range_k: expected 0 < lo <= hi, got {(lo, hi)}")
    mired = 1e6 / hi + u * (1e6 / lo - 1e6 / hi)
    cct = 1e6 / mired
    fn = {"daylight": daylight_spd, "blackbody": blackbody_spd, "led": led_spd}[kind]
    return fn(torch.tensor([cct]), w)[0], cct, kind
