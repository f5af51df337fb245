"""Signal-to-noise ratio of uniform regions, pixel SNR versus signal, and dynamic range."""

from __future__ import annotations

import math
import numbers

import torch

from .._checks import as_tensor, check_bool, check_finite, check_nonnegative, check_window


def snr_uniform(image: torch.Tensor, roi: tuple[int, int, int, int] | None = None, db: bool = False) -> torch.Tensor:
    """SNR of a nominally uniform region: mean / standard deviation (ddof = 1) over its pixels.

    Args:
        image: :math:`(..., H, W)`, e.g. (B, C, H, W); every leading index is one region.
        roi: (row0, row1, col0, col1), end-exclusive; the whole image when None.
        db: return 20 log10(SNR).

    Returns:
        :math:`(...)`. The noise is the total (temporal + fixed-pattern) spatial noise of one frame; for the temporal
        part alone use :func:`snr_curve` on a frame stack. (ISO 15739:2013 section 6 without its high-pass step.)
        A region without noise has SNR inf (0 when it is black; in dB inf and -inf), with a zero gradient. A
        negative mean gives a negative SNR, and with ``db`` a ValueError.
    """
    if not isinstance(image, torch.Tensor) or image.dim() < 2:
        raise ValueError(f"image: expected a tensor (..., H, W), got "
                         f"{tuple(image.shape) if isinstance(image, torch.Tensor) else type(image).__name__}")
    if roi is not None:
        r0, r1, c0, c1 = check_window(roi, image.shape[-2], image.shape[-1], "roi", min_pixels=2)
        image = image[..., r0:r1, c0:c1]
    elif image.shape[-2] * image.shape[-1] < 2:  # (one pixel has no standard deviation: NaN)
        raise ValueError(f"image: expected at least 2 pixels, got shape {tuple(image.shape)}")
    x = image.flatten(-2)
    if not x.is_floating_point():
        x = x.to(torch.get_default_dtype())
    check_finite(x.detach(), "image")
    db = check_bool(db, "db")
    mean, var = x.mean(-1), x.var(-1)
    flat = var == 0  # no noise: SNR inf, and 0 for a black region as pixel_snr at zero signal (0 / 0 was NaN)
    # the standard deviation of the noisy regions only: std's gradient at zero variance is 0 / 0 (a noise-free
    # region's SNR had an inf value and a NaN gradient); a flat region's SNR is a constant, of zero gradient
    sd = torch.where(flat, 1.0, var).sqrt()
    snr = torch.where(flat, torch.where(mean == 0, 0.0, math.inf), mean / sd)
    if db and bool((mean < 0).any()):  # (log10 of a negative SNR had been NaN, with no word)
        raise ValueError(f"image: a region with a negative mean (down to {float(mean.min()):.4g}) has no SNR in dB; "
                         f"expected regions with mean >= 0 for db=True (a dark-subtracted region can go below 0: use "
                         f"db=False for its signed SNR)")
    return 20.0 * torch.log10(snr) if db else snr


def snr_curve(frames: torch.Tensor, dark: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Pixel SNR against signal from frame stacks at several signal levels.

    Args:
        frames: :math:`(M, N, H, W)`: M signal levels, N >= 2 frames of a uniform field each.
        dark: optional dark frames :math:`(N, H, W)` or :math:`(M, N, H, W)`; their mean is subtracted from
            the signal.

    Returns:
        dict with ``signal`` [M] (mean minus dark mean), ``noise_temporal`` [M] (per-pixel std over frames, rms
        over pixels), ``noise_total`` [M] (std over all pixels and frames), ``snr_temporal`` and ``snr_total`` [M].
    """
    if not isinstance(frames, torch.Tensor) or frames.dim() != 4 or frames.shape[1] < 2:
        raise ValueError(f"frames: expected (M, N, H, W) with N >= 2, got "
                         f"{tuple(frames.shape) if isinstance(frames, torch.Tensor) else type(frames).__name__}")
    f = frames if frames.is_floating_point() else frames.to(torch.get_default_dtype())
    check_finite(f.detach(), "frames")
    mean = f.mean(dim=(1, 2, 3))
    if dark is not None:
        if not isinstance(dark, torch.Tensor):
            raise TypeError(f"dark: expected a tensor (N, H, W) or (M, N, H, W), got {type(dark).__name__}")
        d = dark.to(f.dtype)
        check_finite(d.detach(), "dark")
        if d.dim() == 3:
            mean_dark = d.mean()
        elif d.dim() == 4 and d.shape[0] == f.shape[0]:
            mean_dark = d.mean(dim=(1, 2, 3))
        else:
            raise ValueError(f"dark: expected (N, H, W) or (M, N, H, W) with M = {f.shape[0]}, got {tuple(d.shape)}")
        signal = mean - mean_dark
    else:
        signal = mean
    noise_t = f.var(dim=1).mean(dim=(1, 2)).sqrt()
    noise_total = f.flatten(1).std(dim=1)
    return dict(signal=signal, noise_temporal=noise_t, noise_total=noise_total, snr_temporal=signal / noise_t,
                snr_total=signal / noise_total)


def noise_variance_e(signal_e, read_noise_e=0.0, dsnu_e=0.0, *, prnu_percent=0.0, dark_current_e=0.0,
                     column_fpn_e=0.0, lsb_e=None, shot: bool = True) -> torch.Tensor:
    """Pixel noise variance (electrons^2) at mean photo-signals ``signal_e``, the one noise model of the SNR
    figures: ``S + D + read^2 + DSNU^2 + column^2 + (PRNU S)^2 + LSB^2 / 12`` (shot noise of signal S and dark
    electrons D, read noise, DSNU, column FPN, PRNU in percent of the signal as the sensor's
    ``prnu_sigma_percent`` and the calibration's ``prnu_percent``, quantisation step ``lsb_e``; EMVA 1288 release
    4.0 eq. 2-6; ISETCam pixelSNR / sensorSNR; Farrell et al. 2004). ``shot=False`` drops the signal's shot noise
    (a sensor with shot noise off). ``prnu_percent`` and the terms after it are keyword-only (a positional PRNU
    was a fraction before 2026-11-30)."""
    s = as_tensor(signal_e, "signal_e", dtype=torch.float64)
    check_nonnegative(s, "signal_e")
    read, dsnu, prnu, dark, column = (_noise_level(v, n) for v, n in (
        (read_noise_e, "read_noise_e"), (dsnu_e, "dsnu_e"), (prnu_percent, "prnu_percent"),
        (dark_current_e, "dark_current_e"), (column_fpn_e, "column_fpn_e")))
    lsb = 0.0 if lsb_e is None else _noise_level(lsb_e, "lsb_e")
    var = dark + read ** 2 + dsnu ** 2 + column ** 2 + (prnu / 100 * s) ** 2 + lsb ** 2 / 12
    return var + s if check_bool(shot, "shot") else var + torch.zeros_like(s)


def _noise_level(value, name: str) -> float:
    """One noise term of :func:`noise_variance_e`: a finite number >= 0 (a NaN read noise gave SNR inf, a negative
    dark current a lower noise), else an error naming it."""
    if isinstance(value, bool) or not (isinstance(value, numbers.Real) or (
            isinstance(value, torch.Tensor) and value.numel() == 1)):
        raise TypeError(f"{name}: expected one number (electrons), got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{name}: expected a finite value >= 0 (electrons), got {value!r}")
    return v


def pixel_snr(signal_e, read_noise_e=0.0, dsnu_e=0.0, *, prnu_percent=0.0, dark_current_e=0.0, db: bool = False,
              column_fpn_e=0.0, lsb_e=None, shot: bool = True):
    """Model pixel SNR ``S / sqrt(variance)`` with the variance of :func:`noise_variance_e` (all in electrons).
    A noise-free pixel has SNR ``inf`` (0 at zero signal).

    Example:
        >>> float(pixel_snr(400.0))  # shot-noise limited: sqrt(S)
        20.0
    """
    s = as_tensor(signal_e, "signal_e", dtype=torch.float64)
    var = noise_variance_e(s, read_noise_e, dsnu_e, prnu_percent=prnu_percent, dark_current_e=dark_current_e,
                           column_fpn_e=column_fpn_e, lsb_e=lsb_e, shot=shot)
    snr = torch.where(var > 0, s / torch.sqrt(var.clamp_min(torch.finfo(s.dtype).tiny)),
                      torch.where(s > 0, math.inf, 0.0))
    return 20.0 * torch.log10(snr) if check_bool(db, "db") else snr


def dynamic_range_db(max_signal, noise_floor) -> torch.Tensor:
    """Dynamic range 20 log10(max signal / noise floor) in dB, e.g. (full-well - dark) / read noise in electrons
    (ISETCam pixelDR; EMVA 1288 uses mu_sat / mu_min, see :func:`~isettorch.metrics.emva1288`)."""
    m = as_tensor(max_signal, "max_signal", dtype=torch.float64)
    n = as_tensor(noise_floor, "noise_floor", dtype=torch.float64)
    check_finite(m, "max_signal")
    check_finite(n, "noise_floor")
    if (m <= 0).any() or (n <= 0).any():
        raise ValueError(f"max_signal, noise_floor: expected positive values, got {m.tolist()} and {n.tolist()}")
    return 20.0 * torch.log10(m / n)


def dynamic_range_from_curve(signal: torch.Tensor, snr: torch.Tensor, max_signal=None) -> torch.Tensor:
    """Dynamic range (dB) from a measured SNR curve: max signal over the signal at which SNR = 1 (linearly
    interpolated in log-log). ``max_signal`` defaults to the largest signal of the curve."""
    for name, v in (("signal", signal), ("snr", snr)):
        if not isinstance(v, torch.Tensor) or v.dim() != 1:
            raise ValueError(f"{name}: expected a 1-D tensor, got "
                             f"{tuple(v.shape) if isinstance(v, torch.Tensor) else type(v).__name__}")
    check_finite(signal.detach(), "signal")
    if snr.shape != signal.shape:
        raise ValueError(f"snr: expected one value per signal, {tuple(signal.shape)}, got {tuple(snr.shape)}")
    # +inf is a noise-free saturated level, NaN at a signal <= 0 a noise-free dark one (snr_curve's 0 / 0): left out
    # with the other points at signal <= 0; a NaN or -inf above is an error
    bad = (torch.isnan(snr) | (snr == -math.inf)) & (signal > 0)
    if bool(bad.any()):
        raise ValueError(f"snr: expected values that are not NaN or -inf where the signal is positive, got "
                         f"{snr[bad][:4].tolist()} at signals {signal[bad][:4].tolist()}")
    s, r = signal.detach().to(torch.float64), snr.detach().to(torch.float64)
    order = torch.argsort(s)
    s, r = s[order], r[order]
    keep = (s > 0) & (r > 0)
    s, r = s[keep], r[keep]
    above = (r >= 1).nonzero()
    if above.numel() == 0 or int(above[0]) == 0:
        raise ValueError("snr: the curve must start below SNR = 1 and cross it to find the noise floor")
    i = int(above[0])
    ls0, ls1, lr0, lr1 = math.log(s[i - 1]), math.log(s[i]), math.log(r[i - 1]), math.log(r[i])
    s_min = math.exp(ls0 + (0 - lr0) * (ls1 - ls0) / (lr1 - lr0))
    top = float(s.max()) if max_signal is None else float(max_signal)
    if not top > s_min:  # (a negative dynamic range was returned)
        raise ValueError(f"max_signal: expected a signal above the noise floor {s_min:.6g} (where SNR = 1), got "
                         f"{top:.6g}")
    return dynamic_range_db(top, s_min)
