"""Random reflectances and illuminants, checked against colour-science."""

import colour
import numpy as np
import pytest
import torch

from isettorch.data import spectra

W5 = torch.arange(380.0, 781.0, 5.0, dtype=torch.float64)
W10 = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)


def _ohno_cct(spd: torch.Tensor, w: torch.Tensor) -> float:
    xy = spectra.chromaticity_xy(spd[None], w)[0].numpy()
    return float(colour.temperature.uv_to_CCT_Ohno2013(colour.xy_to_UCS_uv(xy))[0])


@pytest.mark.parametrize("model", ["pca", "sigmoid", "mixed"])
def test_reflectances_in_unit_interval_and_smooth(model):
    g = torch.Generator().manual_seed(1)
    r = spectra.random_reflectances(3000, W10, g, model=model)
    assert r.shape == (3000, 31)
    assert float(r.min()) >= 0.0 and float(r.max()) <= 1.0
    # as smooth as measured reflectances: 99 % of spectra have no second difference (10 nm grid) beyond the
    # largest one among the measured sets (colour-science's ColorCheckers, TCS, CQS; 0.131)
    d2 = (r[:, 2:] - 2 * r[:, 1:-1] + r[:, :-2]).abs().amax(dim=1)
    assert float(torch.quantile(d2, 0.99)) <= 0.131 and float(d2.max()) < 0.25
    # and diverse: they span most of [0, 1]
    assert float(r.min()) < 0.05 and float(r.max()) > 0.9


def test_pca_basis_reconstructs_measured_colorchecker():
    """Maloney (1986): a few (8) components describe measured reflectances; check on BabelColor patches."""
    mean, basis, _ = spectra.reflectance_basis(W10, 8, dtype=torch.float64)
    cc = colour.SDS_COLOURCHECKERS["BabelColor Average"]
    rmse = []
    for sd in cc.values():
        r = torch.tensor(np.interp(W10.numpy(), sd.wavelengths, sd.values))
        coef = torch.linalg.lstsq(basis.T, (r - mean)[:, None]).solution[:, 0]
        rmse.append(float(((mean + coef @ basis - r) ** 2).mean().sqrt()))
    assert max(rmse) < 0.02


def test_sigmoid_polynomial_matches_colour_jakob2019():
    c = torch.tensor([[3.0, -2.0, 0.5], [-8.0, 1.0, -1.0]], dtype=torch.float64)
    ours = spectra.sigmoid_polynomial_reflectance(c, W5)
    shape = colour.SpectralShape(380, 780, 5)
    for i in range(2):
        c0, c1, c2 = c[i].tolist()
        # (c0 u^2 + c1 u + c2), u = (l - 550) / 150, expanded in l (colour uses l in nm)
        a = c0 / 150**2
        b = -2 * c0 * 550 / 150**2 + c1 / 150
        cc = c0 * 550**2 / 150**2 - c1 * 550 / 150 + c2
        ref = colour.recovery.sd_Jakob2019(np.array([a, b, cc]), shape).values
        np.testing.assert_allclose(ours[i].numpy(), ref, rtol=0, atol=1e-9)


def test_daylight_matches_colour_d_series():
    for cct in (4000.0, 6504.0, 15000.0):
        ours = spectra.daylight_spd(torch.tensor([cct]), W5)[0].numpy()
        ref = colour.sd_CIE_illuminant_D_series(colour.temperature.CCT_to_xy_CIE_D(cct))
        # colour rounds M1, M2 to 3 decimals (CIE 015); the generator's daylights do not (smooth in the CCT), the
        # named ones (isettorch.spectral.daylight) do: the same formula (spectral.daylight_curves)
        np.testing.assert_allclose(ours, ref[W5.numpy()], rtol=2e-3, atol=1e-3)
        from isettorch import spectral

        np.testing.assert_allclose(spectral.daylight(cct, W5, dtype=torch.float64).numpy(), ref[W5.numpy()],
                                   rtol=0, atol=1e-10)


def test_fluorescent_is_cie_table():
    """The CIE table on its own 5 nm grid; on 10 nm each sample is its band's mean power (isettorch.spectral), so
    the lamp's white keeps its CIE chromaticity (point samples missed the mercury lines: F11 0.024 off)."""
    ours = spectra.fluorescent_spd(torch.tensor([2, 11]), W5)
    for row, name in zip(ours, ("FL2", "FL11")):
        np.testing.assert_allclose(row.numpy(), colour.SDS_ILLUMINANTS[name][W5.numpy()], rtol=1e-12)
    cmf = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"][W10.numpy()].T  # [3, L], colour-science's
    for row, name in zip(spectra.fluorescent_spd(torch.tensor([2, 11]), W10), ("FL2", "FL11")):
        xyz = cmf @ row.numpy()
        ref = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][name]
        assert np.hypot(*(xyz[:2] / xyz.sum() - ref)) < 1.5e-3


@pytest.mark.parametrize("kind,lo,hi,tol", [("daylight", 4000.0, 25000.0, 0.005), ("blackbody", 2000.0, 10000.0, 0.002),
                                            ("led", 2700.0, 6500.0, 0.002)])
def test_illuminant_cct_as_asked(kind, lo, hi, tol):
    g = torch.Generator().manual_seed(7)
    ccts = []
    for _ in range(6):
        spd, cct, _ = spectra.random_illuminant(kind, W5, g, (lo, hi))
        assert lo <= cct <= hi
        assert abs(_ohno_cct(spd, W5) / cct - 1) < tol
        ccts.append(cct)
    assert max(ccts) - min(ccts) > 0.1 * (hi - lo)  # not stuck


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_daylight_cct_with_colour_xy_to_cct():
    """colour.xy_to_CCT's default method inverts the CIE daylight locus: it must return the asked CCT."""
    g = torch.Generator().manual_seed(3)
    for _ in range(5):
        spd, cct, _ = spectra.random_illuminant("daylight", W5, g)
        xy = spectra.chromaticity_xy(spd[None], W5)[0].numpy()
        # compared in mired (1e6 / T), the scale CCTs are drawn on: 0.5 mired is ~20 K at 6500 K
        assert 1e6 / float(colour.xy_to_CCT(xy)) == pytest.approx(1e6 / cct, abs=0.5)


def test_led_spectrum_shape():
    spd = spectra.led_spd(torch.tensor([3000.0, 6000.0]), W5)
    peak_nm = W5[spd.argmax(dim=1)]
    assert float(spd.min()) >= 0
    # the narrow blue pump peak is at 450 nm; warm LEDs put more of their power in the phosphor band
    assert float(peak_nm[1]) == 450.0
    long_fraction = spd[:, W5 > 500].sum(dim=1) / spd.sum(dim=1)
    assert 0.7 < float(long_fraction[0]) and float(long_fraction[1]) < float(long_fraction[0])


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_default_leds_are_on_the_planckian_locus():
    """Default white LEDs sit on the Planckian locus at their CCT (colour-science's Ohno 2013 CCT and Duv): white
    LEDs are binned within Duv +-0.006 (ANSI C78.377); a fixed phosphor peak put warm LEDs at Duv -0.035."""
    t = torch.tensor([1800.0, 2700.0, 3000.0, 3500.0, 4000.0, 5000.0, 6500.0, 10000.0])
    spd = spectra.led_spd(t, W5)
    for row, cct in zip(spd, t.tolist()):
        xy = spectra.chromaticity_xy(row[None], W5)[0].numpy()
        ohno_cct, duv = colour.temperature.uv_to_CCT_Ohno2013(colour.xy_to_UCS_uv(xy))
        assert abs(duv) < 2e-4 and abs(ohno_cct / cct - 1) < 2e-3, (cct, duv)
    # a custom pump keeps the former peak rule (and its off-locus tint)
    custom = spectra.led_spd(torch.tensor([2700.0]), W5, pump_nm=455.0)[0]
    xy = spectra.chromaticity_xy(custom[None], W5)[0].numpy()
    assert colour.temperature.uv_to_CCT_Ohno2013(colour.xy_to_UCS_uv(xy))[1] < -0.01


def test_bad_arguments():
    g = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match="cct_k"):
        spectra.daylight_spd(torch.tensor([3000.0]), W10)
    with pytest.raises(ValueError, match="kind"):
        spectra.random_illuminant("laser", W10, g)
    with pytest.raises(ValueError, match="model"):
        spectra.random_reflectances(2, W10, g, model="rgb")
    with pytest.raises(ValueError, match="numbers"):
        spectra.fluorescent_spd(torch.tensor([13]), W10)


def test_led_closed_form_matches_converged_bisection():
    """The closed-form pump : phosphor ratio is the root the bisection converges to (60 steps: |d log r| ~ 1e-17),
    including CCTs a custom phosphor cannot reach, where both return an end of the log-ratio interval (CCTs outside
    1000-25000 K are refused)."""
    t = torch.tensor([1000.0, 2700.0, 4100.0, 6500.0, 12000.0, 25000.0], dtype=torch.float64)
    closed = spectra.led_spd(t, W10)
    bisect = spectra.led_spd(t, W10, iterations=60)
    np.testing.assert_allclose(closed.numpy(), bisect.numpy(), rtol=1e-11, atol=1e-12)
    kw = {"phosphor_nm": torch.tensor([480.0], dtype=torch.float64)}  # too blue for 2700 K
    np.testing.assert_allclose(spectra.led_spd(t[1:2], W10, **kw).numpy(),
                               spectra.led_spd(t[1:2], W10, iterations=60, **kw).numpy(), rtol=1e-11, atol=1e-12)


def test_wavelength_checks_are_remembered_only_for_valid_grids():
    """Grids are validated once per distinct grid; invalid ones raise every time, whatever was called before."""
    g = torch.Generator().manual_seed(0)
    spectra.random_reflectances(2, W10, g)
    for bad in (torch.flip(W10, [0]), torch.tensor([400.0, float("nan"), 700.0]), torch.tensor([-1.0, 500.0])):
        for _ in range(2):
            with pytest.raises(ValueError, match="wavelengths_nm"):
                spectra.random_reflectances(2, bad, g)
            with pytest.raises(ValueError, match="wavelengths_nm"):
                spectra.daylight_spd(torch.tensor([5000.0]), bad)
    assert spectra.blackbody_spd(torch.tensor([5000.0]), W10.tolist()).shape == (1, W10.numel())


def test_blackbody_matches_colour_planck_law():
    """Planck's law with the exact CODATA 2018 second radiation constant c2 = h c / k, normalised at 560 nm."""
    c2 = 6.62607015e-34 * 299_792_458.0 / 1.380649e-23
    temps = torch.tensor([1500.0, 2856.0, 6500.0, 20000.0], dtype=torch.float64)
    ours = spectra.blackbody_spd(temps, W5).numpy()
    for row, t in zip(ours, temps.tolist()):
        ref = colour.sd_blackbody(t, colour.SpectralShape(380, 780, 5), c2=c2).values
        np.testing.assert_allclose(row, 100 * ref / ref[W5.numpy() == 560.0], rtol=1e-12)


def test_illuminants_are_differentiable_in_cct():
    """Inputs that require grad take the torch path: autograd gradients agree with finite differences."""
    t = torch.tensor([4500.0, 9000.0], dtype=torch.float64, requires_grad=True)
    for fn in (spectra.daylight_spd, spectra.blackbody_spd, spectra.led_spd):
        assert torch.autograd.gradcheck(lambda x, fn=fn: fn(x, W10), (t,), eps=1e-3, atol=1e-6, rtol=1e-5)
    # the torch path gives the numpy path's spectra
    for fn in (spectra.daylight_spd, spectra.blackbody_spd, spectra.led_spd):
        np.testing.assert_allclose(fn(t, W10).detach().numpy(), fn(t.detach(), W10).numpy(), rtol=1e-11)


@pytest.mark.parametrize("kind", ["daylight", "blackbody", "led", "fluorescent"])
def test_random_illuminant_is_the_public_spectrum(kind):
    """random_illuminant's inlined path gives the spectrum of the public function at the CCT it reports."""
    g = torch.Generator().manual_seed(5)
    for _ in range(3):
        spd, cct, name = spectra.random_illuminant(kind, W10, g)
        if kind == "fluorescent":
            ref = spectra.fluorescent_spd(torch.tensor([int(name[1:])]), W10)[0]
        else:
            fn = {"daylight": spectra.daylight_spd, "blackbody": spectra.blackbody_spd, "led": spectra.led_spd}[kind]
            ref = fn(torch.tensor([cct], dtype=torch.float64), W10)[0]
        assert spd.dtype == W10.dtype and spd.shape == W10.shape
        np.testing.assert_allclose(spd.numpy(), ref.numpy(), rtol=1e-6)  # computed at the CCT rounded to float32


def test_dye_concentration_is_beer_lambert():
    """Absorbance relative to the peak, -log(r / r_peak), scales exactly with the concentration; the peak and zeros
    stay; c = 1 is the identity; and colour-science's excitation purity of a ColorChecker red grows with c."""
    r = spectra.measured_reflectances(torch.arange(400.0, 701.0, 10.0, dtype=torch.float64))[:24]
    for c in (0.5, 1.0, 2.5):
        d = spectra.dye_concentration(r, c)
        peak = r.amax(-1, keepdim=True)
        assert torch.allclose(d.amax(-1, keepdim=True), peak)
        pos = r > 1e-6
        rel_in, rel_out = r[pos] / peak.expand_as(r)[pos], d[pos] / peak.expand_as(r)[pos]
        assert torch.allclose(torch.log(rel_out), c * torch.log(rel_in), atol=1e-9)
    assert torch.allclose(spectra.dye_concentration(r, 1.0), r, rtol=1e-14, atol=0)
    per = spectra.dye_concentration(r[:3], torch.tensor([[1.0], [2.0], [3.0]], dtype=torch.float64))
    assert torch.allclose(per[2], spectra.dye_concentration(r[2], 3.0))
    z = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    assert spectra.dye_concentration(z, 3.0)[0] == 0
    assert spectra.dye_concentration(torch.zeros(3, dtype=torch.float64), 2.0).eq(0).all()

    shape = colour.SpectralShape(400, 700, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]

    def purity(refl):
        sd = colour.SpectralDistribution(dict(zip(range(400, 701, 10), refl.tolist())))
        xy = colour.XYZ_to_xy(colour.sd_to_XYZ(sd, cmfs, d65))
        return float(colour.excitation_purity(xy, white, cmfs))

    sd_red = colour.SDS_COLOURCHECKERS["BabelColor Average"]["red"]
    red = torch.from_numpy(np.interp(np.arange(400.0, 701.0, 10.0), sd_red.wavelengths, sd_red.values))
    p1, p2, p4 = (purity(spectra.dye_concentration(red, c)) for c in (1.0, 2.0, 4.0))
    assert 0.3 < p1 < p2 < p4 < 1


def test_dye_concentration_bad_arguments():
    with pytest.raises(ValueError, match="concentration"):
        spectra.dye_concentration(torch.tensor([0.5, 0.2]), 0.0)
    with pytest.raises(ValueError, match="reflectance"):
        spectra.dye_concentration(torch.tensor([1.5, 0.2]), 2.0)


def test_led_parameters_stay_on_the_cct_device():
    """The batched scene generator draws LED lights on the training device: their pump, phosphor peak and width
    follow the CCTs' device (here 'meta', which holds no values: a copy to the CPU on the way raises; on an H200 the
    default on-locus phosphor went to the CPU and PairStream failed on CUDA, 2026-11-30)."""
    from isettorch.data import spectra

    t = torch.full((3,), 5000.0, dtype=torch.float64, device="meta")
    for pump in (None, torch.tensor([450.0])):
        params = spectra._led_params(t, pump, None, None, torch)
        assert [p.device.type for p in params] == ["meta"] * 3
        assert all(p.shape == (3,) and p.dtype == torch.float64 for p in params)


def test_recovery_reflectances_refuse_invalid_beta_parameters():
    """scipy's Beta inverse CDF is NaN for a <= 0 or b <= 0: the reflectances were NaN without a word."""
    w = torch.arange(400.0, 701.0, 10.0)
    for beta in ((-1, 2), (0, 0), (1.0, float("nan"))):
        with pytest.raises(ValueError, match="chroma_beta: expected two positive Beta parameters"):
            spectra.recovery_reflectances(2, w, torch.Generator().manual_seed(0), chroma_beta=beta)
    assert torch.isfinite(spectra.recovery_reflectances(2, w, torch.Generator().manual_seed(0))).all()


def test_a_blackbody_too_cold_for_the_dtype_is_refused():
    """Planck's ratio to 560 nm overflows float32 at 700 nm below about 60 K: random_illuminant and blackbody_spd
    returned inf (spectral.blackbody refused it), found by an audit of the generators."""
    from isettorch.data.spectra import blackbody_spd, random_illuminant

    w = torch.arange(400.0, 701.0, 10.0)
    g = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match="cct_range_k: the blackbody spectrum relative to 560 nm overflows"):
        random_illuminant("blackbody", w, g, (50.0, 50.0))
    with pytest.raises(ValueError, match="temperature_k: the blackbody spectrum relative to 560 nm overflows"):
        blackbody_spd(torch.tensor([40.0]), w)
    assert torch.isfinite(blackbody_spd(torch.tensor([40.0]), w.double())).all()  # float64 holds it
    assert torch.isfinite(random_illuminant("blackbody", w, g, (100.0, 100.0))[0]).all()
