"""EMVA 1288 on frames drawn from a direct sensor model with known K, QE, read noise, DSNU and PRNU."""

import math

import numpy as np
import pytest
import torch

from isettorch.metrics import emva1288

K_DN_PER_E = 0.4
QE = 0.6
READ_NOISE_E = 6.0
DSNU_E = 4.0
PRNU = 0.01
OFFSET_DN = 100.0
MAX_DN = 4095.0
H = W = 64
N_FRAMES = 16


def make_frames(seed=0, levels=20, n_frames=N_FRAMES, per_level_dark=True):
    """Direct camera model: electrons = Poisson(QE mu_p (1 + PRNU map)) + DSNU map + N(0, read noise);
    DN = clip(round(K electrons + offset), 0, 4095). The fixed patterns are drawn once."""
    g = torch.Generator().manual_seed(seed)
    prnu_map = PRNU * torch.randn(H, W, generator=g, dtype=torch.float64)
    dsnu_map = DSNU_E * torch.randn(H, W, generator=g, dtype=torch.float64)
    full_scale_e = (MAX_DN - OFFSET_DN) / K_DN_PER_E
    mu_p = torch.linspace(0.0, 1.15 * full_scale_e / QE, levels, dtype=torch.float64)

    def expose(photons):
        rate = (QE * photons * (1 + prnu_map)).expand(n_frames, H, W)
        e = torch.poisson(rate, generator=g) + dsnu_map + READ_NOISE_E * torch.randn(n_frames, H, W, generator=g,
                                                                                   dtype=torch.float64)
        return torch.clamp(torch.round(K_DN_PER_E * e + OFFSET_DN), 0, MAX_DN)

    bright = torch.stack([expose(float(p)) for p in mu_p])
    dark = torch.stack([expose(0.0) for _ in range(levels)]) if per_level_dark else expose(0.0)
    return bright, dark, mu_p, prnu_map, dsnu_map


@pytest.fixture(scope="module")
def frames():
    return make_frames()


def test_recovers_known_parameters(frames):
    bright, dark, mu_p, prnu_map, dsnu_map = frames
    res = emva1288(bright, dark, photons_per_pixel=mu_p)
    assert float(res.system_gain_dn_per_e) == pytest.approx(K_DN_PER_E, rel=0.02)
    assert float(res.quantum_efficiency) == pytest.approx(QE, rel=0.02)
    assert float(res.dark_noise_e) == pytest.approx(READ_NOISE_E, rel=0.02)
    # the realised fixed patterns (sample std) are the truth for DSNU and PRNU
    assert float(res.dsnu1288_e) == pytest.approx(float(dsnu_map.std()), rel=0.02)
    assert float(res.prnu1288_percent) == pytest.approx(100 * float(prnu_map.std() / (1 + prnu_map).mean()), rel=0.02)
    # dark noise in DN includes quantisation: K^2 sigma_d^2 + 1/12
    assert float(res.dark_noise_dn) == pytest.approx(math.sqrt(K_DN_PER_E**2 * READ_NOISE_E**2 + 1 / 12), rel=0.02)
    # saturation just below the clipping point, (4095 - 100) / K = 9987.5 e-
    full_scale_e = (MAX_DN - OFFSET_DN) / K_DN_PER_E
    assert 0.85 * full_scale_e < float(res.saturation_capacity_e) <= full_scale_e
    # dynamic range: mu_e.sat / (sigma_y.dark / K + 1/2), with the true sigma_y.dark and K (the sensitivity threshold
    # of EMVA 1288 release 3.1, which the EMVA's reference implementation for release 4.0, emva1288 1.x, keeps:
    # Results1288.u_p_min; the exact SNR = 1 solution differs by about 0.5 % here)
    mu_e_min = math.sqrt(K_DN_PER_E**2 * READ_NOISE_E**2 + 1 / 12) / K_DN_PER_E + 0.5
    expect_dr_db = 20 * math.log10(float(res.saturation_capacity_e) / mu_e_min)
    assert float(res.dynamic_range_db) == pytest.approx(expect_dr_db, abs=0.2)
    # measured SNR against the EMVA model with the true parameters, at the mid level
    i = res.spatial_index
    e = QE * float(mu_p[i])
    snr_true = e / math.sqrt(READ_NOISE_E**2 + 1 / 12 / K_DN_PER_E**2 + e)
    assert float(res.snr[i]) == pytest.approx(snr_true, rel=0.02)
    assert float(res.snr_model(mu_p[i])) == pytest.approx(snr_true, rel=0.02)
    # eq. 19 with the fitted parameters, written out (snr_model is the one pixel-SNR model of metrics.snr)
    e_fit = res.quantum_efficiency * mu_p
    eq19 = e_fit / torch.sqrt(res.dark_noise_e**2 + (1 / 12) / res.system_gain_dn_per_e**2 + e_fit)
    torch.testing.assert_close(res.snr_model(mu_p), eq19.double(), rtol=1e-12, atol=0)
    text = res.report()
    assert "System gain" in text and "PRNU1288" in text


def test_single_dark_stack_and_no_photons():
    bright, dark, mu_p, _, dsnu_map = make_frames(seed=1, levels=16, n_frames=4, per_level_dark=False)
    assert dark.shape == (4, H, W)
    res = emva1288(bright, dark)
    assert res.quantum_efficiency is None
    assert float(res.system_gain_dn_per_e) == pytest.approx(K_DN_PER_E, rel=0.02)
    assert float(res.dsnu1288_e) == pytest.approx(float(dsnu_map.std()), rel=0.03)
    with pytest.raises(ValueError, match="quantum efficiency"):
        res.snr_model(mu_p)


def test_bad_input():
    with pytest.raises(ValueError, match="bright"):
        emva1288(torch.zeros(5, 1, 8, 8), torch.zeros(2, 8, 8))
    with pytest.raises(ValueError, match="dark"):
        emva1288(torch.zeros(5, 2, 8, 8), torch.zeros(3, 2, 8, 8))
    with pytest.raises(ValueError, match="photons_per_pixel"):
        emva1288(torch.rand(5, 2, 8, 8) + 1, torch.rand(2, 8, 8), photons_per_pixel=[1.0, 2.0])


def test_plot(frames):
    bright, dark, mu_p, _, _ = frames
    fig = emva1288(bright[:, :2], dark[:, :2], photons_per_pixel=mu_p).plot()
    assert len(fig.axes) == 3


def _well_limited_frames(seed, k_dn_per_e=4.0, full_well_e=800.0, read_e=1.5, levels=30):
    """A well that saturates below the ADC's full scale: past it the pixels keep their read and quantisation noise
    (a flat, noisy variance plateau), the case where the EMVA reference implementation's downward scan stops on a
    bump of the plateau. Truth: the first level at the well, K, QE 0.6, PRNU 1 %."""
    g = torch.Generator().manual_seed(seed)
    prnu_map = 0.01 * torch.randn(H, W, generator=g, dtype=torch.float64)
    mu_p = torch.linspace(0.0, 1.3 * full_well_e / QE, levels, dtype=torch.float64)
    e = torch.poisson((QE * mu_p.view(-1, 1, 1, 1) * (1 + prnu_map)).expand(levels, 4, H, W).contiguous(),
                      generator=g).clamp(max=full_well_e)
    bright = torch.round(OFFSET_DN + k_dn_per_e * (e + read_e * torch.randn(e.shape, generator=g, dtype=torch.float64)))
    dark = torch.round(OFFSET_DN + k_dn_per_e * read_e * torch.randn(4, H, W, generator=g, dtype=torch.float64))
    return bright, dark, mu_p


@pytest.mark.parametrize("seed", range(4))
def test_saturation_is_the_variance_maximum_when_the_well_clips_below_the_adc(seed):
    bright, dark, mu_p = _well_limited_frames(seed)
    res = emva1288(bright, dark, photons_per_pixel=mu_p)
    var = res.var_dn2
    assert res.saturation_index == int(var.argmax())
    # the variance peaks where the mean well reaches about 90 % of the 800 e- well (the brightest pixels clip first;
    # the levels are 26 e- apart in the mean)
    assert 0.8 * 800 < float(res.saturation_capacity_e) < 800
    assert float(res.system_gain_dn_per_e) == pytest.approx(4.0, rel=0.03)
    assert float(res.prnu1288_percent) == pytest.approx(1.0, abs=0.15)


def test_level_order_and_saturated_stacks_are_errors():
    bright, dark, mu_p = _well_limited_frames(0, levels=12)
    with pytest.raises(ValueError, match="photons_per_pixel: expected the levels in increasing exposure"):
        emva1288(bright.flip(0), dark, photons_per_pixel=mu_p.flip(0))
    with pytest.raises(ValueError, match="bright: expected the exposure levels in increasing order"):
        emva1288(bright.flip(0), dark)
    # every lit level saturated (the ADC clips): one clear error, not a reduction over an empty tensor
    d = torch.round(100 + 1.5 * torch.randn(2, 16, 16, generator=torch.Generator().manual_seed(0)))
    saturated = torch.stack([d + 1] + [torch.full((2, 16, 16), 4095.0)] * 4)
    with pytest.raises(ValueError, match="fewer than 2 levels below 70 % of saturation"):
        emva1288(saturated, d)


def test_a_series_that_stops_below_saturation_is_refused(frames):
    """Levels that end below saturation leave the variance largest at the brightest level, which was reported as
    the saturation capacity (here 12 of 20 levels: about 63 % of the 9,988 e- full scale, a dynamic range about 4 dB
    low) without a word. Refused unless saturation_index says the last level saturates; indices must be whole."""
    bright, dark, mu_p, _, _ = frames
    with pytest.raises(ValueError, match="bright: the temporal variance is largest at the brightest level"):
        emva1288(bright[:12], dark[:12], photons_per_pixel=mu_p[:12])
    forced = emva1288(bright[:12], dark[:12], photons_per_pixel=mu_p[:12], saturation_index=11)
    full_scale_e = (MAX_DN - OFFSET_DN) / K_DN_PER_E
    assert float(forced.saturation_capacity_e) == pytest.approx(QE * float(mu_p[11]), rel=0.03)
    assert float(forced.saturation_capacity_e) < 0.7 * full_scale_e
    for name in ("saturation_index", "spatial_index"):
        with pytest.raises(ValueError, match=f"{name}: expected None or an integer level"):
            emva1288(bright, dark, **{name: 2.5})
        with pytest.raises(ValueError, match=f"{name}: expected None or an integer level"):
            emva1288(bright, dark, **{name: 20})


def test_undefined_prnu_and_responsivity_are_errors(frames):
    # PRNU1288 = sqrt(s2_y - s2_y.dark) / (mu_y - mu_y.dark) (EMVA 1288 4.0, 8) is noise over noise below the
    # sensitivity threshold (a signal of the dark noise): a forced spatial_index at the unlit level 0 gave -1277 %.
    # All-zero photons gave NaN QE, R, saturation capacity and dynamic range (0 / 0).
    bright, dark, mu_p, _, _ = frames
    with pytest.raises(ValueError, match="spatial_index: level 0's signal, .* is not above the dark noise"):
        emva1288(bright, dark, photons_per_pixel=mu_p, spatial_index=0)
    with pytest.raises(ValueError, match="photons_per_pixel: expected photons above 0"):
        emva1288(bright, dark, photons_per_pixel=torch.zeros_like(mu_p))
    assert float(emva1288(bright, dark, photons_per_pixel=mu_p, spatial_index=5).prnu1288_percent) == \
        pytest.approx(100 * PRNU, rel=0.2)


def test_a_spatial_level_past_saturation_is_refused(frames):
    """A forced spatial_index past saturation measured flat, clipped frames: PRNU 0 % (truth 1 %) without a word."""
    bright, dark, mu_p, _, _ = frames
    sat = emva1288(bright, dark, photons_per_pixel=mu_p).saturation_index
    assert sat < 19
    with pytest.raises(ValueError, match=f"spatial_index: level 19 is past saturation \\(level {sat}\\)"):
        emva1288(bright, dark, photons_per_pixel=mu_p, spatial_index=19)


def test_a_quantisation_limited_dark_noise_is_reported_as_an_upper_limit():
    """K = 0.05 DN/e-, read noise 2 e-: the dark variance, K^2 2^2 + 1/12 = 0.093 DN^2, is below EMVA 1288's
    0.24 DN^2 (section 6.4), where only sigma_d < 0.40 / K = 7.96 e- can be given. It was printed as a measured
    7.962 e- (truth 2)."""
    g = torch.Generator().manual_seed(3)
    k, levels = 0.05, 16
    mu_p = torch.linspace(0.0, 1.3 * 20000 / 0.6, levels, dtype=torch.float64)

    def expose(p):
        e = torch.poisson(torch.full((2, 32, 32), 0.6 * float(p), dtype=torch.float64), generator=g)
        e = e.clamp_max(20000) + 2.0 * torch.randn(2, 32, 32, generator=g, dtype=torch.float64)
        return torch.round(k * e + 10.0)

    res = emva1288(torch.stack([expose(p) for p in mu_p]), torch.stack([expose(0) for _ in mu_p]),
                   photons_per_pixel=mu_p)
    assert res.dark_noise_is_upper_limit
    assert float(res.dark_noise_e) == pytest.approx(math.sqrt(0.24 - 1 / 12) / float(res.system_gain_dn_per_e))
    report = res.report()
    assert f"< {float(res.dark_noise_e):.4g}" in report and "> " in report and "upper limits" in report
    assert not emva1288(*make_frames(levels=12, n_frames=2)[:2]).dark_noise_is_upper_limit


def test_linearity_error_uses_5_to_95_percent_of_saturation_with_an_offset_fit():
    """EMVA 1288 linearity (Releases 3.1 and 4.0 Linear): a line with offset through the levels within 5-95 % of
    the saturation signal. A compressive response e (1 - 0.06 e / fw) deviates most near saturation; the
    calibration figure had used the gain fit's levels (<= 70 %), hiding it."""
    from isettorch.metrics.emva import linearity_error

    t = np.linspace(0.0, 1.2, 25)  # saturation (fw) reached at t = 1
    e = np.minimum(t, 1.0)
    x = 1000 * e * (1 - 0.06 * e)
    band, err, (offset, slope) = linearity_error(t, x)
    want = (x >= 0.05 * x.max()) & (x <= 0.95 * x.max())
    assert np.array_equal(band, want) and band.sum() == 18
    a1, a0 = np.polyfit(t[want], x[want], 1)  # numpy's least squares, independently
    assert (offset, slope) == pytest.approx((a0, a1))
    np.testing.assert_allclose(err, 100 * (x[want] / (a0 + a1 * t[want]) - 1), rtol=1e-12)
    assert err.max() > 0.5 and err[-1] < -0.5  # bowed: the points near saturation fall below the line, in the band
    assert not linearity_error([1.0, 2.0], [10.0, 20.0])[0].any()  # fewer than 3 levels: nothing
