"""Sensor figures of merit: well capacity, pixel SNR vs signal, dynamic range, ISO saturation speed.

Noise model: :func:`isettorch.metrics.snr.noise_variance_e` (EMVA 1288 release 4.0, eq. 2-6, in electrons): the
signal's shot noise and PRNU, on the dark floor of the sensor's own capture (:meth:`Sensor.poisson_gaussian`'s terms:
CDS, the noise model, temporal row/column noise, dark shading and a sensor without shot noise included).
"""

from __future__ import annotations

import math

import torch

from .. import spectral
from ..metrics.snr import dynamic_range_db as _dynamic_range_db
from ..metrics.snr import noise_variance_e
from ..metrics.snr import pixel_snr as _pixel_snr
from .sensor import Sensor

__all__ = ["well_capacity_e", "saturation_e", "noise_e", "pixel_snr", "pixel_snr_db", "dynamic_range_db",
           "iso_saturation", "electrons_per_lux_second"]


def well_capacity_e(sensor: Sensor) -> float:
    """Electrons at the voltage swing: swing / conversion gain (ISETCam ``pixelGet('well capacity')``, the sensor's
    :attr:`~Sensor.well_capacity_e`); a lower photodiode full well saturates first (:func:`saturation_e`)."""
    return sensor.well_capacity_e


def _pixel_volts_per_adc_volt(sensor: Sensor) -> float:
    """The inverse of the sensor's own analog gain (pixel volts per volt at the ADC input): ``1 / gain``, or ``gain``
    in ISETCam's convention, which divides by it."""
    gain = sensor.analog_gain
    if isinstance(gain, torch.Tensor | list | tuple) and torch.as_tensor(gain).numel() != 1:
        raise ValueError(f"sensor.analog_gain: the sensor's figures of merit take one gain, got "
                         f"{torch.as_tensor(gain).numel()} (one per item); set the sensor's gain to the one to report")
    g = float(torch.as_tensor(gain).detach().reshape(()))
    return g if sensor.gain_convention == "isetcam" else 1.0 / g


def saturation_e(sensor: Sensor) -> float:
    """Electrons at which the sensor's raw saturates, at its own analog gain and offset: the pixel's
    (:meth:`Sensor.saturation_e`: :func:`well_capacity_e`, or the photodiode's full well ``full_well_e`` where that
    is lower, EMVA 1288 release 4.0, section 4.1), or fewer where the readout clips first: the raw's white level
    (:meth:`Sensor.saturation_v`: the ADC's top code, lowered by a black level, or the amplified swing) referred to
    the pixel, ``(saturation_v / gain - offset) / conversion gain``. The IMX363-like preset's 10-bit raw with a
    black level of 64 DN clips at 5619 e- of its 6000 e- well; at analog gain 8 a 10,000 e- pixel's raw clips at
    1250 e-. An electrons readout clips at the pixel's."""
    if sensor.output_units == "electrons":
        return float(sensor.saturation_e())
    per_adc_volt = _pixel_volts_per_adc_volt(sensor)
    v = float(sensor.saturation_v()) * per_adc_volt - sensor.analog_offset_v
    return v / sensor.conversion_gain_v_per_e


def _noise_parameters_e(sensor: Sensor, exposure_s: float | None) -> dict:
    """The sensor's noise in electrons at the pixel, as :func:`isettorch.metrics.snr.noise_variance_e` takes it:
    the whole dark floor of a capture (the sensor's :meth:`~Sensor.poisson_gaussian` terms in pixel volts over the
    conversion gain: read noise, twice with CDS in the physical chain, dark-current shot noise, DSNU and column offsets
    where CDS does not cancel them, temporal row/column noise, dark shading) as ``read_noise_e``, the ADC step of a
    DN readout referred to the pixel through the sensor's analog gain (at gain 8 an eighth of the step; it was taken
    at gain 1 whatever the gain), PRNU, and whether the signal has shot noise."""
    t = float(sensor.exposure_s if exposure_s is None else exposure_s)
    if not (math.isfinite(t) and t >= 0):
        raise ValueError(f"exposure_s: expected a finite exposure >= 0 in seconds, got {exposure_s!r}")
    cg = sensor.conversion_gain_v_per_e
    shot, var_v = sensor._dark_variance_v2(sensor.noise_parameters(enabled=True), t, cg)
    return dict(read_noise_e=math.sqrt(var_v) / cg, prnu_percent=sensor.prnu_sigma_percent,
                lsb_e=sensor.lsb_v * _pixel_volts_per_adc_volt(sensor) / cg if sensor.output_units == "dn" else None,
                shot=shot)


def noise_e(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Total noise (electrons rms) at a mean photo-signal ``signal_e``: :func:`isettorch.metrics.snr.noise_variance_e`
    with the sensor's shot noise, PRNU and dark floor (the variance of a dark pixel in its captures:
    :meth:`Sensor.poisson_gaussian`'s terms, so CDS, the noise model, row/column noise and dark shading count as in
    the capture)."""
    return torch.sqrt(noise_variance_e(signal_e, **_noise_parameters_e(sensor, exposure_s)))


def pixel_snr(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Pixel SNR (ratio) = signal / noise at mean photo-signals ``signal_e`` (electrons)
    (:func:`isettorch.metrics.snr.pixel_snr` with the sensor's parameters)."""
    return _pixel_snr(signal_e, **_noise_parameters_e(sensor, exposure_s))


def pixel_snr_db(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Pixel SNR in dB: 20 log10(signal / noise) (ISETCam ``pixelSNR``)."""
    return _pixel_snr(signal_e, db=True, **_noise_parameters_e(sensor, exposure_s))


def dynamic_range_db(sensor: Sensor, exposure_s: float | None = None) -> float:
    """20 log10(electrons at saturation / noise floor in the dark), ISETCam's ``pixelDR``
    (:func:`isettorch.metrics.snr.dynamic_range_db`; saturation: :func:`saturation_e`, which the full well caps);
    ``inf`` for a noise-free sensor. EMVA 1288's DR divides by ``mu_e.min = sigma_dark + 1/2`` instead
    (:func:`isettorch.metrics.emva1288`): 1.9 dB less at a 2 e- floor."""
    floor = float(noise_e(sensor, 0.0, exposure_s))
    if floor <= 0:
        return math.inf
    return float(_dynamic_range_db(saturation_e(sensor), floor))


def electrons_per_lux_second(sensor: Sensor, illuminant: str = "D65", wavelengths_nm=None) -> torch.Tensor:
    """Photo-electrons per pixel per lux-second of focal-plane exposure, per CFA channel ``[C]``.

    The irradiance has the illuminant's spectrum, scaled to 1 lux (683 sum E V dlambda), on the photodiode's area
    ``fill_factor x pitch^2`` (ISETCam's pixel): without the sensor's pixel optics, whose etendue depends on the
    lens's f-number and chief-ray angles (``Sensor.channel_rates`` of an optical image includes them).
    """
    w = spectral.default_wavelengths(dtype=torch.float64) if wavelengths_nm is None else \
        torch.as_tensor(wavelengths_nm, dtype=torch.float64)
    e = spectral.illuminant(illuminant, w, dtype=torch.float64)
    photons = spectral.energy_to_photons(e, w, dim=0)
    lux = spectral.luminance(photons[:, None, None], w, dim=0).reshape(())
    photons = photons / lux
    qe = sensor.spectral_qe(w, dtype=torch.float64).detach()
    rate = (qe * photons * spectral.wavelength_weights(w)).sum(-1)  # e-/s/m^2 per channel at 1 lux
    return rate * sensor.pixel_area_m2 * sensor.fill_factor


def iso_saturation(sensor: Sensor, illuminant: str = "D65", wavelengths_nm=None) -> float:
    """ISO 12232:2019 saturation-based speed ``S_sat = 78 / H_sat`` (H_sat in lux s).

    H_sat is the focal-plane exposure that saturates the raw (:func:`saturation_e`, at the sensor's analog gain) in
    its most sensitive channel.
    """
    k = electrons_per_lux_second(sensor, illuminant, wavelengths_nm).max().item()
    if k <= 0:
        raise ValueError("iso_saturation: the sensor has no response to the illuminant")
    h_sat = saturation_e(sensor) / k
    return 78.0 / h_sat
