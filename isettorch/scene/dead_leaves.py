"""Dead leaves (spilled coins) texture scene: occluding random disks with power-law radii."""

from __future__ import annotations

import math

import numpy as np
import torch

from .. import spectral
from .._checks import check_seed
from ._common import (
    DEFAULT_DISTANCE_M,
    DEFAULT_HFOV_DEG,
    DEFAULT_MEAN_LUMINANCE_CD_M2,
    check_float,
    check_int,
    check_size,
    finish,
    illuminant_energy,
    resolve_grid,
)
from .macbeth import macbeth_reflectances
from .scene import Scene

__all__ = ["dead_leaves", "sample_power_law_radii", "expected_disk_area_px2", "max_disks_for"]

_CHUNK = 4096  # disks drawn per call to the generator
_MAX_DEFAULT_DISKS = 20_000_000  # the most disks an image may need by default (drawn to 2-4x that: minutes)


def sample_power_law_radii(n: int, alpha: float, rmin_px: float, rmax_px: float,
                           generator: torch.Generator) -> torch.Tensor:
    """``n`` radii [n] (float64) with density proportional to ``r ** -alpha`` on [rmin, rmax], by inverse CDF."""
    u = torch.rand(n, generator=generator, dtype=torch.float64)
    if abs(alpha - 1.0) < 1e-12:
        return rmin_px * (rmax_px / rmin_px) ** u
    e = 1.0 - alpha
    try:
        lo, hi = rmin_px**e, rmax_px**e
    except OverflowError:  # rmin^(1 - alpha) beyond a float (alpha 200, rmin 0.01)
        lo = hi = 0.0
    if lo > 0 and hi > 0 and math.isfinite(lo) and math.isfinite(hi):
        r = (lo + u * (hi - lo)) ** (1.0 / e)
    else:  # beyond a float or under it (alpha 100, rmin 3000: 0 ** (1 / e) had given inf radii): relative to rmin
        r = rmin_px * (1.0 + u * ((rmax_px / rmin_px) ** e - 1.0)) ** (1.0 / e)
    # (rounding near alpha = 1 had reached 3e-5 beyond rmax)
    return r.clamp(rmin_px, rmax_px)


def _leaf_labels(rows: int, cols: int, *, alpha: float, rmin: float, rmax: float, num_disks: int | None,
                 max_disks: int | None, generator: torch.Generator):
    """Index of the front-most disk at each pixel [H, W] (-1 if none), and the disks' centres and radii.

    Disks are drawn front to back (Lee, Mumford & Huang 2001): a pixel shows the first disk that covers its
    centre, so later disks only fill what is still uncovered. Centres are uniform on the image extended by rmax
    on every side, so every disk that can reach the image is drawn with the same probability. Each disk only
    touches its bounding box, so the cost is the total disk area, not disks x pixels.
    """
    labels = np.full((rows, cols), -1, dtype=np.int64)
    uncovered = rows * cols
    centres, radii = [], []
    drawn = 0
    limit = max_disks if num_disks is None else num_disks
    while drawn < limit and uncovered > 0:
        k = min(_CHUNK, limit - drawn)
        c = torch.rand(k, 2, generator=generator, dtype=torch.float64)
        cx = -rmax + c[:, 0] * (cols - 1 + 2 * rmax)
        cy = -rmax + c[:, 1] * (rows - 1 + 2 * rmax)
        r = sample_power_law_radii(k, alpha, rmin, rmax, generator)
        centres.append(torch.stack([cy, cx], dim=1))
        radii.append(r)
        for j, (y0, x0, rj) in enumerate(zip(cy.tolist(), cx.tolist(), r.tolist())):
            r0, r1 = max(0, math.ceil(y0 - rj)), min(rows - 1, math.floor(y0 + rj))
            c0, c1 = max(0, math.ceil(x0 - rj)), min(cols - 1, math.floor(x0 + rj))
            if r0 > r1 or c0 > c1:
                continue
            yy = (np.arange(r0, r1 + 1) - y0)[:, None]
            xx = (np.arange(c0, c1 + 1) - x0)[None, :]
            sub = labels[r0:r1 + 1, c0:c1 + 1]
            new = (yy * yy + xx * xx <= rj * rj) & (sub < 0)
            n_new = int(new.sum())
            if n_new:
                sub[new] = drawn + j
                uncovered -= n_new
                if uncovered == 0 and num_disks is None:
                    k = j + 1  # every later disk would be hidden
                    break
        drawn += k
    centres, radii = torch.cat(centres)[:drawn], torch.cat(radii)[:drawn]
    return torch.from_numpy(labels), centres, radii


def dead_leaves(size=128, *, alpha: float = 3.0, rmin_px: float = 1.0, rmax_px: float | None = None,
                reflectances="gray", reflectance_range: tuple[float, float] = (0.05, 0.95),
                num_disks: int | None = None, max_disks: int | None = None, batch_size: int = 1, seed: int | None = 0,
                generator: torch.Generator | None = None, illuminant="D65", wavelengths=None,
                mean_luminance_cd_m2=DEFAULT_MEAN_LUMINANCE_CD_M2, hfov_deg=DEFAULT_HFOV_DEG,
                distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """Dead leaves texture: opaque disks, radius density ``r ** -alpha`` on [rmin_px, rmax_px], occluding.

    Scale-invariant for ``alpha = 3`` (Lee, Mumford & Huang, IJCV 2001; Cao, Guichard & Hornung, "Dead leaves
    model for measuring texture quality", SPIE 2010; IEEE 1858 / ISO 19567-2 texture chart).

    Args:
        size: rows and cols, or (rows, cols).
        alpha: radius power-law exponent (> 0).
        rmin_px, rmax_px: radius range in pixels (default rmax = min(H, W) / 2).
        reflectances: ``"gray"`` (spectrally flat, level uniform in ``reflectance_range``), ``"macbeth"``
            (one of the 24 ColorChecker reflectances, uniformly), or a tensor [N, L] of reflectances on
            ``wavelengths`` to draw from uniformly.
        num_disks: draw exactly this many disks (pixels left uncovered take reflectance 0); default: draw until
            every pixel is covered (at most ``max_disks``, default the image's expected need, :func:`max_disks_for`,
            with margin; a ValueError naming it if pixels are left: a 512-pixel image left 347 of them black at
            the 200,000 disks this was).
        batch_size: independent samples, drawn one after another from the same generator.
        seed, generator: randomness; a ``generator`` takes precedence, else ``torch.Generator().manual_seed(seed)``.

    Returns:
        Scene (batch_size, L, H, W); ``metadata["labels"]`` [B, H, W] is the visible disk at each pixel (-1: none),
        ``metadata["radii_px"]`` / ``["centres_px"]`` lists of the disks (row, col) of each sample, front first.

    Example:
        >>> s = dead_leaves(32, seed=1)
        >>> bool((s.metadata["labels"] >= 0).all()), round(s.mean_luminance().item(), 3)
        (True, 100.0)
    """
    rows, cols = check_size(size)
    a = check_float(alpha, "alpha", low=0.0, low_open=True)
    rmin = check_float(rmin_px, "rmin_px", low=0.0, low_open=True)
    rmax = min(rows, cols) / 2 if rmax_px is None else check_float(rmax_px, "rmax_px", low=0.0, low_open=True)
    if rmax < rmin:
        if rmax_px is None:  # (it named rmax_px, an argument the caller never gave)
            raise ValueError(f"size: a {rows} x {cols} image's default rmax_px, min(H, W) / 2 = {rmax:g}, is below "
                             f"rmin_px ({rmin:g}); pass rmax_px, or a smaller rmin_px")
        raise ValueError(f"rmax_px: expected rmax_px >= rmin_px ({rmin}), got {rmax}")
    if num_disks is not None:
        num_disks = check_int(num_disks, "num_disks")
    if max_disks is not None:
        max_disks = check_int(max_disks, "max_disks")
    elif num_disks is None:  # until covered: the image's own bound (with num_disks, exactly that many are drawn)
        need = _disks_per_cover(rows, cols, a, rmin, rmax) * math.log(rows * cols)  # the expected need (Boolean)
        if need > _MAX_DEFAULT_DISKS:  # (it would run for hours)
            raise ValueError(f"rmin_px, alpha: disks of {rmin:g} to {rmax:g} px with exponent {a:g} are too small to "
                             f"cover a {rows} x {cols} image (about {need:.3g} needed); raise rmin_px or lower alpha, "
                             f"or pass max_disks to draw that many anyway")
        max_disks = max_disks_for(rows, cols, a, rmin, rmax)
    b = check_int(batch_size, "batch_size")
    if generator is None:
        if seed is None:
            raise ValueError("seed: expected an int seed or a torch.Generator (randomness must be explicit), got None")
        generator = torch.Generator().manual_seed(check_seed(seed))  # ([0, 2^64): 2^64 overflowed, unnamed)
    elif not isinstance(generator, torch.Generator):
        raise TypeError(f"generator: expected a torch.Generator, got {type(generator).__name__}")
    if generator.device.type != "cpu":
        raise ValueError(f"generator: expected a CPU torch.Generator (sampling runs on CPU), got {generator.device}")
    w = resolve_grid(wavelengths, dtype, device)
    try:
        pair = not isinstance(reflectance_range, (str, bytes)) and len(reflectance_range) == 2
    except TypeError:  # (no length: a number)
        pair = False
    if not pair:  # (a one-value list failed in tuple unpacking, naming nothing)
        raise ValueError(f"reflectance_range: expected (low, high), got {reflectance_range!r}")
    lo, hi = (check_float(v, f"reflectance_range[{i}]", low=0.0, high=1.0) for i, v in enumerate(reflectance_range))
    if hi < lo:
        raise ValueError(f"reflectance_range: expected (low, high) with low <= high, got {reflectance_range}")
    if hi == 0 and reflectances == "gray" and mean_luminance_cd_m2 is not None:  # (read "zero luminance on this
        # wavelength grid")
        raise ValueError(f"reflectance_range: {reflectance_range} makes every leaf black, which cannot be scaled to "
                         f"mean_luminance_cd_m2; expected a positive high end (or mean_luminance_cd_m2=None)")

    if isinstance(reflectances, str):
        if reflectances == "gray":
            refl_set = None
        elif reflectances == "macbeth":
            refl_set = macbeth_reflectances(w.double().cpu(), dtype=torch.float64)
        else:
            raise ValueError(f"reflectances: expected 'gray', 'macbeth' or a tensor [N, L], got {reflectances!r}")
    elif isinstance(reflectances, torch.Tensor):
        refl_set = reflectances.detach().to(device="cpu", dtype=torch.float64)
        if refl_set.dim() != 2 or refl_set.shape[1] != w.numel() or refl_set.shape[0] < 1:
            raise ValueError(f"reflectances: expected a tensor [N, {w.numel()}] (one reflectance per row on the "
                             f"wavelength grid), got shape {tuple(reflectances.shape)}")
        if not torch.isfinite(refl_set).all() or (refl_set < 0).any():
            raise ValueError("reflectances: expected finite, non-negative reflectances")
    else:
        raise TypeError(f"reflectances: expected 'gray', 'macbeth' or a tensor [N, L], got "
                        f"{type(reflectances).__name__}")

    # factored: gray leaves are rank 1 (level map x illuminant); leaves drawn from N reflectances are rank N
    # (one indicator map per reflectance x that reflectance times the illuminant)
    maps_all, labels_all, radii_all, centres_all = [], [], [], []
    for _ in range(b):
        labels, centres, radii = _leaf_labels(rows, cols, alpha=a, rmin=rmin, rmax=rmax, num_disks=num_disks,
                                              max_disks=max_disks, generator=generator)
        left = int((labels < 0).sum())
        if num_disks is None and left:
            raise ValueError(f"max_disks: {max_disks} disks left {left} of {rows * cols} pixels uncovered; raise "
                             f"max_disks (or pass num_disks to draw exactly that many, uncovered pixels black)")
        n = radii.numel()
        if refl_set is None:
            levels = lo + (hi - lo) * torch.rand(n, generator=generator, dtype=torch.float64)
            maps_all.append(torch.cat([levels, levels.new_zeros(1)])[labels][None])  # label -1: uncovered, 0
        else:
            pick = torch.randint(refl_set.shape[0], (n,), generator=generator)
            which = torch.cat([pick, pick.new_full((1,), -1)])[labels]  # reflectance index per pixel, -1 none
            maps_all.append(which[None] == torch.arange(refl_set.shape[0])[:, None, None])
        labels_all.append(labels)
        radii_all.append(radii)
        centres_all.append(centres)
    maps = torch.stack(maps_all).to(dtype=w.dtype, device=w.device)  # [B, J, H, W]
    ill_p = spectral.energy_to_photons(illuminant_energy(illuminant, w), w, dim=0)
    refl_rows = torch.ones(1, w.numel(), dtype=torch.float64) if refl_set is None else refl_set
    spectra = (refl_rows.to(dtype=w.dtype, device=w.device) * ill_p[None, :]).expand(b, -1, -1)
    photons = (maps, spectra)
    meta = {"labels": torch.stack(labels_all), "radii_px": radii_all, "centres_px": centres_all, "alpha": a,
            "rmin_px": rmin, "rmax_px": rmax,
            "uncovered_fraction": [float((lab < 0).double().mean()) for lab in labels_all]}
    return finish(photons, w, hfov_deg=hfov_deg, distance_m=distance_m, mean_luminance_cd_m2=mean_luminance_cd_m2,
                  illuminant_photons=ill_p, name="dead leaves", metadata=meta)


def expected_disk_area_px2(alpha: float, rmin_px: float, rmax_px: float) -> float:
    """E[pi r^2] (px^2) for the power-law radius density ``r ** -alpha`` on [rmin, rmax] (closed form; pi r^2 for
    equal radii, which divided by zero)."""
    if rmax_px == rmin_px:
        return math.pi * rmin_px**2
    ratio = rmax_px / rmin_px

    def integral(p):  # int_1^ratio x^p dx, x = r / rmin (rmin^(p + 1) itself overflowed for alpha 200, rmin 0.01)
        if abs(p + 1) < 1e-12:
            return math.log(ratio)
        return (ratio ** (p + 1) - 1.0) / (p + 1)

    return math.pi * rmin_px**2 * integral(2 - alpha) / integral(-alpha)


def max_disks_for(rows: int, cols: int, alpha: float, rmin_px: float, rmax_px: float) -> int:
    """How many disks :func:`dead_leaves` draws at most to cover a ``rows x cols`` image: the disks whose centres
    fall on the image extended by ``rmax`` (where they are drawn) needed to cover each point ``ln(pixels) + 20`` times
    on average, so every pixel is covered unless with probability about ``exp(-20)`` per image (a Boolean model:
    a point stays uncovered by N disks with probability exp(-N E[area] / extended area)); at least 200,000."""
    return max(200_000, math.ceil(_disks_per_cover(rows, cols, alpha, rmin_px, rmax_px) * (math.log(rows * cols) + 20)))


def _disks_per_cover(rows: int, cols: int, alpha: float, rmin_px: float, rmax_px: float) -> float:
    """Disks drawn per mean cover of a point: the extended area the centres fall on over a disk's expected area."""
    return (rows + 2 * rmax_px) * (cols + 2 * rmax_px) / expected_disk_area_px2(alpha, rmin_px, rmax_px)
