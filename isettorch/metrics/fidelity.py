"""Full-reference image fidelity: PSNR, CPSNR (the demosaicing convention) and SSIM.

PSNR is computed here, per image, because ``kornia.metrics.psnr`` pools one MSE over the whole batch; SSIM is
``kornia.metrics.ssim`` (Gaussian window 11, sigma 1.5, K1 = 0.01, K2 = 0.03) averaged over its valid region,
which is scikit-image's ``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``.
``data_range`` None (the default): 1 for floating-point images whose target lies in [0, 1] (scikit-image's default
there), the dtype's largest value for integer ones (255 for uint8; for a signed dtype scikit-image uses max - min,
65535 for int16, where this takes 32767: pass ``data_range``). A floating-point target outside [0, 1] with no
``data_range`` is refused (raw values 0-1023 scored -33.9 dB instead of 26.3; scikit-image refuses values outside
[-1, 1]), as is an integer image against a floating-point one (which range?).
"""

from __future__ import annotations

import torch

from .._checks import check_bool, check_finite, check_positive, is_integer
from .difference import working_dtype


def _pair(image: torch.Tensor, target: torch.Tensor, crop: int, data_range=None) -> tuple[torch.Tensor, torch.Tensor]:
    for name, t in (("image", image), ("target", target)):
        if not isinstance(t, torch.Tensor):
            raise TypeError(f"{name}: expected a torch.Tensor, got {type(t).__name__}")
    if image.shape != target.shape:
        raise ValueError(f"target: expected the shape of image {tuple(image.shape)}, got {tuple(target.shape)}")
    if image.dim() not in (3, 4) or image.numel() == 0:  # (an empty batch failed in min())
        raise ValueError(f"image: expected a non-empty (B, C, H, W) or (C, H, W), got shape {tuple(image.shape)}")
    for name, t in (("image", image), ("target", target)):
        if t.dtype == torch.bool or t.is_complex():
            raise TypeError(f"{name}: expected real pixel values, got {t.dtype}")
    if data_range is None and image.is_floating_point() != target.is_floating_point():
        # (uint8 against [0, 1] floats scored -42 dB: which range?)
        raise TypeError(f"target: expected the kind of image's dtype {image.dtype} (both integer codes or both "
                        f"floating point) or a data_range, got {target.dtype}")
    if data_range is None and not image.is_floating_point() and image.dtype != target.dtype:
        # (the peak is the integer dtype's largest value: uint8 against uint16 scored -42.6 dB, int32 against uint8
        # 95.9 dB)
        raise TypeError(f"target: integer codes of another width than image's {image.dtype} ({target.dtype}); give "
                        f"both the same dtype or a data_range")
    check_finite(image.detach(), "image")  # a NaN pixel would make the score NaN without saying where it came from
    check_finite(target.detach(), "target")
    if isinstance(crop, float) and crop.is_integer():
        crop = int(crop)
    if not is_integer(crop) or crop < 0 or 2 * crop >= min(image.shape[-2:]):
        raise ValueError(f"crop: expected a whole number of pixels, 0 <= crop < {(min(image.shape[-2:]) + 1) // 2} "
                         f"for an image of {tuple(image.shape[-2:])}, got {crop!r}")
    crop = int(crop)
    if crop:
        image, target = image[..., crop:-crop, crop:-crop], target[..., crop:-crop, crop:-crop]
    if not image.is_floating_point():
        image = image.to(torch.get_default_dtype())
    return image, target.to(image.dtype)


def _data_range(data_range, image: torch.Tensor, target: torch.Tensor) -> float:
    """``data_range``, or for None: 1 for floating point (refused for a target outside [0, 1]), the integer dtype's
    largest value (module docstring)."""
    if data_range is None:
        if not image.is_floating_point():
            return float(torch.iinfo(image.dtype).max)
        lo, hi = float(target.detach().min()), float(target.detach().max())
        if lo < -1e-6 or hi > 1 + 1e-6:  # (rounding's -1e-9 is not a signal outside [0, 1])
            raise ValueError(f"data_range: None takes a peak of 1 for floating-point images, but target spans "
                             f"[{lo:.6g}, {hi:.6g}], outside [0, 1]; pass data_range (the signal's full scale, e.g. "
                             f"1023 for 10-bit codes)")
        return 1.0
    return float(check_positive(data_range, "data_range"))


def mse(image: torch.Tensor, target: torch.Tensor, crop: int = 0, *, data_range=None) -> torch.Tensor:
    """Mean squared error per image over (C, H, W): :math:`(B)` (or a scalar for (C, H, W)), computed in at least
    float32 (half precision returns float32). ``data_range``: only to accept an integer image against a
    floating-point one (their common scale)."""
    a, b = _pair(image, target, crop, data_range)
    work = working_dtype(a.dtype)  # (in float16, 1 / MSE overflowed past 48 dB: a PSNR of inf for unequal images)
    return ((a.to(work) - b.to(work)) ** 2).mean(dim=(-3, -2, -1))


def psnr(image: torch.Tensor, target: torch.Tensor, data_range: float | None = None, crop: int = 0) -> torch.Tensor:
    """Peak signal-to-noise ratio per image, 10 log10(data_range^2 / MSE), the MSE over (C, H, W).

    Args:
        image: :math:`(B, C, H, W)` or :math:`(C, H, W)`.
        target: same shape.
        data_range: the peak value; None: 1 for floating-point images (a target outside [0, 1] is refused), 255
            for uint8 (the dtype's largest value).
        crop: border pixels excluded on every side.

    Returns:
        :math:`(B)` in dB (``inf`` for identical images, where the gradient is zero, not NaN).

    Example:
        >>> psnr(torch.ones(1, 1, 4, 4), torch.full((1, 1, 4, 4), 0.9))  # doctest: +SKIP
        tensor([20.])

    Reference: e.g. Wang et al., IEEE TIP 13(4), 2004, eq. 1 context; scikit-image ``peak_signal_noise_ratio``.
    """
    err = mse(image, target, crop, data_range=data_range)
    scored = target[..., int(crop):-int(crop), int(crop):-int(crop)] if crop else target  # (crop checked by mse)
    r = _data_range(data_range, image, scored)
    # identical images: +inf, the maximum, with a zero gradient (10 log10(r^2 / mse) differentiated at mse = 0 is
    # -inf times a zero difference, NaN, which would poison a training step whose batch holds one exact image)
    exact = err == 0
    value = 10.0 * torch.log10(r**2 / torch.where(exact, torch.ones_like(err), err))
    return torch.where(exact, torch.full_like(value, torch.inf), value)


def cpsnr(image: torch.Tensor, target: torch.Tensor, data_range: float | None = None, crop: int = 0
          ) -> torch.Tensor:
    """Colour PSNR of demosaicing benchmarks: one MSE over the three channels of each image (same as :func:`psnr`
    on (B, 3, H, W), with a check for 3 channels). ``crop`` excludes a border (the benchmarks report 0 and 10)."""
    if image.dim() < 3 or image.shape[-3] != 3:
        raise ValueError(f"image: expected 3 colour channels in dim -3, got shape {tuple(image.shape)}")
    return psnr(image, target, data_range, crop)


def ssim(image: torch.Tensor, target: torch.Tensor, data_range: float | None = None, window_size: int = 11,
         crop: int = 0, return_map: bool = False) -> torch.Tensor:
    """Structural similarity (Wang et al. 2004) per image, via ``kornia.metrics.ssim`` with a Gaussian window
    (sigma 1.5), averaged over channels and the valid (unpadded) region.

    Returns:
        :math:`(B)` mean SSIM, or the valid-region map :math:`(B, C, H', W')` with ``return_map``.

    Reference: Z. Wang, A. C. Bovik, H. R. Sheikh, E. P. Simoncelli, "Image quality assessment: from error
    visibility to structural similarity", IEEE TIP 13(4), 2004.
    """
    from kornia.metrics import ssim as kornia_ssim

    check_bool(return_map, "return_map")
    if isinstance(window_size, bool) or not isinstance(window_size, int) or window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"window_size: expected an odd number of pixels >= 1, got {window_size!r}")
    a, b = _pair(image, target, crop, data_range)
    squeeze = a.dim() == 3
    if squeeze:
        a, b = a.unsqueeze(0), b.unsqueeze(0)
    if min(a.shape[-2:]) < window_size:
        raise ValueError(f"image: expected at least {window_size}x{window_size} pixels after crop, got "
                         f"{tuple(a.shape[-2:])}")
    # eps 0: kornia's default 1e-12 is added to a denominator of order data_range^4 (C1 C2), which it dominates
    # for data_range below ~1e-2 (identical images scored 0.075 at data_range 1e-3); C1, C2 > 0 keep it positive
    m = kornia_ssim(a, b, window_size, max_val=_data_range(data_range, image, b), eps=0.0,
                    padding="valid")
    if return_map:
        return m[0] if squeeze else m
    out = m.mean(dim=(-3, -2, -1))
    return out[0] if squeeze else out


class PSNR(torch.nn.Module):
    """Module form of :func:`psnr`."""

    def __init__(self, data_range: float | None = None, crop: int = 0) -> None:
        super().__init__()
        self.data_range, self.crop = data_range, crop

    def forward(self, image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return psnr(image, target, self.data_range, self.crop)


class SSIM(torch.nn.Module):
    """Module form of :func:`ssim`."""

    def __init__(self, data_range: float | None = None, window_size: int = 11) -> None:
        super().__init__()
        self.data_range, self.window_size = data_range, window_size

    def forward(self, image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return ssim(image, target, self.data_range, self.window_size)
