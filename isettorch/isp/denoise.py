"""Classical denoisers of a Bayer mosaic, for noise of variance ``a x + sigma^2`` on its [0, 1] scale
(Poisson-Gaussian, Foi et al. IEEE TIP 2008): ``nlmeans`` (scikit-image's non-local means, Buades, Coll & Morel CVPR
2005) or ``bm3d`` (Dabov et al. IEEE TIP 2007; the ``bm3d`` package, installed by the user: its licence allows
non-commercial use only, so it is no dependency of isettorch), each on the four CFA sub-planes separately, with the
generalised Anscombe transform (Makitalo & Foi, IEEE TIP 2013) when the noise is signal-dependent. The sequential
baseline of the demosaic benchmark (:mod:`isettorch.isp.evaluation`) and the classical expert of the shipped joint
network's high-noise gate (:data:`isettorch.isp.learned.PRETRAINED_GATES`)."""

from __future__ import annotations

import math
import numbers

import numpy as np
import torch

from .._checks import check_finite

__all__ = ["DENOISERS", "check_denoiser", "denoise_mosaic"]

#: classical denoisers of a mosaic (the sequential denoise-then-demosaic baseline)
DENOISERS = ("nlmeans", "bm3d")
#: shot noise whose variance at full scale, ``a``, is at most this fraction of the Gaussian ``sigma^2`` is denoised as
#: Gaussian noise: the Anscombe transform's square root of ``a x + b`` keeps ``a x`` only to ``b``'s float64
#: precision (1e-16 relative), so it needs ``a`` well above that (1e-9 leaves seven digits)
SHOT_NEGLIGIBLE = 1e-9


def _check_noise(noise_sigma: float, noise_shot: float) -> tuple[float, float]:
    for name, v in (("noise_sigma", noise_sigma), ("noise_shot", noise_shot)):
        if isinstance(v, bool) or not isinstance(v, numbers.Real):  # (True was 1.0, "0.1" was read)
            raise TypeError(f"{name}: expected a number, got {v!r}")
    s, a = float(noise_sigma), float(noise_shot)
    if not (math.isfinite(s) and s >= 0):
        raise ValueError(f"noise_sigma: expected a finite standard deviation >= 0 (of the [0, 1] mosaic), "
                         f"got {noise_sigma}")
    if not (math.isfinite(a) and a >= 0):
        raise ValueError(f"noise_shot: expected a finite shot-noise gain a >= 0 (var = a x + sigma^2), "
                         f"got {noise_shot}")
    # the model squares both (the variance sigma^2; a^2 in the Anscombe transform): each square must be a float
    if not math.isfinite(s * s):
        raise ValueError(f"noise_sigma: expected a standard deviation whose square (the noise variance) is finite, "
                         f"got {noise_sigma} (at most about 1e154)")
    if not math.isfinite(a * a):
        raise ValueError(f"noise_shot: expected a shot-noise gain whose square (in the variance-stabilising transform) "
                         f"is finite, got {noise_shot} (at most about 1e154)")
    return s, a


def check_denoiser(method: str) -> None:
    """ValueError unless ``method`` is one of :data:`DENOISERS` and can run here (``bm3d`` needs the user's
    ``bm3d`` package): checked before any work."""
    if method not in DENOISERS:
        raise ValueError(f"denoise: expected one of {DENOISERS}, got {method!r}")
    if method == "bm3d":
        try:
            import bm3d  # noqa: F401
        except ModuleNotFoundError as err:
            if err.name not in (None, "bm3d"):  # (installed, a dependency of it missing: it said "needs bm3d")
                raise ValueError(f"denoise: 'bm3d' is installed but cannot be imported: its dependency {err.name!r} "
                                 f"is missing ({err})") from err
            raise ValueError("denoise: 'bm3d' needs the bm3d package (pip install bm3d; its licence allows "
                             "non-commercial use only, so isettorch does not depend on it)") from err


def _anscombe(z, a, b):
    """Generalised Anscombe transform (Makitalo & Foi 2013, eq. 2, mu = 0): unit variance for var = a z + b."""
    return (2.0 / a) * np.sqrt(np.maximum(a * z + 0.375 * a * a + b, 0.0))


def _anscombe_inverse(y, a, b):
    """Algebraic inverse of :func:`_anscombe`: exact on noise-free values (a clean constant stays itself, which the
    joint model's constant-field guarantee rests on), but a denoised ``y`` estimates ``E[f(z)]``, whose square is
    below ``f(E[z])^2`` by the stabilised variance 1, so noisy data come back low by ``a / 4`` at every level
    (0.6 of an 8-bit code at ``a`` = 0.01; Makitalo & Foi 2013, section III: their asymptotically unbiased inverse
    is ``a y^2 / 4 - a / 8 - b / a``); at a few electrons less (at one, about 0.7 of it: -0.46 of an 8-bit code at
    ``a`` = 0.01). Kept: the shipped joint model's high-noise gate was chosen with it (the exact unbiased inverse
    would raise the shot-noise baseline by 0.03 dB on Kodak at ``a`` = 0.01)."""
    return 0.25 * a * y * y - 0.375 * a - b / a


def _denoise_plane(plane: np.ndarray, sigma: float, method: str) -> np.ndarray:
    if method == "nlmeans":
        from skimage.restoration import denoise_nl_means

        # h = 0.6 sigma with sigma given and fast mode: scikit-image's documented setting (gallery "Non-local means
        # denoising for preserving textures"); patch 5 x 5, search 13 x 13. Fixed, never tuned on a test set.
        out = denoise_nl_means(plane, h=0.6 * sigma, sigma=sigma, patch_size=5, patch_distance=6, fast_mode=True)
        return np.asarray(out).reshape(plane.shape)  # (a one-column plane came back 1-D)
    import bm3d  # (check_denoiser said it is installed)

    return np.asarray(bm3d.bm3d(plane, sigma_psd=sigma), dtype=np.float64).reshape(plane.shape)


def denoise_mosaic(raw: torch.Tensor, method: str, noise_sigma: float = 0.0, noise_shot: float = 0.0
                   ) -> torch.Tensor:
    """Denoise a Bayer mosaic (B, 1, H, W) with a classical denoiser on each of its four CFA sub-planes (every
    sub-plane holds one colour, so a grey-level denoiser applies), for noise ``var = noise_shot x + noise_sigma^2``.

    Signal-dependent noise (``noise_shot > 0``) is stabilised with the generalised Anscombe transform first
    (Makitalo & Foi 2013; its square root's argument is clipped at 0, as theirs, for the darkest samples of
    Gaussian noise, below ``-(3 a / 8 + sigma^2 / a)``), denoised at unit sigma and mapped back by the
    algebraic inverse (its output's level is ``a / 4`` low on noisy data: ``_anscombe_inverse``). Shot noise whose
    variance at full scale is below :data:`SHOT_NEGLIGIBLE` of the Gaussian one is denoised as Gaussian noise of
    variance ``noise_shot + noise_sigma^2`` (the transform's square root then holds ``b`` to float64's precision and
    loses the signal: a ``noise_shot`` of 1e-20 beside ``noise_sigma`` 0.02 came back 129 off). Returns the same shape,
    dtype and device; not differentiable (a NumPy denoiser: no gradient reaches ``raw``).
    """
    check_denoiser(method)
    s, a = _check_noise(noise_sigma, noise_shot)
    if s == 0 and a == 0:
        raise ValueError(f"denoise: {method!r} needs a noise level (noise_sigma or noise_shot > 0)")
    if not isinstance(raw, torch.Tensor):
        raise TypeError(f"raw: expected a torch.Tensor (B, 1, H, W), got {type(raw).__name__}")
    if raw.dim() != 4 or raw.shape[1] != 1 or raw.shape[-2] < 2 or raw.shape[-1] < 2:
        # (an odd H or W is fine: each sub-plane still holds one colour, the last row / column's planes are shorter)
        raise ValueError(f"raw: expected a Bayer mosaic (B, 1, H, W) with H, W >= 2, got {tuple(raw.shape)}")
    if not raw.is_floating_point():  # (a uint8 mosaic was denoised on a 0-255 scale and truncated back)
        raise TypeError(f"raw: expected a floating-point mosaic on the [0, 1] scale, got {raw.dtype}")
    check_finite(raw.detach(), "raw")  # (a NaN sample spread over its non-local search window)
    x = raw.detach().to("cpu", torch.float64).numpy().copy()
    b = s * s
    if 0 < a <= SHOT_NEGLIGIBLE * b:  # shot noise below the transform's precision: Gaussian of the total variance
        s, a = math.sqrt(b + a), 0.0
    for i in range(x.shape[0]):
        for dy in (0, 1):
            for dx in (0, 1):
                plane = x[i, 0, dy::2, dx::2]
                if plane.min() == plane.max():
                    # a constant is its own estimate (every denoiser here averages), kept exactly: the Anscombe clip
                    # took a constant below -(3a/8 + b/a) to 0, and the joint model's constant-field guarantee lost
                    # (-0.5, -0.25, -0.125) to grey -0.10
                    continue
                if a > 0:
                    y = _denoise_plane(_anscombe(plane, a, b), 1.0, method)
                    x[i, 0, dy::2, dx::2] = _anscombe_inverse(y, a, b)
                else:
                    x[i, 0, dy::2, dx::2] = _denoise_plane(plane, s, method)
    return torch.from_numpy(x).to(device=raw.device, dtype=raw.dtype)
