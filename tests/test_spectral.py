"""Spectral core against analytic values and colour-science."""

import math

import colour
import numpy as np
import pytest
import torch

from isettorch import constants, spectral


def test_683_cd_per_m2_at_555nm():
    w = torch.tensor([555.0], dtype=torch.float64)
    photons = spectral.energy_to_photons(torch.ones(1, 1, 1, dtype=torch.float64), w, dim=0)
    lum = spectral.luminance(photons, w, dim=0)
    # V(555) = 1 in the CIE 1924 table; 1 W/sr/m^2/nm over the 1 nm bin of a single-wavelength grid.
    assert lum.item() == pytest.approx(683.0, rel=1e-12)  # Km = 683 lm/W exactly (SI candela definition)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_photon_energy_round_trip(dtype):
    w = spectral.default_wavelengths(380, 780, 5, dtype=dtype)
    x = torch.rand(2, w.numel(), 3, 4, dtype=dtype) * 1e17
    back = spectral.energy_to_photons(spectral.photons_to_energy(x, w, dim=1), w, dim=1)
    assert torch.allclose(back, x, rtol=1e-6, atol=0)


def test_photon_energy_value():
    w = torch.tensor([500.0], dtype=torch.float64)
    e = spectral.photons_to_energy(torch.ones(1, dtype=torch.float64), w, dim=0)
    expected = constants.PLANCK_J_S * constants.SPEED_OF_LIGHT_M_PER_S / 500e-9
    assert e.item() == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(("step", "rtol"), [(1, 2e-5), (5, 2e-5), (10, 2e-5), (20, 2e-3)])
def test_uniform_luminance_independent_of_step(step, rtol):
    # Equal-energy radiance of 1e-3 W/sr/m^2/nm: the luminance is 683 * integral V = 683 * 106.857 * 1e-3.
    w = spectral.default_wavelengths(380, 780, step, dtype=torch.float64)
    e = torch.full((w.numel(), 1, 1), 1e-3, dtype=torch.float64)
    lum = spectral.luminance(spectral.energy_to_photons(e, w, dim=0), w, dim=0).item()
    v = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    reference = 683.0 * 1e-3 * np.trapezoid(v.values, v.wavelengths)
    # the trapezoid rule on the step's samples of the 1 nm table: 1e-5 or better to 10 nm, 1e-3 at 20 nm
    assert lum == pytest.approx(reference, rel=rtol)


def test_resample_linear_and_zero_outside():
    src = torch.tensor([400.0, 500.0, 600.0])
    vals = torch.tensor([[0.0, 1.0, 3.0]])
    out = spectral.resample(vals, src, torch.tensor([390.0, 400.0, 450.0, 550.0, 600.0, 601.0]))
    assert torch.allclose(out, torch.tensor([[0.0, 0.0, 0.5, 2.0, 3.0, 0.0]]))


def test_resample_matches_numpy_on_nonuniform_grid():
    rng = np.random.default_rng(0)
    src = np.sort(rng.uniform(380, 780, 40))
    vals = rng.random(40)
    dst = np.sort(rng.uniform(src[0], src[-1], 57))
    out = spectral.resample(torch.from_numpy(vals), torch.from_numpy(src), torch.from_numpy(dst)).numpy()
    assert np.allclose(out, np.interp(dst, src, vals), atol=1e-12)


def test_wavelength_weights_nonuniform():
    w = torch.tensor([400.0, 410.0, 430.0, 460.0])
    assert torch.allclose(spectral.wavelength_weights(w), torch.tensor([10.0, 15.0, 25.0, 30.0]))
    assert spectral.wavelength_weights(torch.tensor([550.0])).item() == 1.0


def test_luminance_on_nonuniform_grid_matches_fine_grid():
    fine = spectral.default_wavelengths(400, 700, 1, dtype=torch.float64)
    # a jittered grid with steps between 2 and 8 nm
    steps = torch.from_numpy(np.random.default_rng(1).uniform(2, 8, 200))
    coarse = 400 + torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.float64), steps]), 0)
    coarse = coarse[coarse <= 700]
    d65 = spectral.illuminant("blackbody5000", fine)
    d65_c = spectral.illuminant("blackbody5000", coarse)
    lf = spectral.luminance(spectral.energy_to_photons(d65, fine, dim=0), fine, dim=0)
    lc = spectral.luminance(spectral.energy_to_photons(d65_c, coarse, dim=0), coarse, dim=0)
    assert abs(lc.item() / lf.item() - 1) < 5e-3


def test_cmfs_match_colour_science():
    w = spectral.default_wavelengths(380, 780, 5, dtype=torch.float64)
    ref = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"].copy().align(
        colour.SpectralShape(380, 780, 5)).values.T
    assert np.allclose(spectral.cmfs(w, "1964").numpy(), ref, atol=1e-12)


def test_illuminants():
    w = spectral.default_wavelengths(400, 700, 10, dtype=torch.float64)
    d65 = spectral.illuminant("D65", w).numpy()
    assert np.allclose(d65, colour.SDS_ILLUMINANTS["D65"][w.numpy()], rtol=1e-9)
    # D6504 on the modern scale is D65 (CIE 015:2018 note); the tabulated D65 is rounded, so ~1e-3.
    assert np.allclose(spectral.illuminant("D6504", w).numpy(), d65, rtol=5e-3)
    w5 = spectral.default_wavelengths(380, 780, 5, dtype=torch.float64)  # the CIE table's own grid: its values
    f2 = spectral.illuminant("F2", w5).numpy()
    assert np.allclose(f2, colour.SDS_ILLUMINANTS["FL2"][w5.numpy()], rtol=1e-12)
    # Planck: the peak of a 5000 K blackbody is at 2.897771955e-3 / 5000 m = 579.55 nm (Wien).
    fine = spectral.default_wavelengths(400, 700, 0.5, dtype=torch.float64)
    bb = spectral.illuminant("blackbody5000", fine)
    assert abs(fine[bb.argmax()].item() - 579.55) <= 0.5
    ep = spectral.energy_to_photons(spectral.illuminant("equal_photon", w), w, dim=0)
    assert torch.allclose(ep, ep[0].expand_as(ep), rtol=1e-12)


def test_daylight_cct_chromaticity():
    w = spectral.default_wavelengths(360, 830, 5, dtype=torch.float64)
    for cct in (4000, 5500, 10000):
        spd = spectral.illuminant(f"D{cct}", w).numpy()
        sd = colour.SpectralDistribution(dict(zip(w.numpy(), spd)))
        xy = colour.XYZ_to_xy(colour.sd_to_XYZ(sd))
        got = colour.temperature.xy_to_CCT(xy, method="CIE Illuminant D Series")
        assert abs(got - cct) / cct < 0.01


def test_cie_illuminants_reach_830_nm():
    """CIE 015:2018 defines D65, D50, D55, D75 and A to 830 nm; colour-science's tables end at 780, where they fell
    to 0. Past 780 nm: A is its defining Planck formula (colour-science's sd_CIE_standard_illuminant_A), the D
    illuminants the daylight model at their CCT, within 0.1 % of the named CCT's model ('D6504') everywhere."""
    w = spectral.default_wavelengths(380, 830, 10, dtype=torch.float64)
    d65, d6504 = spectral.illuminant("D65", w), spectral.illuminant("D6504", w)
    assert bool((d65 > 0).all())
    torch.testing.assert_close(d65, d6504, rtol=1e-3, atol=0)
    a = spectral.illuminant("A", w).numpy()
    ref = colour.sd_CIE_standard_illuminant_A(colour.SpectralShape(380, 830, 10)).values
    np.testing.assert_allclose(a, ref, rtol=1e-4)  # the table (to 780) rounds the formula to 3 decimals
    inside = spectral.default_wavelengths(400, 780, 10, dtype=torch.float64)  # the tables themselves, unchanged
    np.testing.assert_allclose(spectral.illuminant("D50", inside).numpy(),
                               colour.SDS_ILLUMINANTS["D50"][inside.numpy()], rtol=1e-12)


def test_band_average_bands_tile_a_nonuniform_grid():
    # bands from midpoint to midpoint (ends half a step out): a line between two samples keeps its power. Bands of
    # each sample's width centred on it overlapped on one side and left gaps: a line at 405.62 nm on 400, 403, 410,
    # 420 nm was lost (0 for 1)
    src = torch.tensor([380.0, 405.595, 405.62, 405.645, 780.0], dtype=torch.float64)
    line = torch.tensor([[0.0, 0.0, 40.0, 0.0, 0.0]], dtype=torch.float64)  # a triangle of area 40 x 0.025 = 1
    dst = torch.tensor([400.0, 403.0, 410.0, 420.0], dtype=torch.float64)
    out = spectral.band_average(line, src, dst)
    assert float((out * spectral.wavelength_weights(dst)).sum()) == pytest.approx(1.0, rel=1e-9)
    assert float(out[0, 1]) == pytest.approx(1.0 / 5.0, rel=1e-9)  # all in 403's band, 401.5-406.5 nm
    # F11 on a jittered 2-8 nm grid keeps the power of colour-science's table over the bands (the trapezoid of its
    # piecewise-linear knots, computed here with NumPy): it lost 2.1 %
    steps = torch.from_numpy(np.random.default_rng(1).uniform(2, 8, 200))
    g = 400 + torch.cumsum(torch.cat([torch.zeros(1, dtype=torch.float64), steps]), 0)
    g = g[g <= 700]
    lo, hi = float(g[0] - (g[1] - g[0]) / 2), float(g[-1] + (g[-1] - g[-2]) / 2)
    sd = colour.SDS_ILLUMINANTS["FL11"]
    x = np.linspace(lo, hi, 400001)
    power = np.trapezoid(np.interp(x, sd.wavelengths, sd.values, left=0, right=0), x)
    got = float((spectral.illuminant("F11", g) * spectral.wavelength_weights(g)).sum())
    assert got == pytest.approx(power, rel=1e-6)


@pytest.mark.parametrize("name", ["F2", "F7", "F11"])
@pytest.mark.parametrize("step", [10.0, 20.0])
def test_fluorescent_lines_keep_their_power_on_coarse_grids(name, step):
    """A line spectrum on a grid coarser than its 5 nm table: each sample is its band's mean power (the table's
    bands), so the power is kept and the white's chromaticity stays near CIE 015's (colour-science's
    CCS_ILLUMINANTS); point samples at 10 nm missed the 435 and 545 nm mercury lines (F2 0.024 off in xy, F11 0.029)."""
    fine = spectral.default_wavelengths(380, 775, 5, dtype=torch.float64)  # bands tiling 377.5-777.5 nm
    coarse = spectral.default_wavelengths(377.5 + step / 2, 777.5 - step / 2, step, dtype=torch.float64)
    e5, ec = spectral.illuminant(name, fine), spectral.illuminant(name, coarse)
    assert float(ec.sum() * step) == pytest.approx(float(e5.sum() * 5), rel=1e-12)  # the same bands, the same power
    w = spectral.default_wavelengths(400, 700, 10, dtype=torch.float64)
    cmf = spectral.cmfs(w, dtype=torch.float64)
    xyz = (cmf * spectral.illuminant(name, w)).sum(-1)
    xy = (xyz[:2] / xyz.sum()).numpy()
    ref = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][f"FL{name[1:]}"]
    assert np.hypot(*(xy - ref)) < 1.5e-3  # D65 on this 400-700 nm grid: 3e-4


@pytest.mark.parametrize("bad,match", [
    ("D65x", "unknown illuminant"),
    ("D1000", "cct_k"),
    ("blackbody-5", "temperature"),
])
def test_bad_illuminant_names(bad, match):
    with pytest.raises(ValueError, match=match):
        spectral.illuminant(bad, spectral.default_wavelengths())


def test_bad_grids():
    with pytest.raises(ValueError, match="strictly increasing"):
        spectral.resample(torch.ones(3), torch.tensor([400.0, 500.0, 450.0]), torch.tensor([420.0]))
    with pytest.raises(ValueError, match="src_nm"):
        spectral.resample(torch.ones(3), torch.tensor([400.0, 500.0]), torch.tensor([420.0]))
    with pytest.raises(ValueError, match="finite"):
        spectral.wavelength_weights(torch.tensor([400.0, float("nan")]))
    with pytest.raises(ValueError, match="observer"):
        spectral.cmfs(spectral.default_wavelengths(), "1950")


def test_resample_is_differentiable():
    src = torch.tensor([400.0, 500.0, 600.0], dtype=torch.float64)
    vals = torch.rand(3, dtype=torch.float64, requires_grad=True)
    dst = torch.tensor([420.0, 590.0], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda v: spectral.resample(v, src, dst), (vals,))


def test_a_cold_blackbody_is_finite_and_wiens_law():
    """Below about 36 K both Planck radiances underflow at 560 nm and the normalised spectrum was 0 / 0 = NaN. At
    10 K, where c2 / (lambda T) is above 2000, Planck is Wien's law B ~ lambda^-5 exp(-c2 / (lambda T)) to
    exp(-2000): the ratio to 560 nm in closed form (it underflows to 0 at the short wavelengths, as it should)."""
    import math

    from isettorch import constants

    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    got = spectral.blackbody(10.0, w, dtype=torch.float64)
    c2 = constants.PLANCK_J_S * constants.SPEED_OF_LIGHT_M_PER_S / constants.BOLTZMANN_J_PER_K
    log_wien = [math.log(100.0) + 5 * math.log(560.0 / lam) + c2 / 10.0 * (1 / 560e-9 - 1 / (lam * 1e-9))
                for lam in w.tolist()]
    assert torch.isfinite(got).all()
    for g, lw in zip(got.tolist(), log_wien):
        assert g == (pytest.approx(math.exp(lw), rel=1e-11) if lw > -700 else 0.0)
    with pytest.raises(ValueError, match="temperature_k"):
        spectral.blackbody(True, w)


@pytest.mark.parametrize("dtype", [torch.int64, torch.float16])
def test_photometry_of_integer_or_half_photons_is_refused(dtype):
    """Integer photons gave a luminance of 0 (V(lambda) cast to int64) and half ones an XYZ of 0 (the energy, 1e-19,
    underflows float16): a ValueError naming the photons."""
    w = torch.arange(400.0, 701.0, 10.0)
    photons = (torch.full((31, 1, 1), 1e3)).to(dtype)
    for f in (spectral.luminance, spectral.xyz):
        with pytest.raises(ValueError, match=f"photons: expected torch.float32 or torch.float64, got {dtype}"):
            f(photons, w, dim=0)


def test_default_wavelengths_refuses_what_is_no_grid():
    """NaN bounds gave int()'s 'cannot convert float NaN', a bool step a 1 nm grid, 1e-12 nm a 1.2 PB allocation."""
    import math

    for kw, name in (({"step_nm": math.nan}, "step_nm"), ({"stop_nm": math.inf}, "stop_nm"),
                     ({"step_nm": True}, "step_nm"), ({"step_nm": 1e-12}, "step_nm")):
        with pytest.raises(ValueError, match=f"^{name}: "):
            spectral.default_wavelengths(**kw)
    assert spectral.default_wavelengths().tolist() == [400.0 + 10.0 * i for i in range(31)]


def test_resampling_helpers_refuse_grids_they_cannot_use():
    """resample_rows took values and knots of different lengths (3 on 2 gave 0.5) and decreasing knots (0);
    band_average a decreasing grid (all zeros); photons_to_energy h = 0 (zero energy)."""
    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    v = torch.ones(2, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match="src_nm: expected 3 knots per row"):
        spectral.resample_rows(v, torch.tensor([[500.0, 600.0]] * 2, dtype=torch.float64), w)
    with pytest.raises(ValueError, match="src_nm: expected finite, strictly increasing knots"):
        spectral.resample_rows(v, torch.tensor([[600.0, 550.0, 500.0]] * 2, dtype=torch.float64), w)
    with pytest.raises(ValueError, match="src_nm: expected a strictly increasing wavelength grid"):
        spectral.band_average(v, torch.tensor([600.0, 550.0, 500.0], dtype=torch.float64), w)
    for h in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="h: expected a finite constant > 0"):
            spectral.photons_to_energy(torch.ones(31, 1, 1), w, dim=0, h=h)


def test_light_temperatures_are_numbers():
    """A temperature given as text ('6500') raised a bare comparison TypeError naming nothing."""
    w = torch.arange(400.0, 701.0, 10.0)
    with pytest.raises(ValueError, match=r"cct_k: expected a daylight CCT in \[4000, 25000\] K, got '6500'"):
        spectral.daylight("6500", w)
    with pytest.raises(ValueError, match=r"temperature_k: expected a positive temperature in kelvin, got '6500'"):
        spectral.blackbody("6500", w)
    # one-value numbers of any kind are temperatures (a 0-d tensor or array, a NumPy scalar)
    for t in (torch.tensor(6500.0), np.array(6500.0), np.float32(6500.0)):
        torch.testing.assert_close(spectral.blackbody(t, w), spectral.blackbody(6500.0, w))
        torch.testing.assert_close(spectral.daylight(t, w), spectral.daylight(6500.0, w))
    from isettorch.scene.dead_leaves import dead_leaves

    with pytest.raises(ValueError, match=r"reflectance_range: expected \(low, high\), got \[0.5\]"):
        dead_leaves(16, reflectance_range=[0.5])


def test_spectral_inputs_that_gave_wrong_numbers_are_refused():
    """An integer spectrum was resampled with its interpolation weights rounded to 0 (450 nm between 0 and 10 read
    0, np.interp says 5); a blackbody whose ratio to 560 nm overflows the dtype was inf (5 K in float64, 60 K in
    float32, at 700 nm: e^1027 and e^88 exceed the formats); spectral_integral's weights on another grid raised a
    bare broadcasting error."""
    src, dst = torch.tensor([400.0, 500.0, 600.0]), torch.tensor([450.0, 550.0])
    np.testing.assert_allclose(spectral.resample(torch.tensor([[0.0, 10.0, 20.0]]), src, dst).numpy(),
                               [np.interp([450, 550], [400, 500, 600], [0, 10, 20])])
    for fn, args in ((spectral.resample, (src, dst)), (spectral.resample_rows, (src[None], dst))):
        with pytest.raises(ValueError, match="values: expected floating-point spectra, got torch.int64"):
            fn(torch.tensor([[0, 10, 20]]), *args)
    w = torch.tensor([400.0, 560.0, 700.0])
    for t, dtype in ((5.0, torch.float64), (60.0, torch.float32)):
        with pytest.raises(ValueError, match=f"temperature_k: at {t:g} K the spectrum relative to 560 nm overflows"):
            spectral.blackbody(t, w, dtype=dtype)
    assert torch.isfinite(spectral.blackbody(10.0, w, dtype=torch.float64)).all()  # the cold case that is finite
    assert torch.isfinite(spectral.blackbody(80.0, w, dtype=torch.float32)).all()
    with pytest.raises(ValueError, match=r"weights: expected \[K, 3\] on the 3 wavelengths"):
        spectral.spectral_integral(torch.ones(3, 1, 1), torch.ones(2, 4), torch.tensor([500.0, 550.0, 600.0]))


def test_band_average_holds_the_end_values_where_a_band_overhangs_the_data():
    # A constant table averages to itself in every band, the end samples' too (they were the mean with 0 beyond the
    # data: half). F2 (CIE 015, 380-780 nm at 5 nm) at 380 nm on 380:5:785 is the band 377.5-382.5 nm: 1.18 held
    # below 380, linear to 1.33 at 382.5 (halfway to 385 nm's 1.48): (7 x 1.18 + 1.48) / 8 = 1.2175, whatever
    # the grid beyond (it was 0.63 with a 785 nm sample, the table's 1.18 without). A sample beyond the data is 0.
    src = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    dst = torch.tensor([400.0, 403.0, 550.0, 697.0, 700.0, 705.0], dtype=torch.float64)
    out = spectral.band_average(torch.full((1, src.numel()), 2.5, dtype=torch.float64), src, dst)[0]
    torch.testing.assert_close(out, torch.tensor([2.5] * 5 + [0.0], dtype=torch.float64), rtol=1e-12, atol=0)
    for stop in (785.0, 790.0):
        w = torch.arange(380.0, stop + 1, 5.0, dtype=torch.float64)
        f2 = spectral.illuminant("F2", w, dtype=torch.float64)
        assert float(f2[0]) == pytest.approx((7 * 1.18 + 1.48) / 8, rel=1e-9)
        assert float(f2[-1]) == 0.0 and float(f2[w == 785.0][0]) == 0.0
