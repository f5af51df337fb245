"""Sensor figures of merit: well capacity, pixel SNR vs signal, dynamic range, ISO saturation speed.

Noise model (EMVA 1288 release 4.0, eq. 2-6, in electrons): variance = read^2 + dark e- + signal e-
+ (PRNU x signal)^2 + DSNU^2 + quantisation (LSB^2 / 12).
"""

from __future__ import annotations

import math

import torch

from .. import spectral
from .sensor import Sensor

__all__ = ["well_capacity_e", "noise_e", "pixel_snr", "pixel_snr_db", "dynamic_range_db", "iso_saturation",
           "electrons_per_lux_second"]


def well_capacity_e(sensor: Sensor) -> float:
    """Electrons at saturation: voltage swing / conversion gain (ISETCam ``pixelGet('well capacity')``)."""
    return sensor.well_capacity_e


def noise_e(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Total noise (electrons rms) at a mean photo-signal ``signal_e`` (EMVA 1288 variance model).

    Read noise, DSNU and the quantisation step are converted from volts at the pixel (analog gain 1).
    """
    s = torch.as_tensor(signal_e, dtype=torch.float64)
    t = float(sensor.exposure_s if exposure_s is None else exposure_s)
    cg = sensor.conversion_gain_v_per_e
    read_e = sensor.read_noise_v / cg * (math.sqrt(2) if sensor.cds else 1.0)
    dsnu_e = 0.0 if sensor.cds else sensor.dsnu_sigma_v / cg
    col_e = 0.0 if sensor.cds else sensor.column_fpn_sigma_v / cg
    dark_e = sensor.dark_current_e_per_s * t
    quant_var = 0.0 if sensor.lsb_v is None else (sensor.lsb_v / cg) ** 2 / 12
    prnu = sensor.prnu_sigma_percent / 100
    shot = s if sensor.shot_noise != "off" else torch.zeros_like(s)
    var = read_e**2 + dsnu_e**2 + col_e**2 + quant_var + dark_e + shot + (prnu * s) ** 2
    return torch.sqrt(var)


def pixel_snr(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Pixel SNR (ratio) = signal / noise at mean photo-signals ``signal_e`` (electrons)."""
    s = torch.as_tensor(signal_e, dtype=torch.float64)
    n = noise_e(sensor, s, exposure_s)
    return torch.where(n > 0, s / n.clamp_min(1e-300), torch.full_like(s, math.inf))


def pixel_snr_db(sensor: Sensor, signal_e, exposure_s: float | None = None) -> torch.Tensor:
    """Pixel SNR in dB: 20 log10(signal / noise) (ISETCam ``pixelSNR``)."""
    return 20 * torch.log10(pixel_snr(sensor, signal_e, exposure_s))


def dynamic_range_db(sensor: Sensor, exposure_s: float | None = None) -> float:
    """20 log10(well capacity / noise floor in the dark) (EMVA 1288 DR = mu_sat / sigma_dark)."""
    floor = float(noise_e(sensor, 0.0, exposure_s))
    if floor <= 0:
        return math.inf
    return 20 * math.log10(sensor.well_capacity_e / floor)


def electrons_per_lux_second(sensor: Sensor, illuminant: str = "D65", wavelengths_nm=None) -> torch.Tensor:
    """Photo-electrons per pixel per lux-second of focal-plane exposure, per CFA channel ``[C]``.

    The irradiance has the illuminant's spectrum, scaled to 1 lux (683 sum E V dlambda).
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

    H_sat is the focal-plane exposure that fills the well of the most sensitive channel (analog gain 1).
    """
    k = electrons_per_lux_second(sensor, illuminant, wavelengths_nm).max().item()
    if k <= 0:
        raise ValueError("iso_saturation: the sensor has no response to the illuminant")
    h_sat = sensor.well_capacity_e / k
    return 78.0 / h_sat
