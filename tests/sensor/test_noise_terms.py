"""Real-raw noise terms (isettorch/sensor/noise_terms.py): each term's statistics against its definition."""

import math

import numpy as np
import pytest
import torch

from isettorch.sensor import Sensor
from isettorch.sensor.noise_terms import NoiseTerms, tukey_lambda_quantile, tukey_lambda_variance

scipy_stats = pytest.importorskip("scipy.stats")


def _sensor(**kw):
    base = dict(rows=64, cols=512, cfa="mono", conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0, shot_noise="off",
                seed=3)
    base.update(kw)
    return Sensor(**base)


def _volts(sensor, rate=1e5, frames=8, exposure_s=0.01, seed=0):
    r = torch.full((frames, 1, sensor.rows, sensor.cols), float(rate), dtype=torch.float64)
    return sensor.capture(r, exposure_s=exposure_s, generator=torch.Generator().manual_seed(seed)).data[:, 0]


def test_row_noise_variance_from_row_means():
    """ELD row noise: one offset per row and frame: constant along the row, row means with std row_noise_v."""
    s = _sensor(row_noise_v=2e-3)
    v = _volts(s, frames=16) - 1e5 * 0.01 * 1e-4  # remove the signal (1000 e- x 1e-4 V/e-)
    assert float((v - v.mean(dim=-1, keepdim=True)).abs().max()) < 1e-12  # no pixel-wise part
    row_means = v.mean(dim=-1)  # (16, 64): 1024 independent offsets
    std = float(row_means.std())
    assert std == pytest.approx(2e-3, rel=0.08)  # 1024 samples: std of the std estimate ~2.2 %
    # temporal: the offsets of two frames are uncorrelated
    assert abs(float(torch.corrcoef(row_means[:2])[0, 1])) < 0.35


def test_column_noise_variance_from_column_means():
    s = _sensor(column_noise_v=1e-3)
    v = _volts(s, frames=4) - 0.1
    col_means = v.mean(dim=-2)  # (4, 512)
    assert float((v - v.mean(dim=-2, keepdim=True)).abs().max()) < 1e-12
    assert float(col_means.std()) == pytest.approx(1e-3, rel=0.06)


def test_row_noise_estimator_separates_row_and_pixel_noise():
    """emva.temporal_noise_components recovers row and pixel-wise variances from a Sensor stack."""
    from isettorch.metrics.emva import temporal_noise_components

    s = _sensor(row_noise_v=1e-3, read_noise_v=3e-3)
    v = _volts(s, frames=8) / 1e-3  # in mV
    comps = temporal_noise_components(v)
    assert float(comps["var_row"]) == pytest.approx(1.0, rel=0.15)
    assert float(comps["var_pixel"]) == pytest.approx(9.0, rel=0.02)
    assert abs(float(comps["var_col"])) < 0.02


@pytest.mark.parametrize("lam", [-0.3, -0.1, 0.0, 0.14, 0.5, 1.0])
def test_tukey_lambda_quantile_and_variance_match_scipy(lam):
    u = torch.linspace(0.001, 0.999, 199, dtype=torch.float64)
    np.testing.assert_allclose(tukey_lambda_quantile(u, lam).numpy(), scipy_stats.tukeylambda.ppf(u.numpy(), lam),
                               rtol=1e-9, atol=1e-9)
    assert tukey_lambda_variance(lam) == pytest.approx(float(scipy_stats.tukeylambda.var(lam)), rel=1e-9)


def test_tukey_read_noise_sample_quantiles():
    """Sensor read noise with a Tukey-lambda shape: std = read_noise_v, quantiles of the scaled scipy
    distribution (heavier tails than the Gaussian for lam < 0.14)."""
    lam, read_v = -0.2, 1e-3
    s = _sensor(read_noise_v=read_v, read_noise_tukey_lambda=lam, rows=256, cols=256)
    # zero signal: read noise only; the analog readout clips negative volts at 0, which leaves the upper
    # quantiles (of the symmetric distribution) unchanged
    x = (_volts(s, rate=0, frames=4) / read_v).flatten().numpy()
    scale = 1 / math.sqrt(tukey_lambda_variance(lam))
    q = np.array([0.9, 0.99, 0.999])
    got = np.quantile(x, q)
    want = scale * scipy_stats.tukeylambda.ppf(q, lam)
    np.testing.assert_allclose(got, want, rtol=0.05)
    gauss = scipy_stats.norm.ppf(0.999)
    assert got[-1] > 1.2 * gauss  # heavier tail than a unit Gaussian


def test_tukey_read_noise_std_and_gradient_flow():
    s = _sensor(read_noise_v=1e-3, read_noise_tukey_lambda=0.0, output_units="volts", rows=128, cols=256)
    v = _volts(s, rate=1e5, frames=4) - 0.1  # 1000 e- of signal keeps every sample above the clip
    assert float(v.std()) == pytest.approx(1e-3, rel=0.02)
    lam = torch.tensor(-0.1, dtype=torch.float64, requires_grad=True)
    u = torch.rand(20, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.98 + 0.01
    assert torch.autograd.gradcheck(lambda lam_: tukey_lambda_quantile(u, lam_), (lam,))


def test_dark_shading_scales_with_exposure():
    """PMN dark shading: a fixed pattern whose spatial std is dark_shading_e_per_s x t electrons, the same map at
    every exposure."""
    s = _sensor(dark_shading_e_per_s=2000.0, adc_bits=None, rows=128, cols=128)
    maps = []
    for t in (0.01, 0.04):
        v = _volts(s, rate=1e5 / t * 0.01, frames=1, exposure_s=t)[0] / 1e-4 - 1000  # electrons minus signal
        maps.append(v)
        assert float(v.std()) == pytest.approx(2000.0 * t, rel=0.03)
    assert float(torch.corrcoef(torch.stack([m.flatten() for m in maps]))[0, 1]) > 0.999999


def test_hot_and_dead_pixels():
    s = _sensor(hot_pixel_fraction=0.01, hot_pixel_dark_current_e_per_s=5e4, dead_pixel_fraction=0.002,
                rows=256, cols=256)
    v = _volts(s, rate=1e5, frames=1)[0] / 1e-4  # electrons: 1000 signal, + 500 on hot pixels, 0 on dead ones
    hot = (v > 1200).double().mean()
    dead = (v == 0).double().mean()
    assert float(hot) == pytest.approx(0.01 * (1 - 0.002), abs=4 * math.sqrt(0.01 / 65536))
    assert float(dead) == pytest.approx(0.002, abs=4 * math.sqrt(0.002 / 65536))
    assert float(v[v > 1200].mean()) == pytest.approx(1500.0, rel=1e-9)


def test_full_well_clips_electrons():
    s = _sensor(full_well_e=800.0, shot_noise="poisson", rows=32, cols=32)
    v = _volts(s, rate=1e5, frames=2) / 1e-4
    assert float(v.max()) == pytest.approx(800.0)


def test_fixed_patterns_drawn_once_from_the_seed():
    a, b, c = (NoiseTerms(dark_shading_e_per_s=1.0, hot_pixel_fraction=0.1, seed=s) for s in (5, 5, 6))
    pa = a.patterns(16, 16, dtype=torch.float32, device="cpu")
    assert torch.equal(pa["shading"], b.patterns(16, 16, dtype=torch.float32, device="cpu")["shading"])
    assert not torch.equal(pa["shading"], c.patterns(16, 16, dtype=torch.float32, device="cpu")["shading"])
    a.patterns(16, 16, dtype=torch.float64, device="cpu")
    assert len(a._patterns) == 1  # cached, not redrawn


def test_terms_off_cost_nothing_and_leave_the_output_unchanged():
    """All terms at zero: no pattern is drawn and the output is the plain sensor's, draw for draw."""
    kw = dict(read_noise_v=1e-3, shot_noise="poisson", rows=16, cols=16)
    s = _sensor(**kw)
    out = _volts(s, frames=2)
    assert s.noise_terms._patterns == {}
    explicit = _sensor(**kw, row_noise_v=0.0, column_noise_v=0.0, dark_shading_e_per_s=0.0, full_well_e=None)
    assert torch.equal(out, _volts(explicit, frames=2))


@pytest.mark.parametrize("kw, msg", [
    ({"read_noise_tukey_lambda": -0.5}, "read_noise_tukey_lambda"),
    ({"hot_pixel_fraction": 1.5}, "hot_pixel_fraction"),
    ({"row_noise_v": -1.0}, "row_noise_v"),
    ({"full_well_e": 0}, "full_well_e"),
])
def test_bad_arguments_name_themselves(kw, msg):
    with pytest.raises(ValueError, match=msg):
        _sensor(**kw)


def test_row_noise_gradient_reaches_the_input():
    """Row noise is additive and reparameterised: d output / d electron rate is the conversion gain x exposure."""
    s = _sensor(row_noise_v=1e-3, rows=8, cols=8)
    r = torch.full((1, 1, 8, 8), 1e5, dtype=torch.float64, requires_grad=True)
    s.capture(r, exposure_s=0.01, generator=torch.Generator().manual_seed(0)).data.sum().backward()
    assert torch.allclose(r.grad, torch.full_like(r, 1e-4 * 0.01))


def test_isetcam_noise_model_refuses_the_terms():
    """ISETCam's noise order has no row noise etc.: asking for both is an error, not a silent drop."""
    with pytest.raises(ValueError, match="noise_model: 'isetcam'"):
        _sensor(noise_model="isetcam", row_noise_v=1e-3)
    assert not _sensor(noise_model="isetcam").noise_terms.active


def test_noise_free_output_clips_at_the_full_well():
    """``noise_free`` (capture and readout) saturates at ``full_well_e`` like the noisy chain, not at the ADC top."""
    import torch

    from isettorch.sensor import Sensor

    s = Sensor(rows=4, cols=4, cfa="mono", full_well_e=1000.0, conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0,
               adc_bits=12, output_units="volts", exposure_s=1.0)
    rate = torch.tensor([500.0, 2000.0], dtype=torch.float64).reshape(2, 1, 1, 1).expand(2, 1, 4, 4)
    raw = s.capture(rate.contiguous(), exposure_s=1.0, noise=False)
    nf = raw.noise_free.reshape(2, -1)
    torch.testing.assert_close(nf[0], torch.full((16,), 500 * 1e-4, dtype=torch.float64))
    torch.testing.assert_close(nf[1], torch.full((16,), 1000 * 1e-4, dtype=torch.float64))  # not 2000 e-
    ro = s.readout(rate.contiguous(), 1.0).reshape(2, -1)
    torch.testing.assert_close(ro, nf)
