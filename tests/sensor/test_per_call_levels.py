"""Per-call sensor levels ([B] tensors), exposure compensation, and the all-channel readout used for targets."""

from __future__ import annotations

import pytest
import torch

from isettorch.optics.optical_image import OpticalImage
from isettorch.sensor import Sensor


def _oi(dtype=torch.float64, b=1):
    g = torch.Generator().manual_seed(0)
    photons = torch.rand(b, 31, 16, 16, generator=g, dtype=dtype) * 1e17
    return OpticalImage(photons, torch.arange(400.0, 701.0, 10.0, dtype=dtype), sample_spacing_m=2e-6)


def test_per_call_read_noise_gives_each_sample_its_own_sigma():
    """Dark frame, no shot noise: the volts' std is the read noise given per sample (EMVA 1288 dark noise)."""
    s = Sensor(rows=128, cols=128, cfa="RGGB", shot_noise="off", output_units="volts")
    rate = torch.zeros(2, 1, 128, 128, dtype=torch.float64)
    sigma = torch.tensor([1e-3, 4e-3], dtype=torch.float64)
    # volts are clipped at 0: add an offset so the noise is not clipped
    s.analog_offset_v = 0.05
    raw = s.capture(rate, exposure_s=0.01, read_noise_v=sigma, generator=torch.Generator().manual_seed(1))
    std = raw.data.flatten(1).std(dim=1)
    # std of 16384 normal samples: relative standard error 1/sqrt(2 n) = 0.55 %
    assert torch.allclose(std, sigma, rtol=0.03)
    assert torch.equal(raw.noise["read_noise_v"], sigma)


def test_per_call_levels_equal_the_module_levels():
    oi = _oi()
    kw = dict(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB", adc_bits=10, shot_noise="poisson")
    levels = dict(read_noise_v=2e-3, dark_current_e_per_s=50.0, dsnu_sigma_v=1e-3, prnu_sigma_percent=1.0,
                  conversion_gain_v_per_e=5e-5)
    fixed = Sensor(**kw, fpn_mode="per_frame", **levels)
    per_call = Sensor(**kw, fpn_mode="per_frame")
    a = fixed(oi, exposure_s=0.002, generator=torch.Generator().manual_seed(3))
    b = per_call(oi, exposure_s=0.002, generator=torch.Generator().manual_seed(3),
                 **{k: torch.tensor([v], dtype=torch.float64) for k, v in levels.items()})
    assert torch.allclose(a.noise_free, b.noise_free, rtol=1e-14, atol=0)
    assert float((a.data != b.data).double().mean()) < 1e-3  # same draws (rounding may move a rare ADC step)


def test_a_learnable_isetcam_gain_of_one_keeps_its_gradient():
    """ISETCam's convention divides the volts by the analog gain; a learnable gain of exactly 1 stays in the graph
    (the shortcut for a fixed gain of 1 dropped it: no gradient), its gradient the central difference's."""
    s = Sensor(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB", gain_convention="isetcam", output_units="volts")
    oi = _oi()

    def loss(gain):
        return (s(oi, exposure_s=1e-4, analog_gain=gain, noise=False).data ** 2).mean()

    gain = torch.ones(1, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(loss(gain), gain)
    h = 1e-6
    fd = (loss(torch.tensor([1 + h], dtype=torch.float64)) - loss(torch.tensor([1 - h], dtype=torch.float64))) / (2 * h)
    assert float(fd) < 0 and float(grad) == pytest.approx(float(fd), rel=1e-6)


@pytest.mark.parametrize("name", ["read_noise_v", "dark_current_e_per_s", "dsnu_sigma_v"])
def test_a_learnable_level_at_zero_keeps_its_gradient(name):
    """A per-call level that requires grad stays in the graph at 0 (the stage runs with a zero level): its
    gradient equals a one-sided finite difference with the same generator (common random numbers), not None."""
    s = Sensor(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB", shot_noise="gaussian", output_units="volts")
    s.analog_offset_v = 0.05  # keep negative noise away from the clip at 0
    oi = _oi()
    h = {"read_noise_v": 1e-6, "dark_current_e_per_s": 1e-3, "dsnu_sigma_v": 1e-6}[name]

    def loss(value):
        raw = s(oi, exposure_s=0.002, generator=torch.Generator().manual_seed(4), **{name: value})
        return (raw.data ** 2).mean()

    level = torch.zeros(1, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(loss(level), level)
    with torch.no_grad():
        fd = (loss(torch.full((1,), h, dtype=torch.float64)) - loss(level)) / h
    assert float(grad.abs()) > 0
    torch.testing.assert_close(grad, fd.reshape(1), rtol=1e-3, atol=0)


def test_bad_per_call_level_is_named():
    s = Sensor(rows=4, cols=4)
    with pytest.raises(ValueError, match="read_noise_e"):
        s(_oi(), exposure_s=0.01, read_noise_e=1.0)
    with pytest.raises(ValueError, match="read_noise_v"):
        s(_oi(), exposure_s=0.01, read_noise_v=-1.0)


@pytest.mark.parametrize("kw", [dict(analog_gain=1e-50), dict(analog_gain=1e39), dict(exposure_s=1e-50),
                                dict(conversion_gain_v_per_e=1e-50)])
def test_a_per_call_value_the_data_dtype_cannot_hold_is_named(kw):
    """float32 data: 1e-50 would become 0 (a division by it NaN; an exposure of 0 an all-black raw) and 1e39 inf.
    The value is refused, naming the argument, instead."""
    s = Sensor(rows=4, cols=4, gain_convention="isetcam", output_units="electrons")
    oi = _oi(torch.float32)
    with pytest.raises(ValueError, match=f"{next(iter(kw))}: .* outside the range of torch.float32"):
        s(oi, **kw)
    raw = s(_oi(torch.float64), noise=False, **kw)  # float64 holds it
    assert torch.isfinite(raw.data).all()


def test_exposure_compensation_and_all_channel_readout():
    oi = _oi(b=2)
    s = Sensor(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB", adc_bits=12, auto_exposure="percentile",
               ae_percentile=98.0, ae_target=0.8)
    t0 = s.exposure_for(oi)
    t1 = s.exposure_for(oi, exposure_ev=torch.tensor([1.0, -2.0]))
    assert torch.allclose(t1, t0 * torch.tensor([2.0, 0.25], dtype=t0.dtype), rtol=1e-15)
    rates, xyz = s.channel_rates(oi, extra_weights=torch.ones(31, 1, dtype=torch.float64))
    assert rates.shape == (2, 3, 16, 16) and xyz.shape == (2, 1, 16, 16)
    assert torch.allclose(s.cfa.mosaic(rates), s.electron_rate(oi), rtol=1e-14, atol=0)
    raw = s(oi, noise=False)
    all_channels = s.readout(rates, raw.exposure_s, raw.analog_gain)
    assert torch.allclose(s.cfa.mosaic(all_channels), raw.noise_free, rtol=1e-15, atol=0)
    # the linear response: output units per electron x electrons = noise-free DN above black (below saturation)
    k = s.gain_per_electron(batch=2)
    lin = (rates * raw.exposure_s.reshape(-1, 1, 1, 1)) * k.reshape(-1, 1, 1, 1) + s.black_level_dn
    below = all_channels < s.white_level_dn
    assert torch.allclose(all_channels[below], lin[below], rtol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 7, 1000])
def test_percentile_matches_numpy(n):
    import numpy as np

    from isettorch.sensor.exposure import percentile_linear

    x = torch.rand(3, n, generator=torch.Generator().manual_seed(n), dtype=torch.float64)
    for p in (0.0, 12.5, 50.0, 98.0, 100.0):
        np.testing.assert_allclose(percentile_linear(x, p).numpy(), np.percentile(x.numpy(), p, axis=1),
                                   rtol=1e-14, atol=0)


def test_per_call_pixel_size_equals_a_sensor_of_that_pitch_per_item():
    """A per-call pixel pitch ``[B]`` (one OI sample per pixel, each item at its own spacing): each item's channel
    rates and capture equal those of a sensor built with that item's pitch (the photodiode area fill x pitch^2 is
    the only difference: ISETCam sensorCompute), the raw carries the pitches, and the sensor's own pitch is not
    used. Bad input names ``pixel_size_m``."""
    g = torch.Generator().manual_seed(4)
    pitches = torch.tensor([1.4e-6, 2.8e-6, 2.0e-6], dtype=torch.float64)
    photons = torch.rand(3, 31, 20, 20, generator=g, dtype=torch.float64) * 1e17
    waves = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    oi = OpticalImage(photons, waves, sample_spacing_m=pitches)
    kw = dict(rows=16, cols=16, cfa="RGGB", adc_bits=12, fill_factor=0.6)
    merged = Sensor(pixel_size_m=1.4e-6, **kw)
    rates, _ = merged.channel_rates(oi, qe_scale=torch.tensor([0.5, 0.7, 0.9], dtype=torch.float64),
                                     pixel_size_m=pitches)
    raw = merged(oi, exposure_s=0.004, noise=False, pixel_size_m=pitches)
    assert torch.equal(raw.pixel_size_m, pitches)
    for i, p in enumerate(pitches.tolist()):
        own = Sensor(pixel_size_m=p, **kw)
        one = OpticalImage(photons[i:i + 1], waves, sample_spacing_m=p)
        ref, _ = own.channel_rates(one, qe_scale=[0.5, 0.7, 0.9][i])
        torch.testing.assert_close(rates[i:i + 1], ref, rtol=1e-14, atol=0)
        clean = own(one, exposure_s=0.004, noise=False).noise_free
        torch.testing.assert_close(raw.noise_free[i:i + 1], clean, rtol=1e-12, atol=0)
    # area: the rates scale with the pitch squared for the same irradiance
    same = OpticalImage(photons[:1].expand(3, -1, -1, -1), waves, sample_spacing_m=pitches)
    r3, _ = merged.channel_rates(same, pixel_size_m=pitches)
    torch.testing.assert_close(r3 / r3[:1], (pitches / pitches[0]).pow(2).reshape(3, 1, 1, 1).expand_as(r3),
                               rtol=1e-12, atol=0)
    with pytest.raises(ValueError, match="pixel_size_m"):  # a spacing that is not the pitch
        merged.channel_rates(oi, pixel_size_m=2.0e-6)
    with pytest.raises(ValueError, match="pixel_size_m"):
        merged.channel_rates(oi, pixel_size_m=-pitches)
    with pytest.raises(ValueError, match="pixel_size_m"):  # needs one sample per pixel with area sampling
        Sensor(pixel_size_m=1.4e-6, sampling="isetcam", **kw).channel_rates(oi, pixel_size_m=pitches)
    with pytest.raises(ValueError, match="pixel_size_m"):  # and a fixed size
        Sensor(pixel_size_m=1.4e-6, cfa="RGGB").channel_rates(oi, pixel_size_m=pitches)


def test_exposure_compensation_out_of_the_dtype_range_and_vignetting_shape_are_named():
    s = Sensor(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB")
    for ev in (200.0, -200.0):
        with pytest.raises(ValueError, match="exposure_ev"):
            s(_oi(torch.float32), exposure_ev=ev)
    with pytest.raises(ValueError, match=r"vignetting: expected a scalar or a \[rows, cols\]"):
        Sensor(rows=4, cols=4, vignetting=torch.ones(3, 3))
    sized_later = Sensor(pixel_size_m=2e-6, cfa="RGGB", vignetting=torch.ones(3, 3))
    with pytest.raises(ValueError, match="vignetting: the map is"):
        sized_later(_oi())
    with pytest.raises(ValueError, match=r"expected 1 value \(the batch has one sample\), got 2"):
        s(_oi(), exposure_s=[0.01, 0.02])
