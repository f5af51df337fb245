"""Analog gain and offset against the levels they set: auto-exposure of an electrons readout, the white level with a
negative offset, the sensor metrics at the sensor's own gain, and the Tukey-lambda read noise's logistic shape
(audit of 2026-12-02; each case failed before)."""

from __future__ import annotations

import math

import pytest
import torch

from isettorch.sensor import Sensor, metrics

RAMP = torch.linspace(0, 1e6, 16, dtype=torch.float64).reshape(1, 1, 4, 4)  # electrons/s, brightest 1e6


@pytest.mark.parametrize("kw", [dict(analog_gain=4.0), dict(analog_offset_v=0.3), dict(analog_gain=0.5)])
def test_an_electrons_readout_is_exposed_as_without_gain_or_offset(kw):
    """The electrons chain clips the pixel at the swing (10,000 e- here) with no analog gain or offset, so
    'luminance' auto-exposure puts the brightest pixel at 0.95 of it whatever they are. Before, the aim took the
    gain and offset: the brightest pixel got 2375 e- at gain 4 and 6650 e- with a 0.3 V offset."""
    base = dict(rows=4, cols=4, cfa="RGGB", output_units="electrons", auto_exposure="luminance")
    plain = Sensor(**base)
    s = Sensor(**base, **kw)
    t = s.exposure_for(None, RAMP)
    raw = s.capture(RAMP, exposure_s=t, noise=False)
    assert float(raw.data.max()) == pytest.approx(0.95 * 1.0 / 1e-4, rel=1e-12)
    assert raw.white_level == pytest.approx(1e4)
    assert torch.equal(raw.data, plain.capture(RAMP, exposure_s=plain.exposure_for(None, RAMP), noise=False).data)


@pytest.mark.parametrize("adc_bits, white", [(None, 0.9), (10, 922.0)])
def test_a_negative_offset_lowers_the_white_level_to_what_the_raw_holds(adc_bits, white):
    """The pixel clips at the 1 V swing before the offset: with -0.1 V its raw holds at most 0.9 V (round(0.9 x
    1024) = 922 DN on 10 bits), which the white level now reports (it reported 1.0 V, 1023 DN)."""
    s = Sensor(rows=4, cols=4, cfa="RGGB", analog_offset_v=-0.1, adc_bits=adc_bits)
    raw = s.capture(torch.full((1, 1, 4, 4), 1e9, dtype=torch.float64), exposure_s=0.01, noise=False)
    assert raw.white_level == pytest.approx(white, rel=1e-12)
    assert float(raw.data.max()) == pytest.approx(white, rel=1e-12)


def test_sensor_metrics_are_those_of_the_raw_at_the_sensors_own_gain():
    """Saturation and the ADC step referred to the pixel through the analog gain (they were taken at gain 1): at
    gain 8 a 10-bit, 1 V, 1e-4 V/e- sensor's raw clips at 1023 codes of 1/1024 V over 8 x 1e-4 V/e- = 1248.8 e-,
    and its step is 1.22 e-; the IMX363-like preset's black level of 64 DN clips its raw at 959 codes of
    0.48/1024 V over 8e-5 V/e- = 5619 e- of its 6000 e- well."""
    kw = dict(rows=4, cols=4, cfa="RGGB", conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0, adc_bits=10,
              read_noise_v=1e-4, dark_current_e_per_s=0.0, prnu_sigma_percent=0.0, dsnu_sigma_v=0.0)
    s = Sensor(**kw, analog_gain=8.0)
    sat = 1023 / 1024 / 8 / 1e-4
    assert metrics.saturation_e(s) == pytest.approx(sat, rel=1e-12)
    lsb_e = 1 / 1024 / 8 / 1e-4
    want = 20.0 / math.sqrt(20.0 + 1.0 + lsb_e**2 / 12)  # shot + read (1 e-) + quantisation at the pixel
    assert float(metrics.pixel_snr(s, 20.0)) == pytest.approx(want, rel=1e-12)
    assert metrics.dynamic_range_db(s) == pytest.approx(20 * math.log10(sat / math.sqrt(1.0 + lsb_e**2 / 12)),
                                                        rel=1e-12)
    iso1 = metrics.iso_saturation(Sensor(**kw))
    assert metrics.iso_saturation(s) == pytest.approx(8 * iso1, rel=1e-12)  # an eighth of the light saturates
    with pytest.raises(ValueError, match="sensor.analog_gain: the sensor's figures of merit take one gain"):
        metrics.saturation_e(Sensor(**kw, analog_gain=[1.0, 2.0]))
    imx = Sensor.preset("imx363", rows=8, cols=8)
    assert metrics.saturation_e(imx) == pytest.approx(959 * 0.48 / 1024 / 8e-5, rel=1e-12)
    assert metrics.saturation_e(imx) < float(imx.saturation_e()) == pytest.approx(6000.0)


def test_a_tukey_lambda_of_zero_is_a_noise_term():
    """Lambda 0 is the logistic distribution (excess kurtosis 1.2): it counted as off, so ISETCam's noise model,
    which has no such term, accepted it and read Gaussian noise."""
    with pytest.raises(ValueError, match="noise_model: 'isetcam' has none of the noise terms"):
        Sensor(rows=4, cols=4, cfa="mono", noise_model="isetcam", read_noise_tukey_lambda=0.0)
    s = Sensor(rows=256, cols=256, cfa="mono", read_noise_v=1e-3, analog_offset_v=0.1, read_noise_tukey_lambda=0.0,
               dark_current_e_per_s=0.0, dsnu_sigma_v=0.0, prnu_sigma_percent=0.0)
    d = s.capture(torch.zeros(1, 1, 256, 256, dtype=torch.float64), exposure_s=0.01).data.flatten()
    z = (d - d.mean()) / d.std()
    assert float((z**4).mean() - 3) == pytest.approx(1.2, abs=0.15)  # 65,536 samples: standard error about 0.04


@pytest.mark.parametrize("units", ["volts", "electrons"])
def test_a_readout_before_the_adc_saturates_at_the_swing_whatever_the_dn_black_level(units):
    # imx363 (10 bits, black 64 DN, swing 0.48 V): the volts raw's saturated pixels read the swing, 0.48 V, but its
    # white level was (1023 - 64) LSB = 0.4495 V (normalized 1.068; 1023 LSB with black 0) and auto-exposure aimed at
    # 0.89 of the real saturation. The black level and the top code are the ADC's, which a volts readout is before.
    s = Sensor.preset("imx363", rows=4, cols=4, output_units=units)
    raw = s.capture(torch.full((1, 1, 4, 4), 1e9, dtype=torch.float64), exposure_s=0.01, noise=False)
    assert float(raw.normalized().max()) == pytest.approx(1.0, abs=1e-12)
    if units == "volts":
        assert float(raw.data.max()) == pytest.approx(s.voltage_swing_v) == pytest.approx(raw.white_level)
    dn = Sensor.preset("imx363", rows=4, cols=4)  # the DN readout: the top code, 1023 - 64 above black
    assert float(dn.capture(torch.full((1, 1, 4, 4), 1e9, dtype=torch.float64), exposure_s=0.01,
                            noise=False).normalized().max()) == pytest.approx(1.0)


def test_the_level_methods_check_a_per_call_gain_as_capture_does():
    """white_level / saturation_v / zero_level took any analog_gain: -1 gave a white level of -1024 DN on a 10-bit
    sensor, 0 a bare ZeroDivisionError with ISETCam's gain convention, NaN a NaN black level. They now refuse it as
    capture() does; a valid per-call gain is the documented value (a 10-bit white of 1023 at gain 2 with no full
    well; the offset scaled by the gain in the black level)."""
    s = Sensor(rows=4, cols=4, adc_bits=10, analog_offset_v=0.01, black_level_dn=64)
    assert s.white_level(analog_gain=2.0) == 1023
    assert s.zero_level(analog_gain=2.0) == pytest.approx(64 + 0.01 * 2 / s.lsb_v)
    iset = Sensor(rows=4, cols=4, adc_bits=10, gain_convention="isetcam", analog_offset_v=0.01, full_well_e=5000.0)
    for sensor in (s, iset):
        for bad in (-1.0, 0.0, math.nan, [1.0, -2.0]):
            for method in (sensor.white_level, sensor.saturation_v, sensor.zero_level):
                with pytest.raises(ValueError, match=r"^analog_gain: expected finite positive values"):
                    method(analog_gain=bad)
