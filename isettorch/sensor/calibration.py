"""Sensor calibration from dark and flat frame stacks (EMVA 1288 release 4.0 photon-transfer method), and the
sensor config it writes.

Per CFA channel (the sub-images of one colour; a monochrome sensor is one channel 'W'), from the statistics of
:func:`isettorch.metrics.emva.temporal_noise_components` at every exposure t:

* black level (DN): intercept of the mean dark signal against t; dark current (e-/s): its slope over K;
* conversion gain K (DN/e-): slope through the origin of the pixel-wise temporal variance (row and column noise
  removed) minus the dark's at the same t, against the dark-subtracted mean (EMVA 1288 eq. 9), over the linear range:
  levels below 70 % of the saturation signal and before the variance peak; levels whose variance/signal ratio departs
  from the median ratio by more than 5 % (or 4 standard errors) are left out, and fewer than 3 left is an error;
* read noise (e-): pixel-wise temporal dark variance extrapolated to t = 0 (intercept of a line in t), minus the
  quantisation variance q^2/12 DN^2 (EMVA eq. 5; q = 1 DN, or the common step 2^s of left-aligned data), square root,
  over K; row noise and quantisation are not in it. A dark variance under 0.24 q^2 DN^2 is quantisation-limited
  (EMVA 1288 4.0 section 6.4): unless the pixels' offsets (DSNU >= q / 2) dither the quantiser, the read noise is then
  the upper limit sqrt(0.24 - 1/12) q / K, with a warning; when they do, it is the noise whose dithered-quantiser
  variance (:func:`dithered_quantiser_variance`) is the measured one. Frames of non-integer values remove no q^2/12;
* darks with more than 0.1 % of their pixels at the ADC's top code are left out of the dark fits (warned; an error
  when every dark is);
* row noise (e-): std of the per-frame row offsets from the temporal variance of the row means (ELD, Wei et al.
  2020), averaged over the dark levels; column noise likewise;
* DSNU (e-): spatial std of the frame-averaged dark at the shortest exposure minus the temporal residue
  sigma^2 / N (EMVA section 8.2), over K;
* PRNU (%): spatial std of the frame-averaged flat minus the dark average (pixel by pixel) at the level nearest half
  saturation, temporal residues removed, over its mean;
* full well (e-): mean of the fully saturated flats above the black level, over K (the simulator's clip level;
  where the brightest saturated flat sits at the ADC's top code, ``saturation_at_adc_top``, the ADC clips and the
  sensor config leaves the well out);
* quantum efficiency: slope through the origin of the mean electrons against photons per pixel (linear range);
* hot pixels: pixels whose dark-signal slope exceeds the median slope by more than 6 robust standard deviations
  (1.4826 MAD; the median-absolute-deviation outlier rule of Leys et al., J. Exp. Soc. Psychol. 49(4), 2013, at a
  conservative 6 instead of their 2.5-3), counted and warned about; the EMVA fields above are means over all pixels
  as EMVA defines them, the written sensor config takes dark current and dark shading from the other pixels and the
  hot ones as ``hot_pixel_fraction`` / ``hot_pixel_dark_current_e_per_s``;
* dead (or weak) pixels: in the flat nearest half the brightest flat's signal, a response (less the dark) below the
  median of its 5 x 5 neighbourhood in its CFA plane by more than 6 robust standard deviations (the same rule), counted
  and warned about; ``prnu_percent`` is the other pixels' (EMVA counts every pixel: 12 dead pixels in 6144 made a
  1 % PRNU 4.5 %), and the sensor config models them as ``dead_pixel_fraction``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .._checks import check_integer, is_real
from ..metrics.emva import S2_DARK_FLOOR_DN2, S2_QUANTIZATION_DN2, spatial_variance, temporal_noise_components

__all__ = ["calibrate_capture", "calibrate_directory", "sensor_config", "write_sensor_config", "load_sensor_config",
           "simulate_capture", "photon_transfer_curve", "CALIBRATION_FIELDS"]

CALIBRATION_FIELDS = ("conversion_gain_dn_per_e", "read_noise_e", "row_noise_e", "column_noise_e",
                      "dark_current_e_per_s", "dsnu_e", "dark_shading_e_per_s", "prnu_percent", "full_well_e",
                      "black_level_dn", "quantum_efficiency")
_LINEAR_FRACTION = 0.7  # EMVA 1288 4.0 section 6.3 / reference implementation: fits up to 70 % of saturation
_HOT_MADS = 6.0  # hot pixel: dark-signal slope above median + 6 x 1.4826 MAD (Leys et al. 2013 rule, conservative)
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): MAD -> sigma for a Gaussian


def _planes(stack: np.ndarray, cfa: str | None) -> dict[str, list[np.ndarray]]:
    """``(N, H, W)`` -> {channel letter: [sub-image stacks]} (one stack 'W' for a monochrome sensor)."""
    if cfa is None:
        return {"W": [stack]}
    from .cfa import CFA

    c = CFA(str(cfa))
    ph, pw = c.shape
    out: dict[str, list[np.ndarray]] = {}
    for dy in range(ph):
        for dx in range(pw):
            out.setdefault(c.cell[dy][dx], []).append(stack[:, dy::ph, dx::pw])
    return out


def _nearest(exposures: dict, ms: float) -> float:
    """The key of ``exposures`` (ms) nearest ``ms``: the same exposure when there is one (the dark of a flat)."""
    return ms if ms in exposures else min(exposures, key=lambda k: abs(k - ms))


def _stats(planes: list[np.ndarray]) -> dict[str, Any]:
    """Temporal components averaged over the sub-images of one channel (keeps the averages for spatial stats)."""
    comps = [temporal_noise_components(torch.from_numpy(np.ascontiguousarray(p, dtype=np.float64))) for p in planes]
    out = {k: float(sum(float(c[k]) for c in comps) / len(comps))
           for k in ("mean", "var", "var_pixel", "var_row", "var_col")}
    out["averages"] = [c["average"] for c in comps]
    out["frames"] = comps[0]["frames"]
    out["pixels"] = sum(p[0].size for p in planes)
    return out


#: a flat folder's frames whose signals (mean over the shortest dark's) differ by more than this ratio are refused
#: (mixed exposures or settings), by more than the warning ratio warned about (a flickering light)
FRAME_SIGNAL_RATIO_ERROR, FRAME_SIGNAL_RATIO_WARNING = 1.25, 1.05


#: a dark folder's frame means spread by more than this many times the darks' per-pixel temporal noise (sigma_y) are
#: refused (a lit frame among the darks); by more than ten times the noise of a frame mean, warned about
DARK_SPREAD_PIXEL_SIGMAS = 3.0


def _check_dark_frame_means(capture, step: float, warnings: list[str]) -> None:
    """Every dark folder's frames at one level: a frame taken with the light on (or a leak) among the darks went into
    the black level, dark current and DSNU without a word (a 2 % leak in one of four 10 ms darks: black 66.75 DN for
    64, dark current 24 for 50 e-/s; a lit frame: black 198 DN). A frame mean varies by the temporal noise of a mean
    of HW pixels, s_e^2 / HW + s_r^2 / H + s_c^2 / W (:func:`~isettorch.metrics.emva.temporal_noise_components`),
    and a black level may drift by a step or two: a spread beyond 10 times that is warned about, beyond
    :data:`DARK_SPREAD_PIXEL_SIGMAS` times a pixel's own temporal noise (light, not drift) refused."""
    from ..metrics.emva import temporal_noise_components

    for ms, stack in sorted(capture.dark.items()):
        if stack.shape[0] < 2:
            continue
        means = stack.reshape(stack.shape[0], -1).mean(axis=1, dtype=np.float64)
        spread = float(means.max() - means.min())
        c = temporal_noise_components(torch.from_numpy(np.ascontiguousarray(stack, dtype=np.float64)))
        h, w = stack.shape[-2:]
        sd_mean = math.sqrt(max(float(c["var_pixel"]), 0.0) / (h * w) + max(float(c["var_row"]), 0.0) / h
                            + max(float(c["var_col"]), 0.0) / w)
        sd_pixel = math.sqrt(max(float(c["var"]), 0.0))
        if spread <= max(2 * step, 10 * sd_mean):
            continue
        folder = capture.folders.get(("dark", ms), f"dark_{ms:g}ms")
        shown = [round(float(v), 2) for v in means]
        if spread > max(2 * step, DARK_SPREAD_PIXEL_SIGMAS * sd_pixel):
            raise ValueError(f"{folder}: its frames' mean levels {shown} DN differ by {spread:.3g} DN, "
                             f"{spread / max(sd_pixel, 1e-12):.3g} times a pixel's temporal noise ({sd_pixel:.3g} DN): "
                             f"a lit frame among the darks? expected dark frames (no light) of one exposure")
        warnings.append(f"{folder}: its frames' mean levels {shown} DN differ by {spread:.3g} DN, "
                        f"{spread / sd_mean:.3g} times what their temporal noise allows ({sd_mean:.2g} DN): a light "
                        f"leak in a frame or a drifting black level? the level is their mean")


def _check_frame_means(capture, warnings: list[str]) -> None:
    """Every flat folder's frames at one signal: each frame's mean is taken out before the temporal statistics
    (flicker tolerance, EMVA 1288), so a folder of 12.9 ms and 24.7 ms frames (means 1130 and 2080 DN) was read as one
    level at their average, 46 % too bright, without a word; a frame without signal among lit ones (a failed
    light) as well."""
    dark = capture.dark[min(capture.dark)]
    black = float(dark.mean())
    # a dark frame's mean wanders too (row noise, offset drift): a spread of a few times that is no exposure's
    drift = float(dark.reshape(dark.shape[0], -1).mean(axis=1, dtype=np.float64).std()) if dark.shape[0] > 1 else 0.0
    for ms, stack in sorted(capture.flat.items()):
        signal = stack.reshape(stack.shape[0], -1).mean(axis=1, dtype=np.float64) - black
        lo, hi = float(signal.min()), float(signal.max())
        if len(signal) < 2 or hi - lo <= max(0.5, 6 * drift):
            continue
        folder = capture.folders.get(("flat", ms), f"flat_{ms:g}ms")
        shown = [round(float(v), 1) for v in signal]
        if lo <= 0:
            raise ValueError(f"{folder}: its frames' mean signals (DN over the shortest dark) {shown} range from "
                             f"none to {hi:.3g} DN: a frame without light (or of another exposure) in one folder? "
                             f"expected one exposure per folder")
        if hi / lo > FRAME_SIGNAL_RATIO_ERROR:
            raise ValueError(f"{folder}: its frames' mean signals (DN over the shortest dark) {shown} differ by "
                             f"{hi / lo:.3g}x: frames of other exposures or settings in one folder? (a flickering "
                             f"light varies by a few %); expected one exposure per folder")
        if hi / lo > FRAME_SIGNAL_RATIO_WARNING:
            warnings.append(f"{folder}: its frames' mean signals {shown} DN differ by {100 * (hi / lo - 1):.3g} % "
                            f"(a flickering light?); the level is their mean")


#: the dark's fixed pattern found in a flat at other than this ratio (beyond 4 standard errors) is warned about
_DARK_PATTERN_RATIO_SPREAD = 0.2


def _warn_dark_gain(name: str, dark: dict, flat: dict, folders: dict, warnings: list[str]) -> None:
    """Warn when the darks' fixed pattern (DSNU) reappears in the dimmest flat at another scale: the regression slope
    of the flat's frame average on the dark's (same or nearest exposure), divided by the share of the dark's spatial
    variance that is pattern, not temporal residue (errors in variables), is the flats' gain over the darks'. Darks
    at twice the flats' gain gave twice the read noise and dark current without a word (the gain is fitted through
    flat minus dark variances). Needs a pattern well above the residue (else nothing is said)."""
    ms_f = min(flat)
    ms_d = _nearest(dark, ms_f)
    dd, ff = dark[ms_d], flat[ms_f]
    xs, ys = [], []
    for a_d, a_f in zip(dd["averages"], ff["averages"]):
        x, y = (np.asarray(a, dtype=np.float64).ravel() for a in (a_d, a_f))  # (CPU tensors, as _stats made them)
        xs.append(x - x.mean())
        ys.append(y - y.mean())
    x, y = np.concatenate(xs), np.concatenate(ys)
    # hot pixels (outliers of the dark pattern, _HOT_MADS robust sigmas out) left out: their dark signal grows with
    # exposure, so at a flat's other exposure they lead the regression (12 of 6144 pixels gave 0.58 x, a false alarm)
    dev = np.abs(x - np.median(x))
    mad = float(np.median(dev))
    if mad > 0:
        keep = dev <= _HOT_MADS * _MAD_TO_SIGMA * mad
        x, y = x[keep] - x[keep].mean(), y[keep] - y[keep].mean()
    var_x = float((x * x).mean())
    pattern = var_x - float(dd["var"]) / int(dd["frames"])  # less the frame average's temporal residue
    if not (var_x > 0 and pattern > 0.5 * var_x):
        return
    beta = float((x * y).mean()) / var_x
    ratio = beta * var_x / pattern
    se = math.sqrt(float(((y - beta * x) ** 2).mean()) / (x.size * var_x)) * var_x / pattern
    if abs(ratio - 1) > max(_DARK_PATTERN_RATIO_SPREAD, 4 * se):
        warnings.append(f"channel {name}: the dark's fixed pattern ({folders.get(('dark', ms_d), f'dark_{ms_d:g}ms')}) "
                        f"appears in {folders.get(('flat', ms_f), f'flat_{ms_f:g}ms')} at {ratio:.3g} x its size: "
                        f"darks and flats at other gains (or other settings)? the read noise and dark current are "
                        f"in the darks' gain")


def _column_fpn_dn2(dark_stats) -> float:
    """The variance (DN^2) of a fixed per-column offset in frame-averaged darks (the stats of one dark exposure per
    channel, :func:`_stats`: one average per CFA position, the columns of each one of the sensor's): the column
    means' variance less what the pixels' own spread ``s_r^2`` (DSNU and the averages' temporal residue, about the
    columns) puts in a mean of H rows, ``s_r^2 / H``, and less the temporal column noise's residue in an average of
    N frames, ``s_c^2 / N`` (EMVA 1288 4.0, 8.2: the spatial variance split into column, row and pixel parts, the
    temporal residue removed), over the images; 0 when negative. (Without the last term, 1 e- of temporal column
    noise read as 0.72 / 0.52 / 0.24 e- of column pattern from 2 / 4 / 16 frames.)"""
    est = []
    for st in dark_stats:
        residue = max(float(st["var_col"]), 0.0) / int(st["frames"])
        for a in st["averages"]:
            a = np.asarray(a, dtype=np.float64)
            h = a.shape[0]
            if h < 2 or a.shape[1] < 2:
                continue
            cols = a.mean(axis=0)
            resid = a - cols[None, :]
            est.append(float(cols.var(ddof=1)) - float((resid ** 2).sum() / (a.size - a.shape[1])) / h - residue)
    return max(float(np.mean(est)), 0.0) if est else 0.0


def _inverse_sd(sd) -> np.ndarray | None:
    """Weights 1 / sd for np.polyfit, safe against a zero (or non-finite) standard error, which would give infinite
    weights (LAPACK then fails and prints to stdout): such an sd is raised to 1e-6 of the largest finite one; None
    (unweighted) when none is positive."""
    sd = np.asarray(sd, dtype=np.float64)
    ok = np.isfinite(sd) & (sd > 0)
    if not ok.any():
        return None
    floor = 1e-6 * sd[ok].max()
    return 1 / np.where(ok, np.maximum(sd, floor), floor)


def _line(x: np.ndarray, y: np.ndarray, sd: np.ndarray | None = None) -> tuple[float, float]:
    """Least-squares (slope, intercept), weighted by 1 / sd^2 when the standard errors ``sd`` are given; a single
    point gives slope 0."""
    if len(x) < 2 or np.ptp(x) == 0:
        return 0.0, float(np.mean(y))
    slope, icpt = np.polyfit(x, y, 1, w=None if sd is None else _inverse_sd(sd))
    return float(slope), float(icpt)


def _spatial_sd(fixed_var: float, stats: dict, averages, other: dict | None = None) -> float:
    """Standard error of a spatial-variance estimate of frame averages: the pixel-wise part is sampled by every pixel,
    the temporal row (column) residue only by the rows (columns), sd^2 = 2 v_pix^2 / pixels + 2 v_row^2 / rows + ...
    (each term the sampling variance of a Gaussian sample variance, 2 sigma^4 / n for n samples: (n - 1) s^2 /
    sigma^2 is chi-square with n - 1 degrees of freedom; Papoulis & Pillai, Probability, Random Variables and
    Stochastic Processes, 4th ed., section 8-2)."""
    pixels = sum(a.numel() for a in averages)
    rows, cols = averages[0].shape
    v_pix, v_row, v_col = fixed_var, 0.0, 0.0
    for st in (stats, other) if other is not None else (stats,):
        v_pix += max(st["var_pixel"], 0.0) / st["frames"]
        v_row += max(st["var_row"], 0.0) / st["frames"]
        v_col += max(st["var_col"], 0.0) / st["frames"]
    return math.sqrt(2 * v_pix ** 2 / pixels + 2 * v_row ** 2 / rows + 2 * v_col ** 2 / cols)


def _dsnu_fit(dark: dict[float, dict], s2_override: dict[float, float] | None = None) -> tuple[float, float]:
    """(DSNU variance at the shortest exposure, its growth b in DN^2/s^2): the spatial variances of the frame-averaged
    darks (temporal residue removed, EMVA 8.2) fitted as a + b t^2 (a fixed offset pattern plus a dark-current
    non-uniformity / dark shading growing with t; PMN, Feng et al. 2022), weighted by their standard errors, so
    every dark level contributes to the estimate at the shortest exposure. ``s2_override``: spatial variances to fit
    instead (e.g. of the pixels that are not hot), with the same standard errors."""
    ms = sorted(dark)
    t = np.array(ms) * 1e-3
    s2, sd = [], []
    for k in ms:
        d = dark[k]
        if s2_override is not None:
            s2.append(s2_override[k])
        else:
            s2.append(float(np.mean([float(spatial_variance(a, d["var"], d["frames"])) for a in d["averages"]])))
        sd.append(_spatial_sd(abs(s2[-1]), d, d["averages"]))
    s2, sd = np.array(s2), np.array(sd)
    w = _inverse_sd(sd)
    if w is None:  # no spatial or temporal variance at all (a noiseless, uniform dark)
        return float(np.mean(s2)), 0.0
    if len(ms) >= 3 and np.ptp(t) > 0:
        (b, a), cov = np.polyfit(t ** 2, s2, 1, w=w, cov="unscaled")
        if b > 3 * math.sqrt(cov[0, 0]):  # keep the growth only where it is significant (3 standard errors)
            return float(a + b * t[0] ** 2), float(b)
    return float((w ** 2 * s2).sum() / (w ** 2).sum()), 0.0


def _origin(x: np.ndarray, y: np.ndarray) -> float:
    """Slope of y = a x through the origin (EMVA 1288 reference implementation ``LinearB0``)."""
    return float((x * y).sum() / (x * x).sum())


def _mean_se(images) -> float:
    """Standard error of the mean over the pixels of ``images`` (frame-mean images of one channel's sub-images, or
    frame stacks, averaged over their first axis): their pooled spread over the pixels (the fixed pattern and the
    frames' averaged temporal noise) / sqrt(pixels). The black level of a channel is such a sample of its pixels' fixed
    offsets, and two channels of one black level differ by about this much."""
    values = np.concatenate([np.asarray(a, dtype=np.float64).ravel() for a in images])
    return float(values.std(ddof=1) / math.sqrt(values.size)) if values.size > 1 else 0.0


def _response_variance(average, reference, flat: dict, dark: dict, dead: np.ndarray | None) -> float:
    """EMVA 1288 8.2 spatial variance of ``average - reference`` (a flat's frame average less its dark's), temporal
    residue removed (:func:`~isettorch.metrics.emva.spatial_variance`), over the pixels not ``dead``: those take the
    others' median response, and the variance is scaled back to the k kept pixels, (n - 1) / (k - 1)."""
    if dead is None or not dead.any():
        return float(spatial_variance(average, flat["var"], flat["frames"], reference, dark["var"], dark["frames"]))
    keep = torch.from_numpy(~dead.reshape(average.shape))
    diff = average - reference
    filled = torch.where(keep, average, reference + diff[keep].median())
    n, k = keep.numel(), int(keep.sum())
    return float(spatial_variance(filled, 0.0, 1, reference)) * (n - 1) / max(k - 1, 1) \
        - flat["var"] / flat["frames"] - dark["var"] / dark["frames"]


def _channel(name: str, dark: dict[float, dict], flat: dict[float, dict], photons: dict[float, float] | None,
             folders: dict, warnings: list[str], quantisation_dn2: float = S2_QUANTIZATION_DN2,
             adc_top_dn: float | None = None, step_dn: float = 1.0, dead: list[np.ndarray] | None = None
             ) -> dict[str, Any]:
    """One channel's EMVA 1288 statistics from its planes' stats. ``dead``: the planes' dead-pixel masks
    (:func:`_dead_pixels`, in the order of the stats' averages), left out of the PRNU."""
    t_d = np.array(sorted(dark)) * 1e-3
    mu_d = np.array([dark[k]["mean"] for k in sorted(dark)])
    vp_d = np.array([dark[k]["var_pixel"] for k in sorted(dark)])
    dc_dn, black = _line(t_d, mu_d)
    black_se = _mean_se(dark[min(dark)]["averages"])
    # the pixel-wise dark variance grows with the dark shot noise; weights 1 / var^2 (the standard error of a
    # variance estimate is proportional to it), so the extrapolation to zero exposure rests on the short exposures
    vslope, vicpt = _line(t_d, vp_d, vp_d)
    if len(t_d) >= 2:
        # the dark signal cannot fall with exposure: a fall beyond 5 standard errors of the difference of the dark
        # means (temporal noise over pixels x frames; the same pixels' fixed pattern cancels) is drift between the
        # folders or a changed black level (written as 0 e-/s without a word)
        sem = [math.sqrt(max(dark[k]["var_pixel"], 0.0) / (dark[k]["pixels"] * dark[k]["frames"]))
               for k in sorted(dark)]
        fall = -dc_dn * (t_d[-1] - t_d[0])
        if fall > 5 * math.hypot(sem[0], sem[-1]):
            darks = [folders.get(("dark", k), f"dark_{k:g}ms") for k in sorted(dark)]
            warnings.append(f"channel {name}: the dark signal falls with exposure ({fall:.3g} DN from "
                            f"{darks[0]} to {darks[-1]}, {dc_dn:.4g} DN/s): a negative dark current is not "
                            f"physical (drift or a changed black level between the dark folders?); the sensor "
                            f"config writes 0 e-/s")
    if len(t_d) < 2:
        warnings.append(f"channel {name}: one dark exposure only: the dark current and the extrapolation to zero "
                        f"exposure need at least 2; dark_current_e_per_s is null, black level and read noise are "
                        f"taken at {t_d[0] * 1e3:g} ms")
    ms_f = np.array(sorted(flat))

    def dark_at(ms: float, key: str) -> float:  # the dark at a flat's exposure: measured, else the fitted line
        if ms in dark:
            return dark[ms][key]
        return (black + dc_dn * ms * 1e-3) if key == "mean" else (vicpt + vslope * ms * 1e-3)

    mu_f = np.array([flat[k]["mean"] for k in ms_f])
    vp_f = np.array([flat[k]["var_pixel"] for k in ms_f])
    signal = mu_f - np.array([dark_at(k, "mean") for k in ms_f])
    dvar = vp_f - np.array([dark_at(k, "var_pixel") for k in ms_f])
    folder = lambda ms: folders.get(("flat", ms), f"flat_{ms:g}ms")  # noqa: E731

    if len(ms_f) < 3:  # (one flat at 17 % of the range read "every flat is saturated": it is the top one)
        raise ValueError(f"channel {name}: {len(ms_f)} flat exposure(s) ({[folder(m) for m in ms_f]}); the gain needs "
                         f"at least 3 in the linear range (signal above the dark and below 70 % of saturation)")
    if not (signal > 0).any():  # (reported as "only 0 flat exposures in the linear range")
        raise ValueError(f"channel {name}: every flat's mean is at or below the dark's (the largest difference "
                         f"{float(signal.max()):.4g} DN); are dark and flat folders swapped?")
    # saturation: flats at the top level whose temporal variance has collapsed (all pixels clipped)
    top = mu_f.max()
    peak = int(np.argmax(vp_f))
    at_top = mu_f >= top - 0.005 * (top - black)
    saturated = at_top & (vp_f < 0.25 * vp_f.max())
    if at_top.all():
        raise ValueError(f"channel {name}: every flat is saturated (mean {top:.1f} DN, no temporal variance), e.g. "
                         f"{folder(ms_f[0])}; add shorter exposures")
    sat_signal = float(signal[saturated].mean()) if saturated.any() else float(signal[peak])
    # no flat saturated and the variance still rising at the brightest flat: no saturation in the capture, whose
    # flats are all in the linear range (the 70 % cut of the brightest refused 4 flats at 10-40 % of the well); the
    # ratio test below still leaves out a level departing from the line
    unsaturated = not saturated.any() and peak == int(np.argmax(mu_f))
    cut = np.inf if unsaturated else _LINEAR_FRACTION * sat_signal
    linear = (signal <= cut) & (np.arange(len(ms_f)) <= peak) & ~saturated & (signal > 0)
    if linear.sum() < 3:
        where = "above the dark" if unsaturated else "above the dark and below 70 % of saturation"
        raise ValueError(f"channel {name}: only {int(linear.sum())} flat exposure(s) in the linear range (signal "
                         f"{where}: {[folder(m) for m in ms_f[linear]]}); the gain needs at least 3")
    # robust start: the median of the per-level ratios variance / signal (EMVA eq. 9: var = K signal), over the levels
    # with a temporal variance above the dark's (a level with none, e.g. copied frames, cannot be on the line); then
    # levels departing from it by more than 5 % (or 4 standard errors of their ratio: the variance of a sample variance
    # is 2 sigma^4 / dof) are left out (non-linearity near saturation, a bad stack) and K is fitted through the rest
    ratio = dvar / np.where(signal > 0, signal, 1)
    positive = linear & (dvar > 0)
    if not positive.any():
        raise ValueError(f"channel {name}: the photon-transfer slope is not positive (no flat level in the linear "
                         f"range has more temporal variance than the dark); are dark and flat folders swapped?")
    K0 = float(np.median(ratio[positive]))
    dof = lambda st: st["pixels"] * (st["frames"] - 1)  # noqa: E731
    dof_f = np.array([dof(flat[m]) for m in ms_f], dtype=np.float64)
    dof_d = np.array([dof(dark[_nearest(dark, m)]) for m in ms_f], dtype=np.float64)
    # the ratio's relative standard error from the two variances' (a Gaussian sample variance's is 2 sigma^4 / dof,
    # the chi-square law of (dof) s^2 / sigma^2, as in _spatial_sd)
    se = np.sqrt(2 * vp_f ** 2 / dof_f + 2 * (vp_f - dvar) ** 2 / dof_d) / np.maximum(np.abs(dvar), 1e-300)
    keep = positive & (np.abs(ratio / K0 - 1) < np.maximum(0.05, 4 * se))
    if keep.sum() < 3:
        off = {folder(m): f"{r / K0 - 1:+.1%}" for m, r in zip(ms_f[linear & ~keep], ratio[linear & ~keep])}
        raise ValueError(f"channel {name}: only {int(keep.sum())} of {int(linear.sum())} flat levels in the linear "
                         f"range agree on the gain (variance / signal within 5 % or 4 standard errors of the median "
                         f"{K0:.4g} DN/e-), the gain needs at least 3; the others depart by {off} (copied frames, "
                         f"flicker, a changed setting?)")
    K = _origin(signal[keep], dvar[keep])
    # its standard error: K = sum(x^2 r) / sum(x^2) over the kept levels' ratios r = var / signal (x the signal),
    # each with the relative standard error se above and independent between levels (their temporal variances)
    x2 = signal[keep] ** 2
    gain_se = K * float(np.sqrt((x2 ** 2 * se[keep] ** 2).sum()) / x2.sum())
    if keep.sum() < linear.sum():
        dropped = {folder(m): f"{r / K - 1:+.1%}" for m, r in zip(ms_f[linear & ~keep], ratio[linear & ~keep])}
        warnings.append(f"channel {name}: photon-transfer outliers left out of the gain fit (variance / signal off "
                        f"the fit by): {dropped}")
        linear = keep

    row_var = float(np.mean([d["var_row"] for d in dark.values()]))
    col_var = float(np.mean([d["var_col"] for d in dark.values()]))

    dsnu2, shading_b = _dsnu_fit(dark)

    # EMVA 1288 4.0 section 6.4: a dark variance below 0.24 DN^2 (per quantisation step^2) is quantisation-limited:
    # the q^2/12 of eq. 5 holds only for a noise dithered over the codes, and the standard then reports the floor,
    # an upper limit of the read noise. The pixels' fixed offsets (DSNU) dither the quantiser across the pixels
    # when they spread over half a step or more: the mean of the pixel-wise variances is then that of a dithered
    # quantiser, sigma^2 + q^2/12 from sigma ~ 0.3 q (a 0.30 DN read noise under 0.5 DN of DSNU was measured at 0.30;
    # without, 0.11) and less below (inverted below), and the measurement is kept.
    # The rule is about measured dark variances: where every exposure's is above the floor (the dark current's shot
    # noise dithers each of them) and only their extrapolation to zero exposure falls under it, the extrapolation of
    # Sheppard-corrected points is kept (a 0.36 DN read noise under 0.25 DN of DSNU and 53 DN/s of dark signal was
    # reported as the 0.40 DN upper limit, 11 % high; measured from the points, 0.0 %)
    floor = S2_DARK_FLOOR_DN2 / S2_QUANTIZATION_DN2 * quantisation_dn2
    step = math.sqrt(quantisation_dn2 / S2_QUANTIZATION_DN2)
    read_var = vicpt - quantisation_dn2
    dsnu_dn = math.sqrt(max(dsnu2, 0.0))
    # ... and only where the extrapolation resolves a read noise of 0.3 q or more, where Sheppard's q^2/12 holds (a
    # 0.1 DN read noise under strong dark current extrapolated to 0 e- or +30-58 % with the quantiser's phase)
    measured_above = bool(vp_d.min() >= floor) and read_var >= (0.3 * step) ** 2
    if quantisation_dn2 <= 0:  # non-integer frames: no quantiser, no floor (a negative intercept read as 0)
        read_var = max(read_var, 0.0)
    elif vicpt < floor and measured_above:
        warnings.append(f"channel {name}: the dark variance extrapolated to zero exposure ({vicpt:.4g} DN^2) is "
                        f"below {floor:.4g} DN^2, where quantisation would dominate it (EMVA 1288 4.0 section 6.4), "
                        f"but every measured dark variance is above it (the shortest exposure's "
                        f"{float(vp_d.min()):.4g} DN^2) and it resolves a read noise of 0.3 q or more: the "
                        f"extrapolation of the measured points is kept")
    elif vicpt < floor and dsnu_dn >= 0.5 * step:
        # the dithered quantiser's variance is sigma^2 + q^2/12 only from sigma ~ 0.3 q; below, it is less (0.056 q^2
        # at sigma 0.1 q, where sigma^2 + q^2/12 is 0.093): invert it (a 0.1 q read noise read 0, 0.2 q read 14 % low)
        read_var = (dithered_quantiser_sigma(vicpt / step ** 2) * step) ** 2
        warnings.append(f"channel {name}: the dark variance at zero exposure ({vicpt:.4g} DN^2) is below "
                        f"{floor:.4g} DN^2 (EMVA 1288 4.0 section 6.4 would report the upper limit "
                        f"{math.sqrt(floor - quantisation_dn2):.3g} DN); the pixels' offsets (DSNU "
                        f"{dsnu_dn:.3g} DN) dither the quantiser, so the measurement is kept: "
                        f"{math.sqrt(max(read_var, 0.0)):.3g} DN, the noise whose quantised variance averaged "
                        f"over the offsets is the measured one")
    elif vicpt < floor:
        read_var = floor - quantisation_dn2
        warnings.append(f"channel {name}: the dark variance at zero exposure ({vicpt:.4g} DN^2) is below "
                        f"{floor:.4g} DN^2, where quantisation dominates it, and the pixels' offsets (DSNU "
                        f"{dsnu_dn:.3g} DN) are too uniform to dither it (EMVA 1288 4.0 "
                        f"section 6.4): read noise reported as the upper limit {math.sqrt(read_var):.3g} DN (the "
                        f"floor less q^2/12); " + (
                            "the measured dark variances are above the floor, but their extrapolation resolves "
                            "a read noise under 0.3 q, below Sheppard's correction" if vp_d.min() >= floor else
                            "the dark current and DSNU of a dark signal this far under one DN are biased low"))

    # PRNU: (s^2 / signal^2) of the dark-subtracted flat averages (EMVA 8.2, the dark of the same or nearest exposure
    # subtracted pixel by pixel), combined over the linear levels and the one nearest half saturation, each weighted
    # by its standard error (a single level with few frames is dominated by the temporal residue when PRNU is small)
    cand = np.flatnonzero(~saturated & (signal > 0))
    half = int(cand[np.argmin(np.abs(signal[cand] - 0.5 * sat_signal))])
    est, sds = [], []
    for i in sorted(set(np.flatnonzero(linear).tolist()) | {half}):
        ms = ms_f[i]
        fd, dd = flat[ms], dark[_nearest(dark, ms)]
        shift = dark_at(ms, "mean") - dd["mean"]
        v = np.mean([_response_variance(a, b + shift, fd, dd, m)
                     for a, b, m in zip(fd["averages"], dd["averages"], dead or [None] * len(fd["averages"]))])
        est.append(v / signal[i] ** 2)
        sds.append(_spatial_sd(abs(v), fd, fd["averages"], dd) / signal[i] ** 2)
    w = 1 / np.array(sds) ** 2
    prnu2 = float((w * np.array(est)).sum() / w.sum())
    ms = ms_f[half]

    full_well = float((mu_f[saturated].mean() - black) / K) if saturated.any() else None
    # the brightest saturated flat at the ADC's top code (every pixel): the ADC clips, not the photodiode's well
    at_adc_top = bool(saturated.any()) and adc_top_dn is not None and \
        float(mu_f[saturated].max()) >= adc_top_dn - 0.5 * step_dn
    if full_well is None:
        warnings.append(f"channel {name}: no flat reaches saturation (brightest {folder(ms_f[-1])}); full_well_e is "
                        f"null")
    qe = None
    if photons is not None:
        mu_p = np.array([photons[m] for m in ms_f])
        if (mu_p[linear] > 0).sum() >= 2:
            qe = _origin(mu_p[linear], signal[linear] / K)
    return {
        "conversion_gain_dn_per_e": K,
        "conversion_gain_se_dn_per_e": gain_se,
        "read_noise_e": math.sqrt(max(read_var, 0.0)) / K,
        "row_noise_e": math.sqrt(max(row_var, 0.0)) / K,
        "column_noise_e": math.sqrt(max(col_var, 0.0)) / K,
        "dark_current_e_per_s": dc_dn / K if len(t_d) >= 2 else None,
        "dsnu_e": math.sqrt(max(dsnu2, 0.0)) / K,
        "dark_shading_e_per_s": math.sqrt(shading_b) / K,
        "prnu_percent": 100 * math.sqrt(max(prnu2, 0.0)),
        "full_well_e": full_well,
        "saturation_at_adc_top": at_adc_top,
        "black_level_dn": black,
        "black_level_se_dn": black_se,
        "quantum_efficiency": qe,
        "photon_transfer": {"exposure_ms": ms_f.tolist(), "signal_dn": signal.tolist(),
                            "variance_dn2": vp_f.tolist(), "variance_minus_dark_dn2": dvar.tolist(),
                            "dark_exposure_ms": (t_d * 1e3).tolist(), "dark_mean_dn": mu_d.tolist(),
                            "dark_variance_dn2": vp_d.tolist(), "linear": linear.tolist(),
                            "saturated": saturated.tolist(), "prnu_exposure_ms": float(ms)},
    }


class QuantisationStep:
    """:func:`quantisation_step` over frames added one at a time (``add``), so frames read once answer it at any
    ``min_distinct`` up to ``distinct_needed`` (``step``)."""

    def __init__(self, distinct_needed: int = 32):
        self.acc, self.distinct, self.whole = 0, set(), True
        self._needed = distinct_needed

    def add(self, st) -> None:
        if not self.whole:
            return
        if not np.array_equal(st, np.round(st)):
            self.whole = False
            return
        self.acc |= int(np.bitwise_or.reduce(st.astype(np.int64), axis=None))
        if len(self.distinct) < self._needed:
            self.distinct.update(np.unique(st).tolist())

    @classmethod
    def pooled(cls, parts) -> QuantisationStep:
        """One accumulator of the frames of several (``add`` each frame once, then pool)."""
        out = cls(max((p._needed for p in parts), default=32))
        for p in parts:
            out.whole = out.whole and p.whole
            out.acc |= p.acc
            if len(out.distinct) < out._needed:
                out.distinct |= p.distinct
        return out

    def step(self, min_distinct: int = 32) -> int:
        if min_distinct > self._needed:
            raise ValueError(f"min_distinct: this accumulator keeps {self._needed} distinct values, asked "
                             f"{min_distinct}")
        if not self.whole or self.acc == 0 or len(self.distinct) < min_distinct:
            return 1
        s = (self.acc & -self.acc).bit_length() - 1  # trailing zero bits of the OR: the largest 2^s dividing all
        return 2 ** s if s else 1


def quantisation_step(stacks, min_distinct: int = 32) -> int:
    """The common power-of-two step q = 2^s (s >= 1) of every value of every frame (left-aligned data: 12-bit values
    in 16-bit words are multiples of 16), else 1. Needs integer values and at least ``min_distinct`` distinct ones (a
    chance common factor 2 of n distinct noisy values has probability 2^-n). One pass: ``stacks`` may be a generator
    reading frames one at a time."""
    return _quantisation(stacks, min_distinct).step(min_distinct)


def _quantisation(stacks, min_distinct: int = 32) -> QuantisationStep:
    """The :class:`QuantisationStep` of ``stacks`` read once (it stops at the first non-integer frame): its
    ``step()`` and whether every value is whole (``whole``)."""
    acc = QuantisationStep(min_distinct)
    for st in stacks:
        acc.add(st)
        if not acc.whole:
            break
    return acc


def dithered_quantiser_variance(sigma_q) -> np.ndarray:
    """The variance, in units of the quantisation step q squared, of ``round(sigma Z + u)`` for a Gaussian noise of
    ``sigma_q`` steps (Z standard normal), averaged over offsets u uniform in [0, 1): the mean pixel-wise dark
    variance of pixels whose fixed offsets (DSNU) spread over a step or more. It tends to sigma^2 + 1/12 (Sheppard's
    correction; EMVA 1288 eq. 5) from about sigma = 0.3 and to 0 as sigma -> 0 (0.056 at 0.1, 0.113 at 0.2). By the
    probabilities of the codes, Phi((k + 1/2 - u) / sigma) - Phi((k - 1/2 - u) / sigma), on 256 offsets."""
    from scipy.stats import norm

    sig = np.atleast_1d(np.asarray(sigma_q, dtype=np.float64))
    u = (np.arange(256) + 0.5) / 256
    out = np.empty_like(sig)
    for i, sg in enumerate(sig):
        if sg <= 0:
            out[i] = 0.0
            continue
        k = np.arange(-int(math.ceil(8 * sg)) - 2, int(math.ceil(8 * sg)) + 3)[:, None]
        p = norm.cdf((k + 0.5 - u) / sg) - norm.cdf((k - 0.5 - u) / sg)  # [codes, offsets]
        m = (k * p).sum(0)
        out[i] = float(((k * k * p).sum(0) - m * m).mean())
    return out.reshape(np.shape(sigma_q))


_DITHER_SIGMA_Q = np.linspace(0.0, 0.6, 241)


def dithered_quantiser_sigma(variance_q2: float) -> float:
    """The noise (in steps) whose :func:`dithered_quantiser_variance` is ``variance_q2`` (in steps squared): its
    inverse on [0, 0.6] (monotonic there), linear in between its 241 nodes; Sheppard's sqrt(v - 1/12) above."""
    table = _dither_table()
    if variance_q2 >= table[-1]:
        return math.sqrt(max(variance_q2 - 1 / 12, 0.0))
    return float(np.interp(max(variance_q2, 0.0), table, _DITHER_SIGMA_Q))


def _dither_table() -> np.ndarray:
    global _DITHER_TABLE
    if _DITHER_TABLE is None:
        _DITHER_TABLE = dithered_quantiser_variance(_DITHER_SIGMA_Q)
    return _DITHER_TABLE


_DITHER_TABLE: np.ndarray | None = None


def _hot_pixels(capture, quantisation_dn2: float = 0.0) -> dict[str, Any] | None:
    """Hot pixels: per-pixel slope of the frame-averaged dark against exposure (DN/s), above the median slope by more
    than ``_HOT_MADS`` robust standard deviations (1.4826 MAD, Leys et al. 2013), the robust spread floored at the
    slope's own temporal standard error, each frame's variance at least the quantiser's ``quantisation_dn2`` (a
    read noise of 0.2 DN reads one code in most frames: the spread collapsed and pixels one code up in two frames
    were 'hot'). None with fewer than 2 dark exposures. Returns the mask and slopes."""
    ms = sorted(capture.dark)
    if len(ms) < 2:
        return None
    t = np.array(ms) * 1e-3
    tc = t - t.mean()
    stt = float((tc ** 2).sum())
    if stt == 0:
        return None
    slope = np.zeros(next(iter(capture.dark.values())).shape[-2:])
    var_slope = 0.0
    for k, w in zip(ms, tc):
        st = capture.dark[k]
        slope += w * st.mean(axis=0, dtype=np.float64)
        # temporal residue of the average
        frame_var = max(float(st.var(axis=0, ddof=1, dtype=np.float64).mean()), quantisation_dn2)
        var_slope += w ** 2 * frame_var / st.shape[0]
    slope /= stt
    med = float(np.median(slope))
    spread = max(_MAD_TO_SIGMA * float(np.median(np.abs(slope - med))), math.sqrt(var_slope) / stt)
    threshold = med + _HOT_MADS * spread
    return {"mask": slope > threshold, "slope_dn_per_s": slope, "threshold_dn_per_s": threshold}


def _dead_pixels(capture) -> dict[str, Any] | None:
    """Dead (or weak) pixels: in the flat whose signal is nearest half the brightest flat's, frame-averaged and less
    the dark of the nearest exposure, a response below the median of its 5 x 5 neighbourhood in its CFA plane (so a
    flat's smooth shading or vignetting is not read as dead pixels) by more than ``_HOT_MADS`` robust standard
    deviations of those departures (1.4826 MAD, the hot-pixel rule turned downwards), floored at the average's
    temporal noise. A pixel that does not respond reads the dark level: its deviation is the whole signal, and 12 such
    pixels in 6144 took a 1 % PRNU to 4.5 % in the sensor config. Returns the mask and the rule, or None when no flat
    stands above the dark noise."""
    dark_mean = {ms: float(st.mean(dtype=np.float64)) for ms, st in capture.dark.items()}  # (each once)
    sig = {ms: float(st.mean(dtype=np.float64)) - dark_mean[_nearest(dark_mean, ms)] for ms, st in capture.flat.items()}
    top = max(sig.values())
    if not top > 0:
        return None
    ms = min((m for m in sig if sig[m] > 0), key=lambda m: abs(sig[m] - 0.5 * top))
    flat, dark = capture.flat[ms], capture.dark[_nearest(capture.dark, ms)]
    resp = flat.mean(axis=0, dtype=np.float64) - dark.mean(axis=0, dtype=np.float64)
    noise = math.sqrt(float(flat.var(axis=0, ddof=1, dtype=np.float64).mean()) / flat.shape[0]
                      + float(dark.var(axis=0, ddof=1, dtype=np.float64).mean()) / dark.shape[0])
    from scipy.ndimage import median_filter

    mask = np.zeros(resp.shape, dtype=bool)
    for r_plane, m_plane in zip((p[0] for ps in _planes(resp[None], capture.cfa).values() for p in ps),
                                (p[0] for ps in _planes(mask[None], capture.cfa).values() for p in ps)):
        local = median_filter(r_plane, size=5, mode="reflect")
        dev = r_plane - local
        spread = max(_MAD_TO_SIGMA * float(np.median(np.abs(dev - np.median(dev)))), noise)
        # (where the neighbourhood's signal is not above the spread, there is no dead pixel to find)
        m_plane[...] = (dev < -_HOT_MADS * spread) & (local > _HOT_MADS * spread)  # (a view of mask: set in place)
    return {"mask": mask, "exposure_ms": ms}


def _dark_without(capture, hot: np.ndarray, dark_stats: dict[float, dict]) -> tuple[float, float, float]:
    """(dark current DN/s, DSNU variance DN^2 at the shortest exposure, dark shading growth DN^2/s^2) of the pixels
    not in ``hot``: the same estimators as for all pixels (mean dark against t; EMVA 8.2 spatial variances of the
    frame averages minus the temporal residue, per CFA sub-image, fitted as a + b t^2 by :func:`_dsnu_fit`)."""
    ms = sorted(capture.dark)
    t = np.array(ms) * 1e-3
    keep_planes = [p[0] for ps in _planes(~hot[None], capture.cfa).values() for p in ps]
    means, s2 = [], {}
    for k in ms:
        st = capture.dark[k]
        means.append(float(st.mean(axis=0, dtype=np.float64)[~hot].mean()))
        v = []
        for pl, keep in zip((p for ps in _planes(st, capture.cfa).values() for p in ps), keep_planes):
            pl = pl.astype(np.float64)
            centred = pl - pl.mean(axis=(1, 2), keepdims=True)
            temporal = float(centred.var(axis=0, ddof=1)[keep].mean())
            v.append(float(spatial_variance(torch.from_numpy(pl.mean(axis=0)[keep]), temporal, st.shape[0])))
        s2[k] = float(np.mean(v))
    dc_dn, _ = _line(t, np.array(means))
    dsnu2, shading_b = _dsnu_fit(dark_stats, s2)
    return dc_dn, dsnu2, shading_b


def calibrate_capture(capture, *, progress: bool = False) -> dict[str, Any]:
    """Calibrate a :class:`~isettorch.io.frames.Capture`; returns the JSON-ready result.

    Monochrome: every field of ``CALIBRATION_FIELDS`` is a number (electrons unless named otherwise; null where it
    cannot be measured, with the reason in ``warnings``). Colour (``cfa`` set): every field is ``{channel: value}``
    (the sub-images of one letter pooled), and ``sensor`` holds one value per field for the whole sensor (gain,
    read/row/column noise, PRNU: means over channels; dark current, DSNU, black level: from all pixels); channels
    whose gains differ by more than 5 % or black levels by more than 0.5 DN, and by more than 4 standard errors of
    the difference (a small capture's sampling spread), are warned about (the sensor config has one of each).

    Also: ``quantisation_step_dn`` (1, or 2^s for left-aligned data; the read noise then removes step^2 / 12) and
    ``effective_bits`` (bit_depth - s); ``hot_pixels`` (count, fraction, threshold and mean dark current of the hot
    pixels; null with one dark exposure) and, when there are any, ``sensor_config_dark`` (dark current, DSNU, dark
    shading of the other pixels, which the written sensor config uses).
    """
    from .._progress import progress as progress_bar

    warnings: list[str] = list(getattr(capture, "warnings", []))
    check_integer(capture.bit_depth, "capture.bit_depth", minimum=1)
    shape = None
    for kind in ("dark", "flat"):  # (the folder reader checks files; a Capture built in code was not: a NaN pixel
        # hid the saturation, moved the gain 1.5 % and called the frames non-integer; an empty dict, 2-D stacks, a
        # frame of another size or a flat without its photon count failed with StopIteration, "not enough values to
        # unpack", a tensor size mismatch or a KeyError)
        stacks = getattr(capture, kind)
        if not isinstance(stacks, dict) or not stacks:
            raise ValueError(f"capture.{kind}: expected a dict exposure (ms) -> (N, H, W) stack, with at least one "
                             f"exposure, got {stacks!r:.80}")
        for ms, stack in stacks.items():
            if not (is_real(ms) and math.isfinite(ms) and ms >= 0):
                raise ValueError(f"capture.{kind}: expected exposures in ms >= 0 as its keys, got {ms!r}")
            folder = capture.folders.get((kind, ms), f"{kind}_{ms:g}ms")
            a = np.asarray(stack)
            if a.ndim != 3 or a.shape[0] < 2:
                raise ValueError(f"capture.{kind}[{ms:g}] ({folder}): expected a stack (N, H, W) of at least 2 frames "
                                 f"(temporal noise needs a stack), got shape {a.shape}")
            if shape is not None and a.shape[1:] != shape:
                raise ValueError(f"capture.{kind}[{ms:g}] ({folder}): expected frames of {shape[0]}x{shape[1]} "
                                 f"pixels as the others, got {a.shape[1]}x{a.shape[2]}")
            shape = a.shape[1:]
            if kind == "flat" and capture.photons_per_pixel is not None and ms not in capture.photons_per_pixel:
                raise ValueError(f"capture.photons_per_pixel: expected a photon count for every flat exposure, "
                                 f"missing {ms:g} ms")
            if not np.isfinite(a).all():
                raise ValueError(f"capture.{kind}[{ms:g}] ({folder}): NaN or infinite values in its frames; "
                                 f"expected finite DN")
    acc = _quantisation(list(capture.dark.values()) + list(capture.flat.values()))
    step = acc.step()
    # frames of non-integer values (float .npy) have no quantiser of one DN: no q^2/12 to remove, no EMVA floor (a
    # 0.6 e- read noise read 12 % low, 0.4 e- was reported as the floor's "upper limit")
    quantisation_dn2 = step ** 2 / 12 if acc.whole else 0.0
    if not acc.whole:
        warnings.append("the frames hold non-integer values (no ADC step): no quantisation variance is removed from "
                        "the dark noise")
    bits_eff = int(capture.bit_depth) - int(math.log2(step))
    if step > 1:
        warnings.append(f"every value of every frame is a multiple of {step} DN (left-aligned {bits_eff}-bit data in "
                        f"{capture.bit_depth}-bit words?): the quantisation variance is {step}^2/12 DN^2 (EMVA 1288 "
                        f"eq. 5 for a step of {step} DN); results are in the files' DN, the sensor config is written "
                        f"for {bits_eff} bits (DN / {step})")
    if not acc.whole and capture.bit_depth > 1:
        top = max(float(st.max()) for st in (*capture.dark.values(), *capture.flat.values()))
        if top <= 1.0:  # (DN / 4095 as float32: a conversion gain 4000x too small, a black level of 0.02 DN)
            raise ValueError(f"the frames' values are all within 0..{top:.3g}, not DN: normalised frames of a "
                             f"{capture.bit_depth}-bit capture? expected DN (0..{2 ** capture.bit_depth - 1}); "
                             f"multiply by 2^bit_depth - 1")
    capture = _without_clipped_darks(capture, step, warnings)
    _check_plane_shape(capture)
    _check_dark_frame_means(capture, step, warnings)
    _check_frame_means(capture, warnings)
    dark_p = {ms: _planes(s, capture.cfa) for ms, s in capture.dark.items()}
    flat_p = {ms: _planes(s, capture.cfa) for ms, s in capture.flat.items()}
    names = list(next(iter(dark_p.values())))
    stats: dict[str, tuple[dict, dict]] = {}
    with progress_bar(total=len(names) * (len(dark_p) + len(flat_p)), desc="statistics", unit="stack",
                      quiet=not progress) as bar:
        for n in names:
            d, f = {}, {}
            for ms, p in dark_p.items():
                d[ms] = _stats(p[n])
                bar.update(1)
            for ms, p in flat_p.items():
                f[ms] = _stats(p[n])
                bar.update(1)
            stats[n] = (d, f)
    for ms, stack in capture.dark.items():  # a pedestal too low for the dark noise: the statistics are biased
        frac = float((stack <= 0).mean())
        if frac > 1e-3:
            warnings.append(f"{capture.folders.get(('dark', ms), f'dark_{ms:g}ms')}: {100 * frac:.2g} % of the pixels "
                            f"are at 0 DN (clipped below the black level); dark statistics are biased")
    top_dn = (2 ** bits_eff - 1) * step  # the ADC's top code in the files' DN (left-aligned: its multiple)
    dead = _dead_pixels(capture)
    dead_p = _planes(dead["mask"][None], capture.cfa) if dead is not None and dead["mask"].any() else None
    per = {n: _channel(n, d, f, capture.photons_per_pixel, capture.folders, warnings, quantisation_dn2,
                       adc_top_dn=top_dn, step_dn=step, dead=None if dead_p is None else [p[0] for p in dead_p[n]])
           for n, (d, f) in stats.items()}
    saturating = [n for n in per if per[n]["full_well_e"] is not None]
    adc_clips = bool(saturating) and all(per[n]["saturation_at_adc_top"] for n in saturating)
    if adc_clips:
        warnings.append(f"the saturated flats sit at the ADC's top code ({top_dn:g} DN): the saturation is the "
                        f"ADC's, so the sensor config leaves full_well_e out (the photodiode's well is above the ADC "
                        f"range; a simulated well there would clip before the ADC and add read noise to blown "
                        f"highlights); full_well_e in the results is the saturation in electrons")
    out: dict[str, Any] = {"cfa": capture.cfa, "bit_depth": capture.bit_depth, "pixel_size_m": capture.pixel_size_m,
                           "frame_shape": list(next(iter(capture.dark.values())).shape[-2:]),
                           "black_level_dn_nominal": capture.black_level_dn, "quantisation_step_dn": step,
                           "effective_bits": bits_eff, "saturation_at_adc_top": adc_clips}
    if capture.cfa is None:
        _warn_mosaic_as_mono(*stats["W"], capture.folders, warnings)
        res = per["W"]
        out.update({k: res[k] for k in CALIBRATION_FIELDS})
        out["photon_transfer"] = res["photon_transfer"]
    else:
        for k in CALIBRATION_FIELDS:
            out[k] = {n: per[n][k] for n in names}
        allp = {ms: _stats([p for n in names for p in dark_p[ms][n]]) for ms in dark_p}
        t = np.array(sorted(allp)) * 1e-3
        dc_dn, black = _line(t, np.array([allp[k]["mean"] for k in sorted(allp)]))
        K = float(np.mean([per[n]["conversion_gain_dn_per_e"] for n in names]))
        dsnu2, shading_b = _dsnu_fit(allp)
        fw = [per[n]["full_well_e"] for n in names if per[n]["full_well_e"] is not None]
        sensor = {"conversion_gain_dn_per_e": K,
                  "read_noise_e": float(np.sqrt(np.mean([per[n]["read_noise_e"] ** 2 for n in names]))),
                  "row_noise_e": float(np.sqrt(np.mean([per[n]["row_noise_e"] ** 2 for n in names]))),
                  "column_noise_e": float(np.sqrt(np.mean([per[n]["column_noise_e"] ** 2 for n in names]))),
                  "dark_current_e_per_s": dc_dn / K if len(t) >= 2 else None, "dsnu_e": math.sqrt(max(dsnu2, 0.0)) / K,
                  "dark_shading_e_per_s": math.sqrt(shading_b) / K,
                  "prnu_percent": float(np.sqrt(np.mean([per[n]["prnu_percent"] ** 2 for n in names]))),
                  # one clip level in electrons for the sensor: the channels that reach it
                  "full_well_e": float(np.mean(fw)) if fw else None,
                  "black_level_dn": black, "quantum_efficiency": None}
        out["sensor"] = sensor
        out["photon_transfer"] = {n: per[n]["photon_transfer"] for n in names}
        _warn_channels_differ(per, names, warnings, step)
        _warn_positions_differ(dark_p, capture.cfa, warnings, step)
    for n, (d, f) in stats.items():
        _warn_dark_gain(n, d, f, capture.folders, warnings)
    # column fixed pattern (EMVA 1288 4.0 section 8.2 splits the spatial variance into column, row and pixel parts):
    # in the sensor config it was pixel DSNU, so the simulated camera had no column stripes
    shortest = min(capture.dark)
    k_dn = _scalars(out)["conversion_gain_dn_per_e"]
    out["column_fpn_e"] = math.sqrt(_column_fpn_dn2([stats[n][0][shortest] for n in names])) / k_dn
    _hot_pixel_result(capture, out, stats if capture.cfa is None else {"all": (allp, None)}, warnings,
                      quantisation_dn2)
    out["dead_pixels"] = None
    if dead is not None:
        nd = int(dead["mask"].sum())
        out["dead_pixels"] = {"count": nd, "fraction": nd / dead["mask"].size, "exposure_ms": dead["exposure_ms"],
                              "rule": f"flat-minus-dark response below its 5x5 CFA-plane neighbourhood's median by "
                                      f"more than {_HOT_MADS:g} x 1.4826 MAD"}
        if nd:
            rows, cols = np.nonzero(dead["mask"])
            warnings.append(f"{nd} dead or weak pixel(s) ({100 * nd / dead['mask'].size:.2g} % of the pixels, e.g. "
                            f"(row, col) {[(int(r), int(c)) for r, c in zip(rows[:5], cols[:5])]}): response far below "
                            f"their channel's at {dead['exposure_ms']:g} ms; prnu_percent is the other pixels' (EMVA "
                            f"1288 counts every pixel), and the sensor config models them as dead_pixel_fraction")
    nominal, measured = capture.black_level_dn, _scalars(out)["black_level_dn"]
    if nominal is not None and abs(measured - float(nominal)) > step:
        warnings.append(f"the measured black level {measured:.2f} DN differs from the nominal black_level_dn "
                        f"{float(nominal):g} of capture.yaml by more than {step} DN; the measured one is used")
    _warn_raw_black_level(capture.raw_black_level_dn, measured, step, warnings)
    out["warnings"] = warnings
    return out


#: channels whose gains differ by more than this (relative) or whose black levels differ by more than this (DN) are
#: warned about: the sensor config has one of each (issue 17's bounds are 2 % and 0.5 DN per channel)
_CHANNEL_GAIN_SPREAD, _CHANNEL_BLACK_SPREAD_DN = 0.05, 0.5


def _warn_raw_black_level(tagged: float | None, measured: float, step: int, warnings: list[str]) -> None:
    """Warn when the raws' own black level (their BlackLevel tags, :attr:`Capture.raw_black_level_dn`) is further
    from the one the dark frames measure than ``isettorch process`` allows between a raw and its config
    (:data:`isettorch.io.frames.RAW_BLACK_TOLERANCE_DN`, in right-aligned DN): it would refuse this camera's raws."""
    from ..io.frames import RAW_BLACK_TOLERANCE_DN

    if tagged is not None and abs(tagged - measured) > RAW_BLACK_TOLERANCE_DN * step:
        warnings.append(f"the raws' BlackLevel tags (mean over the CFA cell {tagged:.2f} DN) differ from the black "
                        f"level the dark frames measure, {measured:.2f} DN, by more than "
                        f"{RAW_BLACK_TOLERANCE_DN * step:g} DN: isettorch process will refuse this camera's raws "
                        f"carrying those tags (the difference would stay in its output); check the darks (a light "
                        f"leak?) and the camera's black level setting")


#: a monochrome capture whose flats' 2 x 2 phases differ by more than this (relative signal) and by more than 10
#: standard errors is warned about as a colour mosaic read without its ``cfa``
_MOSAIC_PHASE_SPREAD = 0.02


def _warn_mosaic_as_mono(dark: dict, flat: dict, folders: dict, warnings: list[str]) -> None:
    """Warn when a capture without ``cfa`` has flats whose 2 x 2 phases differ (a Bayer mosaic in PNG / TIFF / .npy
    frames, which carry no CFA): calibrated as monochrome, its PRNU holds the colours' differences (23 % for a 1 %
    sensor) and its full well the least sensitive channel's. Measured on the flat whose mean signal (over the
    shortest dark's mean) is nearest half the brightest flat's: below any channel's saturation. ``dark`` / ``flat``:
    the monochrome channel's statistics (:func:`_stats`: their means and frame-mean images, not read again)."""
    black = dark[min(dark)]["mean"]
    signals = {ms: st["mean"] - black for ms, st in flat.items()}
    ms = min(signals, key=lambda k: abs(signals[k] - 0.5 * max(signals.values())))
    mean = np.asarray(flat[ms]["averages"][0], dtype=np.float64) - black  # the frames' mean image
    if min(mean.shape) < 4:
        return
    phases = [mean[dy::2, dx::2] for dy in (0, 1) for dx in (0, 1)]
    signal = np.array([float(q.mean()) for q in phases])
    se = max(float(q.std()) / math.sqrt(q.size) for q in phases)
    if signal.mean() <= 0:
        return
    spread = float(signal.max() - signal.min())
    if spread > _MOSAIC_PHASE_SPREAD * signal.mean() and spread > 10 * se:
        folder = folders.get(("flat", ms), f"flat_{ms:g}ms")
        warnings.append(f"the flats' 2 x 2 phases differ by {100 * spread / signal.mean():.0f} % (signals "
                        f"{', '.join(f'{v:.1f}' for v in signal)} DN in {folder}): a colour mosaic read as "
                        f"monochrome? set cfa in capture.yaml (as monochrome, the PRNU and full well pool the colours)")


def _warn_positions_differ(dark_p: dict, cfa: str, warnings: list[str], step: int) -> None:
    """Warn when the CFA positions of one colour (a Bayer cell's two greens) have black levels further apart than
    the channels may be (:data:`_CHANNEL_BLACK_SPREAD_DN`): the channel statistics pool them, the sensor config has
    one black level, so frames without levels of their own (PNG, TIFF, .npy) keep the difference when processed (a
    maze pattern in flat areas; ``isettorch process`` subtracts a camera raw's per-position BlackLevel tags).
    Measured at the shortest dark exposure (the dark current adds the same to both)."""
    shortest = dark_p[min(dark_p)]
    for name, planes in shortest.items():
        if len(planes) < 2:
            continue
        means = [float(np.mean(p)) for p in planes]
        hi, lo = int(np.argmax(means)), int(np.argmin(means))
        se = math.hypot(_mean_se([planes[hi].mean(axis=0)]), _mean_se([planes[lo].mean(axis=0)]))
        if means[hi] - means[lo] > max(_CHANNEL_BLACK_SPREAD_DN * step, 4 * se):
            warnings.append(f"the {len(planes)} {name} positions of the {cfa} cell have black levels "
                            f"{', '.join(f'{m:.2f}' for m in means)} DN (more than {_CHANNEL_BLACK_SPREAD_DN * step:g}"
                            f" DN and 4 standard errors, {4 * se:.2g} DN, apart): the channel statistics pool them"
                            f" and the sensor config has one black "
                            f"level, so PNG, TIFF and .npy frames keep the difference when processed (a camera "
                            f"raw's own BlackLevel per position is subtracted)")


def _warn_channels_differ(per: dict, names: list[str], warnings: list[str], step: int = 1) -> None:
    """Warn when the CFA channels disagree on the conversion gain or the black level beyond the calibration's own
    accuracy: the written sensor config has one gain (their mean) and one black level (all pixels'), so such a raw
    (per-channel digital gains, e.g. a white balance applied before the file was written; per-channel black levels)
    is not reproduced channel by channel."""
    gains = {n: per[n]["conversion_gain_dn_per_e"] for n in names}
    hi, lo = max(gains, key=gains.get), min(gains, key=gains.get)
    se = math.hypot(per[hi]["conversion_gain_se_dn_per_e"], per[lo]["conversion_gain_se_dn_per_e"])
    # beyond the spread and beyond 4 standard errors of the difference: a small capture (16 x 16 RGGB frames, 2 per
    # level) measures one gain 10-50 % apart per channel from its photon transfer alone
    if gains[hi] > (1 + _CHANNEL_GAIN_SPREAD) * gains[lo] and gains[hi] - gains[lo] > 4 * se:
        warnings.append(f"the channels' conversion gains differ by more than {100 * _CHANNEL_GAIN_SPREAD:g} % "
                        f"and 4 standard errors ({', '.join(f'{n} {k:.4g}' for n, k in gains.items())} DN/e-, "
                        f"{hi} - {lo} = {gains[hi] - gains[lo]:.3g} +- {se:.2g}; per-channel digital gains in "
                        f"the raw?): the sensor values and the sensor config use their mean, "
                        f"{float(np.mean(list(gains.values()))):.4g} DN/e-, for every channel")
    blacks = {n: per[n]["black_level_dn"] for n in names}
    hi, lo = max(blacks, key=blacks.get), min(blacks, key=blacks.get)
    se = math.hypot(per[hi]["black_level_se_dn"], per[lo]["black_level_se_dn"])
    # in the files' DN: a quantisation step of 16 (left-aligned 12-bit data) makes 0.5 right-aligned DN 8 (the
    # channels of one black level, 0.09 DN apart right-aligned, were warned about at 1.4 file DN); and beyond 4
    # standard errors: 16 x 16 RGGB frames with 1.6 DN of DSNU put one black level's channels 0.5 DN apart
    if blacks[hi] - blacks[lo] > max(_CHANNEL_BLACK_SPREAD_DN * step, 4 * se):
        warnings.append(f"the channels' black levels differ by more than {_CHANNEL_BLACK_SPREAD_DN * step:g} DN "
                        f"and 4 standard errors ({', '.join(f'{n} {b:.2f}' for n, b in blacks.items())} DN, "
                        f"{hi} - {lo} = {blacks[hi] - blacks[lo]:.3g} +- {se:.2g}): the sensor values and the "
                        f"sensor config have one black level for every channel")


def _without_clipped_darks(capture, step: int, warnings: list[str]):
    """The capture without its dark exposures that have more than 0.1 % of their pixels at the ADC's top code
    (``2^bit_depth - step``: a long dark of a high dark current, or a hot region, clipped): their mean, variance and
    spatial spread are biased low, and the fits in t would carry that into the black level, read noise and dark
    current. A warning names them; an error when no dark is left."""
    import dataclasses

    top = 2 ** int(capture.bit_depth) - step
    clipped = {ms: float((st >= top).mean()) for ms, st in capture.dark.items()}
    bad = sorted(ms for ms, f in clipped.items() if f > 1e-3)
    if not bad:
        return capture
    names = [capture.folders.get(("dark", ms), f"dark_{ms:g}ms") for ms in bad]
    detail = ", ".join(f"{n} {100 * clipped[ms]:.2g} %" for n, ms in zip(names, bad))
    if len(bad) == len(capture.dark):
        raise ValueError(f"every dark exposure has pixels clipped at the ADC's top code {top} DN ({detail}); the "
                         f"dark statistics need darks below saturation: add shorter dark exposures")
    warnings.append(f"dark exposures with pixels clipped at the ADC's top code {top} DN left out of the dark fits "
                    f"(black level, read noise, dark current, DSNU): {detail}")
    return dataclasses.replace(capture, dark={ms: v for ms, v in capture.dark.items() if ms not in bad})


def _check_plane_shape(capture) -> None:
    """Every channel's sub-image needs 2 rows and 2 columns: the pixel-wise temporal variance is separated from the
    row and column noise (:func:`~isettorch.metrics.emva.temporal_noise_components`), which one row or column
    cannot do (a line-scan sensor is not supported)."""
    h, w = next(iter(capture.dark.values())).shape[-2:]
    ph, pw = (1, 1)
    if capture.cfa is not None:
        from .cfa import CFA

        ph, pw = CFA(str(capture.cfa)).shape
    if h // ph < 2 or w // pw < 2:
        raise ValueError(f"frames: {h} x {w} pixels give {capture.cfa or 'the monochrome'} channel sub-images of "
                         f"{h // ph} x {w // pw}; calibration needs at least 2 x 2 (row and column noise are "
                         f"separated from the pixel noise; line-scan sensors are not supported)")


def _hot_pixel_result(capture, out: dict, stats: dict, warnings: list[str], quantisation_dn2: float = 0.0) -> None:
    """Count the hot pixels into ``out`` (``hot_pixels``) and, if any, the dark terms of the other pixels
    (``sensor_config_dark``), with a warning."""
    hot = _hot_pixels(capture, quantisation_dn2)
    out["hot_pixels"] = None
    if hot is None:
        return
    mask = hot["mask"]
    n = int(mask.sum())
    K = _scalars(out)["conversion_gain_dn_per_e"]
    out["hot_pixels"] = {"count": n, "fraction": n / mask.size, "threshold_e_per_s": hot["threshold_dn_per_s"] / K,
                         "mean_dark_current_e_per_s": float(hot["slope_dn_per_s"][mask].mean()) / K if n else None,
                         "rule": f"dark-signal slope > median + {_HOT_MADS:g} x 1.4826 MAD (Leys et al. 2013)"}
    if n == 0:
        return
    dark_stats = next(iter(stats.values()))[0]
    dc_dn, dsnu2, shading_b = _dark_without(capture, mask, dark_stats)
    clean = {"dark_current_e_per_s": dc_dn / K, "dsnu_e": math.sqrt(max(dsnu2, 0.0)) / K,
             "dark_shading_e_per_s": math.sqrt(shading_b) / K,
             "hot_pixel_fraction": n / mask.size,
             "hot_pixel_dark_current_e_per_s": max(0.0, float(hot["slope_dn_per_s"][mask].mean()) / K - dc_dn / K)}
    out["sensor_config_dark"] = clean
    rows, cols = np.nonzero(mask)
    first = [(int(r), int(c)) for r, c in zip(rows[:5], cols[:5])]
    s = _scalars(out)
    warnings.append(f"{n} hot pixel(s) ({100 * n / mask.size:.2g} % of the pixels, e.g. (row, col) {first}): dark "
                    f"current above {hot['threshold_dn_per_s'] / K:.4g} e-/s (median + {_HOT_MADS:g} robust sigmas), "
                    f"{out['hot_pixels']['mean_dark_current_e_per_s']:.4g} e-/s on average; dark_current_e_per_s, "
                    f"dsnu_e and dark_shading_e_per_s include them (EMVA 1288 means over all pixels: "
                    f"{s['dark_current_e_per_s']:.4g} e-/s, {s['dsnu_e']:.4g} e-, {s['dark_shading_e_per_s']:.4g} "
                    f"e-/s); the sensor config uses the other pixels' ({clean['dark_current_e_per_s']:.4g} e-/s, "
                    f"{clean['dsnu_e']:.4g} e-, {clean['dark_shading_e_per_s']:.4g} e-/s) and models the hot ones as "
                    f"hot_pixel_fraction / hot_pixel_dark_current_e_per_s")


def calibrate_directory(directory, *, progress: bool = False) -> dict[str, Any]:
    """Read ``directory`` (:func:`isettorch.io.frames.read_capture`) and calibrate it."""
    from ..io.frames import read_capture

    return calibrate_capture(read_capture(directory, progress=progress), progress=progress)


def _scalars(result: dict) -> dict:
    return result["sensor"] if result.get("cfa") else {k: result[k] for k in CALIBRATION_FIELDS}


def sensor_config(result: dict) -> dict[str, Any]:
    """Sensor constructor arguments reproducing a calibration: a 1 V swing, so the ADC step is 2^-bits V and the
    conversion gain K x step V/e-; noise terms in volts at the pixel; the photodiode clips at the full well.

    Left-aligned data (``quantisation_step_dn`` q = 2^s > 1) are written for their ``effective_bits`` = bits - s, in
    DN / q (right-aligned): the step is then 2^-(bits - s) V and K / q DN/e-, so the V/e- gain and the electron
    quantities are the same. With hot pixels (``sensor_config_dark``), dark current and dark shading are the other
    pixels' and the hot ones are ``hot_pixel_fraction`` with ``hot_pixel_dark_current_e_per_s`` on top."""
    s = _scalars(result)
    step = int(result.get("quantisation_step_dn") or 1)
    bits = int(result.get("effective_bits") or result["bit_depth"])
    lsb_v = 1.0 / 2 ** bits
    cg = s["conversion_gain_dn_per_e"] / step * lsb_v
    rows, cols = (int(v) for v in result["frame_shape"])
    dsnu_t_s = min(result["photon_transfer"][n]["dark_exposure_ms"][0] for n in result["photon_transfer"]) * 1e-3 \
        if result.get("cfa") else result["photon_transfer"]["dark_exposure_ms"][0] * 1e-3
    dark = dict(s)
    col_fpn_e = float(result.get("column_fpn_e") or 0.0)  # (results written before it have none)
    hot = {}
    if result.get("sensor_config_dark"):
        dark.update({k: result["sensor_config_dark"][k] for k in ("dark_current_e_per_s", "dsnu_e",
                                                                  "dark_shading_e_per_s")})
        hot = {k: result["sensor_config_dark"][k] for k in ("hot_pixel_fraction", "hot_pixel_dark_current_e_per_s")}
    cfg = {"rows": rows, "cols": cols, "pixel_size_m": float(result["pixel_size_m"]), "fill_factor": 1.0,
           "cfa": result["cfa"] or "mono", "adc_bits": bits, "voltage_swing_v": 1.0, "conversion_gain_v_per_e": cg,
           "black_level_dn": max(0.0, round(float(s["black_level_dn"]) / step, 4)),
           "read_noise_v": s["read_noise_e"] * cg, "row_noise_v": s["row_noise_e"] * cg,
           "column_noise_v": s["column_noise_e"] * cg,
           "dark_current_e_per_s": max(0.0, dark["dark_current_e_per_s"] or 0.0),
           # the DSNU at t = 0: the shortest exposure's minus the dark shading grown by then and the column part
           "dsnu_sigma_v": math.sqrt(max(dark["dsnu_e"] ** 2 - (dark["dark_shading_e_per_s"] * dsnu_t_s) ** 2
                                         - col_fpn_e ** 2, 0.0)) * cg,
           "column_fpn_sigma_v": col_fpn_e * cg,
           "dark_shading_e_per_s": dark["dark_shading_e_per_s"], "prnu_sigma_percent": s["prnu_percent"],
           # (None where the ADC saturates first: it clips at its top code, with no noise after it, as the camera)
           "full_well_e": None if result.get("saturation_at_adc_top") else s["full_well_e"],
           "shot_noise": "poisson", **hot}
    if (result.get("dead_pixels") or {}).get("count"):  # (results written before it have none)
        cfg["dead_pixel_fraction"] = float(result["dead_pixels"]["fraction"])
    return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in cfg.items()}


def write_sensor_config(result: dict, path) -> dict[str, Any]:
    """Write :func:`sensor_config` as ``sensor:`` YAML (the section a camera YAML takes); returns the mapping."""
    import yaml

    cfg = sensor_config(result)
    header = ("# Sensor calibrated by `isettorch calibrate` (EMVA 1288 photon transfer); load with\n"
              "# Sensor.from_config(path) or paste the section into a camera YAML.\n")
    qe = result.get("quantum_efficiency")
    if isinstance(qe, dict):  # per channel: the ones measured (a CFA capture without photon counts has none)
        qe = {k: v for k, v in qe.items() if v is not None} or None
    if qe is not None:
        header += f"# measured quantum efficiency: {qe}\n"
    if result.get("saturation_at_adc_top"):
        header += ("# the saturated flats sit at the ADC's top code: full_well_e is left out, so the simulated ADC "
                   "clips there as the camera's\n")
    step = int(result.get("quantisation_step_dn") or 1)
    if step > 1:
        header += (f"# the frames' values were multiples of {step} DN (left-aligned): written for adc_bits "
                   f"{cfg['adc_bits']}, in DN / {step} (black_level_dn too); multiply the simulated DN by {step} to "
                   f"compare with the frames\n")
    if _scalars(result)["dark_current_e_per_s"] is None:  # (the YAML alone read as a camera without dark current)
        header += ("# darks at one exposure only: the dark current was not measured and is written as 0; the black "
                   "level and read noise include the dark signal and its shot noise at that exposure, so the config "
                   "matches the camera there only\n")
    if result.get("sensor_config_dark"):
        n = result["hot_pixels"]["count"]
        header += (f"# {n} hot pixel(s) measured: dark_current_e_per_s, dark_shading_e_per_s and dsnu_sigma_v are "
                   f"from the other pixels, the hot ones are hot_pixel_fraction / hot_pixel_dark_current_e_per_s (at "
                   f"random positions); the calibration result's EMVA fields include them\n")
    Path(path).write_text(header + yaml.safe_dump({"sensor": cfg}, sort_keys=False))
    return cfg


def load_sensor_config(config, **overrides):
    """A :class:`Sensor` from a YAML path or mapping of constructor arguments (``sensor:`` section accepted).

    The file is read as a camera config is (:func:`isettorch.camera.load_yaml`: safe, YAML 1.2 floats such as
    ``1e-2``), and its values are checked as a camera config's ``sensor:`` section
    (:func:`isettorch.camera.check_sensor_values`: booleans are booleans, numbers are finite numbers)."""
    from ..camera import check_sensor_values, load_yaml
    from .sensor import Sensor

    if isinstance(config, (str, Path)):
        try:
            config = load_yaml(Path(config).read_text())
        except OSError as err:
            raise ValueError(f"config: cannot read {config} ({err})") from err
    if not isinstance(config, dict):
        raise ValueError(f"config: expected a mapping of Sensor arguments, got {type(config).__name__}")
    cfg = dict(config.get("sensor", config))
    cfg.update(overrides)
    check_sensor_values({k: v for k, v in cfg.items() if k != "preset"})
    preset = cfg.pop("preset", None)
    try:
        return Sensor.preset(preset, **cfg) if preset else Sensor(**cfg)
    except TypeError as err:
        raise ValueError(f"config: {err}") from err


def photon_transfer_curve(flat: dict[float, np.ndarray], dark: dict[float, np.ndarray], cfa: str | None
                          ) -> dict[str, list[tuple[float, float]]]:
    """{channel: [(dark-subtracted mean DN, temporal variance DN^2 incl. row noise)] per flat exposure}, darks
    matched by exposure (EMVA 1288 photon-transfer data)."""
    missing = sorted(ms for ms in flat if ms not in dark)
    if missing:  # (a bare KeyError)
        raise ValueError(f"dark: no dark stack at the flat exposure(s) {missing} ms; this curve subtracts the dark of "
                         f"the same exposure (calibrate_capture fits the dark over exposure instead)")
    out: dict[str, list] = {}
    for ms in sorted(flat):
        fp, dp = _planes(flat[ms], cfa), _planes(dark[ms], cfa)
        for n in fp:
            f, d = _stats(fp[n]), _stats(dp[n])
            out.setdefault(n, []).append((f["mean"] - d["mean"], f["var"]))
    return out


def simulate_capture(sensor, result: dict, frames: int = 2, generator: torch.Generator | None = None
                     ) -> tuple[dict[float, np.ndarray], dict[float, np.ndarray]]:
    """Simulate the calibrated capture with ``sensor`` (e.g. from :func:`load_sensor_config`): at every flat
    exposure, a uniform electron rate per channel equal to the measured mean signal (DN) / K / t, and dark frames.
    At a saturated level the measured mean is the clipped one, so the rate is the linear levels' signal per second
    (through the origin) instead: the sensor's full well then clips it as the camera's did (the clipped mean as a
    rate put the well at the mean electron count, so half the pixels read below it).
    Returns ``(flat, dark)``: {exposure_ms: (frames, H, W) DN}."""
    from .cfa import CFA

    rows, cols = (int(v) for v in result["frame_shape"])
    ptc = result["photon_transfer"]
    cfa = CFA(result["cfa"] or "mono")
    idx = cfa.channel_index(rows, cols)
    flat, dark = {}, {}
    for i, ms in enumerate(ptc[cfa.channel_names[0]]["exposure_ms"] if result["cfa"] else ptc["exposure_ms"]):
        rate = torch.zeros(rows, cols, dtype=torch.float64)
        k = _scalars(result)["conversion_gain_dn_per_e"]  # the simulated sensor has one gain
        for c, n in enumerate(cfa.channel_names):
            p = ptc[n] if result["cfa"] else ptc
            signal = max(p["signal_dn"][i], 0.0)
            if p["saturated"][i]:
                lin = [j for j, on in enumerate(p["linear"]) if on]
                signal = ms * _origin(np.array([p["exposure_ms"][j] for j in lin]),
                                      np.array([p["signal_dn"][j] for j in lin]))
            rate[idx == c] = signal / k / (ms * 1e-3)
        rate = rate.expand(frames, 1, rows, cols)
        t = ms * 1e-3
        flat[ms] = sensor.capture(rate, exposure_s=t, generator=generator).data[:, 0].numpy()
        dark[ms] = sensor.capture(torch.zeros_like(rate), exposure_s=t, generator=generator).data[:, 0].numpy()
    return flat, dark
