"""Sensor noise sources and differentiable rounding.

* Photon (and dark-electron) shot noise: exact Poisson with a straight-through gradient
  (``torch.poisson`` alone has zero gradient), a reparameterised Gaussian ``mu + sqrt(mu) z``, or off.
* Gaussian read noise, fixed-pattern maps (DSNU, PRNU, column offsets) as standard-normal
  draws scaled at use, and round-half-away-from-zero quantisation with a straight-through estimator.

Every random draw takes an explicit ``torch.Generator``.
"""

from __future__ import annotations

import torch

from .._autograd import records_grad, safe_sqrt
from .._checks import check_seed, is_integer

__all__ = ["SHOT_NOISE_MODES", "safe_sqrt", "shot_noise", "isetcam_shot_noise", "normal", "round_half_away",
           "quantize_ste", "fixed_pattern_draws", "poisson_gaussian"]

SHOT_NOISE_MODES = ("poisson", "gaussian", "off")
POISSON_GAUSSIAN_ABOVE_E = 2.0 ** 31  # 'poisson' shot noise is Gaussian, N(mean, mean), above this mean (electrons)


def normal(like: torch.Tensor, generator: torch.Generator | None, shape=None) -> torch.Tensor:
    """Standard normal draws with ``like``'s dtype/device (``shape`` defaults to ``like.shape``)."""
    return torch.randn(like.shape if shape is None else shape, generator=generator, dtype=like.dtype,
                       device=like.device)


def shot_noise(mean_e: torch.Tensor, mode: str = "poisson", generator: torch.Generator | None = None
               ) -> torch.Tensor:
    """Electron counts with Poisson statistics around ``mean_e`` (any shape, electrons, >= 0).

    ``'poisson'``: exact Poisson draws (Gaussian ``N(mean, mean)`` above :data:`POISSON_GAUSSIAN_ABOVE_E`, 2^31
    electrons, where the two differ by a skewness under 2e-5 and torch's integer counts would overflow: at 2^32 on
    CUDA, 2^63 on the CPU); the gradient passes straight through (d out / d mean = 1). That is exact for a loss
    linear in the output, but biased for one that depends on the noise's size: d E[e^2] / d mean is 2 mean + 1 while
    the straight-through estimate averages 2 mean, a relative error -1 / (2 mean + 1) (-20 % at 2 e-, -4.8 % at 10,
    -0.5 % at 100; measured in an audit of 2026-11-30). ``'gaussian'`` differentiates the noise's scale too and is
    unbiased there.
    ``'gaussian'``: ``mean + sqrt(mean) z`` (reparameterised, same first two moments), a good model from about 10
    electrons up; below, the readout's clip at 0 V shifts both moments (at 0.5 e-: mean +20 %, variance -36 %).
    ``'off'``: the mean. Source: photon transfer / EMVA 1288 (variance = mean in electrons).

    Common random numbers: a ``'poisson'`` draw takes a number of the generator's numbers that depends on the mean
    (on the CPU), so the same generator on a slightly different signal redraws this and every later draw from it
    (a sensor's read noise too: correlation 0.0004 between two captures 1e-4 apart). For finite differences or
    paired comparisons with common noise, use ``'gaussian'`` (the same normal draws for any mean).
    """
    if mode == "off":
        return mean_e
    if mode == "poisson":
        m = mean_e.detach().clamp_min(0)
        # torch.poisson's counts overflow (CUDA's curand_poisson returns a 32-bit unsigned count, the CPU's an int64:
        # -9.2e18 e- at 1e19, read as black). Above T = 2^31 the draw is Gaussian, m + sqrt(m) z (skewness
        # 1 / sqrt(m) < 2e-5), with z the standardised Poisson draw at T: the same single draw per pixel, no host
        # sync, and the same random numbers as before wherever m <= T
        t = POISSON_GAUSSIAN_ABOVE_E
        draw = torch.poisson(m.clamp(max=t), generator=generator)
        # (an infinite mean, rate x exposure beyond float32, stays infinite and saturates: inf + (draw - t) inf
        # was NaN for a draw below t)
        draw = torch.where(m > t, torch.where(torch.isinf(m), m, m + (draw - t) * torch.sqrt(m / t)), draw)
        # a straight-through estimator only when autograd records (here and in quantize_ste): x + (y - x) can differ
        # from y by a rounding step, so without a gradient the exact draw is returned
        return mean_e + (draw - mean_e).detach() if records_grad(mean_e) else draw
    if mode == "gaussian":
        out = mean_e + safe_sqrt(mean_e) * normal(mean_e, generator)
        return torch.where(torch.isinf(mean_e), mean_e, out)  # (inf + inf z was NaN for z < 0; as 'poisson')
    raise ValueError(f"shot_noise: expected mode in {SHOT_NOISE_MODES}, got {mode!r}")


def isetcam_shot_noise(mean_e: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """ISETCam ``noiseShot``: ``round(e + sqrt(e) z)`` where e >= 25 electrons, Poisson below (FORMAT 4.8 step 2).

    Straight-through gradient, as :func:`shot_noise`.
    """
    m = mean_e.detach().clamp_min(0)
    low = m < 25
    gauss = round_half_away(m + torch.sqrt(m) * normal(m, generator))
    pois = torch.poisson(torch.where(low, m, torch.zeros_like(m)), generator=generator)
    draw = torch.where(low, pois, gauss)
    return mean_e + (draw - mean_e).detach()


def round_half_away(x: torch.Tensor) -> torch.Tensor:
    """MATLAB ``round``: halves away from zero (``torch.round`` rounds halves to even), exact for every float:
    ``torch.round`` except at a tie (a fraction of exactly 1/2), which goes to ``trunc(x) + sign(x)``. The former
    ``floor(|x| + 1/2)`` rounded in the addition: in float32 0.49999997 became 1 and 8388609 became 8388610."""
    t = torch.trunc(x)
    tie = (x - t).abs() == 0.5  # (exact: x - trunc(x) is representable)
    return torch.where(tie, t + torch.sign(x), torch.round(x))


def quantize_ste(x: torch.Tensor) -> torch.Tensor:
    """Round half away from zero in the forward pass, identity gradient (straight-through estimator)."""
    return x + (round_half_away(x) - x).detach() if records_grad(x) else round_half_away(x)


def fixed_pattern_draws(rows: int, cols: int, seed: int, *, dtype=torch.float64, device=None
                        ) -> dict[str, torch.Tensor]:
    """Standard-normal maps for the fixed-pattern noise of one sensor instance, from its seed.

    Returns ``{'dsnu': [rows, cols], 'prnu': [rows, cols], 'column': [cols]}``; drawn on the CPU in
    float64 so the pattern is the same on every device and dtype.
    """
    check_seed(seed)  # (1.5 was drawn as seed 1, True as 1)
    for name, n in (("rows", rows), ("cols", cols)):
        if not (is_integer(n) and n >= 1):
            raise ValueError(f"{name}: expected an integer number of pixels >= 1, got {n!r}")
    g = torch.Generator().manual_seed(int(seed))
    dsnu = torch.randn(rows, cols, generator=g, dtype=torch.float64)
    prnu = torch.randn(rows, cols, generator=g, dtype=torch.float64)
    column = torch.randn(cols, generator=g, dtype=torch.float64)
    return {k: v.to(dtype=dtype, device=device) for k, v in
            {"dsnu": dsnu, "prnu": prnu, "column": column}.items()}


def poisson_gaussian(signal: torch.Tensor, shot_gain: float = 0.0, read_sigma: float = 0.0,
                     generator: torch.Generator | None = None, shot_mode: str = "poisson") -> torch.Tensor:
    """Signal-dependent noise ``var = a x + b`` on a normalised signal ``x`` (Foi, Trimeche, Katkovnik &
    Egiazarian, "Practical Poissonian-Gaussian noise modeling and fitting", IEEE TIP 2008).

    ``a = shot_gain`` is the signal per electron (shot noise: :func:`shot_noise` of ``x / a`` electrons, scaled
    back by ``a``), ``b = read_sigma^2`` a Gaussian floor (:func:`normal`). Either may be 0 (that source is
    skipped, so ``a = 0`` gives additive white Gaussian noise of std ``read_sigma``). Nothing is clipped.
    """
    a, s = float(shot_gain), float(read_sigma)
    if not (a >= 0 and s >= 0):  # also rejects NaN
        raise ValueError(f"shot_gain, read_sigma: expected finite values >= 0, got {shot_gain}, {read_sigma}")
    out = signal
    if a > 0:
        if bool((signal < 0).any()):
            raise ValueError("signal: expected values >= 0 for shot noise (shot_gain > 0)")
        out = shot_noise(signal / a, shot_mode, generator) * a
    if s > 0:
        out = out + s * normal(signal, generator)
    return out
