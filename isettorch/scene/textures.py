"""Procedural textures (scene content) for the natural-scene generator (:mod:`isettorch.data.natural`); each
draws only from its generator.

* :func:`power_law_noise`: Gaussian noise with amplitude spectrum ``|f|^-s`` (power ``|f|^-2s``): natural images
  have ``s ~ 1`` (Field, JOSA A 4, 1987; van der Schaaf & van Hateren, Vision Res. 36, 1996).
* :func:`warped_grating`: a sine grating whose phase is displaced by smooth power-law noise (wood grain, fabric,
  ripples: oriented texture that is not perfectly periodic).
* :func:`colour_line_weights`: mixing weights in [0, 1] between two materials, so that a region's colours lie on a
  line in colour space (the colour-lines model of Omer & Werman, CVPR 2004).
"""

from __future__ import annotations

import math

import torch

__all__ = ["power_law_noise", "warped_grating", "colour_line_weights"]


def power_law_noise(h: int, w: int, exponent: float, generator: torch.Generator, *, dtype=torch.float32
                    ) -> torch.Tensor:
    """Zero-mean, unit-std Gaussian field ``[h, w]`` with radial amplitude spectrum ``|f|^-exponent`` (power
    spectrum slope ``-2 exponent`` on log-log axes); periodic (FFT synthesis), DC removed.

    Example:
        >>> power_law_noise(64, 64, 1.0, torch.Generator().manual_seed(0)).shape
        torch.Size([64, 64])
    """
    if h < 2 or w < 2:
        raise ValueError(f"h, w: expected at least 2 x 2, got {h} x {w}")
    if not 0 <= float(exponent) <= 4:
        raise ValueError(f"exponent: expected a spectral exponent in [0, 4], got {exponent}")
    fy = torch.fft.fftfreq(h, dtype=torch.float64)[:, None]
    fx = torch.fft.rfftfreq(w, dtype=torch.float64)[None, :]
    f = torch.sqrt(fx * fx + fy * fy)
    amp = torch.where(f > 0, f.clamp_min(1e-12) ** -float(exponent), torch.zeros_like(f))
    white = torch.randn(h, w, generator=generator, dtype=torch.float64)
    x = torch.fft.irfft2(torch.fft.rfft2(white) * amp, s=(h, w))
    return (x / x.std().clamp_min(1e-12)).to(dtype)


def warped_grating(h: int, w: int, frequency_cpp: float, angle_rad: float, warp_px: float,
                   generator: torch.Generator, *, warp_exponent: float = 2.0, dtype=torch.float32) -> torch.Tensor:
    """``0.5 + 0.5 sin(2 pi f (u + d(x)) + phi)`` in [0, 1], ``u`` the coordinate along ``angle_rad``, ``d`` a
    smooth power-law displacement field (``|f|^-warp_exponent``) of std ``warp_px`` pixels, ``phi`` uniform."""
    if not 0 < frequency_cpp <= 2:
        raise ValueError(f"frequency_cpp: expected (0, 2] cycles/pixel, got {frequency_cpp}")
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None, :]
    u = x * math.cos(angle_rad) + y * math.sin(angle_rad)
    d = power_law_noise(h, w, warp_exponent, generator, dtype=torch.float64) * float(warp_px)
    phi = 2 * math.pi * float(torch.rand((), generator=generator, dtype=torch.float64))
    return (0.5 + 0.5 * torch.sin(2 * math.pi * frequency_cpp * (u + d) + phi)).to(dtype)


def colour_line_weights(h: int, w: int, exponent: float, generator: torch.Generator, *, contrast: float = 1.0,
                        dtype=torch.float32) -> torch.Tensor:
    """Weights ``t`` in [0, 1] ``[h, w]``: the normal CDF of ``contrast`` x :func:`power_law_noise`; a material
    blend ``(1 - t) R_a + t R_b`` then has colours on the segment between two colours (Omer & Werman 2004)."""
    n = power_law_noise(h, w, exponent, generator, dtype=torch.float64) * float(contrast)
    return (0.5 * (1 + torch.erf(n / math.sqrt(2)))).to(dtype)
