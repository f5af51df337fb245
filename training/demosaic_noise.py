"""Sensor noise of the demosaic trainer's synthetic batches (``noise.enabled: true``, the joint denoise+demosaic
variant): heteroscedastic Poisson-Gaussian levels per image (:func:`noise_params`, :func:`gaussian_params`), drawn by
one :class:`isettorch.sensor.Sensor` with per-image levels (:func:`add_noise`), and the network's noise inputs
(:func:`noise_features`). Part of ``training/train_demosaic.py``."""

from __future__ import annotations

import functools
import math

import torch

from isettorch.isp import learned
from isettorch.sensor import Sensor
from isettorch.sensor.noise import poisson_gaussian


def noise_params(batch: int, cfg: dict, g: torch.Generator) -> torch.Tensor:
    """[B, 2] (a, b) of ``var = a x + b`` at log-uniform random gains (x relative to white = 1), the photon-transfer
    model (EMVA 1288; Foi et al. 2008): shot noise of ``x / a`` electrons, ``a = gain / full_well_e``, and
    ``b = a^2 (read_noise_e^2 + dsnu_e^2 + dark_e) + q^2 / 12`` (read noise, DSNU, dark-current shot noise after
    black-level subtraction, and quantisation with step ``q = 1 / (2^bits - 1)`` when ``bits`` is set)."""
    n = cfg["noise"]
    lo, hi = float(n.get("gain_min", 1.0)), float(n.get("gain_max", 32.0))
    gain = lo * (hi / lo) ** torch.rand(batch, generator=g)
    a = gain / float(n.get("full_well_e", 10000.0))
    add_e2 = float(n.get("read_noise_e", 3.0)) ** 2 + float(n.get("dsnu_e", 0.0)) ** 2 + float(n.get("dark_e", 0.0))
    bits = int(n.get("bits", 0) or 0)
    q2 = (1.0 / (2**bits - 1)) ** 2 / 12 if bits else 0.0
    return torch.stack([a, a * a * add_e2 + q2], 1)


def gaussian_params(batch: int, noise_cfg: dict, g: torch.Generator) -> torch.Tensor:
    """[B, 2] (a, b) = (0, sigma^2) with ``sigma`` log-uniform in [``sigma_min``, ``sigma_max``] (of the [0, 1]
    mosaic): signal-independent white Gaussian noise, the noise of ``isettorch demosaic-eval --noise-sigma``
    (``noise.gaussian_fraction`` of every batch is drawn this way)."""
    lo, hi = float(noise_cfg.get("sigma_min", 0.002)), float(noise_cfg.get("sigma_max", 0.08))
    if not 0 < lo <= hi:
        raise ValueError(f"noise.sigma_min, noise.sigma_max: expected 0 < sigma_min <= sigma_max, got {lo}, {hi}")
    sigma = lo * (hi / lo) ** torch.rand(batch, generator=g)
    return torch.stack([torch.zeros_like(sigma), sigma * sigma], 1)


# Pedestal below black: this many standard deviations of the largest noise floor, so read noise and DSNU at x = 0
# are not clipped by the sensor's low clip (EMVA 1288 section 4.6 asks for an offset that keeps the dark signal
# above zero).
_PEDESTAL_SIGMAS = 6.0


@functools.lru_cache(maxsize=8)
def _noise_sensor(bits: int, prnu_percent: float, dark_e: float, pedestal: float) -> Sensor:
    """The run's one noise sensor (mono CFA, fixed patterns redrawn per frame, 1 s exposure, unit analog gain),
    in normalised units: 1 V is white. ``bits``: an ADC with one bit of headroom (``bits + 1``) whose step is
    ``lsb = 1 / (2^bits - 1)`` V, so white sits at code ``2^bits - 1`` above a black level of ``pedestal`` codes;
    ``bits = 0``: an analog readout with a ``pedestal`` V offset. Either way the clip is about 2x white, above."""
    common_kw = dict(cfa="mono", exposure_s=1.0, fpn_mode="per_frame", shot_noise="poisson", noise_model="physical",
                     prnu_sigma_percent=prnu_percent, dark_current_e_per_s=dark_e)
    if bits:
        lsb = 1.0 / (2**bits - 1)
        return Sensor(adc_bits=bits + 1, black_level_dn=pedestal, voltage_swing_v=2 ** (bits + 1) * lsb,
                      output_units="dn", **common_kw)
    return Sensor(adc_bits=None, analog_offset_v=pedestal, voltage_swing_v=2.0 + pedestal, output_units="volts",
                  **common_kw)


def add_noise(raw: torch.Tensor, ab: torch.Tensor, g: torch.Generator, noise_cfg: dict | None = None
              ) -> torch.Tensor:
    """Sensor noise per image from :class:`isettorch.sensor.Sensor` (one sensor per run, per-image levels as [B]
    tensors): PRNU (``prnu_percent``, redrawn per frame), Poisson shot noise of signal + dark electrons
    (``dark_e``, its mean subtracted again as a dark frame), DSNU (``dsnu_e``), Gaussian read noise
    (``read_noise_e``) and ADC quantisation (``bits``).

    Photon-transfer model (EMVA 1288 release 4.0 eq. 6; Foi et al., IEEE TIP 17(10) 2008): a pixel with ``n_e``
    mean electrons reads ``y = K (n_e + n_d) + noise`` with variance ``K^2 (n_e + sigma_d^2) + sigma_q^2``. The
    input ``raw`` x (0 black, 1 white) holds ``n_e = x / a`` electrons with ``a`` = ``ab[:, 0]`` from
    :func:`noise_params`; choosing the conversion gain ``K = a`` V/e- (1 V = white, analog gain 1) gives
    ``var(y) = a^2 (x / a) + a^2 (read_e^2 + dsnu_e^2 + dark_e) + q^2 / 12 = a x + b``, the ``b`` of
    :func:`noise_params` with ``q = 1 / (2^bits - 1)`` the ADC step, so the network's noise inputs
    ``(sqrt(a), sqrt(b))`` describe the batch (plus PRNU's ``(prnu x)^2``, left out of them). Read noise and DSNU
    are passed in volts, ``read_e * a`` and ``dsnu_e * a``. The output is ``(DN - black) * q - a dark_e`` (or
    ``v - pedestal - a dark_e`` with no ADC), clipped only above about 2x white.
    With no ``noise_cfg`` it is :func:`isettorch.sensor.noise.poisson_gaussian` (shot + Gaussian floor ``b``)."""
    if not noise_cfg:
        return torch.stack([poisson_gaussian(raw[i].clamp_min(0), float(ab[i, 0]), float(ab[i, 1]) ** 0.5, g)
                            for i in range(raw.shape[0])])
    prnu = float(noise_cfg.get("prnu_percent", 0.0))
    dark, dsnu = float(noise_cfg.get("dark_e", 0.0)), float(noise_cfg.get("dsnu_e", 0.0))
    read, bits = float(noise_cfg.get("read_noise_e", 3.0)), int(noise_cfg.get("bits", 0) or 0)
    # the largest floor (at gain_max), in normalised units, sets the pedestal below black
    a_max = float(noise_cfg.get("gain_max", 32.0)) / float(noise_cfg.get("full_well_e", 10000.0))
    sigma_max = a_max * math.sqrt(read * read + dsnu * dsnu + dark)
    if bits:
        white = 2**bits - 1
        pedestal = float(math.ceil(_PEDESTAL_SIGMAS * sigma_max * white))
        if pedestal >= 2**bits:
            raise ValueError(f"noise: a {_PEDESTAL_SIGMAS:g} sigma pedestal of {pedestal:g} DN for a floor of "
                             f"{sigma_max:.4g} (white = 1) does not fit below the {bits}-bit white; expected a "
                             f"floor under {2**bits / white / _PEDESTAL_SIGMAS:.3g} (lower gain_max or noise)")
    else:
        pedestal = _PEDESTAL_SIGMAS * sigma_max
    sensor = _noise_sensor(bits, prnu, dark, pedestal)
    a = ab[:, 0].double()
    rate = raw.clamp_min(0).double() / a.reshape(-1, 1, 1, 1)  # electrons (1 s exposure)
    out = sensor.capture(rate, exposure_s=1.0, analog_gain=1.0, noise=True, generator=g,
                         conversion_gain_v_per_e=a, read_noise_v=read * a, dsnu_sigma_v=dsnu * a).data
    x = (out - pedestal) / (2**bits - 1) if bits else out - pedestal
    return (x - dark * a.reshape(-1, 1, 1, 1)).to(raw.dtype)


def noise_features(ab: torch.Tensor) -> torch.Tensor:
    return learned.noise_features(ab[:, 0], ab[:, 1]).to(ab.dtype)
