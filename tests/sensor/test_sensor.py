import math

import pytest
import torch

from isettorch import constants, spectral
from isettorch.optics import OpticalImage
from isettorch.sensor import CFA, PRESETS, RawImage, Sensor, SpectralQE, metrics

W3 = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)


def assert_close(actual, expected, rtol=1.3e-6, atol=1e-5):
    """torch.allclose with the error in the message (torch.testing's first call costs seconds of imports)."""
    assert actual.shape == expected.shape, (actual.shape, expected.shape)
    assert torch.allclose(actual, expected, rtol=rtol, atol=atol), (actual - expected).abs().max().item()


def flat_qe(cfa, value=0.5, w=W3):
    return SpectralQE(torch.full((cfa.num_channels, w.numel()), value, dtype=torch.float64), w, cfa.channel_names)


def uniform_oi(level=1e15, size=(16, 16), b=1, dx=2e-6):
    return OpticalImage(torch.full((b, 3, *size), level, dtype=torch.float64), W3, sample_spacing_m=dx)


def simple_sensor(**kw):
    cfa = kw.pop("cfa", CFA("mono"))
    base = dict(rows=6, cols=8, pixel_size_m=2e-6, fill_factor=0.5, cfa=cfa, spectral_qe=flat_qe(cfa),
                conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0, exposure_s=0.01, shot_noise="off")
    base.update(kw)
    return Sensor(**base)


@pytest.mark.parametrize("sampling", ["area", "area_linear", "isetcam"])
def test_uniform_signal_chain_analytic(sampling):
    s = simple_sensor(sampling=sampling, output_units="electrons")
    raw = s(uniform_oi(), noise=False)
    # electrons = E * QE * dlambda * L * pitch^2 * ff * t (ISETCam SignalCurrentDensity x area x t / q)
    expected = 1e15 * 0.5 * 100 * 3 * (2e-6) ** 2 * 0.5 * 0.01
    assert_close(raw.data, torch.full_like(raw.data, expected), rtol=1e-12, atol=0)
    assert raw.units == "electrons" and raw.white_level == pytest.approx(1e4)
    volts = simple_sensor(sampling=sampling)(uniform_oi(), noise=False)
    assert_close(volts.data, torch.full_like(volts.data, expected * 1e-4), rtol=1e-12, atol=0)


def test_gain_conventions_clipping_and_adc():
    e = 1e15 * 0.5 * 100 * 3 * 4e-12 * 0.5 * 0.01 * 1e-4  # 0.03 V
    mult = simple_sensor(analog_gain=2.0)(uniform_oi(), noise=False).data
    iset = simple_sensor(analog_gain=2.0, gain_convention="isetcam")(uniform_oi(), noise=False).data
    assert mult[0, 0, 0, 0].item() == pytest.approx(2 * e, rel=1e-12)
    assert iset[0, 0, 0, 0].item() == pytest.approx(e / 2, rel=1e-12)
    off = simple_sensor(analog_gain=2.0, analog_offset_v=0.01)(uniform_oi(), noise=False).data
    assert off[0, 0, 0, 0].item() == pytest.approx(2 * (e + 0.01), rel=1e-12)
    sat = simple_sensor(exposure_s=10.0)(uniform_oi(), noise=False).data
    assert torch.all(sat == 1.0)  # clipped at the voltage swing
    # ADC: saturation is 2^N - 1 by default, 2^N in ISETCam's mode (FORMAT 4.6 step 9)
    assert torch.all(simple_sensor(exposure_s=10.0, adc_bits=10)(uniform_oi(), noise=False).data == 1023)
    assert torch.all(simple_sensor(exposure_s=10.0, adc_bits=10, adc_mode="isetcam")(uniform_oi(),
                                                                                        noise=False).data == 1024)
    s = simple_sensor(adc_bits=8, black_level_dn=16)
    lsb = 1.0 / 256
    assert s.lsb_v == lsb
    v = torch.tensor([0.5, 1.5, 2.5, 3.49]) * lsb
    assert s.volts_to_dn(v).tolist() == [17, 18, 19, 19]  # round half away from zero, plus black level
    # a fractional black level: whole codes (a real ADC's output), the fraction an offset before the rounding, so
    # over read noise the mean code is the black level plus the signal
    f = simple_sensor(adc_bits=8, black_level_dn=16.25)
    assert f.volts_to_dn(v).tolist() == [17, 18, 19, 20]  # round(x + 0.25) + 16
    assert f.volts_to_dn(torch.tensor([-16.25]) * lsb).tolist() == [0]  # the lowest clipped volts read code 0
    g = torch.Generator().manual_seed(0)
    codes = f.volts_to_dn((3 + torch.randn(200_000, generator=g, dtype=torch.float64)) * lsb)
    assert torch.equal(codes, codes.round()) and codes.mean().item() == pytest.approx(19.25, abs=0.01)
    assert f.white_level_dn == 255
    raw = s(uniform_oi(), noise=False)
    assert raw.units == "dn" and raw.black_level == 16 and raw.white_level == 255
    assert raw.data[0, 0, 0, 0].item() == math.floor(e / lsb + 0.5) + 16
    full = simple_sensor(adc_bits=8, black_level_dn=16, exposure_s=10.0)(uniform_oi(), noise=False)
    assert torch.all(full.data == 255) and torch.all(full.noise_free == 255)
    # auto-exposure with a black level aims at 95 % of the volts that reach code 255
    ae = simple_sensor(adc_bits=8, black_level_dn=16, auto_exposure="luminance")(uniform_oi(), noise=False)
    assert s.usable_swing_v == pytest.approx(239 / 256)
    assert ae.noise_free.max().item() == pytest.approx(16 + 0.95 * 239, rel=1e-9)


def test_adc_codes_beyond_the_dtypes_whole_numbers_are_refused():
    """float32 holds whole numbers up to 2^24: a 25-bit ADC's top code 2^25 - 1 read 2^25 (above white, normalized()
    above 1) and a 32-bit mid code 530242489 read 530242496. Such an ADC now asks for float64, where the codes are
    exact; 24 bits in float32 are."""
    from isettorch.sensor import Sensor

    for bits, dtype in ((24, torch.float32), (25, torch.float64), (32, torch.float64)):
        s = Sensor(rows=4, cols=4, cfa="W", adc_bits=bits).to(dtype)
        top = s.capture(torch.full((1, 1, 4, 4), 1e12, dtype=dtype), exposure_s=1.0, noise=False).data
        assert bool((top == 2 ** bits - 1).all()), (bits, float(top.max()))
        mid = s.capture(torch.full((1, 1, 4, 4), 1234.567, dtype=dtype), exposure_s=1.0, noise=False).data
        v = 1234.567 * s.conversion_gain_v_per_e  # volts of 1234.567 e-
        assert float(mid[0, 0, 0, 0]) == round(v / (s.voltage_swing_v / 2 ** bits)), bits
    s = Sensor(rows=4, cols=4, cfa="W", adc_bits=25)
    with pytest.raises(ValueError, match=r"^adc_bits: 25-bit codes are not whole numbers in torch.float32"):
        s.capture(torch.full((1, 1, 4, 4), 1e3), exposure_s=1.0, noise=False)


def test_batched_exposure_and_gain_equal_one_at_a_time():
    torch.manual_seed(0)
    photons = torch.rand(3, 3, 16, 16, dtype=torch.float64) * 1e15
    oi = OpticalImage(photons, W3, sample_spacing_m=torch.tensor([2e-6, 2.5e-6, 1.5e-6]))
    s = simple_sensor(cfa=CFA("RGGB"), spectral_qe=flat_qe(CFA("RGGB")), dsnu_sigma_v=1e-3,
                      prnu_sigma_percent=1.0, column_fpn_sigma_v=5e-4, adc_bits=12)
    t = torch.tensor([0.01, 0.02, 0.005], dtype=torch.float64)
    g = torch.tensor([1.0, 2.0, 4.0], dtype=torch.float64)
    for sampling in ("area", "area_linear", "isetcam"):
        s.sampling = sampling
        batched = s(oi, exposure_s=t, analog_gain=g)
        for i in range(3):
            one = s(oi[i], exposure_s=t[i], analog_gain=g[i])
            assert_close(batched.data[i:i + 1], one.data, rtol=0, atol=0)
            assert_close(batched.noise_free[i:i + 1], one.noise_free, rtol=1e-15, atol=0)
        assert torch.equal(batched.exposure_s, t)


def test_fixed_pattern_noise_fixed_across_frames_and_seeded():
    kw = dict(dsnu_sigma_v=2e-3, prnu_sigma_percent=2.0, column_fpn_sigma_v=1e-3, rows=64, cols=64)
    s = simple_sensor(seed=1, **kw)
    oi = uniform_oi(size=(140, 140))
    a, b = s(oi).data, s(oi).data
    assert torch.equal(a, b)  # FPN identical across frames (no temporal noise configured)
    c = simple_sensor(seed=2, **kw)(oi).data
    assert not torch.allclose(a, c)
    d = simple_sensor(seed=1, **kw)(oi).data
    assert torch.equal(a, d)  # a new instance with the same seed has the same pattern
    assert "fpn_dsnu" in dict(s.named_buffers())
    # ISETCam mode redraws the patterns on every call
    r = simple_sensor(seed=1, fpn_mode="per_frame", **kw)
    assert not torch.equal(r(oi).data, r(oi).data)
    # DSNU alone: offsets with the configured sigma (4096 pixels: 1.1 % standard error of the std)
    dark = simple_sensor(seed=3, dsnu_sigma_v=2e-3, rows=64, cols=64, analog_offset_v=0.1)
    v = dark(uniform_oi(0.0, size=(140, 140))).data - 0.1
    assert v.std().item() == pytest.approx(2e-3, rel=0.05)
    # CDS cancels the fixed offsets
    cds = simple_sensor(seed=3, dsnu_sigma_v=2e-3, column_fpn_sigma_v=1e-3, cds=True, analog_offset_v=0.1)
    assert torch.allclose(cds(uniform_oi(0.0)).data, torch.full((1, 1, 6, 8), 0.1, dtype=torch.float64))


def test_zero_noise_stages_are_skipped():
    s = simple_sensor(shot_noise="off")
    g = torch.Generator().manual_seed(0)
    state = g.get_state().clone()
    raw = s(uniform_oi(), generator=g)
    assert torch.equal(raw.data, raw.noise_free)
    # skipped, not run at sigma 0 (which gives the same data): no random number was drawn
    assert torch.equal(g.get_state(), state)


def test_gradcheck_noise_free_chain():
    cfa = CFA("GBRG")
    s = simple_sensor(cfa=cfa, spectral_qe=flat_qe(cfa), rows=3, cols=4)
    g = torch.Generator().manual_seed(0)
    photons = (torch.rand(1, 3, 5, 6, dtype=torch.float64, generator=g) * 1e14).requires_grad_()
    t = torch.tensor([0.01], dtype=torch.float64, requires_grad=True)
    scale = torch.tensor(1e-14, dtype=torch.float64)

    def f(p, t):
        oi = OpticalImage(p / scale, W3, sample_spacing_m=2e-6, validate=False)
        return s(oi, exposure_s=t, noise=False).noise_free

    for sampling in ("area", "area_linear", "isetcam"):
        s.sampling = sampling
        assert torch.autograd.gradcheck(f, (photons.detach() * scale, t), eps=1e-6, atol=1e-8)


def _mean_output_grad_matches_fd(sensor, photons, t, qe_param=None):
    """d(sum of noisy output)/d input (straight-through) vs central differences of the noise-free mean."""
    def mean_out(p, tt):
        return sensor(OpticalImage(p, W3, sample_spacing_m=2e-6, validate=False), exposure_s=tt,
                      noise=False).noise_free.sum()

    p = photons.clone().requires_grad_()
    tt = t.clone().requires_grad_()
    g = torch.Generator().manual_seed(0)
    noisy = sensor(OpticalImage(p, W3, sample_spacing_m=2e-6, validate=False), exposure_s=tt, generator=g).data
    params = [p, tt] + ([qe_param] if qe_param is not None else [])
    grads = torch.autograd.grad(noisy.sum(), params)
    for gr in grads:
        assert torch.isfinite(gr).all()
    # exposure
    h = 1e-6
    fd_t = (mean_out(photons, t + h) - mean_out(photons, t - h)) / (2 * h)
    assert grads[1].item() == pytest.approx(fd_t.item(), rel=1e-6)
    # irradiance (one entry)
    e = torch.zeros_like(photons)
    e[0, 1, 5, 6] = 1e12
    fd_p = (mean_out(photons + e, t) - mean_out(photons - e, t)) / (2 * 1e12)
    assert grads[0][0, 1, 5, 6].item() == pytest.approx(fd_p.item(), rel=1e-6)
    return grads


def test_gradients_of_mean_output_match_finite_differences():
    cfa = CFA("RGGB")
    qe = SpectralQE(torch.tensor([[0.6, 0.1, 0.05], [0.1, 0.7, 0.1], [0.05, 0.1, 0.5]], dtype=torch.float64), W3,
                    cfa.channel_names, learnable=True)
    s = simple_sensor(cfa=cfa, spectral_qe=qe, rows=6, cols=8, shot_noise="poisson", read_noise_v=1e-4)
    torch.manual_seed(1)
    photons = torch.rand(1, 3, 16, 16, dtype=torch.float64) * 1e15
    t = torch.tensor([0.01], dtype=torch.float64)
    grads = _mean_output_grad_matches_fd(s, photons, t, qe.raw_filters)
    # QE (softplus parameter): central difference on one filter entry
    h = 1e-6
    with torch.no_grad():
        base = qe.raw_filters.clone()

        def mean_out():
            return s(OpticalImage(photons, W3, sample_spacing_m=2e-6), exposure_s=t, noise=False).noise_free.sum()

        qe.raw_filters[1, 1] = base[1, 1] + h
        up = mean_out()
        qe.raw_filters[1, 1] = base[1, 1] - h
        down = mean_out()
        qe.raw_filters.copy_(base)
    assert grads[2][1, 1].item() == pytest.approx(((up - down) / (2 * h)).item(), rel=1e-5)


def test_gradients_finite_at_zero_light():
    for mode in ("poisson", "gaussian"):
        s = simple_sensor(shot_noise=mode, read_noise_v=0.0, dark_current_e_per_s=0.0, adc_bits=10)
        p = torch.zeros(1, 3, 16, 16, dtype=torch.float64, requires_grad=True)
        t = torch.tensor([0.01], dtype=torch.float64, requires_grad=True)
        out = s(OpticalImage(p, W3, sample_spacing_m=2e-6, validate=False), exposure_s=t).data
        gp, gt = torch.autograd.grad(out.sum(), (p, t))
        assert torch.isfinite(gp).all() and torch.isfinite(gt).all()
        # the response to the first photons is not lost: the shot noise passes the expected response's gradient
        # (d DN / d photon rate = QE dl pixel_area fill_factor t cg / LSB = 0.5 * 100 nm * (2 um)^2 * 0.5 * 0.01 s
        # * 1e-4 V/e / (1 V / 1024) = 1.024e-13) at every sample under a pixel of the 6 x 8 sensor (rows 5-10,
        # columns 4-11 of the 16 x 16 image), none elsewhere; 550 nm, the grid's interior sample
        expected = 0.5 * 100 * (2e-6) ** 2 * 0.5 * 0.01 * 1e-4 * 1024
        under = gp[0, 1, 5:11, 4:12]
        torch.testing.assert_close(under, torch.full_like(under, expected), rtol=1e-9, atol=0)
        assert float(gp[0, 1].abs().sum()) == pytest.approx(48 * expected, rel=1e-9)


def test_auto_exposure_methods():
    torch.manual_seed(2)
    oi = OpticalImage(torch.rand(2, 3, 16, 16, dtype=torch.float64) * 1e15, W3, sample_spacing_m=2e-6)
    for method, target in (("luminance", 0.95), ("mean", 0.18), ("percentile", 0.95)):
        s = simple_sensor(auto_exposure=method, analog_gain=2.0, gain_convention="isetcam")
        raw = s(oi, noise=False)
        v = raw.noise_free.flatten(1)
        stat = {"luminance": v.amax(1), "mean": v.mean(1), "percentile": torch.quantile(v, 0.99, dim=1)}[method]
        assert_close(stat, torch.full_like(stat, target), rtol=1e-9, atol=0)
        assert raw.exposure_s.shape == (2,)
    # ISETCam measures after the (dividing) gain: gain 2 doubles the exposure
    t1 = simple_sensor(auto_exposure="luminance").exposure_for(oi)
    t2 = simple_sensor(auto_exposure="luminance", analog_gain=2.0, gain_convention="isetcam").exposure_for(oi)
    assert_close(t2, 2 * t1)


@pytest.mark.parametrize("convention", ["multiply", "isetcam"])
def test_auto_exposure_leaves_room_for_the_analog_offset(convention):
    # the light's volts reach 0.95 of the room above the offset: (1 - offset x gain) for a 1 V swing; the offset
    # was counted as room, so a 0.3 V offset put the brightest pixel at the swing (clipped, 0.70 V of light)
    torch.manual_seed(3)
    oi = OpticalImage(torch.rand(1, 3, 16, 16, dtype=torch.float64) * 1e15, W3, sample_spacing_m=2e-6)
    # the offset after gain is 0.15 V either way (a multiplying gain above 1: below 1 the pixel's swing limits first)
    gain, offset = (1.5, 0.1) if convention == "multiply" else (2.0, 0.3)
    s = simple_sensor(auto_exposure="luminance", analog_offset_v=offset, analog_gain=gain, gain_convention=convention)
    raw = s(oi, noise=False)
    assert float(raw.noise_free.max()) == pytest.approx(0.15 + 0.95 * (1.0 - 0.15), rel=1e-9)
    with pytest.raises(ValueError, match="analog_offset_v"):
        simple_sensor(auto_exposure="luminance", analog_offset_v=1.2)(oi, noise=False)


def test_capture_and_qe_refuse_what_the_sensor_cannot_read():
    s = simple_sensor(rows=4, cols=4, dsnu_sigma_v=1e-3)
    with pytest.raises(ValueError, match="electron_rate.*4x4"):  # (read as a 5x7 raw)
        s.capture(torch.full((1, 1, 5, 7), 1e4, dtype=torch.float64), exposure_s=0.01)
    w = torch.arange(750.0, 1001.0, 10.0, dtype=torch.float64)  # the filters span 400-700 nm: a black raw
    far = OpticalImage(torch.full((1, w.numel(), 8, 8), 1e15, dtype=torch.float64), w, sample_spacing_m=2e-6)
    with pytest.raises(ValueError, match="wavelengths_nm.*miss"):
        Sensor(rows=4, cols=4, cfa="RGGB")(far, exposure_s=0.01, noise=False)


@pytest.mark.parametrize("method", ["luminance", "mean", "percentile"])
def test_auto_exposure_is_in_the_graph(method):
    # Auto-exposure holds its statistic at the target, so a brightness scale k of the optical image leaves the
    # noise-free signal's statistic unchanged: its total derivative with respect to k is 0 (a detached exposure
    # would give stat / k instead), and the exposure's own derivative is -t / k.
    torch.manual_seed(3)
    base = torch.rand(2, 3, 16, 16, dtype=torch.float64) * 1e15 + 1e14
    k = torch.tensor(1.7, dtype=torch.float64, requires_grad=True)
    s = simple_sensor(auto_exposure=method)
    raw = s(OpticalImage(base * k, W3, sample_spacing_m=2e-6), noise=False)
    v = raw.noise_free.flatten(1)
    stat = {"luminance": v.amax(1), "mean": v.mean(1), "percentile": torch.quantile(v, 0.99, dim=1)}[method]
    (g_stat,) = torch.autograd.grad(stat.sum(), k, retain_graph=True)
    assert abs(float(g_stat)) < 1e-9 * float(stat.detach().sum())
    (g_t,) = torch.autograd.grad(raw.exposure_s.sum(), k)
    assert_close(g_t, -raw.exposure_s.sum().detach() / k.detach(), rtol=1e-9, atol=0)
    # a black image gets the capped exposure, with a finite (zero) gradient
    k0 = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    black = s(OpticalImage(torch.zeros(1, 3, 16, 16, dtype=torch.float64) * k0, W3, sample_spacing_m=2e-6),
              noise=False)
    (g0,) = torch.autograd.grad(black.exposure_s.sum(), k0)
    assert float(black.exposure_s) == 10.0 and float(g0) == 0.0


def test_presets_and_metrics():
    d = Sensor.preset("isetcam_default")
    assert d.pixel_size_m == 2.8e-6 and d.fill_factor == 0.75 and d.cfa.pattern == "GRBG"
    assert d.well_capacity_e == pytest.approx(1e4)
    assert d.dark_current_e_per_s * d.conversion_gain_v_per_e == pytest.approx(1e-3)  # 1 mV/s
    p = Sensor.preset("iset2004_cds")
    assert metrics.well_capacity_e(p) == pytest.approx(1 / 15e-6)
    assert p.read_noise_v / p.conversion_gain_v_per_e == pytest.approx(50.0)
    assert p.dsnu_sigma_v == 2e-3 and p.exposure_s == 0.016 and p.cds
    imx = Sensor.preset("imx363", rows=8, cols=8)
    assert imx.adc_bits == 10 and imx.pixel_size_m == 1.4e-6
    with pytest.raises(ValueError, match="unknown sensor preset"):
        Sensor.preset("nope")
    assert set(PRESETS) >= {"isetcam_default", "imx363", "iset2004_cds"}
    # SNR: shot-noise limited sensor -> sqrt(S); 2004 CDS sensor dark floor = sqrt(2 * 50^2 + 10 * 0.016) e-
    ideal = simple_sensor(shot_noise="poisson")
    assert metrics.pixel_snr(ideal, 400.0).item() == pytest.approx(20.0)
    floor = math.sqrt(2 * 50.0**2 + 10 * 0.016)
    assert metrics.dynamic_range_db(p) == pytest.approx(20 * math.log10((1 / 15e-6) / floor))
    assert metrics.pixel_snr_db(p, 1e4).item() == pytest.approx(
        20 * math.log10(1e4 / math.sqrt(1e4 + floor**2)))


def test_iso_saturation_against_colour_science():
    import colour
    import numpy as np

    s = Sensor.preset("isetcam_default")
    w = np.arange(400, 701, 10.0)
    e = np.asarray(colour.SDS_ILLUMINANTS["D65"][w])  # tabulated at these wavelengths
    v = np.asarray(colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"][w])
    lux = 683 * np.sum(e * v) * 10
    photons = e / lux * w * 1e-9 / (constants.PLANCK_J_S * constants.SPEED_OF_LIGHT_M_PER_S)
    qe = s.spectral_qe(torch.tensor(w)).numpy()
    per_lux_s = (qe * photons).sum(1) * 10 * (2.8e-6) ** 2 * 0.75
    np.testing.assert_allclose(metrics.electrons_per_lux_second(s).numpy(), per_lux_s, rtol=1e-6)
    assert metrics.iso_saturation(s) == pytest.approx(78 / (1e4 / per_lux_s.max()), rel=1e-6)
    # a photodiode full well below the swing's 1e4 e- saturates first: half the well, twice the speed, 6.02 dB
    # less dynamic range (the metrics used the swing's well capacity whatever the full well)
    half = Sensor.preset("isetcam_default", full_well_e=5000.0)
    assert metrics.saturation_e(half) == 5000.0 and metrics.well_capacity_e(half) == pytest.approx(1e4)
    assert metrics.iso_saturation(half) == pytest.approx(2 * metrics.iso_saturation(s), rel=1e-12)
    assert metrics.dynamic_range_db(s) - metrics.dynamic_range_db(half) == pytest.approx(20 * math.log10(2))


def test_raw_image_to_and_checks():
    raw = simple_sensor(adc_bits=10)(uniform_oi(), noise=False)
    r32 = raw.to(dtype=torch.float32)
    assert r32.data.dtype == torch.float32 and r32.noise_free.dtype == torch.float32
    assert r32.exposure_s.dtype == torch.float32
    assert torch.equal(raw.normalized(), raw.data / 1023)
    with pytest.raises(ValueError, match="units"):
        RawImage(torch.zeros(1, 1, 2, 2), "lux", CFA("mono"))
    with pytest.raises(ValueError, match=r"\[B, 1, H, W\]"):
        RawImage(torch.zeros(1, 3, 2, 2), "volts", CFA("mono"))


@pytest.mark.parametrize("key,value", [("exposure_s", -1.0), ("exposure_s", 0.0), ("exposure_s", float("nan")),
                                       ("analog_gain", -1.0), ("analog_gain", float("inf")),
                                       ("exposure_s", torch.tensor([0.01, -0.02]))])
def test_exposure_and_gain_are_checked_at_construction(key, value):
    """As every other level: a bad exposure or gain fails when the sensor is built (a config typo names its key), not
    at the first capture; a [B] tensor of good values is accepted."""
    with pytest.raises(ValueError, match=f"{key}: expected"):
        Sensor(rows=4, cols=4, **{key: value})
    Sensor(rows=4, cols=4, exposure_s=torch.tensor([0.01, 0.02]), analog_gain=2.0)


def test_input_errors():
    with pytest.raises(ValueError, match="fill_factor"):
        simple_sensor(fill_factor=1.5)
    with pytest.raises(ValueError, match="read_noise_v"):
        simple_sensor(read_noise_v=-1.0)
    with pytest.raises(ValueError, match="sampling"):
        simple_sensor(sampling="nearest")
    with pytest.raises(ValueError, match="exposure_s"):
        simple_sensor()(uniform_oi(), exposure_s=-1.0)
    with pytest.raises(TypeError, match="OpticalImage"):
        simple_sensor()(torch.ones(1, 3, 8, 8))


def test_size_to_oi_and_fov():
    s = Sensor(pixel_size_m=2.8e-6, cfa="GBRG")
    oi = OpticalImage(torch.ones(1, 3, 80, 120, dtype=torch.float64), W3, sample_spacing_m=7.063304871579908e-6,
                      pad_rows=8, pad_cols=12)
    rows, cols = s.size_for(oi)
    assert rows % 2 == 0 and cols % 2 == 0
    assert cols * 2.8e-6 <= 96 * 7.063304871579908e-6 < (cols + 2) * 2.8e-6
    # ISETCam sensorSetSizeToFOV: 10 deg at the parity case's focal plane -> 242 columns (FORMAT case)
    s2 = Sensor(rows=72, cols=88, pixel_size_m=2.8e-6, cfa="GBRG").set_size_to_fov(10.0, 0.0038752293174003525)
    assert s2.cols == 242 and s2.rows == 198  # the parity case's 198 x 242 (aspect of the 72 x 88 default)
    oi2 = oi.replace(image_distance_m=torch.tensor([0.0038752293174003525], dtype=torch.float64))
    assert Sensor(rows=72, cols=88, cfa="GBRG").set_size_to_fov(10.0, oi2).cols == 242
    w = spectral.default_wavelengths()
    assert s.qe(OpticalImage(torch.ones(1, 31, 4, 4), w)).shape == (3, 31)


def test_isetcam_noise_model_residual_std():
    # FORMAT 4.8: residual std = sqrt(prnu^2 (v + dt)^2 + cg (v + dt) + cg^2 / 12 + read^2 + dsnu^2)
    cg, read, dsnu, prnu, dark_v, t = 1e-4, 1e-3, 2e-3, 1.0, 1e-3, 0.05
    s = simple_sensor(rows=200, cols=250, noise_model="isetcam", fpn_mode="per_frame", shot_noise="poisson",
                      read_noise_v=read, dsnu_sigma_v=dsnu, prnu_sigma_percent=prnu,
                      dark_current_e_per_s=dark_v / cg, exposure_s=t)
    oi = uniform_oi(level=0.3 / (0.5 * 100 * 3 * 4e-12 * 0.5 * t * cg), size=(210, 260))
    raw = s(oi, generator=torch.Generator().manual_seed(0))
    resid = (raw.data - raw.noise_free).flatten()
    v = 0.3 + dark_v * t
    expected = math.sqrt((prnu / 100 * v) ** 2 + cg * v + cg**2 / 12 + read**2 + dsnu**2)
    assert resid.std().item() == pytest.approx(expected, rel=0.01)  # 50 000 pixels: 0.3 % standard error
    assert resid.mean().item() == pytest.approx(dark_v * t, abs=3 * expected / math.sqrt(resid.numel()))
    # few electrons: Poisson counts (integers x cg)
    low = simple_sensor(noise_model="isetcam", shot_noise="poisson", rows=50, cols=50)
    e = low(uniform_oi(level=1e12, size=(60, 60))).data / cg
    assert torch.allclose(e, e.round(), atol=1e-6)


def test_sensor_snr_is_the_metrics_noise_model():
    """sensor.metrics and metrics.snr share one noise model: every term, written out by hand (EMVA 1288 eq. 2-6)
    for a sensor with read noise, DSNU, PRNU, column FPN, dark current and a 10-bit ADC."""
    from isettorch.metrics import snr

    s = simple_sensor(shot_noise="poisson", read_noise_v=2e-4, dsnu_sigma_v=3e-4, prnu_sigma_percent=1.0,
                      column_fpn_sigma_v=1e-4, dark_current_e_per_s=100.0, adc_bits=10)
    sig = torch.tensor([0.0, 10.0, 1000.0, 5000.0], dtype=torch.float64)
    lsb_e = (1.0 / 2**10) / 1e-4  # swing / 2^N in electrons
    assert s.lsb_v / 1e-4 == pytest.approx(lsb_e)
    var = sig + 100.0 * 0.01 + 2.0**2 + 3.0**2 + 1.0**2 + (0.01 * sig) ** 2 + lsb_e**2 / 12
    torch.testing.assert_close(metrics.noise_e(s, sig), var.sqrt(), rtol=1e-12, atol=0)
    expect = sig / var.sqrt()
    torch.testing.assert_close(metrics.pixel_snr(s, sig), expect, rtol=1e-12, atol=0)
    torch.testing.assert_close(snr.pixel_snr(sig, 2.0, 3.0, prnu_percent=1.0, dark_current_e=1.0, column_fpn_e=1.0,
                                             lsb_e=lsb_e), expect, rtol=1e-12, atol=0)
    # saturation: the raw's top code, 1023 of 1024 steps of the 1e4 e- swing (the ADC clips before the pixel)
    assert metrics.dynamic_range_db(s) == pytest.approx(float(snr.dynamic_range_db(1e4 * 1023 / 1024,
                                                                                   var[0].sqrt())), rel=1e-12)
    # a noise-free pixel: SNR inf above zero signal, 0 at zero; dynamic range inf
    quiet = simple_sensor()
    assert metrics.pixel_snr(quiet, sig).tolist() == [0.0, math.inf, math.inf, math.inf]
    assert metrics.dynamic_range_db(quiet) == math.inf


@pytest.mark.parametrize("levels", [{"noise_model": "isetcam"}, {"cds": True},
                                    {"row_noise_v": 5e-4, "column_noise_v": 3e-4}, {"shot_noise": "off"},
                                    {"dark_shading_e_per_s": 20.0}])
def test_sensor_noise_floor_is_the_captures(levels):
    """The figures of merit's dark floor is the variance of the sensor's own dark captures (64 frames of 64 x 64,
    12-bit): ISETCam's noise model samples the read noise once and adds DSNU, temporal row/column noise and dark shading
    count, a sensor without shot noise has no dark-current shot noise. A parameter formula of its own gave 3.94,
    3.10, 3.10 and 3.10 DN^2 for the first, third, fourth and fifth sensors against 3.12, 8.77, 2.27 and 3.77
    measured. The variance's standard error here is under 1 % (row/column noise: 64 x 64 draws a frame)."""
    s = Sensor(adc_bits=12, conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0, read_noise_v=3e-4,
               dark_current_e_per_s=50.0, dsnu_sigma_v=2e-4, exposure_s=0.1, black_level_dn=200, cfa="mono",
               rows=64, cols=64, fpn_mode="per_frame", **levels)
    dark = s.capture(torch.zeros(64, 1, 64, 64, dtype=torch.float64), exposure_s=0.1, analog_gain=1.0, noise=True,
                     generator=torch.Generator().manual_seed(0))
    lsb_e = s.lsb_v / s.conversion_gain_v_per_e
    floor_dn2 = float(metrics.noise_e(s, 0.0, 0.1)) ** 2 / lsb_e**2
    assert floor_dn2 == pytest.approx(float(dark.data.double().var()), rel=0.015)
    _, b = s.poisson_gaussian(exposure_s=0.1, analog_gain=1.0)
    assert floor_dn2 == pytest.approx(float(b[0]), rel=1e-12)


def test_prnu_beyond_the_gaussian_gain_models_range_is_an_error():
    """PRNU is a gain 1 + sigma z per pixel: above 20 % enough pixels would get a negative gain, clipped to 0
    silently (150 % zeroed a quarter of them); 20 % is accepted."""
    from isettorch.sensor.sensor import MAX_PRNU_SIGMA_PERCENT

    with pytest.raises(ValueError, match=r"prnu_sigma_percent: expected at most 20\.0 %"):
        Sensor(rows=4, cols=4, prnu_sigma_percent=150.0)
    s = Sensor(rows=4, cols=4, prnu_sigma_percent=MAX_PRNU_SIGMA_PERCENT)
    rate = torch.full((2, 1, 4, 4), 1e5)
    for per_call in (150.0, torch.tensor([1.0, 150.0])):  # per-call levels (the data pairs' path) are checked too
        with pytest.raises(ValueError, match=r"prnu_sigma_percent: expected at most 20\.0 %"):
            s.capture(rate, exposure_s=1e-3, prnu_sigma_percent=per_call, generator=torch.Generator().manual_seed(0))


def test_capture_inputs_that_gave_silent_wrong_numbers_are_refused():
    """Bad input audit: an integer electron rate truncated the exposure 0.0123 s to 0 and read black; a bool level
    (exposure_s=True) was 1 s; readout clipped a negative rate to 0 and passed NaN; auto-exposure gave a NaN or
    negative image the longest exposure (10 s), hiding it, and took a zero or negative swing or maximum exposure."""
    import math

    from isettorch.sensor.exposure import auto_exposure

    s = Sensor(rows=8, cols=8, adc_bits=10)
    with pytest.raises(ValueError, match="electron_rate: expected torch.float32 or torch.float64, got torch.int64"):
        s.capture(torch.full((1, 1, 8, 8), 10**4), exposure_s=0.0123, noise=False)
    for name, value in (("exposure_s", True), ("analog_gain", torch.tensor([True]))):
        with pytest.raises(TypeError, match=f"{name}: expected a number"):
            s.capture(torch.full((1, 1, 8, 8), 1e4), **{"exposure_s": 0.01, name: value}, noise=False)
    for bad in (-torch.ones(1, 3, 8, 8), torch.full((1, 3, 8, 8), math.nan)):
        with pytest.raises(ValueError, match="electron_rate: expected finite, non-negative"):
            s.readout(bad, 0.01)
    v = torch.full((2, 1, 8, 8), 10.0, dtype=torch.float64)
    v[1, 0, 0, 0] = math.nan
    t = auto_exposure(v, 1.0)
    assert t[0].item() == pytest.approx(0.95 / 10.0) and math.isnan(t[1].item())  # (item 0 unaffected)
    assert math.isnan(auto_exposure(-torch.ones(1, 1, 4, 4), 1.0).item())
    assert auto_exposure(torch.zeros(1, 1, 4, 4), 1.0).item() == 10.0  # black: the longest exposure, as documented
    with pytest.raises(ValueError, match="exposure_s: expected finite values"):  # a capture refuses the NaN exposure
        s.capture(torch.full((2, 1, 8, 8), 1e4), exposure_s=t, noise=False)
    for kw, name in (({"voltage_swing_v": 0.0}, "voltage_swing_v"), ({"max_exposure_s": -1.0}, "max_exposure_s")):
        with pytest.raises(ValueError, match=f"{name}: expected a finite number > 0"):
            auto_exposure(v, **{"voltage_swing_v": 1.0, **kw})


def test_a_raw_images_levels_are_checked():
    """RawImage took a white level equal to the black level (normalized() gave inf), NaN levels (NaN) and a
    fractional ADC bit depth; each is a ValueError naming the level. [B] tensor levels are the capture's own."""
    import math

    from isettorch.sensor import CFA, RawImage

    d = torch.zeros(1, 1, 4, 4)
    for kw, name in (({"white_level": 64.0, "black_level": 64.0}, "white_level"),
                     ({"white_level": 0.0}, "white_level"), ({"white_level": math.nan}, "white_level"),
                     ({"black_level": math.nan, "white_level": 1.0}, "black_level"),
                     ({"white_level": 1.0, "adc_bits": 2.5}, "adc_bits")):
        with pytest.raises(ValueError, match=f"^{name}: expected"):
            RawImage(d, "dn", CFA("RGGB"), **kw)
    ok = RawImage(d + 32.0, "dn", CFA("RGGB"), black_level=0.0, white_level=torch.tensor([64.0]))
    assert float(ok.normalized().mean()) == 0.5


def test_sensor_cfa_and_filter_errors_name_the_sensors_arguments():
    """Sensor(cfa=5) and Sensor(filters='x') raised errors naming the CFA's 'cell' and the filter set's 'name',
    arguments a Sensor user never wrote."""
    with pytest.raises(TypeError, match="^cfa: cell: expected a pattern string"):
        Sensor(cfa=5)
    with pytest.raises(ValueError, match="^filters: unknown filter set 'x'"):
        Sensor(filters="x")


def test_saturation_is_the_wells_whatever_the_readout_gain_and_black_level():
    """An audit of the sensor's numbers (2026-12-02): (a) at a multiplying analog gain below 1 the DN and volts raws
    recorded 15,000 e- from a 10,000 e- well (swing / conversion gain), the electrons raw 10,000; (b) an ISETCam ADC
    (no clamp at the top code) with a black level reported a white level of 2^N while its saturated pixels read
    2^N + black (normalized 1.067); (c) cds=True with the ISETCam noise model was ignored."""

    rate = torch.full((1, 1, 2, 2), 15000.0, dtype=torch.float64)  # 15,000 e- in 1 s
    kw = dict(rows=2, cols=2, cfa="W", conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0)
    dn = Sensor(**kw, adc_bits=12).capture(rate, exposure_s=1.0, analog_gain=0.5, noise=False)
    volts = Sensor(**kw).capture(rate, exposure_s=1.0, analog_gain=0.5, noise=False)
    electrons = Sensor(**kw, output_units="electrons").capture(rate, exposure_s=1.0, analog_gain=0.5, noise=False)
    assert float(dn.data.max()) == 2048.0 and float(dn.white_level) == 2048.0  # 10,000 e- x 1e-4 V x 0.5 / (1/4096)
    assert float(volts.data.max()) == 0.5 and float(volts.white_level) == 0.5
    assert float(electrons.data.max()) == 10000.0
    assert float(dn.normalized().max()) == 1.0 and float(volts.normalized().max()) == 1.0
    below = Sensor(**kw, adc_bits=12).capture(rate / 3, exposure_s=1.0, analog_gain=0.5, noise=False)
    assert float(below.data.max()) == pytest.approx(5000 * 1e-4 * 0.5 * 4096, abs=0.5)  # unclipped below the well
    for fw, want in ((None, 1024 + 64), (5000.0, 512 + 64), (20000.0, 1024 + 64)):
        s = Sensor(**kw, adc_bits=10, adc_mode="isetcam", black_level_dn=64, full_well_e=fw)
        r = s.capture(torch.full((1, 1, 2, 2), 3e4, dtype=torch.float64), exposure_s=1.0, noise=False)
        assert float(r.data.max()) == want and float(r.white_level) == want and float(r.normalized().max()) == 1.0
    with pytest.raises(ValueError, match="cds: noise_model 'isetcam' has no correlated double sampling"):
        Sensor(cds=True, noise_model="isetcam")


def test_a_sensor_sized_to_a_magnified_image_is_refused_not_allocated():
    """A 1 m lens imaging a 10 deg scene at 1.2 m (magnification 5) gave an optical image 1.05 m wide: the default
    camera sized its sensor to 374,950^2 pixels and died in the allocator after 18 s and 8 GB, naming nothing. Beyond
    2.5e8 pixels automatic sizing is refused naming rows / cols; given rows and cols still render."""
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.scene import uniform

    oi = DiffractionLimitedOptics(f_number=4, focal_length_m=1.0)(uniform(size=8))
    with pytest.raises(ValueError, match=r"rows, cols: sized to the optical image \(1050 x 1050 mm at pixel_size_m "
                                         r"2.8e-06\), the sensor would have 374950 x 374950 pixels"):
        Sensor(pixel_size_m=2.8e-6).size_for(oi)
    assert Sensor(pixel_size_m=2.8e-6, rows=4, cols=6).size_for(oi) == (4, 6)
