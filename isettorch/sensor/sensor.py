"""`Sensor`: optical-image irradiance -> raw mosaic (electrons, volts or DN), with noise and ADC.

Signal chain (per pixel, ISETCam ``sensorCompute`` / Farrell et al. SPIE 2004 / EMVA 1288):

1. electrons/s = area (or point) sample of ``sum_lambda E(lambda) QE_c(lambda) dlambda`` x pixel area x fill
   factor (x optional pixel vignetting; x the microlens etendue map of ``pixel_optics``, ``microlens.py``);
2. mean photo-electrons = rate x exposure (x (1 + PRNU) when PRNU is on);
3. + dark electrons (dark current x exposure), shot noise on the total (Poisson / Gaussian / off);
4. volts = electrons x conversion gain + read noise + DSNU + column offsets (with CDS the fixed offsets
   cancel and the read noise is sampled twice: reset and signal);
5. analog gain and offset: ``(v + offset) * gain`` (default) or ISETCam's ``(v + offset) / gain``;
6. clip to ``[0, voltage swing]`` (down to ``-black level`` when a black level is set);
7. ADC with N bits: ``round(v / (swing / 2^N)) + black level``, clamped to ``2^N - 1`` (default) or
   unclamped (ISETCam, FORMAT 4.6 step 9). Rounding is straight-through for gradients.

``noise_free`` in the output is the same chain with no dark signal, noise or fixed pattern, and no
rounding (a training target).
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from .. import spectral
from .._autograd import full_precision, records_grad
from .._checks import (
    batch_param,
    check_bool,
    check_float_dtype,
    check_in_dtype_range,
    check_seed,
    is_integer,
    is_real,
    round_half_away,
    seed_for,
    tensor_hint,
    tensor_version,
)
from ..metrics.emva import S2_QUANTIZATION_DN2
from ..optics.optical_image import OpticalImage
from . import noise as _noise
from .cfa import CFA
from .exposure import AE_METHODS, MAX_EXPOSURE_S, auto_exposure
from .filters import SpectralQE
from .microlens import PixelOptics
from .noise_terms import NoiseTerms
from .presets_emva import EMVA_PRESETS
from .raw import RawImage
from .sampling import electron_rate_density, isetcam_preblur, isetcam_preblur_size, sample_area, sample_point

__all__ = ["Sensor", "PRESETS", "SAMPLING_MODES", "ISETCAM_CONVENTIONS", "PER_CALL_LEVELS"]

# Levels a call may override per sample (scalar or [B] tensors), e.g. to randomise noise in a training loop
# without rebuilding the module: ``sensor(oi, read_noise_v=torch.tensor([...]), ...)``.
PER_CALL_LEVELS = ("conversion_gain_v_per_e", "read_noise_v", "dark_current_e_per_s", "dsnu_sigma_v",
                   "prnu_sigma_percent", "column_fpn_sigma_v")

# Every ISETCam behaviour that differs from the documented default, for ``Sensor(..., **ISETCAM_CONVENTIONS)``:
# Gaussian pre-blur + point sampling, analog gain divides, ADC without clamp, ISETCam noise order with
# DSNU/PRNU redrawn on every call (FORMAT.md 4.6, 4.8), the rectangle rule over wavelength with the first bin's
# width for every band (FORMAT.md 4.1; the same as the default on a uniform grid).
ISETCAM_CONVENTIONS: dict[str, str] = {"sampling": "isetcam", "gain_convention": "isetcam", "adc_mode": "isetcam",
                                       "noise_model": "isetcam", "fpn_mode": "per_frame", "spectral_rule": "isetcam"}

SAMPLING_MODES = ("area", "area_linear", "isetcam")

#: the random stream (:func:`isettorch._checks.seed_for`) of the default temporal-noise generator of a sensor's seed
TEMPORAL_STREAM = 1
#: the fixed-pattern maps' buffers (:meth:`Sensor.fixed_pattern`; the seed's, never saved)
FIXED_PATTERN_BUFFERS = ("fpn_dsnu", "fpn_prnu", "fpn_column")

# Presets. Values in SI; dark current in e-/s (ISETCam gives V/s: 1 mV/s / 1e-4 V/e- = 10 e-/s).
PRESETS: dict[str, dict[str, Any]] = {
    # ISETCam sensorCreate default (sensorCreate.m / pixelCreate.m, commit 3b10ec1): 2.8 um, fill 0.75,
    # 1e-4 V/e-, 1 V swing, dark 1 mV/s, read noise 1 mV, GRBG Bayer, analog readout.
    # ISETCam's sensorCreate default. As in ISETCam, no pedestal: the pixel voltage is clipped at 0 V, so half the
    # pixels of a dark frame read 0 and read noise and dark current cannot be measured from its dark frames (an
    # audit: 5.7 e- and 8 e-/s for 10 and 10); give analog_offset_v (e.g. 0.02 V) to calibrate a capture of it.
    "isetcam_default": dict(pixel_size_m=2.8e-6, fill_factor=0.75, conversion_gain_v_per_e=1e-4, voltage_swing_v=1.0,
                            dark_current_e_per_s=10.0, read_noise_v=1e-3, cfa="GRBG", adc_bits=None,
                            rows=72, cols=88),
    # IMX363-like phone sensor (1.4 um BSI dual-pixel, 12 MP; typical public numbers for this pixel class:
    # ~6000 e- full well, ~2 e- read noise, 10-bit raw). Not manufacturer-measured values. The raw clips at 5619 e-:
    # the 64 DN black level is added after the ADC, so the top code is reached at 0.4495 V of the 0.48 V swing.
    "imx363": dict(pixel_size_m=1.4e-6, fill_factor=1.0, conversion_gain_v_per_e=8e-5, voltage_swing_v=0.48,
                   dark_current_e_per_s=5.0, read_noise_v=1.6e-4, dsnu_sigma_v=8e-5, prnu_sigma_percent=0.6,
                   cfa="RGGB", adc_bits=10, black_level_dn=64, rows=3024, cols=4032),
    # Farrell, Xiao, Catrysse, Wandell, "A simulation tool for evaluating digital camera image quality",
    # SPIE 5294 (2004), CDS sensor: 4 um, 50 % fill, dark 10 e-/s, read 50 e-, 15 uV/e-, DSNU 2 mV,
    # PRNU 0, 1 V swing, 16 ms. With CDS (ISETCam's), the reset frame cancels the DSNU and the read noise is drawn
    # in both frames: the raw shows 50 sqrt(2) = 70.7 e- of read noise and no DSNU.
    "iset2004_cds": dict(pixel_size_m=4e-6, fill_factor=0.5, conversion_gain_v_per_e=15e-6, voltage_swing_v=1.0,
                         dark_current_e_per_s=10.0, read_noise_v=50 * 15e-6, dsnu_sigma_v=2e-3,
                         prnu_sigma_percent=0.0, exposure_s=0.016, cds=True, cfa="GRBG", adc_bits=None),
}

PRESETS.update(EMVA_PRESETS)  # EMVA 1288 datasheet presets (presets_emva.py)


#: the most negative electron rate, relative to the item's peak rate, taken for ringing of the optics' discrete
#: Fourier blur and set to 0 (:func:`_without_ringing`); below it, an error. The deepest lobe measured: 1.9 % of the
#: peak, a point source through diffraction-limited optics at f/1-f/8 on 0.8-6 um samples, in one band
#: (tests/sensor/test_ringing.py)
RINGING_TOLERANCE = 0.03


def _without_ringing(rates: torch.Tensor) -> torch.Tensor:
    """Electron rates ``[B, C, H, W]`` with the optics' ringing removed. A non-negative irradiance through a
    non-negative QE gives non-negative rates, but the optics blur on the sample grid: their OTF stops at the grid's
    Nyquist frequency while the diffraction cut-off ``1 / (lambda N)`` lies beyond it (Goodman, Introduction to
    Fourier Optics, 3rd ed., sec. 6.3), so the kernel applied is the PSF band-limited by the grid, with small
    negative lobes (down to 1.9 % of the peak next to a point source), plus the FFT's round-off: next to black
    regions a rate can fall below 0 (3e-5 of the peak on an HDR natural scene with specular highlights). Values
    down to :data:`RINGING_TOLERANCE` of each item's peak are set to 0 (as
    :func:`isettorch.optics.blur.convolve_psf` clamps its result; ISETCam takes the absolute value instead,
    ``abs(ifft2(...))`` in ``oiApplyOTF``, which adds light); more negative ones raise, since they are no ringing.
    Non-negative rates are returned as they are (bitwise)."""
    flat = rates.detach().flatten(1)
    lo, hi = flat.amin(1), flat.amax(1)
    if not bool((lo < 0).any()):
        return rates
    if bool((lo < -RINGING_TOLERANCE * hi.clamp_min(0)).any()):
        raise ValueError(f"electron rates: expected non-negative values (ringing of the optics' blur down to "
                         f"{RINGING_TOLERANCE} of the peak is set to 0), got a minimum of {float(lo.min()):.4g} "
                         f"against a peak of {float(hi.max()):.4g}")
    return rates.clamp_min(0)


#: the largest PRNU the Gaussian gain model ``1 + sigma z`` takes: at 20 % a pixel's gain is negative (and clipped to
#: 0) only for z < -5, about 3 pixels in 10^7
MAX_PRNU_SIGMA_PERCENT = 20.0


def _check_prnu(value: float) -> None:
    """The PRNU level (constructor or per call) within the Gaussian gain model's range."""
    if value > MAX_PRNU_SIGMA_PERCENT:  # the gain 1 + sigma z would go negative
        raise ValueError(f"prnu_sigma_percent: expected at most {MAX_PRNU_SIGMA_PERCENT} % (the Gaussian gain "
                         f"1 + sigma z is negative, and clipped to 0, for z < -100 / sigma; sensors have 0.5-2 %), "
                         f"got {value!r}")


def _check_rate(rate, mosaic: bool) -> torch.Tensor:
    """A capture's electron rate: a float32/float64 ``(B, 1, rows, cols)`` mosaic (``mosaic``) or ``(B, C, rows,
    cols)`` tensor of finite, non-negative electrons/s (an integer rate truncated the exposure to 0 s and read
    black), with at least one item; else a ValueError naming ``electron_rate``."""
    shape = "(B, 1, rows, cols)" if mosaic else "(B, C, rows, cols)"
    if not isinstance(rate, torch.Tensor) or rate.dim() != 4 or (mosaic and rate.shape[1] != 1) or rate.numel() == 0:
        raise ValueError(f"electron_rate: expected a non-empty {shape} tensor, got "
                         f"{tuple(rate.shape) if isinstance(rate, torch.Tensor) else type(rate).__name__}")
    check_float_dtype(rate.dtype, "electron_rate")
    lo, hi = torch.aminmax(rate.detach())  # one pass; NaN propagates to both (a check: no graph, no warning)
    if not (float(lo) >= 0 and math.isfinite(float(hi))):
        hint = ("; an optical image's photons that overflow the dtype when integrated over wavelength (about 3e37 "
                "in float32) give inf here: render in float64" if rate.dtype == torch.float32 and float(lo) >= 0
                else "")
        raise ValueError(f"electron_rate: expected finite, non-negative electrons/s, got values in [{float(lo):.6g}, "
                         f"{float(hi):.6g}]{hint}")
    return rate


#: the most pixels :meth:`Sensor.size_for` sizes a sensor to (a 24 MP photograph's sensor is 2.4e7): beyond it the
#: optical image is far wider than any sensor (a magnified scene), and the mosaic alone would not fit in memory
MAX_AUTO_PIXELS = 250_000_000


class Sensor(nn.Module):
    """An image sensor: pixel geometry, CFA and spectral QE, exposure, noise, analog gain and ADC.

    Args:
        rows, cols: sensor size in pixels (None: as many pixels as fit in the OI's unpadded area). Centred on the
            optical image; where a larger sensor extends beyond it, its pixels read no light (0, as ISETCam's
            ``regridOI2ISA``; a pixel on the edge its covered fraction), then dark signal and noise.
        pixel_size_m: pixel pitch (square pixels, no gaps); fill_factor: photodiode area / pixel area.
        cfa: a :class:`CFA` or pattern string.
        spectral_qe: a :class:`SpectralQE` (default: ``filters`` for the CFA's letters x ``ir_filter`` x
            ``pixel_qe``); ``learnable_filters`` makes the filters ``nn.Parameter`` s. ``filters``: a set name
            (:func:`~isettorch.sensor.filters.filter_set_names`), which must have every CFA letter, or a dict of user
            spectra; None (default): R, G, B from ``'isetcam_rgb'``, C, Y, M from ``'isetcam_cmy'``, W ``'clear'``.
        conversion_gain_v_per_e, voltage_swing_v: the pixel's output; well capacity = swing / gain.
        exposure_s: exposure (s), scalar or ``[B]``; ``auto_exposure`` (``'luminance'``, ``'mean'``,
            ``'percentile'``) overrides it, aiming the light's volts at ``ae_target`` (a fraction in (0, 1]) of the
            room above the analog offset, :meth:`saturation_v` less the offset after gain; ``ae_target`` tunes it,
            ``ae_percentile`` (default 99) the ``'percentile'`` method; either without a method that uses it is an
            error.
        analog_gain, analog_offset_v: ``gain_convention='multiply'`` (default) gives ``(v + offset) * gain``,
            ``'isetcam'`` gives ISETCam's ``(v + offset) / gain``.
        adc_bits: None for an analog (volts) readout, else N; steps of ``swing / 2^N``; ``adc_mode='clamp'``
            clamps to ``2^N - 1``, ``'isetcam'`` does not (so the swing maps to ``2^N``). ``black_level_dn`` is
            added to DN (auto-exposure then aims below the top code, see ``usable_swing_v``); its fraction, if
            any (a calibrated pedestal), is added before the rounding, so the DN stay whole codes; an analog
            readout takes none.
        shot_noise: ``'poisson'`` (straight-through gradient), ``'gaussian'`` or ``'off'``.
        read_noise_v, dark_current_e_per_s, dsnu_sigma_v, prnu_sigma_percent, column_fpn_sigma_v: noise.
        fpn_mode: ``'fixed'`` (drawn once from ``seed``, stored as buffers) or ``'per_frame'`` (ISETCam redraws
            DSNU/PRNU on every call).
        noise_model: ``'physical'`` (PRNU scales the photo signal before shot noise; EMVA 1288) or ``'isetcam'``
            (ISETCam's order: dark, shot with Gaussian-rounded counts above 25 e-, read, then ``v (1 + PRNU) + DSNU``).
        cds: correlated double sampling (fixed offsets cancel, read noise sampled twice).
        vignetting: optional pixel vignetting / etendue map ``[rows, cols]`` (or scalar) multiplying the signal.
        pixel_optics: microlens / pixel-stack optics (:class:`~isettorch.sensor.microlens.PixelOptics` or a dict of
            its arguments, e.g. ``{"method": "optimal", "layer_thicknesses_m": [2e-6, 5e-6]}``): the etendue map
            over the array from each pixel's chief-ray angle (ISETCam ``sensorVignetting``), applied to the signal
            (per wavelength with ``diffraction``). None (default): no pixel optics.
        sampling: ``'area'`` (integrate over the photodiode, OI samples as cell means; default),
            ``'area_linear'`` (integrate the bilinear reconstruction of the OI) or ``'isetcam'`` (ISETCam's
            Gaussian pre-blur + bilinear point sampling at pixel centres); ``preblur_size`` overrides ISETCam's k.
        spectral_rule: the quadrature over wavelength, :func:`isettorch.spectral.wavelength_weights`'s ``rule``:
            ``'midpoint'`` (each band its own width; default) or ``'isetcam'`` (the first bin's width for every band,
            ISETCam's rectangle rule). The two agree on a uniform grid.
        output_units: ``'dn'`` (default when ``adc_bits``), ``'volts'`` (default otherwise) or ``'electrons'``.
        seed: seed of the fixed patterns and of the default temporal-noise generator. The patterns are functions
            of (seed, size), not saved in the state_dict: a checkpoint restores a sensor built with the same seed.

    Example:
        >>> s = Sensor.preset('isetcam_default', rows=4, cols=6, read_noise_v=0, dark_current_e_per_s=0)
        >>> oi = OpticalImage(torch.full((1, 31, 8, 8), 1e15), torch.arange(400., 701., 10.), sample_spacing_m=2e-6)
        >>> s(oi, exposure_s=0.01).data.shape
        torch.Size([1, 1, 4, 6])

    Reference: J. Farrell et al., "A simulation tool for evaluating digital camera image quality", SPIE 2004;
    EMVA Standard 1288 release 4.0; ISETCam ``sensorCompute``.
    """

    def __init__(self, *, rows: int | None = None, cols: int | None = None, pixel_size_m: float = 2.8e-6,
                 fill_factor: float = 0.75, cfa: CFA | str = "GRBG", spectral_qe: SpectralQE | None = None,
                 filters: str | dict | None = None, ir_filter=None, pixel_qe=None, learnable_filters: bool = False,
                 conversion_gain_v_per_e: float = 1e-4, voltage_swing_v: float = 1.0, exposure_s=0.01,
                 auto_exposure: str | None = None, ae_target: float | None = None, ae_percentile: float | None = None,
                 analog_gain=1.0, analog_offset_v: float = 0.0, gain_convention: str = "multiply",
                 adc_bits: int | None = None, adc_mode: str = "clamp", black_level_dn: float = 0.0,
                 shot_noise: str = "poisson", read_noise_v: float = 0.0, dark_current_e_per_s: float = 0.0,
                 dsnu_sigma_v: float = 0.0, prnu_sigma_percent: float = 0.0, column_fpn_sigma_v: float = 0.0,
                 fpn_mode: str = "fixed", noise_model: str = "physical", cds: bool = False, vignetting=None,
                 pixel_optics=None, sampling: str = "area", spectral_rule: str = "midpoint",
                 preblur_size: int | None = None, output_units: str | None = None, seed: int = 0,
                 name: str = "",
                 row_noise_v: float = 0.0, column_noise_v: float = 0.0, read_noise_tukey_lambda: float | None = None,
                 dark_shading_e_per_s: float = 0.0, hot_pixel_fraction: float = 0.0,
                 hot_pixel_dark_current_e_per_s: float = 0.0, dead_pixel_fraction: float = 0.0,
                 full_well_e: float | None = None) -> None:
        super().__init__()
        for label, v in (("rows", rows), ("cols", cols)):
            if v is not None and (not is_integer(v) or v < 1):
                raise ValueError(f"{label}: expected a positive integer pixel count or None, got {v!r}")
        for label, v in (("pixel_size_m", pixel_size_m), ("conversion_gain_v_per_e", conversion_gain_v_per_e),
                         ("voltage_swing_v", voltage_swing_v)):
            if not (is_real(v) and v > 0):
                raise ValueError(f"{label}: expected a positive number, got {v!r}{tensor_hint(v)}")
        if not (is_real(fill_factor) and 0 < fill_factor <= 1):
            raise ValueError(f"fill_factor: expected a number in (0, 1], got {fill_factor!r}{tensor_hint(fill_factor)}")
        for label, v in (("read_noise_v", read_noise_v), ("dark_current_e_per_s", dark_current_e_per_s),
                         ("dsnu_sigma_v", dsnu_sigma_v), ("prnu_sigma_percent", prnu_sigma_percent),
                         ("column_fpn_sigma_v", column_fpn_sigma_v), ("black_level_dn", black_level_dn)):
            if not (is_real(v) and v >= 0):
                raise ValueError(f"{label}: expected a non-negative number, got {v!r}")
        _check_prnu(prnu_sigma_percent)
        if not is_real(analog_offset_v):
            raise ValueError(f"analog_offset_v: expected a finite number (volts), got {analog_offset_v!r}")
        seed = check_seed(seed)  # [0, 2^64): torch's seeds (2^64 failed at the first capture, naming no argument)
        choices = {"gain_convention": (gain_convention, ("multiply", "isetcam")),
                   "adc_mode": (adc_mode, ("clamp", "isetcam")),
                   "shot_noise": (shot_noise, _noise.SHOT_NOISE_MODES),
                   "fpn_mode": (fpn_mode, ("fixed", "per_frame")), "sampling": (sampling, SAMPLING_MODES),
                   "spectral_rule": (spectral_rule, spectral.WEIGHT_RULES),
                   "noise_model": (noise_model, ("physical", "isetcam"))}
        for label, (v, allowed) in choices.items():
            if v not in allowed:
                raise ValueError(f"{label}: expected one of {allowed}, got {v!r}")
        for label, v in (("exposure_s", exposure_s), ("analog_gain", analog_gain)):
            if v is not None:  # checked here as in forward (a config typo fails at construction, naming the key)
                n = v.numel() if isinstance(v, torch.Tensor) else len(v) if isinstance(v, (list, tuple)) else 1
                if n == 0:  # (min() of an empty sequence, naming nothing)
                    raise ValueError(f"{label}: expected a number or one per batch item, got an empty list")
                batch_param(v.detach() if isinstance(v, torch.Tensor) else v, label, n, dtype=None, device=None,
                            positive=True)
        if auto_exposure is not None and auto_exposure not in AE_METHODS:
            raise ValueError(f"auto_exposure: expected None or one of {sorted(AE_METHODS)}, got {auto_exposure!r}")
        if ae_target is not None:
            if not (is_real(ae_target) and 0 < ae_target <= 1):
                raise ValueError(f"ae_target: expected a fraction of the usable saturation in (0, 1], got "
                                 f"{ae_target!r}")
            if auto_exposure is None:
                raise ValueError(f"ae_target: {ae_target!r} tunes auto-exposure, but auto_exposure is None (a fixed "
                                 f"exposure_s); set auto_exposure ({sorted(AE_METHODS)}) or drop ae_target")
        if ae_percentile is not None:
            if not (is_real(ae_percentile) and 0 < ae_percentile <= 100):
                raise ValueError(f"ae_percentile: expected a percentile in (0, 100], got {ae_percentile!r}")
            if auto_exposure != "percentile":
                raise ValueError(f"ae_percentile: only auto_exposure='percentile' uses it, got auto_exposure="
                                 f"{auto_exposure!r}; set auto_exposure: percentile or drop ae_percentile")
        if adc_bits is not None and (not is_integer(adc_bits) or not 1 <= adc_bits <= 32):
            raise ValueError(f"adc_bits: expected None (analog) or an integer in 1..32, got {adc_bits!r}")
        if adc_bits is not None and black_level_dn >= 2 ** adc_bits - 1:
            raise ValueError(f"black_level_dn: expected a level below 2^{adc_bits} - 1, got {black_level_dn}")
        if adc_bits is None and black_level_dn != 0:
            raise ValueError(f"black_level_dn: {black_level_dn!r} DN needs an ADC, but adc_bits is None (an analog "
                             f"readout in volts has no DN); set adc_bits, or black_level_dn to 0 (analog_offset_v is "
                             f"the analog pedestal)")
        if output_units not in (None, "dn", "volts", "electrons"):
            raise ValueError(f"output_units: expected None, 'dn', 'volts' or 'electrons', got {output_units!r}")
        if output_units == "dn" and adc_bits is None:
            raise ValueError("output_units: 'dn' needs adc_bits (the sensor has an analog readout)")
        if preblur_size is not None and (not is_integer(preblur_size) or preblur_size < 1):
            raise ValueError(f"preblur_size: expected None or a positive integer, got {preblur_size!r}")

        try:  # the CFA's and the filter set's own checks, named with the Sensor's arguments ('cell', 'name')
            self.cfa = cfa if isinstance(cfa, CFA) else CFA(cfa)
        except (TypeError, ValueError) as err:
            raise type(err)(f"cfa: {err}") from err
        check_bool(learnable_filters, "learnable_filters")  # ('no' made the filters trainable)
        if spectral_qe is None:
            try:
                spectral_qe = SpectralQE.from_cfa(self.cfa, filters, ir_filter=ir_filter, pixel_qe=pixel_qe,
                                                  learnable=learnable_filters)
            except ValueError as err:
                if not str(err).startswith("name: "):
                    raise
                raise ValueError(f"filters: {str(err).removeprefix('name: ')}") from err
        if spectral_qe.channel_names != self.cfa.channel_names:
            raise ValueError(f"spectral_qe: channel names {spectral_qe.channel_names} differ from the CFA's "
                             f"{self.cfa.channel_names}")
        self.spectral_qe = spectral_qe
        self.rows, self.cols = rows, cols
        self.pixel_size_m = float(pixel_size_m)
        self.fill_factor = float(fill_factor)
        self.conversion_gain_v_per_e = float(conversion_gain_v_per_e)
        self.voltage_swing_v = float(voltage_swing_v)
        self.exposure_s = exposure_s
        self.auto_exposure = auto_exposure
        self.ae_target = ae_target
        self.ae_percentile = 99.0 if ae_percentile is None else float(ae_percentile)
        self.analog_gain = analog_gain
        self.analog_offset_v = float(analog_offset_v)
        self.gain_convention = gain_convention
        self.adc_bits = adc_bits
        self.adc_mode = adc_mode
        self.black_level_dn = float(black_level_dn)
        self.shot_noise = shot_noise
        self.read_noise_v = float(read_noise_v)
        self.dark_current_e_per_s = float(dark_current_e_per_s)
        self.dsnu_sigma_v = float(dsnu_sigma_v)
        self.prnu_sigma_percent = float(prnu_sigma_percent)
        self.column_fpn_sigma_v = float(column_fpn_sigma_v)
        self.fpn_mode = fpn_mode
        self.noise_model = noise_model
        self.cds = check_bool(cds, "cds")
        self.sampling = sampling
        self.spectral_rule = spectral_rule
        self.preblur_size = preblur_size
        self.output_units = output_units or ("dn" if adc_bits is not None else "volts")
        self.seed = int(seed)
        self.name = name
        if vignetting is not None:
            vignetting = torch.as_tensor(vignetting, dtype=torch.float64)
            if (vignetting < 0).any() or not torch.isfinite(vignetting).all():
                raise ValueError("vignetting: expected finite non-negative factors")
            if vignetting.dim() == 1 and vignetting.numel() == 1:
                vignetting = vignetting.reshape(())
            # (a 1-D profile was applied along the columns whatever it was meant along)
            if vignetting.dim() not in (0, 2) or rows is not None and cols is not None and vignetting.dim() == 2 \
                    and tuple(vignetting.shape) != (rows, cols):
                raise ValueError(f"vignetting: expected a scalar or a [rows, cols] = [{rows}, {cols}] map, got "
                                 f"shape {tuple(vignetting.shape)}")
        self.register_buffer("vignetting", vignetting)
        if isinstance(pixel_optics, dict):
            pixel_optics = PixelOptics(**pixel_optics)
        if pixel_optics is not None and not isinstance(pixel_optics, PixelOptics):
            raise TypeError(f"pixel_optics: expected None, a dict or a PixelOptics, got {type(pixel_optics).__name__}")
        po_pitch = None if pixel_optics is None else pixel_optics.pixel.get("pixel_size_m")
        if po_pitch is not None and not math.isclose(float(po_pitch), self.pixel_size_m, rel_tol=1e-9):
            raise ValueError(f"pixel_optics.pixel_size_m: {po_pitch!r} m differs from the sensor's pixel_size_m "
                             f"{self.pixel_size_m!r} m (one pixel, one pitch); leave it out (it defaults to the "
                             f"sensor's) or make them equal")
        po_diode = None if pixel_optics is None else pixel_optics.pixel.get("photodiode_size_m")
        if po_diode is not None and not math.isclose((float(po_diode) / self.pixel_size_m) ** 2, self.fill_factor,
                                                     rel_tol=1e-6):
            # (two photodiodes: the etendue took this one, the rate the fill factor's; ISETCam's pixel has one)
            raise ValueError(f"pixel_optics.photodiode_size_m: {float(po_diode)!r} m is a fill factor of "
                             f"{(float(po_diode) / self.pixel_size_m) ** 2:.6g}, not the sensor's fill_factor "
                             f"{self.fill_factor!r} (one pixel, one photodiode); leave it out (it defaults to "
                             f"sqrt(fill_factor) x pixel_size_m) or make them agree")
        self.pixel_optics = pixel_optics
        # Real-raw noise terms (row/column banding, Tukey read noise, dark shading, defects, full well):
        # isettorch.sensor.noise_terms; all off by default.
        self.noise_terms = NoiseTerms(row_noise_v=row_noise_v, column_noise_v=column_noise_v,
                                      read_noise_tukey_lambda=read_noise_tukey_lambda,
                                      dark_shading_e_per_s=dark_shading_e_per_s, hot_pixel_fraction=hot_pixel_fraction,
                                      hot_pixel_dark_current_e_per_s=hot_pixel_dark_current_e_per_s,
                                      dead_pixel_fraction=dead_pixel_fraction, full_well_e=full_well_e, seed=self.seed)
        if noise_model == "isetcam" and self.cds:  # (ignored: ISETCam's order samples the read noise once, adds DSNU)
            raise ValueError("cds: noise_model 'isetcam' has no correlated double sampling (its order samples the read "
                             "noise once and adds the DSNU); use noise_model='physical' with cds=True")
        if noise_model == "isetcam" and self.noise_terms.active:
            raise ValueError(f"noise_model: 'isetcam' has none of the noise terms {self.noise_terms.as_dict()}; use "
                             f"noise_model='physical'")
        # Fixed-pattern maps (standard normal), drawn from the seed on first use for a given size: functions of
        # (seed, size), so not in the state_dict (a camera that had rendered could not be loaded into a new one)
        for name in FIXED_PATTERN_BUFFERS:
            self.register_buffer(name, None, persistent=False)
        self._generators: dict[str, torch.Generator] = {}
        self._weights_cache: dict = {}

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints saved before the maps left the state_dict hold them: they are the seed's, drawn again
        for name in FIXED_PATTERN_BUFFERS:
            state_dict.pop(prefix + name, None)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    # --- construction helpers ------------------------------------------------------------
    @classmethod
    def preset(cls, name: str, **overrides) -> Sensor:
        """A named sensor (:data:`PRESETS`: 'isetcam_default', 'imx363', 'iset2004_cds' and the EMVA 1288 ones of
        :mod:`~isettorch.sensor.presets_emva`), with overrides."""
        key = str(name).lower()
        if key not in PRESETS:
            raise ValueError(f"name: unknown sensor preset {name!r}; expected one of {sorted(PRESETS)}")
        kw = dict(PRESETS[key])
        kw.update(overrides)
        kw.setdefault("name", key)
        return cls(**kw)

    @classmethod
    def from_config(cls, config, **overrides) -> Sensor:
        """A sensor from a YAML file (read as a camera config, :func:`isettorch.camera.load_yaml`) or a mapping of
        constructor arguments, e.g. the output of ``isettorch calibrate DIR --out SENSOR.yaml``; a top-level
        ``sensor:`` section (camera YAML) and a ``preset:`` key are accepted; values are checked as a camera
        config's (:func:`isettorch.camera.check_sensor_values`)."""
        from .calibration import load_sensor_config

        return load_sensor_config(config, **overrides)

    @property
    def well_capacity_e(self) -> float:
        """Electrons at the voltage swing: swing / conversion gain (ISETCam ``pixelGet('well capacity')``)."""
        return self.voltage_swing_v / self.conversion_gain_v_per_e

    @property
    def pixel_area_m2(self) -> float:
        return self.pixel_size_m ** 2

    def collecting_area_m2(self, pixel_size_m=None):
        """The area (m^2) that scales a pixel's irradiance to its electron rate in :meth:`channel_rates`, before the
        pixel optics' etendue and the vignetting: the photodiode's, ``fill_factor x pitch^2`` (ISETCam
        sensorCompute), or, with pixel optics in the physical convention, the whole pixel's (the etendue then holds
        the photodiode's share: about 0.76 on axis and off at fill 0.5 with the phone camera's microlenses). A
        float, or ``[B]`` for a per-call pitch ``pixel_size_m`` (``[B]`` tensor; no pixel optics then). The colour
        targets of the pair generators scale XYZ by it: their white is the camera's response before the etendue
        and vignetting."""
        if pixel_size_m is not None:
            return self.fill_factor * pixel_size_m * pixel_size_m
        return self.pixel_area_m2 if self._microlens_aperture else self.fill_factor * self.pixel_area_m2

    @property
    def _microlens_aperture(self) -> bool:
        """Whether the light of the whole pixel meets the pixel optics' etendue (the physical convention: the microlens,
        as wide as the pixel, gathers it; the etendue holds the photodiode's share), not the photodiode's alone: the
        area of :meth:`collecting_area_m2` and the window of :meth:`sample`."""
        po = self.pixel_optics
        return po is not None and po.convention == "physical"

    @property
    def lsb_v(self) -> float | None:
        """ADC step in volts, ``swing / 2^N`` (ISETCam ``analog2digital``), None for analog."""
        return None if self.adc_bits is None else self.voltage_swing_v / 2 ** self.adc_bits

    @property
    def usable_swing_v(self) -> float:
        """Volts that reach the top code: the swing, or less when a black level pushes ``2^N - 1`` below it (a DN
        readout only: volts and electrons are read before the ADC, up to the swing; a volts raw of saturated pixels
        at 0.48 V reported a white level of 0.4495 V, normalized 1.068)."""
        if self.adc_bits is None or self.adc_mode == "isetcam" or self.output_units != "dn":
            return self.voltage_swing_v
        return min(self.voltage_swing_v, (2 ** self.adc_bits - 1 - self.black_level_dn) * self.lsb_v)

    def saturation_v(self, analog_gain=None, conversion_gain_v_per_e=None) -> float | torch.Tensor:
        """The usable saturation: volts at the ADC input (after analog gain and offset) of the brightest signal the
        raw records, the one quantity auto-exposure aims below and the raw's white level reports
        (:attr:`white_level_dn`, :meth:`white_level`).

        ``min(usable_swing_v, (min(full_well_e x conversion gain, swing) + offset) x analog gain)``: the voltage
        swing (ISETCam ``sensorGet(sensor, 'max output')``, whose well capacity is swing / conversion gain,
        ``pixelGet(pixel, 'well capacity')``), less when a black level puts the ADC's top code below it
        (:attr:`usable_swing_v`), when the photodiode's full well ``full_well_e`` saturates first (EMVA 1288 release
        4.0, section 4.1: the saturation capacity; the noisy chain clips there, :meth:`NoiseTerms.after_shot`) or
        when a multiplying gain below 1 scales the pixel's saturated swing down. ISETCam's gain convention divides
        (and clips after the gain only: its pixel is not clipped at the swing first, FORMAT 4.6 steps 7-8).

        Args:
            analog_gain: None (the sensor's), a number or ``[B]``.
            conversion_gain_v_per_e: None (the sensor's), a number or a per-call ``[B]`` / ``[B, 1, 1, 1]`` tensor.

        Returns a float, or ``[B]`` when a per-call gain is a tensor and ``full_well_e`` is set.
        """
        return self._saturation_v(self._level_gain(analog_gain), conversion_gain_v_per_e)

    def _saturation_v(self, analog_gain, conversion_gain_v_per_e) -> float | torch.Tensor:
        """:meth:`saturation_v` for a checked gain (the capture's own calls: no host reads of a device gain)."""
        top = self.usable_swing_v
        fw = self.noise_terms.full_well_e
        gain = self.analog_gain if analog_gain is None else analog_gain
        multiply = self.gain_convention != "isetcam"
        # the swing, unless the pixel's clip (at the swing, before the gain) lands below it: a gain below 1 or a
        # negative offset (-0.1 V reported a white of 1.0 V, 1023 DN where the raw held at most 0.9 V, 922 DN)
        if fw is None and (not multiply or is_real(gain) and gain >= 1 and self.analog_offset_v >= 0):
            return top
        cg = self.conversion_gain_v_per_e if conversion_gain_v_per_e is None else conversion_gain_v_per_e
        # per-call tensors keep their dtype and device (no float64 on devices without it); lists become tensors
        cg, gain = (x if is_real(x) else x.reshape(-1) if isinstance(x, torch.Tensor)
                    else torch.as_tensor(x, dtype=torch.float64).reshape(-1) for x in (cg, gain))
        if fw is None:  # the pixel saturates at the swing, then the gain (below 1: :meth:`_readout`)
            v = self.voltage_swing_v
        else:  # (in the multiply convention the pixel is also clipped at the swing before the gain)
            v = fw * cg if not multiply else (fw * cg).clamp(max=self.voltage_swing_v) \
                if isinstance(cg, torch.Tensor) else min(fw * cg, self.voltage_swing_v)
        v = v + self.analog_offset_v
        v = v / gain if not multiply else v * gain
        if isinstance(v, torch.Tensor):
            # the swing is a constant white level from the gain where it reaches it (as the number branch above):
            # clamp passes the gradient at equality, so at gain 1 (the default) the white followed the gain and a
            # signal divided by it had zero gradient in the gain
            return torch.where(v < top, v, torch.full_like(v, top))
        return min(top, float(v))

    def saturation_e(self, conversion_gain_v_per_e=None) -> float | torch.Tensor:
        """Electrons at which a pixel saturates: its well capacity, swing / conversion gain (ISETCam
        ``pixelGet('well capacity')``, :attr:`well_capacity_e`), or the photodiode's own full well ``full_well_e``
        (EMVA 1288 release 4.0, section 4.1) where that is lower: a property of the pixel (a DN raw whose black level
        lowers the ADC's top code clips below it, at :meth:`saturation_v`). ``conversion_gain_v_per_e``: None (the
        sensor's), a number or a per-call tensor (then ``[B]``)."""
        cg = self.conversion_gain_v_per_e if conversion_gain_v_per_e is None else conversion_gain_v_per_e
        cg = cg.reshape(-1) if isinstance(cg, torch.Tensor) else cg
        well = self.voltage_swing_v / cg
        fw = self.noise_terms.full_well_e
        if fw is None:
            return well
        return well.clamp(max=fw) if isinstance(well, torch.Tensor) else min(well, fw)

    def white_level(self, analog_gain=None, conversion_gain_v_per_e=None) -> float | torch.Tensor:
        """The raw's saturation value in :attr:`output_units` (its ``white_level``): :meth:`saturation_v` in DN (the
        ADC's code for it, ``round(v / lsb) + black``, at most the top code) or volts; for electrons, the swing /
        conversion gain or the full well, whichever is lower. A float, or ``[B]`` for per-call tensors (see
        :meth:`saturation_v`). Without ``full_well_e``: the top code (``2^N + black`` with ``adc_mode='isetcam'``,
        which does not clamp), the swing, swing / conversion gain (a multiplying gain below 1 lowers the first two:
        the pixel saturates at the swing before the gain). With
        ``full_well_e`` below the swing, the read noise is added after the photodiode clips, so saturated pixels
        scatter around this level (about half above it): normalise by it and clip, or take a high percentile of a
        flat, saturated frame."""
        return self._white_level(self._level_gain(analog_gain), conversion_gain_v_per_e)

    def _white_level(self, analog_gain, conversion_gain_v_per_e) -> float | torch.Tensor:
        """:meth:`white_level` for a checked gain (the capture's own call)."""
        if self.output_units == "electrons":  # the electrons chain clips the pixel volts (no analog gain)
            return self.saturation_e(conversion_gain_v_per_e)
        cg = self.conversion_gain_v_per_e if conversion_gain_v_per_e is None else conversion_gain_v_per_e
        cg = cg.reshape(-1) if isinstance(cg, torch.Tensor) else cg
        if self.output_units == "volts":
            return self._saturation_v(analog_gain, cg)
        return self._white_dn(analog_gain, cg)

    @property
    def white_level_dn(self) -> float | None:
        """The DN of :meth:`saturation_v` at the sensor's own gains: the ADC's top code (``2^N - 1``; ``2^N`` plus
        the black level with ``adc_mode='isetcam'``, whose codes are not clamped), or less when ``full_well_e`` (or a
        multiplying gain below 1) saturates first. None for an analog readout."""
        return None if self.adc_bits is None else self._white_dn(None, None)

    def zero_level(self, analog_gain=None) -> float | torch.Tensor:
        """The raw's value of no light in :attr:`output_units`, a capture's ``black_level``: the black level plus the
        analog offset after the analog gain, ``black_level_dn + offset x gain / lsb`` in DN (``offset / gain`` with
        ISETCam's gain convention), ``offset x gain`` in volts, 0 in electrons (that chain takes no gain or offset).
        ISETCam's ``sensorGet(sensor, 'zero level')``, the response to a black image, which ``ipCompute`` subtracts
        before demosaicking for a colour sensor; here not rounded to whole codes, as a fractional black level is not
        (it is the mean of a dark pixel over noise; a noise-free capture's whole codes differ from it by up to half a
        code, where ISETCam's zero level, a noise-free black capture, is rounded). The offset is a pedestal, not
        signal: the Poisson-Gaussian model (:meth:`poisson_gaussian`) and every normalisation
        (``RawImage.normalized``, the training pairs, ``isettorch process``) measure the signal from here. On the
        clipped part of the response (a negative offset below the ADC's floor) dark pixels read above it.

        Args:
            analog_gain: None (the sensor's), a number or ``[B]``.

        Returns a float, or ``[B]`` for a tensor or list gain when the sensor has an offset.
        """
        return self._zero_and_offset(self._level_gain(analog_gain))[0]

    def _zero_and_offset(self, analog_gain=None) -> tuple[float | torch.Tensor, float | torch.Tensor | None]:
        """``(zero level, the analog offset after the analog gain)`` in :attr:`output_units` (:meth:`zero_level`);
        the offset None without one."""
        black = self.black_level_dn if self.output_units == "dn" else 0.0
        if self.output_units == "electrons" or self.analog_offset_v == 0:
            return black, None
        gain = self.analog_gain if analog_gain is None else analog_gain
        if not is_real(gain):
            gain = (gain if isinstance(gain, torch.Tensor) else torch.as_tensor(gain, dtype=torch.float64)).reshape(-1)
        off = self.analog_offset_v / gain if self.gain_convention == "isetcam" else self.analog_offset_v * gain
        if self.output_units == "dn":
            off = off / self.lsb_v
        off = off if isinstance(off, torch.Tensor) else float(off)
        return black + off, off

    def _level_gain(self, analog_gain):
        """The analog gain the level methods (:meth:`saturation_v`, :meth:`white_level`, :meth:`zero_level`) use: the
        sensor's, or a per-call one checked as :meth:`capture` checks it, finite and positive (a gain of -1 had
        reported a white level of -1024 DN, 0 a bare ZeroDivisionError in the isetcam convention)."""
        if analog_gain is None:
            return self.analog_gain
        if isinstance(analog_gain, bool):
            raise TypeError(f"analog_gain: expected a number or a [B] tensor of numbers, got {analog_gain!r}")
        t = analog_gain if isinstance(analog_gain, torch.Tensor) else torch.as_tensor(analog_gain, dtype=torch.float64)
        t = t.detach()
        if not bool(torch.isfinite(t).all()) or not bool((t > 0).all()):
            raise ValueError(f"analog_gain: expected finite positive values, got {t.reshape(-1)[:4].tolist()}")
        return analog_gain

    def _white_dn(self, analog_gain, conversion_gain_v_per_e) -> float | torch.Tensor:
        """The code the ADC gives :meth:`saturation_v`: ``round(v / lsb) + black`` (MATLAB round, as
        :meth:`volts_to_dn`), at most the top code."""
        # ISETCam's ADC does not clamp at the top code (adc_mode 'isetcam'): its saturated pixels read
        # round(swing / lsb) + black (a 10-bit raw with black 64 read 1088 against a white level of 1024)
        top = math.inf if self.adc_mode == "isetcam" else float(2 ** self.adc_bits - 1)
        x = self._saturation_v(analog_gain, conversion_gain_v_per_e) / self.lsb_v
        whole, part = self._black_parts()
        if isinstance(x, torch.Tensor):
            x = x + part
            return (torch.sign(x) * torch.floor(x.abs() + 0.5) + whole).clamp(max=top)
        return min(top, float(round_half_away(x + part)) + whole)

    def _black_parts(self) -> tuple[float, float]:
        """The black level's whole codes and its fraction. The fraction is an offset before the ADC's rounding (a
        pedestal of 64.25 DN gives whole codes whose mean over noise is 64.25, as a real ADC's analog offset does);
        a whole black level is added after it, ``round(v / lsb) + black`` as ISETCam adds none."""
        whole = math.floor(self.black_level_dn)
        return float(whole), self.black_level_dn - whole

    def set_size_to_fov(self, hfov_deg: float, image_distance_m) -> Sensor:
        """Set cols so the sensor spans ``hfov_deg`` at ``image_distance_m`` (rows keep the aspect ratio),
        rounded to the nearest whole CFA cells. The width is the exact ``2 d tan(hfov / 2)``; ISETCam's
        ``sensorSetSizeToFOV`` scales the current size by the ratio of the angles instead and rounds up to whole
        cells, so for wide fields, or a size that started far from the target, the two can differ by a cell or more.
        ``image_distance_m`` may be an :class:`OpticalImage` (its image distance, else focal length). Returns self."""
        if isinstance(image_distance_m, OpticalImage):
            oi = image_distance_m
            d = oi.image_distance_m if oi.image_distance_m is not None else oi.focal_length_m
            if d is None:
                raise ValueError("image_distance_m: the OpticalImage has neither image_distance_m nor focal_length_m")
            image_distance_m = float(d[0])
        if not image_distance_m > 0 or not 0 < hfov_deg < 180:
            raise ValueError(f"hfov_deg, image_distance_m: expected 0 < hfov < 180 deg and a positive distance, got "
                             f"{hfov_deg}, {image_distance_m}")
        aspect = (self.rows / self.cols) if (self.rows and self.cols) else 1.0
        width = 2 * image_distance_m * math.tan(math.radians(hfov_deg) / 2)
        ph, pw = self.cfa.shape
        cols = max(pw, round(width / self.pixel_size_m / pw) * pw)
        rows = max(ph, round(cols * aspect / ph) * ph)
        self.rows, self.cols = int(rows), int(cols)
        self.fpn_dsnu = self.fpn_prnu = self.fpn_column = None
        return self

    def size_for(self, oi: OpticalImage) -> tuple[int, int]:
        """(rows, cols): the configured size, else what fits in the OI's unpadded area in whole CFA cells."""
        if self.rows is not None and self.cols is not None:
            return self.rows, self.cols
        dx = float(oi.sample_spacing_m[0])
        ph, pw = self.cfa.shape
        h = (oi.height - 2 * oi.pad_rows) * dx
        w = (oi.width - 2 * oi.pad_cols) * dx
        # whole pixels to 1e-6 relative: a float32 OI of 32 samples at the pitch spans 31.9999994 pitches, which
        # lost a whole CFA cell (30 x 30)
        rows = self.rows or max(ph, math.floor(h / self.pixel_size_m * (1 + 1e-6)) // ph * ph)
        cols = self.cols or max(pw, math.floor(w / self.pixel_size_m * (1 + 1e-6)) // pw * pw)
        if rows * cols > MAX_AUTO_PIXELS:  # (a 5x magnification on the default camera: 375,000^2 pixels, a bare
            # allocator error after 18 s and 8 GB)
            raise ValueError(f"rows, cols: sized to the optical image ({w * 1e3:.4g} x {h * 1e3:.4g} mm at "
                             f"pixel_size_m {self.pixel_size_m:.4g}), the sensor would have {rows} x {cols} pixels, "
                             f"beyond the {MAX_AUTO_PIXELS:.3g} sized automatically; give rows and cols, or image a "
                             f"smaller field (a narrower hfov_deg, a shorter focal length or a farther scene)")
        return rows, cols

    # --- randomness -----------------------------------------------------------------------
    def _default_generator(self, device: torch.device) -> torch.Generator:
        key = str(device)
        g = self._generators.get(key)
        if g is None:
            # a stream of its own (seed + 1 was the next seed's fixed pattern: Sensor(seed=0)'s first frame of read
            # noise equalled Sensor(seed=1)'s DSNU map)
            g = torch.Generator(device=device).manual_seed(seed_for(self.seed, 0, stream=TEMPORAL_STREAM))
            self._generators[key] = g
        return g

    def fixed_pattern(self, rows: int, cols: int, *, dtype, device) -> dict[str, torch.Tensor]:
        """The sensor's fixed-pattern standard-normal maps (drawn once from ``seed``, stored as buffers)."""
        if self.fpn_dsnu is None or tuple(self.fpn_dsnu.shape) != (rows, cols):
            d = _noise.fixed_pattern_draws(rows, cols, self.seed, dtype=torch.float64)
            # kept on the device of the call (the same draws on every device): they were on the CPU, a host to
            # device copy per batch on a GPU
            self.fpn_dsnu, self.fpn_prnu, self.fpn_column = (d[k].to(device) for k in ("dsnu", "prnu", "column"))
        return {"dsnu": self.fpn_dsnu.to(dtype=dtype, device=device),
                "prnu": self.fpn_prnu.to(dtype=dtype, device=device),
                "column": self.fpn_column.to(dtype=dtype, device=device)}

    # --- stages ----------------------------------------------------------------------------
    def _qe_module(self, spectral_qe, batch: int):
        """The QE of a call: the sensor's ``spectral_qe``, or a per-call :class:`SpectralQE` (one for the batch, or
        per item with ``batch_size`` B) with the CFA's channels."""
        if spectral_qe is not None:
            if not isinstance(spectral_qe, SpectralQE):
                raise TypeError(f"spectral_qe: expected None or a SpectralQE, got {type(spectral_qe).__name__}")
            if spectral_qe.channel_names != self.cfa.channel_names:
                raise ValueError(f"spectral_qe: channel names {spectral_qe.channel_names} differ from the CFA's "
                                 f"{self.cfa.channel_names}")
        qe_mod = self.spectral_qe if spectral_qe is None else spectral_qe
        n = getattr(qe_mod, "batch_size", None)
        if n not in (None, batch):
            raise ValueError(f"spectral_qe: expected one QE or {batch} per-item QEs (one per batch sample), got {n}")
        return qe_mod

    def qe(self, oi: OpticalImage, spectral_qe: SpectralQE | None = None) -> torch.Tensor:
        """Combined spectral QE on the OI's wavelengths ``[C, L]`` (cached per grid), or ``[B, C, L]`` for a
        per-item QE (``spectral_qe``: a per-call :class:`SpectralQE` instead of the sensor's, see :meth:`forward`)."""
        qe_mod = self._qe_module(spectral_qe, oi.batch_size)
        key = self._qe_cache_key(qe_mod, oi, "qe")
        hit = None if key is None else self._weights_cache.get(key)
        if hit is not None and hit[0] is qe_mod:
            return hit[1]
        out = qe_mod(oi.wavelengths_nm, dtype=oi.dtype, device=oi.device)
        self._qe_cache_put(key, qe_mod, out)
        return out

    def _qe_cache_key(self, qe_mod, oi: OpticalImage, kind: str) -> tuple | None:
        """The cache key of a QE term of ``oi``'s grid, or None where it must be evaluated (a learnable QE, fixed
        filters that require grad, or one per item). It holds the QE's tensors' identity and version
        (``SpectralQE.cache_state``; :meth:`_qe_cache_put` keeps the tensors, so their ids are not reused)."""
        if not getattr(qe_mod, "cacheable", False) or getattr(qe_mod, "batch_size", None) is not None:
            return None
        return (kind, id(qe_mod), qe_mod.cache_state()[0], self._grid_key(oi.wavelengths_nm), oi.dtype,
                str(oi.device))

    def _grid_key(self, wavelengths_nm: torch.Tensor) -> tuple:
        """A wavelength grid's values as a tuple, memoised for the last grid tensor seen (a batch's calls share
        one; the entry keeps it alive, so its id is not reused)."""
        memo = self.__dict__.get("_grid_key_memo")
        if memo is not None and memo[0] is wavelengths_nm and memo[1] == tensor_version(wavelengths_nm):
            return memo[2]
        key = tuple(wavelengths_nm.tolist())
        self.__dict__["_grid_key_memo"] = (wavelengths_nm, tensor_version(wavelengths_nm), key)
        return key

    def _qe_cache_put(self, key: tuple | None, qe_mod, out: torch.Tensor) -> None:
        if key is None:
            return
        if len(self._weights_cache) > 32:
            self._weights_cache.clear()
        # the module and its tensors are kept: their ids cannot be reused while cached
        self._weights_cache[key] = (qe_mod, out, qe_mod.cache_state()[1])

    def spectral_weights(self, oi: OpticalImage, spectral_qe: SpectralQE | None = None) -> torch.Tensor:
        """``QE_c(l) dl`` as ``[L, C]`` (``[B, L, C]`` for a per-item QE): the projection from irradiance
        (photons/s/m^2/nm) to electrons/s/m^2 (cached per QE module and grid unless the QE is learnable or per
        item). ``spectral_qe``: as in :meth:`qe`."""
        qe_mod = self._qe_module(spectral_qe, oi.batch_size)
        key = self._qe_cache_key(qe_mod, oi, "weights")
        hit = None if key is None else self._weights_cache.get(key)
        if hit is not None and hit[0] is qe_mod:
            return hit[1]
        dl = spectral.wavelength_weights(oi.wavelengths_nm, self.spectral_rule).to(device=oi.device, dtype=oi.dtype)
        out = (qe_mod(oi.wavelengths_nm, dtype=oi.dtype, device=oi.device) * dl).transpose(-2, -1)
        self._qe_cache_put(key, qe_mod, out)
        return out

    def electron_rate_density(self, oi: OpticalImage, spectral_qe: SpectralQE | None = None) -> torch.Tensor:
        """Photo-electrons/s/m^2 per channel at every OI sample ``[B, C, H, W]`` (before pixel sampling).

        A factored optical image is projected on the C QE weightings directly (C planes, never the L cube).
        ``spectral_qe``: as in :meth:`qe`.
        """
        if oi.factors_hold_image:
            return oi.project(self.spectral_weights(oi, spectral_qe))
        return electron_rate_density(oi.photons, self.qe(oi, spectral_qe), oi.wavelengths_nm, self.spectral_rule)

    def electron_rate(self, oi: OpticalImage, *, qe_scale=None, spectral_qe: SpectralQE | None = None,
                      pixel_size_m=None) -> torch.Tensor:
        """Mean photo-electrons per second per pixel ``[B, 1, rows, cols]`` (before PRNU and noise)."""
        rates, _ = self.channel_rates(oi, qe_scale=qe_scale, spectral_qe=spectral_qe, pixel_size_m=pixel_size_m)
        return self.cfa.mosaic(rates)

    def channel_rates(self, oi: OpticalImage, extra_weights: torch.Tensor | None = None, *, qe_scale=None,
                      spectral_qe: SpectralQE | None = None, pixel_size_m=None
                      ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean photo-electrons/s of **every** channel at every pixel ``[B, C, rows, cols]`` (the CFA's mosaic of
        it is :meth:`electron_rate`), and optionally other spectral projections sampled the same way.

        Args:
            oi: the optical image.
            extra_weights: optional ``[L, K]`` weightings (e.g. CIE XYZ) projected together with the QE (one pass
                over the image: for a factored image, one set of inverse FFTs) and area-sampled at the pixels.
            qe_scale: optional per-sample factor (scalar or ``[B]``) on the spectral QE (e.g. a peak QE drawn per
                sample), so one module serves sensors that differ only by it.
            spectral_qe: optional per-call :class:`SpectralQE` used instead of the sensor's: one for the batch, or
                per item (filters ``[B, C, Ln]``, e.g. :func:`~isettorch.sensor.filters.shifted_qe`), so one module
                serves sensors that differ only by their QE curves.
            pixel_size_m: optional per-call pixel pitch (scalar or ``[B]``, metres) used instead of the sensor's,
                so one module serves sensors that differ only by their pitch (a batch of cameras with drawn pixel
                sizes). Each item must have one optical-image sample per pixel (its OI spacing equal to its pitch,
                the sensor's rows and cols set, area sampling, no pixel optics): the pixel then reads its own
                sample, and its photodiode area ``fill_factor x pitch^2`` scales the rate.

        Returns:
            ``(rates [B, C, rows, cols], extra [B, K, rows, cols] or None)``; ``extra`` is the pixel mean of the
            projected irradiance (per m^2, not multiplied by the pixel area).
        """
        if not isinstance(oi, OpticalImage):
            raise TypeError(f"oi: expected an OpticalImage, got {type(oi).__name__}")
        po = self.pixel_optics
        c = len(self.cfa.channel_names)
        pitch = None if pixel_size_m is None else self._call_pitch(pixel_size_m, oi)
        sample = self.sample if pitch is None else self._sample_own
        if po is not None and po.wavelength_dependent:
            sampled = self._sample_with_spectral_etendue(oi, extra_weights, spectral_qe)
        elif extra_weights is None:
            density = self.electron_rate_density(oi, spectral_qe)  # e-/s/m^2 per filter
            sampled = sample(density, oi)
        else:
            density = oi.project(self._joint_weights(oi, extra_weights, spectral_qe))
            sampled = sample(density, oi)
        # with pixel optics in the physical convention the light of the whole pixel meets the etendue, which
        # holds the photodiode's width; otherwise the photodiode's area (ISETCam sensorCompute)
        area = self.collecting_area_m2()
        if pitch is not None:  # per item: [B, 1, 1, 1]
            area = self.collecting_area_m2(pitch).to(sampled.dtype).reshape(-1, 1, 1, 1)
        if qe_scale is None:
            rates = sampled[:, :c] * area
        elif isinstance(qe_scale, (int, float)) and not isinstance(qe_scale, bool):
            if not (math.isfinite(qe_scale) and qe_scale > 0):
                raise ValueError(f"qe_scale: expected a positive finite factor, got {qe_scale!r}")
            rates = sampled[:, :c] * (area * qe_scale)  # one pass
        else:
            k = batch_param(qe_scale, "qe_scale", sampled.shape[0], dtype=sampled.dtype, device=sampled.device,
                            positive=True)
            rates = sampled[:, :c] * (area * k.reshape(-1, 1, 1, 1))
        if self.vignetting is not None:
            v = self.vignetting
            if v.dim() == 2 and tuple(v.shape) != tuple(rates.shape[-2:]):
                raise ValueError(f"vignetting: the map is {tuple(v.shape)} but the sensor has "
                                 f"{tuple(rates.shape[-2:])} pixels here (rows, cols)")
            rates = rates * v.to(rates.dtype).to(rates.device)
        if po is not None and not po.wavelength_dependent:
            rates = rates * self.etendue_map(oi)[:, None].to(rates.dtype)
        return _without_ringing(rates), (sampled[:, c:] if extra_weights is not None else None)

    def etendue_map(self, oi: OpticalImage) -> torch.Tensor:
        """The pixel optics' etendue at every pixel for ``oi``'s geometry: ``[B, rows, cols]`` (``[B, L, rows, cols]``
        with diffraction); ones when the sensor has no ``pixel_optics``."""
        rows, cols = self.size_for(oi)
        if self.pixel_optics is None:
            return torch.ones(oi.batch_size, rows, cols, dtype=torch.float64, device=oi.device)
        return self.pixel_optics.etendue_map(oi, rows, cols, self.pixel_size_m, self.fill_factor).to(oi.device)

    def _sample_with_spectral_etendue(self, oi: OpticalImage, extra_weights: torch.Tensor | None,
                                      spectral_qe: SpectralQE | None = None) -> torch.Tensor:
        """Pixel values ``[B, C (+ K), rows, cols]`` when the etendue depends on the wavelength: every band is
        sampled, weighted by its etendue map, then projected on the QE (the extra weightings without the etendue,
        as in the wavelength-independent path)."""
        bands = self.sample(oi.photons, oi)  # [B, L, rows, cols] photons/s/m^2/nm at the pixels
        rows, cols = bands.shape[-2:]
        e, i0, w = self.pixel_optics.radial_etendue(oi, rows, cols, self.pixel_size_m, self.fill_factor)
        e, i0, w = e.to(bands.device), i0.to(bands.device), w.to(bands.device)
        qe_w = self.spectral_weights(oi, spectral_qe)  # [L, C] (or [B, L, C] per item)
        n_c = qe_w.shape[-1]
        out = None
        for band in range(bands.shape[1]):  # one band's etendue map at a time (no [B, L, rows, cols] map)
            emap = self.pixel_optics.interpolate(e[:, band], i0, w).to(bands.dtype)  # [B, rows, cols]
            weighted = (bands[:, band] * emap)[:, None]
            qe_band = qe_w[..., band, :].to(bands.dtype).reshape(-1, n_c, 1, 1)
            # accumulated in place (one pass per band, not three; autograd keeps the product's inputs, not ``out``)
            out = weighted * qe_band if out is None else out.addcmul_(weighted, qe_band)
        if extra_weights is not None:
            extra = torch.einsum("blrc,lk->bkrc", bands, extra_weights.to(device=oi.device, dtype=bands.dtype))
            out = torch.cat([out, extra], 1)
        return out

    def _joint_weights(self, oi: OpticalImage, extra: torch.Tensor, spectral_qe: SpectralQE | None = None
                       ) -> torch.Tensor:
        """``[L, C + K]`` (``[B, L, C + K]`` for a per-item QE): the QE weightings then ``extra``'s (memoised per
        pair of tensors when neither needs a gradient; the entry keeps both alive, so their ids are not reused)."""
        qe_w = self.spectral_weights(oi, spectral_qe)
        if qe_w.dim() == 3:
            extra = extra.to(device=oi.device, dtype=oi.dtype)
            return torch.cat([qe_w, extra.expand(qe_w.shape[0], *extra.shape)], dim=2)
        if qe_w.requires_grad or extra.requires_grad:
            return torch.cat([qe_w, extra.to(device=oi.device, dtype=oi.dtype)], dim=1)
        key = (id(qe_w), id(extra), tensor_version(extra), oi.dtype, str(oi.device))
        memo = self.__dict__.setdefault("_joint_memo", {})
        hit = memo.get(key)
        if hit is None or hit[0] is not qe_w or hit[1] is not extra:
            if len(memo) > 16:
                memo.clear()
            hit = memo[key] = (qe_w, extra, torch.cat([qe_w, extra.to(device=oi.device, dtype=oi.dtype)], dim=1))
        return hit[2]

    def sample(self, density: torch.Tensor, oi: OpticalImage) -> torch.Tensor:
        """Per-m^2 planes on the OI grid ``[B, K, H, W]`` -> their value at each pixel ``[B, K, rows, cols]``
        (the sensor's ``sampling``: area over the photodiode, or over the whole pixel under pixel optics in the
        physical convention (the microlens's aperture), or ISETCam's pre-blur + point sampling)."""
        rows, cols = self.size_for(oi)
        dx = oi.sample_spacing_m
        if self.sampling == "isetcam":
            planes = []
            spacings = dx.detach().cpu().tolist()
            groups = [slice(None)] if len(set(spacings)) == 1 else [slice(i, i + 1) for i in range(len(spacings))]
            for sl in groups:
                k = self.preblur_size or isetcam_preblur_size(self.pixel_size_m, dx[sl][0].item())
                # ISETCam regridOI2ISA + interp2 at pixel centres; pixel current = scd x ff x pitch^2.
                planes.append(sample_point(isetcam_preblur(density[sl], k), dx[sl], self.pixel_size_m, rows, cols))
            return torch.cat(planes) if len(planes) > 1 else planes[0]
        dr, dc = oi.height - rows, oi.width - cols
        if self.sampling == "area" and dr >= 0 and dc >= 0 and dr % 2 == 0 and dc % 2 == 0:
            # One OI sample per pixel, pixel centres on sample centres (both grids centred on the axis): the
            # photodiode (inside its cell) averages a constant, so area sampling returns the samples under the
            # sensor (exact; the spacings may differ by the geometry's own float rounding, a few eps)
            # (not for a spacing that records a gradient: the slice has none, sample_area the area's)
            if self._same_grid(dx) and not records_grad(dx):
                return density[..., dr // 2:dr // 2 + rows, dc // 2:dc // 2 + cols]
        recon = "linear" if self.sampling == "area_linear" else "constant"
        # pixel optics in the physical convention: the microlens (as wide as the pixel) gathers the light over the
        # whole pixel and its etendue holds the photodiode's share (collecting_area_m2); the photodiode's window
        # dropped the light between photodiodes (an edge, the sampling MTF and aliasing were a bare pixel's)
        window = 1.0 if self._microlens_aperture else self.fill_factor
        return sample_area(density, dx, self.pixel_size_m, rows, cols, window, recon)

    def _call_pitch(self, pixel_size_m, oi: OpticalImage) -> torch.Tensor:
        """A per-call pixel pitch as ``[B]`` float64 on the OI's device, checked: every item has one OI sample
        per pixel (see :meth:`channel_rates`)."""
        dx = oi.sample_spacing_m.detach()
        p = batch_param(pixel_size_m, "pixel_size_m", oi.batch_size, dtype=torch.float64, device=dx.device,
                        positive=True)
        if self.sampling != "area" or self.pixel_optics is not None or self.rows is None or self.cols is None:
            raise ValueError(f"pixel_size_m: a per-call pixel size needs one optical-image sample per pixel (area "
                             f"sampling, rows and cols set, no pixel optics); this sensor has sampling="
                             f"{self.sampling!r}, rows={self.rows}, cols={self.cols}, pixel_optics="
                             f"{type(self.pixel_optics).__name__ if self.pixel_optics is not None else None}")
        dr, dc = oi.height - self.rows, oi.width - self.cols
        eps = torch.finfo(dx.dtype).eps
        if dr < 0 or dc < 0 or dr % 2 or dc % 2 or not bool(((dx.to(p.dtype) / p - 1).abs() <= 4 * eps).all()):
            raise ValueError(f"pixel_size_m: expected each item's optical-image spacing to equal its pixel size "
                             f"(one sample per pixel) on an image at least the sensor's size, with an even margin; "
                             f"got spacings {dx.tolist()} m, pixel sizes {p.tolist()} m, image {oi.height}x"
                             f"{oi.width} for a {self.rows}x{self.cols} sensor")
        return p

    def _sample_own(self, density: torch.Tensor, oi: OpticalImage) -> torch.Tensor:
        """Each pixel's own sample (one OI sample per pixel, centred; :meth:`_call_pitch` checked it)."""
        dr, dc = (oi.height - self.rows) // 2, (oi.width - self.cols) // 2
        return density[..., dr:dr + self.rows, dc:dc + self.cols]

    def _same_grid(self, dx: torch.Tensor) -> bool:
        """Whether the OI spacings ``dx [B]`` equal the pixel pitch to a few eps of their dtype (memoised per
        spacing tensor: an optics' cached geometry returns the same one; the entry keeps it alive)."""
        key = (id(dx), self.pixel_size_m)
        memo = self.__dict__.setdefault("_same_grid_memo", {})
        hit = memo.get(key)
        if hit is not None and hit[0] is dx and hit[1] == tensor_version(dx):  # (a spacing changed in place had
            return hit[2]  # kept its stale answer: raw samples for a grid twice the pitch, up to 92 % off)
        eps = torch.finfo(dx.dtype).eps
        same = bool(((dx.detach() / self.pixel_size_m - 1).abs() <= 4 * eps).all())
        if not dx.requires_grad:
            if len(memo) > 64:
                memo.clear()
            memo[key] = (dx, tensor_version(dx), same)
        return same

    def _analog(self, volts: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
        g = gain.reshape(-1, 1, 1, 1)
        if self.gain_convention == "isetcam":
            if self.analog_offset_v == 0 and not records_grad(gain) and bool((gain == 1).all()):
                return volts  # (a learnable gain of 1 keeps its gradient: the division below)
            return (volts + self.analog_offset_v) / g  # ISETCam sensorComputeImage divides by the gain
        return (volts + self.analog_offset_v) * g if self.analog_offset_v != 0 else volts * g

    def _clip_low_v(self) -> float:
        return -self.black_level_dn * self.lsb_v if self.adc_bits is not None else 0.0

    def _readout(self, pixel_volts: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
        """Pixel volts -> clipped volts at the ADC input (electrons output: pixel volts clipped to the swing)."""
        if self.output_units == "electrons":
            return pixel_volts.clamp(0, self.voltage_swing_v)
        if self.gain_convention != "isetcam":
            # the pixel's output saturates at the swing (its well capacity is swing / conversion gain) before the
            # amplifier: a gain below 1 read 15,000 e- from a 10,000 e- well (ISETCam's convention gains first,
            # FORMAT 4.6 steps 7-8)
            pixel_volts = pixel_volts.clamp(max=self.voltage_swing_v)
        return self._analog(pixel_volts, gain).clamp(self._clip_low_v(), self.voltage_swing_v)

    def _to_units(self, volts: torch.Tensor, *, quantize: bool, cg=None) -> torch.Tensor:
        """Clipped analog volts -> output units (DN with ADC rounding and clamping)."""
        if self.output_units == "volts":
            return volts
        if self.output_units == "electrons":
            return volts / (self.conversion_gain_v_per_e if cg is None else cg)
        return self.volts_to_dn(volts, quantize=quantize)

    def volts_to_dn(self, volts: torch.Tensor, *, quantize: bool = True) -> torch.Tensor:
        """ADC: clipped volts -> DN, ``round(v / lsb_v) + black`` (clamped to ``2^N - 1`` unless
        ``adc_mode='isetcam'``; ISETCam ``analog2digital`` 'linear'). A fractional black level's fraction is added
        before the rounding, so the DN are whole codes whose mean is the black level plus the signal."""
        if self.adc_bits is None:
            raise ValueError("volts_to_dn: the sensor has an analog readout (adc_bits is None)")
        # whole numbers are exact up to 2^(mantissa bits + 1): 1 / eps = 2^mantissa bits
        exact_bits = round(math.log2(1 / torch.finfo(volts.dtype).eps)) + 1 if volts.is_floating_point() else 64
        if self.adc_bits > exact_bits:  # (float32 rounded a 25-bit top code 2^25 - 1 up to 2^25, above white)
            raise ValueError(f"adc_bits: {self.adc_bits}-bit codes are not whole numbers in {volts.dtype} (exact up to "
                             f"2^{exact_bits}); render in float64 (e.g. camera.double()) or use at most "
                             f"{exact_bits} bits")
        whole, part = self._black_parts()
        x = volts / self.lsb_v + part if part else volts / self.lsb_v
        if quantize:
            x = _noise.quantize_ste(x)  # MATLAB round: halves away from zero
        x = x + whole
        if self.adc_mode == "clamp":
            x = x.clamp(max=2 ** self.adc_bits - 1)
        return x

    def exposure_for(self, oi: OpticalImage | None, rate: torch.Tensor | None = None, analog_gain=None, *,
                     exposure_ev=None, conversion_gain_v_per_e=None,
                     max_exposure_s: float = MAX_EXPOSURE_S) -> torch.Tensor:
        """The exposure ``[B]`` (s): fixed, or from auto-exposure on the noise-free volts (after gain), at most
        ``max_exposure_s`` (:func:`~isettorch.sensor.exposure.auto_exposure`'s cap; a black image gets it), times
        ``2^exposure_ev`` (exposure compensation in stops, scalar or ``[B]``; default 0).

        ``oi`` may be None when ``rate`` (the mosaic's electrons/s ``[B, 1, rows, cols]``) is given.
        """
        if rate is None and oi is None:
            raise ValueError("oi, rate: expected an optical image or the electron rate")
        like = rate if rate is not None else oi.sample_spacing_m
        b = rate.shape[0] if rate is not None else oi.batch_size
        dt, dev = like.dtype, like.device
        if self.auto_exposure is None:
            t = batch_param(self.exposure_s, "exposure_s", b, dtype=dt, device=dev, positive=True)
        else:
            rate = self.electron_rate(oi) if rate is None else rate
            gain = batch_param(self.analog_gain if analog_gain is None else analog_gain, "analog_gain", b,
                               dtype=dt, device=dev, positive=True)
            cg = self._level("conversion_gain_v_per_e", conversion_gain_v_per_e, b, dt, dev)
            if self.output_units == "electrons":
                # the electrons chain clips the pixel volts at the swing or the full well, with no analog gain or
                # offset (_readout): aimed there (gain and offset scaled the aim: at gain 4 the brightest pixel got
                # 0.24 of the saturation for a target of 0.95, with a 0.3 V offset 0.67)
                v1 = rate * cg
                room = self.saturation_e(cg) * (cg.reshape(-1) if isinstance(cg, torch.Tensor) else cg)
            else:
                v1 = self._analog(rate * cg, gain)
                room = self._saturation_v(gain, cg)
            if self.analog_offset_v != 0 and self.output_units != "electrons":
                # the response to light, aimed below the saturation less the offset
                off = self._analog(torch.zeros_like(rate[:, :, :1, :1]), gain)  # the offset after gain, [B,1,1,1]
                v1 = v1 - off
                room = room - off.reshape(-1)  # (the offset was counted as light's room: a 0.3 V offset clipped
                if bool((room <= 0).any()):    # the brightest pixel at 0.7 V of light for 0.95)
                    raise ValueError(f"analog_offset_v: an offset of {self.analog_offset_v} V (after the analog "
                                     f"gain) leaves no room for light below the saturation "
                                     f"({self.saturation_v(gain, cg)} V)")
            t = auto_exposure(v1, room, self.auto_exposure, target=self.ae_target,
                              percentile=self.ae_percentile, max_exposure_s=max_exposure_s).to(dt)
        if exposure_ev is not None:
            ev = batch_param(exposure_ev, "exposure_ev", b, dtype=torch.float64, device=dev)
            t = t * torch.exp2(ev).to(dt)
            small = ev.tolist() if ev.device.type == "cpu" and ev.numel() <= 64 else None
            # within +-60 stops every exposure from 1e-20 s to 10 s stays a positive float32: no check (no sync)
            bad = None if small is not None and max(map(abs, small)) < 60 else ~torch.isfinite(t.detach()) | (
                t.detach() <= 0)
            if bad is not None and bool(bad.any()):
                raise ValueError(f"exposure_ev: {ev[bad].tolist()} stops make the exposure "
                                 f"{t.detach()[bad].tolist()} s, which {dt} cannot hold as a positive finite time")
        return t

    def _level(self, name: str, value, b: int, dtype, device):
        """A level of :data:`PER_CALL_LEVELS`: the module's float, or a per-call value as a ``[B, 1, 1, 1]`` tensor."""
        if value is None:
            return getattr(self, name)
        positive = name == "conversion_gain_v_per_e"
        if isinstance(value, (int, float)) and not isinstance(value, bool):  # a scalar for the whole batch
            if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
                raise ValueError(f"{name}: expected a {'positive' if positive else 'non-negative'} finite value, "
                                 f"got {value!r}")
            check_in_dtype_range(value, name, dtype)
            if name == "prnu_sigma_percent":
                _check_prnu(value)
            return float(value)
        t = batch_param(value, name, b, dtype=dtype, device=device, positive=positive)
        if not positive and bool((t < 0).any()):
            raise ValueError(f"{name}: expected non-negative values, got {t.min().item():.6g}")
        if name == "prnu_sigma_percent":
            _check_prnu(float(t.detach().max()))
        return t.reshape(-1, 1, 1, 1)

    def levels(self, b: int, dtype, device, **overrides) -> dict[str, Any]:
        """The levels of a capture (:data:`PER_CALL_LEVELS`): the module's floats, with per-call overrides
        (scalar or ``[B]``) as ``[B, 1, 1, 1]`` tensors. ValueError naming an unknown level."""
        bad = [k for k in overrides if k not in PER_CALL_LEVELS]
        if bad:
            raise ValueError(f"{bad[0]}: not a per-call sensor level; expected one of {PER_CALL_LEVELS}")
        return {k: self._level(k, overrides.get(k), b, dtype, device) for k in PER_CALL_LEVELS}

    def gain_per_electron(self, analog_gain=None, *, batch: int = 1, dtype=torch.float64, device=None,
                          conversion_gain_v_per_e=None) -> torch.Tensor:
        """Output units per photo-electron ``[B]`` on the linear part of the response (no clipping, black level or
        offset): ``cg x gain / lsb`` for DN (``cg / gain`` with ISETCam's gain), volts: without ``/ lsb``."""
        gain = batch_param(self.analog_gain if analog_gain is None else analog_gain, "analog_gain", batch,
                           dtype=dtype, device=device, positive=True)
        cg = self._level("conversion_gain_v_per_e", conversion_gain_v_per_e, batch, dtype, device)
        cg = cg.reshape(-1) if isinstance(cg, torch.Tensor) else cg
        if self.output_units == "electrons":
            return torch.ones_like(gain)
        k = cg / gain if self.gain_convention == "isetcam" else cg * gain
        return k / self.lsb_v if self.output_units == "dn" else k

    def readout(self, electron_rate: torch.Tensor, exposure_s, analog_gain=None, *,
                conversion_gain_v_per_e=None) -> torch.Tensor:
        """The noise-free chain (exposure, conversion gain, analog gain, clipping, ADC scale without rounding) for
        any number of channels ``[B, C, rows, cols]`` -> output units: the ``noise_free`` of a capture, per channel
        (e.g. of :meth:`channel_rates`: a camera-RGB target with no CFA)."""
        electron_rate = _check_rate(electron_rate, mosaic=False)  # (a negative rate was clipped to 0, NaN passed)
        b = electron_rate.shape[0]
        dtype, device = electron_rate.dtype, electron_rate.device
        t = batch_param(exposure_s, "exposure_s", b, dtype=dtype, device=device, positive=True)
        gain = batch_param(self.analog_gain if analog_gain is None else analog_gain, "analog_gain", b,
                           dtype=dtype, device=device, positive=True)
        cg = self._level("conversion_gain_v_per_e", conversion_gain_v_per_e, b, dtype, device)
        photo_e = self._full_well_clip(electron_rate * t.reshape(-1, 1, 1, 1))
        return self._to_units(self._readout(photo_e * cg, gain), quantize=False, cg=cg)

    def _full_well_clip(self, photo_e: torch.Tensor) -> torch.Tensor:
        """The photodiode's saturation (``full_well_e``, EMVA 1288 section 4.1) on the noise-free signal, as the
        noisy chain applies it after shot noise (:meth:`NoiseTerms.after_shot`)."""
        fw = self.noise_terms.full_well_e
        return photo_e if fw is None else photo_e.clamp(max=fw)

    # --- forward -----------------------------------------------------------------------------
    @full_precision
    def forward(self, oi: OpticalImage, *, exposure_s=None, analog_gain=None, noise: bool = True,
                generator: torch.Generator | None = None, exposure_ev=None, qe_scale=None,
                spectral_qe: SpectralQE | None = None, pixel_size_m=None, **levels) -> RawImage:
        """Simulate a capture of ``oi``; returns a :class:`RawImage` ``[B, 1, rows, cols]``.

        Args:
            oi: the optical image (photons/s/m^2/nm) ``[B, L, H, W]``.
            exposure_s, analog_gain: per-call overrides, scalar or ``[B]`` (an explicit exposure also
                overrides auto-exposure).
            noise: False gives the noise-free capture (no dark signal, noise or fixed pattern).
            generator: torch.Generator for the temporal noise (default: the sensor's own, seeded from ``seed``).
            exposure_ev: exposure compensation (stops, scalar or ``[B]``) applied to the fixed or auto exposure
                (with an explicit ``exposure_s`` it is a ValueError).
            qe_scale: per-sample factor on the spectral QE (see :meth:`channel_rates`).
            spectral_qe: a per-call :class:`SpectralQE` (one, or per item ``[B, C, Ln]``) used instead of the
                sensor's (see :meth:`channel_rates`); the raw carries it.
            pixel_size_m: a per-call pixel pitch, scalar or ``[B]`` (see :meth:`channel_rates`); the raw carries it.
            levels: per-call values (scalar or ``[B]``) of :data:`PER_CALL_LEVELS` (``read_noise_v``,
                ``dark_current_e_per_s``, ``dsnu_sigma_v``, ``prnu_sigma_percent``, ``column_fpn_sigma_v``,
                ``conversion_gain_v_per_e``), e.g. to randomise noise per sample without rebuilding the module.
        """
        if not isinstance(oi, OpticalImage):
            raise TypeError(f"oi: expected an OpticalImage, got {type(oi).__name__}")
        if exposure_s is not None and exposure_ev is not None:  # (the compensation was silently dropped)
            raise ValueError("exposure_ev: compensates the sensor's fixed or auto exposure; with an explicit "
                             "exposure_s give the exposure you want (exposure_s * 2 ** exposure_ev) instead")
        rate = self.electron_rate(oi, qe_scale=qe_scale, spectral_qe=spectral_qe, pixel_size_m=pixel_size_m)
        if exposure_s is None:
            exposure_s = self.exposure_for(oi, rate, analog_gain, exposure_ev=exposure_ev,
                                           conversion_gain_v_per_e=levels.get("conversion_gain_v_per_e"))
        return self.capture(rate, exposure_s=exposure_s, analog_gain=analog_gain, noise=noise, generator=generator,
                            spectral_qe=spectral_qe, pixel_size_m=pixel_size_m, **levels)

    @full_precision
    def capture(self, electron_rate: torch.Tensor, *, exposure_s=None, analog_gain=None, noise: bool = True,
                generator: torch.Generator | None = None, spectral_qe: SpectralQE | None = None,
                pixel_size_m=None, **levels) -> RawImage:
        """The capture from a precomputed mean electron rate (what :meth:`forward` does after
        :meth:`electron_rate`): exposure, noise, analog gain, ADC.

        Args:
            electron_rate: mean photo-electrons/s per pixel ``(B, 1, rows, cols)``, e.g. from :meth:`electron_rate`
                (callers that already hold the per-channel irradiance integrals avoid recomputing them).
            exposure_s: scalar or ``[B]``; None uses the sensor's fixed ``exposure_s`` (auto-exposure needs
                :meth:`forward` or :meth:`exposure_for`).
            analog_gain, noise, generator, levels: as in :meth:`forward`.
            spectral_qe: the per-call QE the rate was computed with (:meth:`forward`), carried by the raw (default:
                the sensor's).
            pixel_size_m: the per-call pixel pitch the rate was computed with, scalar or ``[B]``, carried by the
                raw (default: the sensor's).

        Example:
            >>> s = Sensor(rows=2, cols=2, cfa="RGGB", adc_bits=10)
            >>> s.capture(torch.full((1, 1, 2, 2), 1e4), exposure_s=0.01, noise=False).data.shape
            torch.Size([1, 1, 2, 2])
        """
        rate = _check_rate(electron_rate, mosaic=True)
        check_bool(noise, "noise")  # ('yes', None or 0 were read as flags)
        if self.rows is not None and self.cols is not None and tuple(rate.shape[-2:]) != (self.rows, self.cols):
            # (a 5x7 rate on a 4x4 sensor was read as a 5x7 raw, and redrew the sensor's fixed patterns at 5x7)
            raise ValueError(f"electron_rate: expected the sensor's {self.rows}x{self.cols} pixels, got "
                             f"{rate.shape[-2]}x{rate.shape[-1]}")
        b = rate.shape[0]
        dtype, device = rate.dtype, rate.device
        if exposure_s is None:
            if self.auto_exposure is not None:
                raise ValueError(f"exposure_s: auto_exposure={self.auto_exposure!r} needs the optical image; "
                                 f"call forward(oi) or pass exposure_s (e.g. from exposure_for)")
            exposure_s = self.exposure_s
        t = batch_param(exposure_s, "exposure_s", b, dtype=dtype, device=device, positive=True)
        gain = batch_param(self.analog_gain if analog_gain is None else analog_gain, "analog_gain", b,
                           dtype=dtype, device=device, positive=True)
        lv = self.levels(b, dtype, device, **levels)
        cg = lv["conversion_gain_v_per_e"]
        photo_e = rate * t.reshape(-1, 1, 1, 1)
        swing = self.voltage_swing_v

        clean_v = self._readout(self._full_well_clip(photo_e) * cg, gain)
        noise_free = self._to_units(clean_v, quantize=False, cg=cg)

        if noise:
            g = generator if generator is not None else self._default_generator(device)
            volts = self._noisy_pixel_volts(photo_e, t, g, lv)
            data = self._to_units(self._readout(volts, gain), quantize=True, cg=cg)
        else:
            data = self._to_units(clean_v, quantize=True, cg=cg)

        cg_out = cg.reshape(-1) if isinstance(cg, torch.Tensor) else cg
        pitch = self.pixel_size_m if pixel_size_m is None else batch_param(
            pixel_size_m, "pixel_size_m", b, dtype=torch.float64, device=device, positive=True)
        # the call's own gains: a per-call tensor gives [B] levels only when the full well sets the saturation (a list
        # or array as the call's [B] gain tensor, on the data's device)
        sequence = analog_gain is not None and not is_real(analog_gain) and not isinstance(analog_gain, torch.Tensor)
        white = self._white_level(self.analog_gain if analog_gain is None else gain.reshape(-1) if sequence
                                  else analog_gain, cg_out)
        # the black level and the analog offset: no light (per item from the call's [B] gain, on its device)
        per_call = analog_gain if analog_gain is None or is_real(analog_gain) else gain.reshape(-1)
        black, offset = self._zero_and_offset(per_call)
        if offset is not None and (not isinstance(black, torch.Tensor) or black.device.type == "cpu") and \
                not bool(torch.as_tensor(black < white).all()):  # (no host read of device levels)
            raise ValueError(f"analog_offset_v: the offset of {self.analog_offset_v} V at the analog gain "
                             f"{self.analog_gain if analog_gain is None else analog_gain} reaches the raw's white "
                             f"level, leaving no room for light; expected a smaller offset or gain")
        return RawImage(
            data=data, units=self.output_units, cfa=self.cfa, black_level=black, white_level=white,
            exposure_s=t, analog_gain=gain, analog_offset_v=self.analog_offset_v,
            conversion_gain_v_per_e=cg_out, voltage_swing_v=swing, pixel_size_m=pitch,
            fill_factor=self.fill_factor, adc_bits=self.adc_bits, noise=self.noise_parameters(enabled=noise, **lv),
            noise_free=noise_free, electrons=photo_e,
            metadata={"sensor": self.name, "sampling": self.sampling, "gain_convention": self.gain_convention},
            spectral_qe=self._qe_module(spectral_qe, b), offset_level=0.0 if offset is None else offset,
        )

    def _fixed_or_fresh_patterns(self, like: torch.Tensor, g: torch.Generator | None, lv: dict
                                 ) -> dict[str, torch.Tensor]:
        b, _, rows, cols = like.shape
        if not (_on(lv["dsnu_sigma_v"]) or _on(lv["prnu_sigma_percent"]) or _on(lv["column_fpn_sigma_v"])):
            return {}  # no fixed-pattern stage: nothing drawn
        if self.fpn_mode == "fixed":
            fp = self.fixed_pattern(rows, cols, dtype=like.dtype, device=like.device)
            return {"dsnu": fp["dsnu"].expand(b, 1, rows, cols), "prnu": fp["prnu"].expand(b, 1, rows, cols),
                    "column": fp["column"].expand(b, 1, 1, cols)}
        # ISETCam sensorAddNoise / noiseFPN: new DSNU/PRNU images on every call (only those in use)
        out = {}
        if _on(lv["dsnu_sigma_v"]):
            out["dsnu"] = _noise.normal(like, g)
        if _on(lv["prnu_sigma_percent"]):
            out["prnu"] = _noise.normal(like, g)
        if _on(lv["column_fpn_sigma_v"]):
            out["column"] = _noise.normal(like, g, (b, 1, 1, cols))
        return out

    def _noisy_pixel_volts(self, photo_e: torch.Tensor, t: torch.Tensor, g: torch.Generator | None,
                           lv: dict | None = None) -> torch.Tensor:
        """Pixel volts (before analog gain and clipping) with dark signal, shot, read and fixed-pattern noise.

        ``lv``: the capture's levels (:meth:`levels`; floats, or ``[B, 1, 1, 1]`` per-call tensors)."""
        lv = self.levels(photo_e.shape[0], photo_e.dtype, photo_e.device) if lv is None else lv
        cg = lv["conversion_gain_v_per_e"]
        read_v, dark, dsnu_v = lv["read_noise_v"], lv["dark_current_e_per_s"], lv["dsnu_sigma_v"]
        prnu, column_v = lv["prnu_sigma_percent"], lv["column_fpn_sigma_v"]
        tt = t.reshape(-1, 1, 1, 1)
        fp = self._fixed_or_fresh_patterns(photo_e, g, lv)
        if self.noise_model == "isetcam":
            # ISETCam sensorAddNoise order (FORMAT 4.8): dark, shot (noiseShot), read, then v (1 + PRNU) + DSNU
            electrons = photo_e + dark * tt if _on(dark) else photo_e
            if self.shot_noise != "off":
                electrons = _noise.isetcam_shot_noise(electrons, g)
            volts = electrons * cg
            if _on(read_v):
                volts = volts + read_v * _noise.normal(volts, g)
            if _on(prnu):
                volts = volts * (1 + prnu / 100 * fp["prnu"])
            if _on(dsnu_v):
                volts = volts + dsnu_v * fp["dsnu"]
            if _on(column_v):
                volts = volts + column_v * fp["column"]
            return volts
        signal_e = photo_e
        if _on(prnu):  # PRNU: per-pixel gain of the photo signal (EMVA 1288)
            signal_e = signal_e * (1 + prnu / 100 * fp["prnu"])
        if _on(dark):
            signal_e = signal_e + dark * tt
        nt = self.noise_terms  # hot pixels, full well, dead pixels, dark shading, row/column noise (noise_terms.py)
        signal_e = nt.mean_dark_e(signal_e, tt)
        volts = nt.after_shot(_noise.shot_noise(signal_e, self.shot_noise, g), tt, cg, g)
        if _on(read_v):
            volts = volts + read_v * nt.read_noise_draw(volts, g)
            if self.cds:  # the reset sample has its own read noise
                volts = volts - read_v * nt.read_noise_draw(volts, g)
        if not self.cds:  # CDS subtracts the reset level, cancelling the fixed offsets
            if _on(dsnu_v):
                volts = volts + dsnu_v * fp["dsnu"]
            if _on(column_v):
                volts = volts + column_v * fp["column"]
        return volts

    def noise_parameters(self, enabled: bool = True, **levels) -> dict[str, Any]:
        """The noise settings of a capture (floats, or ``[B]`` tensors for per-call levels)."""
        lv = {k: (v.reshape(-1) if isinstance(v, torch.Tensor) else v) for k, v in levels.items()
              if k != "conversion_gain_v_per_e"}
        return {"enabled": enabled, "shot_noise": self.shot_noise, "read_noise_v": self.read_noise_v,
                "dark_current_e_per_s": self.dark_current_e_per_s, "dsnu_sigma_v": self.dsnu_sigma_v,
                "prnu_sigma_percent": self.prnu_sigma_percent, "column_fpn_sigma_v": self.column_fpn_sigma_v,
                **lv,
                "fpn_mode": self.fpn_mode, "noise_model": self.noise_model, "cds": self.cds, "seed": self.seed,
                **self.noise_terms.as_dict()}

    def poisson_gaussian(self, raw: RawImage | None = None, *, exposure_s=None, analog_gain=None
                         ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(a, b)`` ``[B]`` (float64, detached) of the Poisson-Gaussian model ``var(data - noise_free) = a x + b``
        of this sensor's captures, ``x`` the noise-free signal above black, in the output units (Foi et al.,
        "Practical Poissonian-Gaussian noise modeling", IEEE TIP 17(10), 2008; EMVA 1288 release 4.0 eq. 6): the
        terms of :meth:`_noisy_pixel_volts`. Of a capture ``raw`` (:meth:`capture`: the levels it used, ``raw.noise``,
        ``raw.exposure_s``, ``raw.analog_gain``), or, without one, of a capture with the sensor's own levels at
        ``exposure_s`` (seconds, >= 0; the dark current's share) and ``analog_gain`` (default the sensor's).

        ``a``: output units per electron (shot noise; 0 with ``shot_noise='off'`` or a capture without noise).
        ``b``: read noise (twice its variance with CDS: the reset sample has its own), dark-current shot noise,
        DSNU and column offsets (cancelled by CDS), temporal row/column noise and dark shading
        (:mod:`~isettorch.sensor.noise_terms`), each times the output units per pixel volt squared, plus the ADC's
        rounding to whole codes, 1/12 DN^2 (EMVA 1288 eq. 5; none for a volts or electrons readout). Left out:
        PRNU, which adds ``(prnu_sigma_percent / 100 x)^2`` across pixels, hot and dead pixels (defects), and
        clipping at black and white. An analog offset (``analog_offset_v``) is not signal: ``x`` is
        ``noise_free - raw.black_level``, the capture's black level being its zero level (:meth:`zero_level`: the
        black level plus the offset after gain; measured from ``black_level_dn`` alone, the offset counted as signal
        and overstated the variance by ``a`` times it: gain 2, 0.02 V, 537 against 403 DN^2).

        Example:
            >>> s = Sensor(adc_bits=10, conversion_gain_v_per_e=1e-4, read_noise_v=1e-3, cds=True)
            >>> a, b = s.poisson_gaussian(exposure_s=0.01)  # DN: 1 V / 1024 codes, read noise 10 e- sampled twice
            >>> round(float(a[0]), 4), round(float(b[0]), 3)
            (0.1024, 2.18)
        """
        f64 = torch.float64
        if raw is not None:
            if not isinstance(raw, RawImage):
                raise TypeError(f"raw: expected a RawImage (a capture of this sensor), got {type(raw).__name__}")
            if exposure_s is not None or analog_gain is not None:
                raise ValueError("exposure_s, analog_gain: a raw carries the ones it was captured with; give a raw "
                                 "or these, not both")
            nz, units, dev = raw.noise, raw.units, raw.data.device
            t, gain, cg = raw.exposure_s, raw.analog_gain, raw.conversion_gain_v_per_e
        else:
            if not (is_real(exposure_s) and exposure_s >= 0):
                raise ValueError(f"exposure_s: expected a finite exposure >= 0 in seconds, got {exposure_s!r}")
            gain = self.analog_gain if analog_gain is None else analog_gain
            if not isinstance(gain, torch.Tensor) and not (is_real(gain) and gain > 0):
                raise ValueError(f"analog_gain: expected a finite positive gain, got {gain!r}")
            nz, units, dev = self.noise_parameters(enabled=True), self.output_units, None
            t, cg = float(exposure_s), self.conversion_gain_v_per_e
            if isinstance(gain, torch.Tensor):
                dev = gain.device

        def level(v):  # a float, or a [B] per-call level
            return v.detach().to(f64).reshape(-1) if isinstance(v, torch.Tensor) else float(v)

        t, gain = (torch.as_tensor(v.detach() if isinstance(v, torch.Tensor) else v, dtype=f64, device=dev)
                   .reshape(-1) for v in (t, gain))
        t, gain = torch.broadcast_tensors(t, gain)
        cg = level(cg)
        gain = 1.0 / gain if self.gain_convention == "isetcam" else gain  # volts at the ADC per pixel volt
        # output units per pixel volt (_readout, _to_units): the electrons readout takes no analog gain
        if units == "electrons":
            per_v = torch.ones_like(gain) / cg
        else:
            per_v = gain / self.lsb_v if units == "dn" else gain
        quant = S2_QUANTIZATION_DN2 if units == "dn" else 0.0  # rounding to whole DN
        if not nz.get("enabled", True):  # the noise-free chain, rounded
            return torch.zeros_like(per_v), torch.full_like(per_v, quant)
        shot, var_v = self._dark_variance_v2(nz, t, cg, level)
        a = per_v * cg if shot else torch.zeros_like(per_v)
        return a, var_v * per_v ** 2 + quant

    def _dark_variance_v2(self, nz: dict, t, cg, level=float):
        """``(shot, var_v)``: whether the capture has shot noise, and the variance of a dark pixel at the pixel in
        volts^2 over exposure ``t`` (s) with conversion gain ``cg`` (V/e-), of the noise levels ``nz``
        (:meth:`noise_parameters`): read noise (twice its variance with CDS), dark-current shot noise, DSNU and column
        offsets (cancelled by CDS), temporal row/column noise and dark shading. The terms of
        :meth:`_noisy_pixel_volts`, shared by :meth:`poisson_gaussian` and the figures of merit
        (:mod:`isettorch.sensor.metrics`)."""
        # CDS in the physical chain only (ISETCam's order samples the read noise once and adds DSNU)
        cds = bool(nz.get("cds", self.cds)) and nz.get("noise_model", self.noise_model) == "physical"
        shot = nz.get("shot_noise", self.shot_noise) != "off"
        read_v, dark = level(nz.get("read_noise_v", 0.0)), level(nz.get("dark_current_e_per_s", 0.0))
        dsnu_v, column_v = level(nz.get("dsnu_sigma_v", 0.0)), level(nz.get("column_fpn_sigma_v", 0.0))
        row_v, col_v = float(nz.get("row_noise_v", 0.0)), float(nz.get("column_noise_v", 0.0))
        shading = float(nz.get("dark_shading_e_per_s", 0.0))
        var_e = (dark * t if shot else 0.0 * t) + (shading * t) ** 2  # electrons^2 at the pixel
        var_v = (read_v ** 2 * (2.0 if cds else 1.0) + (0.0 if cds else dsnu_v ** 2 + column_v ** 2)
                 + row_v ** 2 + col_v ** 2 + var_e * cg ** 2)  # pixel volts^2
        return shot, var_v

    def extra_repr(self) -> str:
        return (f"name={self.name!r}, size={self.rows}x{self.cols}, pixel={self.pixel_size_m * 1e6:g} um, "
                f"fill={self.fill_factor}, cfa={self.cfa!r}, bits={self.adc_bits}, sampling={self.sampling!r}")


def _on(level) -> bool:
    """A noise stage runs when its level (float or per-sample tensor) is positive for some sample, or when the
    level requires grad (a learnable level at 0 keeps its place in the graph: its gradient, not None)."""
    if isinstance(level, torch.Tensor):
        return level.requires_grad or bool((level > 0).any())
    return level > 0
