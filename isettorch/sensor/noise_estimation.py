"""Single-raw noise estimate: the Poisson-Gaussian fit of Foi, Trimeche, Katkovnik, Egiazarian, "Practical
Poissonian-Gaussian noise modeling and fitting for single-image raw-data", IEEE TIP 17(10), 2008.

Model (Foi et al. eq. 2-3): z = y + sigma(y) xi with sigma^2(y) = a y + b; for a linear sensor a = K (DN/e-, the
conversion gain) and b = the signal-independent variance (read noise, quantisation and, in one frame, the DSNU).
Method (Foi et al. section 3, simplified): per CFA sub-image, 2 x 2 blocks give a local mean and a diagonal Haar
detail coefficient d = (x00 - x01 - x10 + x11) / 2 (var d = sigma^2; a locally planar signal cancels); blocks whose
block-mean Laplacian exceeds 3 noise sigmas (edges, texture) are left out, as are clipped blocks (at 0 DN when the
frame is clipped there, or at the white level); the rest are grouped into level sets by their mean, each level's
variance is the variance of its details within 4 sigmas of a median-absolute-deviation scale, and sigma^2 = a y + b
is fitted by weighted least squares (weights = the inverse variance of each level's estimate, 2 sigma^4 / n).
"""

from __future__ import annotations

import math

import numpy as np

from .._checks import is_integer, is_real

__all__ = ["estimate_poisson_gaussian"]

_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): MAD -> sigma for a Gaussian
_TRUNC4 = 1 - 8 * math.exp(-8) / math.sqrt(2 * math.pi) / math.erf(4 / math.sqrt(2))  # E[x^2 | |x| < 4], x ~ N(0,1)


def _blocks(plane: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2 x 2 block means, diagonal Haar details, and the Laplacian of the block means (edges), all ``(h/2, w/2)``."""
    h, w = (plane.shape[0] // 2) * 2, (plane.shape[1] // 2) * 2
    p = plane[:h, :w]
    x00, x01, x10, x11 = p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]
    m = (x00 + x01 + x10 + x11) / 4
    mp = np.pad(m, 1, mode="edge")
    lap = m - (mp[:-2, 1:-1] + mp[2:, 1:-1] + mp[1:-1, :-2] + mp[1:-1, 2:]) / 4
    return m, (x00 - x01 - x10 + x11) / 2, lap


def _levels(m, d, levels, min_blocks):
    edges = np.unique(np.quantile(m, np.linspace(0, 1, levels + 1)))
    which = np.clip(np.searchsorted(edges, m, side="right") - 1, 0, len(edges) - 2)
    pts = []
    for k in range(len(edges) - 1):
        sel = which == k
        n = int(sel.sum())
        if n < min_blocks:
            continue
        dk = d[sel]
        # the MAD gives a robust scale, but on integer DN it is quantised (biased); the variance of the values within
        # 4 MAD-sigmas is not (a Gaussian truncated at 4 sigma keeps 0.99893 of its variance)
        centre = np.median(dk)
        sigma = _MAD_TO_SIGMA * np.median(np.abs(dk - centre))
        inside = dk[np.abs(dk - centre) < 4 * max(sigma, 0.5)]
        # the mean (not the median) of the level: the variance is linear in y, so its level average is a mean_y + b
        pts.append((float(np.mean(m[sel])), float(inside.var(ddof=1) / _TRUNC4), n))
    return pts


def _fit(pts) -> tuple[float, float]:
    """Weighted least squares for v = a y + b; var(v_hat) ~ 2 v^2 / n (iterated: the weights use the model)."""
    y, v, n = (np.array(c, dtype=np.float64) for c in zip(*pts))
    a, b = np.polyfit(y, v, 1)
    for _ in range(3):
        model = np.maximum(a * y + b, 1e-12)
        a, b = np.polyfit(y, v, 1, w=np.sqrt(n) / model)
    return float(a), float(b)


def _saturation_plateau(z: np.ndarray) -> float | None:
    """The lowest code of a saturation pile-up at a frame's largest values, or None. An unclipped distribution thins
    towards its largest value (fewer pixels on the top code than on the next one down, even for a low-noise bright
    patch); clipped pixels pile up on it, or on the few codes the clip spreads them over (an analog clip followed by
    ADC noise): from the top code down, each code holding at least 0.1 % of the pixels (and 32) and more than the
    next code down belongs to the pile-up (at most 8 codes)."""
    values, counts, top = [], [], math.inf
    for _ in range(9):  # the nine largest codes and their counts, from the top down (no copy of the frame)
        top = float(np.max(z, where=z < top, initial=-math.inf))
        if top == -math.inf:
            break
        values.append(top)
        counts.append(int(np.count_nonzero(z == top)))
    need = max(32, 1e-3 * z.size)
    white = None
    for i in range(min(8, len(values) - 1)):
        if counts[i] < need or counts[i] <= counts[i + 1]:
            break
        white = float(values[i])
    return white


def _saturation_bump(z: np.ndarray, need: float) -> tuple[float, float, float] | None:
    """A saturation pile-up spread into a bump below the frame's largest value (an analog clip at the full well,
    then read noise: the codes above the clip hold its upper tail, so :func:`_saturation_plateau`'s count from the
    top finds nothing): ``(lowest code of the bump, its mode, the variance of its pixels)``, or None. A bump is a
    mode of the top codes (64 DN, or 1024 for coarse codes) holding at least ``need`` pixels whose counts fall to
    under a quarter of it below as well as above; its lower edge mirrors its upper one about the mode. A bright
    uniform patch makes such a bump too: the caller tells them apart by its variance (a clip keeps the read noise
    only)."""
    top = float(z.max())
    for window in (64.0, 1024.0):
        vals, counts = np.unique(z[z >= top - window], return_counts=True)
        if len(vals) >= 8:
            break
    else:
        return None
    i = int(np.argmax(counts))
    if counts[i] < need or i == 0 or i == len(vals) - 1:
        return None
    above = len(vals) - 1 - i
    below = counts[max(i - 2 * above - 2, 0):i]
    if below.min() >= counts[i] / 4:  # no fall below the mode: the rising tail of the frame's values, not a bump
        return None
    lo = float(vals[max(i - above - 1, 0)])
    return lo, float(vals[i]), float(np.var(z[z >= lo]))


def _fit_quality(pts, a: float, b: float) -> tuple[float, float, float]:
    """``(standard errors of a and of b, chi^2 per degree of freedom)`` of the line through the level variances, each
    with its sampling variance ``2 v^2 / n`` under the model (a sample variance of n Gaussian values): a large standard
    error is a signal range too narrow to separate a from b; a chi^2 far above 1 is variance the model does not
    hold (texture or edges the detail coefficients did not cancel, non-linearity)."""
    y, v, n = (np.array(c, dtype=np.float64) for c in zip(*pts))
    var = 2 * np.maximum(a * y + b, 1e-12) ** 2 / n
    x = np.stack([y, np.ones_like(y)], axis=1)
    cov = np.linalg.pinv(x.T @ (x / var[:, None]))
    chi2 = float(((v - (a * y + b)) ** 2 / var).sum()) / max(len(y) - 2, 1)
    return float(math.sqrt(max(cov[0, 0], 0.0))), float(math.sqrt(max(cov[1, 1], 0.0))), chi2


def estimate_poisson_gaussian(raw, *, cfa: str | None = None, black_level_dn: float = 0.0,
                              white_level_dn: float | None = None, levels: int = 24,
                              min_blocks: int = 200, _bump: bool = True) -> dict:
    """Fit sigma^2(y) = a y + b to one raw frame (DN) with the Poisson-Gaussian method of Foi et al. 2008.

    Args:
        raw: one raw mosaic ``(H, W)`` in DN (NumPy array or tensor).
        cfa: CFA pattern (e.g. ``'RGGB'``) to split the mosaic into its sub-images; None for monochrome.
        black_level_dn: subtracted first (y is the signal above black).
        white_level_dn: blocks touching it (or 0 DN) are left out as clipped.
        levels: number of level sets (quantiles of the block means).

    Returns:
        ``{'a': K in DN/e-, 'b': DN^2, 'conversion_gain_dn_per_e': a, 'read_noise_dn': sqrt(b),
        'read_noise_e': sqrt(b) / a, 'a_standard_error', 'b_standard_error', 'fit_chi2_per_dof' (the line through
        the levels' variances, each with its sampling variance 2 v^2 / n), 'levels': [(mean DN, variance DN^2,
        blocks)], 'warnings': [...]}`` (a negative b gives read noise 0, with a warning). Warned: a narrow signal
        range (a's standard error over 5 %), variance the line does not hold (chi^2 per degree of freedom over 3:
        texture biases a high, up to several times on natural photographs: a flat-field or smooth frame is what
        this estimate is for), a poorly determined b, a frame clipped at 0 DN, and a saturation pile-up at the
        frame's largest values taken as the white level when ``white_level_dn`` is None or above it.
    """
    z = np.asarray(raw.detach().cpu() if hasattr(raw, "detach") else raw, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"raw: expected one 2-D mosaic (H, W), got shape {z.shape}")
    if not np.isfinite(z).all():
        raise ValueError("raw: expected finite DN values")
    # (a NaN white level silently turned off the exclusion of clipped blocks; NaN black gave a misleading error)
    for name, v in (("black_level_dn", black_level_dn), ("white_level_dn", white_level_dn)):
        if v is not None and not is_real(v):
            raise ValueError(f"{name}: expected a finite number of DN, got {v!r}")
    for name, v, lo in (("levels", levels, 2), ("min_blocks", min_blocks, 1)):
        if not (is_integer(v) and v >= lo):
            raise ValueError(f"{name}: expected an integer >= {lo}, got {v!r}")
    if cfa is None:
        planes = [z]
    else:
        from .cfa import CFA

        ph, pw = CFA(str(cfa)).shape
        planes = [z[dy::ph, dx::pw] for dy in range(ph) for dx in range(pw)]
    if min(min(p.shape) for p in planes) < 2:  # (an empty or 1 x 1 frame crashed in NumPy's min / pad)
        raise ValueError(f"raw: expected a mosaic with at least one 2 x 2 block per colour plane, got shape "
                         f"{z.shape}")
    low_clipped = bool(z.min() == 0)  # a frame clipped at 0 DN has no negative values and some at 0
    warnings = []
    # a frame that saturates piles its clipped pixels on its largest values; counted as bright noise-free levels
    # they pulled a down (0.25 for 0.5 with 23 % saturated, through the CLI, which has no white level for a PNG or
    # .npy frame; 0.49 for 2.0 from a DNG whose WhiteLevel, 65535, is above where the sensor clips, 4095)
    plateau = _saturation_plateau(z)
    if plateau is not None and (white_level_dn is None or plateau < white_level_dn):
        n = int((z >= plateau).sum())
        given = "" if white_level_dn is None else f", below the given white level {white_level_dn:g} DN"
        warnings.append(f"{n} pixels ({100 * n / z.size:.3g} %) pile up at the frame's largest values, {plateau:g} "
                        f"DN and up{given}: taken as its white level (saturated) and left out")
        white_level_dn = plateau
    bump = _saturation_bump(z, max(32, 1e-3 * z.size)) if plateau is None and _bump else None
    given_white = white_level_dn

    def _without_bump() -> dict:
        return estimate_poisson_gaussian(raw, cfa=cfa, black_level_dn=black_level_dn, white_level_dn=given_white,
                                         levels=levels, min_blocks=min_blocks, _bump=False)
    if bump is not None and (white_level_dn is None or bump[0] < white_level_dn):
        white_level_dn = bump[0]  # left out for the fit; kept below if its variance says it is clipped
    else:
        bump = None
    means, details, laps = [], [], []
    for p in planes:
        m, d, lap = _blocks(p)
        ok = np.ones(m.shape, dtype=bool)
        if low_clipped:  # leaving out blocks by their noisy values would bias the variance: only where clipped
            ok &= _blocks((p <= 0).astype(np.float64))[0] == 0
        if white_level_dn is not None:
            ok &= _blocks((p >= white_level_dn).astype(np.float64))[0] == 0
        ok[[0, -1], :] = False  # the Laplacian needs all four neighbours
        ok[:, [0, -1]] = False
        means.append(m[ok] - black_level_dn)
        details.append(d[ok])
        laps.append(lap[ok])
    m, d, lap = np.concatenate(means), np.concatenate(details), np.concatenate(laps)
    if m.size < 2 * min_blocks:
        if bump is not None:  # (the bump was most of the frame: a uniform one, not a clip)
            return _without_bump()
        raise ValueError(f"raw: only {m.size} unclipped 2 x 2 blocks; need at least {2 * min_blocks}")

    def fit(sel):
        pts = _levels(m[sel], d[sel], levels, min_blocks)
        if len(pts) < 2:
            raise ValueError(f"raw: fewer than 2 signal levels with {min_blocks} blocks each; the fit needs a range "
                             f"of signal (a uniform frame cannot separate a from b)")
        return pts, _fit(pts)

    try:  # (with a bump left out, a frame that was mostly the bump has too few levels: not a clip)
        pts, (a, b) = fit(np.ones(m.shape, dtype=bool))
        # smooth blocks only (Foi et al. 2008 section 3.1 use an edge detector): the Laplacian of the block means has
        # variance sigma^2 / 4 x 5 / 4 where the signal is locally planar; edges and texture exceed 3 of its std
        for _ in range(2):
            noise_var = np.maximum(a * m + b, 1e-12)
            smooth = np.abs(lap) < 3 * np.sqrt(noise_var * 5 / 16)
            if low_clipped:  # blocks within 3 noise sigmas of the clip at 0 DN: their noise is truncated (a
                # +27..42 % on a dark photograph with no pedestal, read noise -45 %, when only blocks holding a 0 were
                # left out)
                smooth &= m + black_level_dn > 3 * np.sqrt(noise_var)
            pts, (a, b) = fit(smooth)
    except ValueError:
        if bump is None:
            raise
        return _without_bump()
    if bump is not None:
        # a clipped pile-up keeps the read noise after the clip only; a bright patch the shot noise of its level too
        # (clipped at 25 % of the pixels, the bump read as a bright noise-free level took a to 0.155 for 0.4)
        expected = a * (bump[1] - black_level_dn) + b
        if not (a > 0 and bump[2] < 0.5 * expected):
            return _without_bump()
        n = int((z >= bump[0]).sum())
        warnings.append(f"{n} pixels ({100 * n / z.size:.3g} %) form a pile-up below the frame's largest value, "
                        f"{bump[0]:g} DN and up (mode {bump[1]:g} DN, variance {bump[2]:.3g} DN^2 where the noise at "
                        f"that level would be {expected:.3g}): taken as its white level (saturated) and left out")
    se_a, se_b, chi2 = _fit_quality(pts, a, b)
    zeros = int((z == 0).sum()) if low_clipped else 0
    # (a dead pixel or two at 0 DN is no clipped frame; nor are dead pixels under a pedestal)
    if zeros >= max(32, 1e-3 * z.size) and black_level_dn < 3 * math.sqrt(max(b, 1.0)):
        warnings.append(f"the frame is clipped at 0 DN (no pedestal; {zeros} pixels at 0): blocks within 3 noise "
                        f"sigmas of 0 DN are left out and the read noise is extrapolated from brighter levels")
    elif zeros:
        warnings.append(f"{zeros} pixels at 0 DN under a black level of {black_level_dn:g} DN (dead pixels?): their "
                        f"blocks are left out")
    if a > 0 and se_a > 0.05 * a:
        warnings.append(f"the signal levels span too narrow a range to separate a from b: a = {a:.4g} +- {se_a:.2g} "
                        f"DN/e- (a frame with a range of brightness, e.g. a gradient, separates them)")
    if chi2 > 3:  # (for ~20 levels, a chi^2 per degree of freedom above 3 has a probability under 1e-5)
        warnings.append(f"the level variances depart from a line by {chi2:.3g} times their sampling variance: texture "
                        f"or edges that the 2 x 2 details do not cancel add variance, so a and the read noise are "
                        f"biased high (x1.2-3 on natural photographs in an audit); a flat-field or smooth frame, or a "
                        f"calibration capture (isettorch calibrate DIR), is reliable")
    if b > 0 and se_b > 0.5 * b:
        warnings.append(f"the signal-independent variance is poorly determined, b = {b:.4g} +- {se_b:.2g} DN^2 (few "
                        f"dark levels: it is extrapolated from {float(np.min([p[0] for p in pts])):.4g} DN up)")
    if b < 0:  # a black level below the frame's by d DN moves the intercept to b - a d (Foi et al. eq. 3 at y + d)
        cause = ("a signal range too narrow to separate a from b (above), or " if a > 0 and se_a > 0.05 * a else "") \
            + ("texture (above), or " if chi2 > 3 else "") + f"a black level ({black_level_dn:g} DN) below the frame's"
        warnings.append(f"the fitted signal-independent variance b = {b:.4g} DN^2 is negative, so read_noise_dn and "
                        f"read_noise_e are reported as 0; its cause may be {cause} (d DN too low moves b by -a d)")
    # A black level d DN above the frame's moves b by +a d (the other way round from the negative b above) and
    # leaves the darkest levels below 0. Block means of pure read noise (a 4-pixel mean has sigma / 2) lie within
    # 1.45 of their pixels' sigmas below black in the darkest of 48 levels (360 frames, 95 % dark); more than 3 below,
    # the black level is wrong (500 DN for a frame at 64 gave b = 436 for 4, with no warning).
    y_low, v_low = min(pts, key=lambda q: q[0])[:2]
    if y_low < -3 * math.sqrt(max(v_low, 0.0)):
        warnings.append(f"black_level_dn = {black_level_dn:g} DN is above the frame's black: its darkest level lies "
                        f"{-y_low:.4g} DN below it, where its noise ({math.sqrt(max(v_low, 0.0)):.3g} DN) allows "
                        f"3 sigma; d DN too high moves b by +a d, so b, read_noise_dn and read_noise_e are "
                        f"biased high")
    if not a > 0:
        warnings.append(f"the fitted slope a = {a:.4g} DN/e- is not positive: no conversion gain; read_noise_e is "
                        f"null")
    return {"a": a, "b": b, "conversion_gain_dn_per_e": a, "read_noise_dn": math.sqrt(max(b, 0.0)),
            "read_noise_e": math.sqrt(max(b, 0.0)) / a if a > 0 else None,
            "a_standard_error": se_a, "b_standard_error": se_b, "fit_chi2_per_dof": chi2,
            "levels": [list(p) for p in pts], "method": "Foi et al. 2008 Poisson-Gaussian fit", "warnings": warnings}
