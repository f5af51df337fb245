"""Noise terms of real raws beyond Poisson-Gaussian: temporal row/column (banding) noise, heavy-tailed
(Tukey-lambda) read noise, dark shading, hot and dead pixels, and the pixel's full-well clip.

Low-light denoising work shows that networks trained on Poisson-Gaussian noise alone fail on real raws unless
these terms are modelled and calibrated per camera:

* Wei, Fu, Yang, Huang, "A Physics-based Noise Formation Model for Extreme Low-light Raw Denoising" (ELD),
  CVPR 2020: row noise (one Gaussian offset per row and frame), Tukey-lambda read noise, quantisation, and the
  black-level offset;
* Zhang, Qin, Yin, Tian, Wang, "Rethinking Noise Synthesis and Modeling in Raw Denoising", ICCV 2021: signal-
  independent noise (row/column banding, fixed pattern) taken from real dark frames;
* Feng, Wang, Xu, Zhang, Fu, "Learnability Enhancement for Low-light Raw Denoising" (PMN), ACM MM 2022: dark
  shading, a fixed per-pixel offset pattern that grows with exposure (and ISO), and the black-level error;
* EMVA Standard 1288 release 4.0 (2021), sections 4 and 8: dark signal non-uniformity growing with exposure time
  (dark-current non-uniformity), defect pixels (hot and dead), saturation.

Every term is off (and costs nothing) at its zero value. Continuous temporal terms are reparameterised (a fixed
distribution of unit scale times the parameter), so gradients reach the parameters. Fixed patterns (dark shading,
hot and dead pixel positions) are drawn once per sensor instance from its seed, on the CPU in float64, so they are
the same on every device.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from .._checks import check_seed, seed_for

__all__ = ["NoiseTerms", "tukey_lambda_quantile", "tukey_lambda_variance", "tukey_lambda_noise", "row_noise",
           "column_noise"]

# The random stream (``_checks.seed_for``) of these terms' fixed patterns, independent of the DSNU/PRNU/column draws
# of ``noise.fixed_pattern_draws`` (which use ``seed`` itself) and of the sensor's temporal noise (its own stream).
# (seed + 7919 was the fixed pattern of sensor seed + 7919.)
PATTERN_STREAM = 2


def tukey_lambda_quantile(u: torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Quantile function of the standard Tukey-lambda distribution,
    ``Q(u) = (u^lam - (1 - u)^lam) / lam`` (``log(u / (1 - u))`` at lam = 0, the logistic).

    Source: Joiner and Rosenblatt, "Some properties of the range in samples from Tukey's symmetric lambda
    distributions", JASA 66 (1971); used for read noise by Wei et al. CVPR 2020 (ELD), eq. 6.
    """
    lam_t = torch.as_tensor(lam, dtype=u.dtype, device=u.device)
    small = lam_t.abs() < 1e-6
    safe = torch.where(small, torch.ones_like(lam_t), lam_t)
    general = (u.pow(safe) - (1 - u).pow(safe)) / safe
    return torch.where(small, torch.log(u) - torch.log1p(-u), general)


def tukey_lambda_variance(lam: float) -> float:
    """Variance of the standard Tukey-lambda distribution (finite for lam > -1/2):
    ``2 / lam^2 (1 / (1 + 2 lam) - Gamma(lam + 1)^2 / Gamma(2 lam + 2))``, ``pi^2 / 3`` at lam = 0 (logistic).

    Source: Joiner and Rosenblatt (1971); the same closed form as ``scipy.stats.tukeylambda.var``.
    """
    lam = float(lam)
    if not lam > -0.5:
        raise ValueError(f"read_noise_tukey_lambda: expected a shape > -0.5 (finite variance), got {lam}")
    if abs(lam) < 1e-6:
        return math.pi ** 2 / 3
    return 2.0 / lam ** 2 * (1.0 / (1.0 + 2.0 * lam) - math.exp(2 * math.lgamma(lam + 1) - math.lgamma(2 * lam + 2)))


def tukey_lambda_noise(like: torch.Tensor, lam: float, generator: torch.Generator | None) -> torch.Tensor:
    """Tukey-lambda draws of unit variance with ``like``'s shape, dtype and device (inverse-CDF sampling of a
    uniform variate: a reparameterisation, the scale multiplies the result)."""
    tiny = torch.finfo(like.dtype).eps
    u = torch.rand(like.shape, generator=generator, dtype=like.dtype, device=like.device).clamp(tiny, 1 - tiny)
    return tukey_lambda_quantile(u, lam) / math.sqrt(tukey_lambda_variance(lam))


def row_noise(like: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """Standard-normal offsets, one per row and frame, ``(B, C, H, 1)`` for ``like`` of shape ``(B, C, H, W)``
    (temporal row noise; Wei et al. CVPR 2020, ELD, eq. 7)."""
    b, c, h, _ = like.shape
    return torch.randn((b, c, h, 1), generator=generator, dtype=like.dtype, device=like.device)


def column_noise(like: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """Standard-normal offsets, one per column and frame, ``(B, C, 1, W)`` (temporal column banding; Zhang et al.
    ICCV 2021)."""
    b, c, _, w = like.shape
    return torch.randn((b, c, 1, w), generator=generator, dtype=like.dtype, device=like.device)


@dataclasses.dataclass
class NoiseTerms:
    """The extra noise terms of a :class:`~isettorch.sensor.Sensor` (all off at their defaults).

    Args:
        row_noise_v: std of the temporal row offsets (V at the pixel, before analog gain), one Gaussian draw per
            row and frame (ELD row noise).
        column_noise_v: std of the temporal column offsets (V), one draw per column and frame.
        read_noise_tukey_lambda: None (Gaussian read noise, the default) or the Tukey-lambda shape (> -0.5; < 0.14
            is heavier-tailed than a Gaussian); the read noise keeps its std ``read_noise_v`` (ELD eq. 6).
        dark_shading_e_per_s: std of a fixed, zero-mean per-pixel offset pattern that grows linearly with exposure
            (electrons per second of exposure; PMN dark shading / EMVA 1288 dark-current non-uniformity). Added
            after shot noise: a mean offset, not a source of shot noise.
        hot_pixel_fraction, hot_pixel_dark_current_e_per_s: fraction of pixels with an extra dark current (they
            collect these electrons per second, with shot noise; EMVA 1288 section 8.3 defect pixels).
        dead_pixel_fraction: fraction of pixels with no response (they read the black level plus offsets).
        full_well_e: None or the electron count where the photodiode clips (after shot noise, before read
            noise); without it the clip is the ADC / voltage swing only.
        seed: seed of the fixed patterns (dark shading, hot and dead pixel positions).
    """

    row_noise_v: float = 0.0
    column_noise_v: float = 0.0
    read_noise_tukey_lambda: float | None = None
    dark_shading_e_per_s: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_dark_current_e_per_s: float = 0.0
    dead_pixel_fraction: float = 0.0
    full_well_e: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        check_seed(self.seed)  # (1.5 was taken, as int(1.5) = 1)
        for name in ("row_noise_v", "column_noise_v", "dark_shading_e_per_s", "hot_pixel_dark_current_e_per_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: expected a non-negative number, got {v!r}")
        for name in ("hot_pixel_fraction", "dead_pixel_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1):
                raise ValueError(f"{name}: expected a fraction in [0, 1], got {v!r}")
        lam = self.read_noise_tukey_lambda
        if lam is not None:
            if not (isinstance(lam, (int, float)) and not isinstance(lam, bool) and math.isfinite(lam)):
                raise ValueError(f"read_noise_tukey_lambda: expected None or a finite number, got {lam!r}")
            tukey_lambda_variance(lam)  # raises for shapes without a finite variance
        fw = self.full_well_e
        if fw is not None and not (isinstance(fw, (int, float)) and not isinstance(fw, bool) and math.isfinite(fw)
                                   and fw > 0):
            raise ValueError(f"full_well_e: expected None or a positive electron count, got {self.full_well_e!r}")
        self._patterns: dict[tuple[int, int], dict[str, torch.Tensor]] = {}

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "seed"}

    @property
    def active(self) -> bool:
        """Whether any term is on (a Tukey-lambda shape of 0, the logistic distribution, is on: it counted as off, so
        ``noise_model='isetcam'`` accepted it and read Gaussian noise)."""
        return any((v is not None) if f.name == "read_noise_tukey_lambda" else v not in (0, 0.0, None)
                   for f in dataclasses.fields(self) if f.name != "seed" for v in (getattr(self, f.name),))

    @property
    def has_fixed_patterns(self) -> bool:
        return self.dark_shading_e_per_s > 0 or self.hot_pixel_fraction > 0 or self.dead_pixel_fraction > 0

    def patterns(self, rows: int, cols: int, *, dtype, device) -> dict[str, torch.Tensor]:
        """Fixed patterns ``[rows, cols]`` of this sensor instance, drawn once from ``seed`` (CPU, float64):
        ``'shading'`` (standard normal), ``'hot'`` and ``'dead'`` (0/1 masks with the configured fractions)."""
        key = (rows, cols)
        if key not in self._patterns:
            g = torch.Generator().manual_seed(seed_for(self.seed, 0, stream=PATTERN_STREAM))
            shading = torch.randn(rows, cols, generator=g, dtype=torch.float64)
            u_hot = torch.rand(rows, cols, generator=g, dtype=torch.float64)
            u_dead = torch.rand(rows, cols, generator=g, dtype=torch.float64)
            self._patterns[key] = {"shading": shading, "hot": (u_hot < self.hot_pixel_fraction).double(),
                                   "dead": (u_dead < self.dead_pixel_fraction).double()}
        return {k: v.to(dtype=dtype, device=device) for k, v in self._patterns[key].items()}

    def read_noise_draw(self, like: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """Unit-variance read-noise draws: Gaussian by default, Tukey lambda when a shape is set."""
        if self.read_noise_tukey_lambda is None:
            return torch.randn(like.shape, generator=generator, dtype=like.dtype, device=like.device)
        return tukey_lambda_noise(like, self.read_noise_tukey_lambda, generator)

    def mean_dark_e(self, signal_e: torch.Tensor, exposure_s: torch.Tensor) -> torch.Tensor:
        """Add the hot pixels' extra dark electrons to the mean electrons ``(B, 1, H, W)`` (before shot noise);
        ``exposure_s`` broadcasts as ``(B, 1, 1, 1)``."""
        if self.hot_pixel_fraction == 0 or self.hot_pixel_dark_current_e_per_s == 0:
            return signal_e
        p = self.patterns(signal_e.shape[-2], signal_e.shape[-1], dtype=signal_e.dtype, device=signal_e.device)
        return signal_e + self.hot_pixel_dark_current_e_per_s * exposure_s * p["hot"]

    def after_shot(self, electrons: torch.Tensor, exposure_s: torch.Tensor, conversion_gain_v_per_e: float,
                   generator: torch.Generator | None) -> torch.Tensor:
        """Electrons after shot noise ``(B, 1, H, W)`` -> pixel volts with the full-well clip, dead pixels, dark
        shading and the temporal row/column offsets (read noise and DSNU are added by the sensor)."""
        e = electrons
        if self.full_well_e is not None:
            e = e.clamp(max=self.full_well_e)  # the photodiode saturates (EMVA 1288 section 4.1)
        if self.dead_pixel_fraction > 0:
            p = self.patterns(e.shape[-2], e.shape[-1], dtype=e.dtype, device=e.device)
            e = e * (1 - p["dead"])
        if self.dark_shading_e_per_s > 0:
            p = self.patterns(e.shape[-2], e.shape[-1], dtype=e.dtype, device=e.device)
            e = e + self.dark_shading_e_per_s * exposure_s * p["shading"]
        volts = e * conversion_gain_v_per_e
        if self.row_noise_v > 0:
            volts = volts + self.row_noise_v * row_noise(volts, generator)
        if self.column_noise_v > 0:
            volts = volts + self.column_noise_v * column_noise(volts, generator)
        return volts
