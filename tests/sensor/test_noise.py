import math

import pytest
import torch

from isettorch.sensor import quantize_ste, round_half_away, shot_noise
from isettorch.sensor.noise import safe_sqrt

N = 1_000_000


@pytest.mark.parametrize("mode", ["poisson", "gaussian"])
@pytest.mark.parametrize("mean", [0.5, 5.0, 50.0, 5000.0])
def test_shot_noise_moments(mode, mean):
    g = torch.Generator().manual_seed(int(mean * 10) + (mode == "gaussian"))
    x = shot_noise(torch.full((N,), mean, dtype=torch.float64), mode, g)
    # Poisson: mean = variance (1e6 samples: standard errors 0.14 % / 0.2 % at mean 0.5)
    assert abs(x.mean().item() - mean) / mean < 0.01
    assert abs(x.var().item() - mean) / mean < 0.01
    if mode == "poisson":
        assert torch.equal(x, x.round())  # integer electron counts


def test_poisson_zero_probability():
    g = torch.Generator().manual_seed(7)
    x = shot_noise(torch.full((N,), 0.5, dtype=torch.float64), "poisson", g)
    p0 = (x == 0).double().mean().item()
    assert abs(p0 - math.exp(-0.5)) < 0.002  # 4 standard errors


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA device"))])
@pytest.mark.parametrize("mean", [1e10, 1e19, 1e30])
def test_poisson_shot_noise_beyond_integer_counts(mean, device):
    """Above 2^31 electrons 'poisson' draws N(mean, mean): torch.poisson's count overflowed (CUDA's 32-bit count from
    2^32, the CPU's int64 from 2^63: -9.2e18 at a mean of 1e19, a saturated pixel read black). Moments over 1e5
    draws (standard errors 0.3 % of sqrt(mean) and 0.45 % of the variance); the small means in the same tensor keep
    their exact Poisson draws (integers), the same numbers as a draw of them alone."""
    g = torch.Generator(device).manual_seed(3)
    x = shot_noise(torch.full((100_000,), mean, dtype=torch.float64, device=device), "poisson", g).cpu()
    z = (x - mean) / math.sqrt(mean)
    assert abs(z.mean().item()) < 0.02 and abs(z.var().item() - 1) < 0.02
    small = torch.tensor([3.0, 50.0], dtype=torch.float64, device=device).repeat(500)
    alone = shot_noise(small, "poisson", torch.Generator(device).manual_seed(4))
    mixed = shot_noise(torch.cat([small, torch.full((1,), mean, dtype=torch.float64, device=device)]), "poisson",
                       torch.Generator(device).manual_seed(4))
    assert torch.equal(mixed[:-1], alone) and torch.equal(alone, alone.round()) and float(mixed[-1]) > 0.9 * mean


def test_shot_noise_off_and_bad_mode():
    m = torch.tensor([1.0, 2.0])
    assert torch.equal(shot_noise(m, "off"), m)
    with pytest.raises(ValueError, match="mode"):
        shot_noise(m, "laplace")


def test_gradients_straight_through_and_finite_at_zero():
    g = torch.Generator().manual_seed(0)
    for mode in ("poisson", "gaussian"):
        m = torch.tensor([0.0, 1e-12, 3.0, 400.0], dtype=torch.float64, requires_grad=True)
        shot_noise(m, mode, g).sum().backward()
        assert torch.isfinite(m.grad).all()
        if mode == "poisson":
            assert torch.equal(m.grad, torch.ones(4, dtype=torch.float64))  # straight-through
        assert m.grad[0].item() == 1.0  # zero light: d(mean + sqrt(mean) z)/d mean with safe sqrt -> 1
    x = torch.tensor([0.0], requires_grad=True)
    safe_sqrt(x).sum().backward()
    assert x.grad.item() == 0.0


def test_gaussian_reparameterised_gradient_mean_is_one():
    # E[d/dmu (mu + sqrt(mu) z)] = 1: the reparameterised estimator is unbiased for the mean's gradient
    g = torch.Generator().manual_seed(3)
    m = torch.full((N,), 20.0, dtype=torch.float64, requires_grad=True)
    shot_noise(m, "gaussian", g).sum().backward()
    assert abs(m.grad.mean().item() - 1.0) < 0.005


def test_round_half_away_and_ste():
    x = torch.tensor([-2.5, -1.5, -0.5, 0.5, 1.5, 2.5, 2.4999, 1023.5], requires_grad=True)
    assert round_half_away(x).tolist() == [-3, -2, -1, 1, 2, 3, 2, 1024]  # MATLAB round
    y = quantize_ste(x)
    assert y.tolist() == [-3, -2, -1, 1, 2, 3, 2, 1024]
    y.sum().backward()
    assert torch.equal(x.grad, torch.ones_like(x))
    # exact for every float32: floor(|x| + 1/2) rounded in the addition (0.49999997 -> 1, 8388609 -> 8388610);
    # the reference is the same rule in float64, where those additions are exact
    v = torch.tensor([0.49999997, -0.49999997, 8388609.0, -8388611.0, 4194304.5, 0.0, 1.0 - 2**-24],
                     dtype=torch.float32)
    ref = torch.sign(v.double()) * torch.floor(v.double().abs() + 0.5)
    assert round_half_away(v).double().tolist() == ref.tolist() == [0, 0, 8388609, -8388611, 4194305, 0, 1]


def test_poisson_gaussian_floor_is_the_dark_variance_of_a_numpy_camera():
    """The floor b of var(x) = a x + b (Sensor.poisson_gaussian) against the variance of dark frames simulated in
    NumPy (independent of isettorch): K = 1 DN/e- (1 mV/e- into 1 mV codes), read noise 1 e-, DSNU 0.5 e- (fixed per
    pixel, so across pixels it is variance too), 2 dark electrons (Poisson, mean subtracted), rounding to whole DN;
    b = 1 + 0.25 + 2 + 1/12 DN^2. Over 2e6 pixels the variance's standard error is 0.1 %; the quantisation term is
    2.5 % of b, so 1 % tells it apart. CDS samples the read noise twice and cancels the DSNU."""
    import numpy as np

    from isettorch.sensor import Sensor

    rng = np.random.default_rng(0)
    n, k, black = 2_000_000, 1.0, 64.0
    e = rng.poisson(2.0, n) + 1.0 * rng.standard_normal(n) + 0.5 * rng.standard_normal(n)
    x = np.round(k * e + black) - black - k * 2.0
    kw = dict(adc_bits=12, voltage_swing_v=4.096, conversion_gain_v_per_e=1e-3, read_noise_v=1e-3,
              dsnu_sigma_v=0.5e-3, dark_current_e_per_s=2.0)
    a, b = Sensor(**kw).poisson_gaussian(exposure_s=1.0)
    assert float(a) == pytest.approx(k, rel=1e-12)
    assert float(b) == pytest.approx(x.var(), rel=0.01)
    assert float(b) == pytest.approx(1 + 0.25 + 2 + 1 / 12, rel=1e-12)
    assert abs((float(b) - 1 / 12) / x.var() - 1) > 0.015
    _, b_cds = Sensor(**kw, cds=True).poisson_gaussian(exposure_s=1.0)
    assert float(b_cds) == pytest.approx(2 * 1 + 2 + 1 / 12, rel=1e-12)


def test_fixed_pattern_seeds_are_integers():
    """fixed_pattern_draws(seed=1.5) drew seed 1's pattern and seed=True too; NoiseTerms(seed=1.5) was taken."""
    from isettorch.sensor.noise import fixed_pattern_draws
    from isettorch.sensor.noise_terms import NoiseTerms

    assert torch.equal(fixed_pattern_draws(4, 4, 1)["dsnu"], fixed_pattern_draws(4, 4, 1)["dsnu"])
    for seed in (1.5, True, -1, 2**64):
        with pytest.raises(ValueError, match="seed: expected an integer"):
            fixed_pattern_draws(4, 4, seed)
        with pytest.raises(ValueError, match="seed: expected an integer"):
            NoiseTerms(seed=seed)
    with pytest.raises(ValueError, match="rows: expected an integer number of pixels"):
        fixed_pattern_draws(2.5, 4, 1)


def test_shot_noise_gradient_of_a_noise_dependent_loss():
    # d E[e^2] / d mean = 2 mean + 1 (Poisson: E[e^2] = mean + mean^2). The straight-through Poisson draw averages
    # 2 mean (the documented bias, -1 / (2 mean + 1)); the reparameterised Gaussian is unbiased.
    for mode, expected in (("poisson", 4.0), ("gaussian", 5.0)):
        m = torch.full((400_000,), 2.0, dtype=torch.float64, requires_grad=True)
        (shot_noise(m, mode, torch.Generator().manual_seed(1)) ** 2).sum().backward()
        assert float(m.grad.mean()) == pytest.approx(expected, abs=0.03)


@pytest.mark.parametrize("mode", ["poisson", "gaussian"])
def test_an_infinite_mean_saturates_instead_of_turning_nan(mode):
    """Electrons beyond float32 (1e6 e-/s for 1e33 s) are an infinite mean: the Gaussian tail's inf + (draw - T) inf
    (and inf + inf z) was NaN for a draw below the mean, and the capture's raw NaN where its noise-free raw saturates.
    Now inf stays inf and the pixel is full, as without noise; finite means draw as before."""
    from isettorch.sensor import Sensor

    mean = torch.tensor([1e3, float("inf"), 5e9, float("inf")])
    out = shot_noise(mean, mode, generator=torch.Generator().manual_seed(0))
    assert torch.isinf(out[[1, 3]]).all() and (out[[1, 3]] > 0).all() and torch.isfinite(out[[0, 2]]).all()
    sen = Sensor.preset("isetcam_default", rows=2, cols=2, shot_noise=mode)
    r = sen.capture(torch.full((1, 1, 2, 2), 1e6), exposure_s=1e33, generator=torch.Generator().manual_seed(0))
    assert torch.equal(r.data, r.noise_free) and torch.equal(r.noise_free, torch.ones_like(r.noise_free))
