"""Demosaic benchmark scoring (the convention of shared/data/README.md): ground truth = 8-bit image / 255 taken as
linear values; noise-free Bayer mosaic; output clipped to [0, 1]; CPSNR = 10 log10(1 / MSE) with the MSE over the
three channels of the (optionally cropped) image; the mean CPSNR over images is reported."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch

from .demosaicing import demosaic, mosaic

__all__ = ["IMAGE_SUFFIXES", "cpsnr", "evaluate_demosaic", "load_images"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def cpsnr(estimate: torch.Tensor, reference: torch.Tensor, crop: int = 0, peak: float = 1.0) -> torch.Tensor:
    """Colour PSNR per image: 10 log10(peak^2 / MSE), the MSE over all channels and pixels, a ``crop``-pixel
    border excluded.

    Args:
        estimate, reference: (B, C, H, W) of the same shape.
        crop: border width excluded on each side (pixels).

    Returns:
        (B,) in dB (inf where the images are equal).

    Example:
        >>> cpsnr(torch.full((1, 3, 4, 4), 0.5), torch.full((1, 3, 4, 4), 0.6)).item()  # 10 log10(1 / 0.01)
        20.0...
    """
    if estimate.shape != reference.shape or estimate.dim() != 4:
        raise ValueError(f"estimate, reference: expected equal shapes (B, C, H, W), got {tuple(estimate.shape)} "
                         f"and {tuple(reference.shape)}")
    from ..metrics.fidelity import psnr  # one PSNR implementation (per image, MSE over C, H, W)

    return psnr(estimate, reference, data_range=peak, crop=crop)


def load_images(source: str | Path | Iterable) -> list[tuple[str, np.ndarray]]:
    """8-bit RGB images as (name, uint8 array [H, W, 3]) from a folder (png/tif, sorted by name) or an iterable
    of (name, array) pairs."""
    if not isinstance(source, (str, Path)):
        return [(str(n), np.asarray(a)) for n, a in source]
    from PIL import Image

    folder = Path(source)
    if not folder.is_dir():
        raise ValueError(f"images: expected a folder of .png/.tif images, {str(folder)!r} is not a directory")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ValueError(f"images: no {'/'.join(IMAGE_SUFFIXES)} files in {str(folder)!r}")
    out = []
    for f in files:
        with Image.open(f) as im:
            if im.mode != "RGB":
                raise ValueError(f"images: expected 8-bit RGB images, {f.name} has mode {im.mode!r}")
            out.append((f.name, np.asarray(im)))
    return out


def evaluate_demosaic(images, method: str | Callable = "bilinear", pattern: str = "RGGB", crop: int = 0, *,
                      dtype: torch.dtype = torch.float64, device="cpu", **kwargs) -> dict:
    """Score a demosaic method on 8-bit images with the benchmark convention (module docstring).

    Args:
        images: a folder of .png/.tif 8-bit RGB images, or an iterable of (name, uint8 [H, W, 3]) pairs.
        method: a name in ``METHODS`` or a callable (raw, pattern) -> RGB.
        pattern: Bayer pattern of the simulated mosaic.
        crop: border width excluded from the score (pixels).
        dtype, device: where the demosaic runs. kwargs: passed to the method.

    Returns:
        {"method", "pattern", "crop", "mean_cpsnr", "ms_per_image", "images": [{"name", "cpsnr", "ms"}, ...]};
        ms is the wall time of the demosaic call alone (after one warm-up call).
    """
    device = torch.device(device)
    items = load_images(images)
    results = []

    def run(raw):
        with torch.no_grad():
            out = demosaic(raw, pattern, method, **kwargs)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return out

    for i, (name, array) in enumerate(items):
        if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
            raise ValueError(f"images: expected uint8 arrays [H, W, 3], {name} is {array.dtype} {array.shape}")
        truth = torch.from_numpy(array.astype(np.float64) / 255.0).permute(2, 0, 1)[None]
        raw = mosaic(truth, pattern).to(device=device, dtype=dtype)
        if i == 0:
            run(raw)  # warm-up: first-call allocations and kernel selection are not the method's cost
        t0 = time.perf_counter()
        out = run(raw)
        ms = 1e3 * (time.perf_counter() - t0)
        score = cpsnr(out.to("cpu", torch.float64).clamp(0, 1), truth, crop)[0].item()
        results.append({"name": name, "cpsnr": score, "ms": ms})
    scores = [r["cpsnr"] for r in results]
    return {
        "method": method if isinstance(method, str) else type(method).__name__,
        "pattern": pattern,
        "crop": crop,
        "mean_cpsnr": float(np.mean(scores)) if all(map(math.isfinite, scores)) else math.inf,
        "ms_per_image": float(np.mean([r["ms"] for r in results])),
        "images": results,
    }
