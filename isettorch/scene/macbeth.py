"""The Macbeth ColorChecker (24 patches, BabelColor average reflectances) as a scene."""

from __future__ import annotations

import functools

import numpy as np
import torch

from .. import spectral
from ._common import (
    DEFAULT_DISTANCE_M,
    DEFAULT_HFOV_DEG,
    DEFAULT_MEAN_LUMINANCE_CD_M2,
    check_float,
    check_int,
    finish,
    illuminant_energy,
    resolve_grid,
)
from .scene import Scene

__all__ = ["macbeth", "macbeth_reflectances", "macbeth_patch_names", "macbeth_patch_slices"]

MACBETH_ROWS, MACBETH_COLS = 4, 6
_SOURCE = "BabelColor Average"


@functools.cache
def _native_reflectances() -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    import colour

    # Pascale, "RGB coordinates of the Macbeth ColorChecker" (BabelColor, 2006): mean of 30 charts,
    # 380-730 nm at 10 nm, as shipped by colour-science.
    sds = colour.characterisation.SDS_COLOURCHECKERS[_SOURCE]
    names = tuple(sds.keys())
    first = sds[names[0]]
    w = np.asarray(first.wavelengths, float)
    values = np.stack([np.asarray(sds[n].values, float) for n in names])
    for n in names:
        if not np.array_equal(np.asarray(sds[n].wavelengths, float), w):  # pragma: no cover - data sanity
            raise RuntimeError(f"colour-science {_SOURCE}: patch {n!r} has a different wavelength grid")
    return names, w, values


def macbeth_patch_names() -> list[str]:
    """The 24 patch names in the standard order (row-major, 'dark skin' top-left, 'black' bottom-right; ISETCam
    numbers the patches down the columns instead, its white patch 4 being index 18 here)."""
    return list(_native_reflectances()[0])


def macbeth_reflectances(wavelengths=None, *, dtype=None, device=None) -> torch.Tensor:
    """Reflectances [24, L] of the ColorChecker patches (BabelColor average) on a wavelength grid.

    The data (380-730 nm, 10 nm) are interpolated linearly; outside 380-730 nm the end values are held
    (colour-science's default constant extrapolation), since a reflectance does not drop to 0 there.

    Example:
        >>> macbeth_reflectances().shape
        torch.Size([24, 31])
    """
    w = resolve_grid(wavelengths, dtype, device)
    _, src, vals = _native_reflectances()
    out = spectral.resample_held(torch.from_numpy(vals), torch.from_numpy(src), w.detach().cpu())
    return out.to(dtype=w.dtype, device=w.device)


def macbeth_patch_slices(patch_size: int = 16, *, fraction: float = 0.5) -> list[tuple[slice, slice]]:
    """Central (rows, cols) slices of the 24 patches of :func:`macbeth` with ``patch_size``, standard order.

    Each window is the centred ``fraction`` of the patch (at least 1 pixel), away from the patch borders,
    for measuring a patch's mean value in a rendered, blurred or demosaicked chart.
    """
    p = check_int(patch_size, "patch_size")
    frac = check_float(fraction, "fraction", low=0.0, high=1.0, low_open=True)
    n = max(1, round(p * frac))
    start = (p - n) // 2
    out = []
    for r in range(MACBETH_ROWS):
        for c in range(MACBETH_COLS):
            out.append((slice(r * p + start, r * p + start + n), slice(c * p + start, c * p + start + n)))
    return out


def macbeth(illuminant="D65", patch_size: int = 16, wavelengths=None, *,
            mean_luminance_cd_m2: float | None = DEFAULT_MEAN_LUMINANCE_CD_M2, hfov_deg=DEFAULT_HFOV_DEG,
            distance_m=DEFAULT_DISTANCE_M, dtype=None, device=None) -> Scene:
    """Macbeth ColorChecker scene: 4 x 6 patches of ``patch_size`` pixels, 'dark skin' top-left.

    Radiance = reflectance x illuminant (photons), scaled to ``mean_luminance_cd_m2``; the scene carries
    ``illuminant_photons`` so ``scene.reflectance()`` returns the patch reflectances.
    ISETCam: ``sceneCreate('macbeth d65', patchSize)`` (64 x 96 at the default 16 px patches): the same layout,
    patch order and geometry, but not the same reflectances (BabelColor's average, not ISETCam's macbethChart data:
    patch luminances differ by -26 % to +18 % and chromaticities by up to 0.036; ISETCam parity uses the parity
    case's own scene).

    Args:
        illuminant: a name accepted by :func:`isettorch.spectral.illuminant` or an energy SPD tensor [L].
        patch_size: patch width and height (pixels).
        wavelengths: grid [L] (nm); default 400:10:700.

    Returns:
        Scene with photons (1, L, 4 patch_size, 6 patch_size).

    Example:
        >>> s = macbeth(patch_size=4)
        >>> tuple(s.photons.shape), round(s.mean_luminance().item(), 3)
        ((1, 31, 16, 24), 100.0)
    """
    p = check_int(patch_size, "patch_size")
    w = resolve_grid(wavelengths, dtype, device)
    refl = macbeth_reflectances(w)  # [24, L]
    ill_p = spectral.energy_to_photons(illuminant_energy(illuminant, w), w, dim=0)
    # factored: 24 patch indicator maps x (reflectance x illuminant) spectra
    n = MACBETH_ROWS * MACBETH_COLS
    cells = torch.eye(n, dtype=w.dtype, device=w.device).reshape(n, MACBETH_ROWS, MACBETH_COLS)
    maps = cells.repeat_interleave(p, dim=1).repeat_interleave(p, dim=2).unsqueeze(0)  # [1, 24, 4p, 6p]
    spectra = (refl * ill_p[None, :]).unsqueeze(0)  # [1, 24, L]
    name = f"macbeth {illuminant}" if isinstance(illuminant, str) else "macbeth"
    return finish((maps, spectra), w, hfov_deg=hfov_deg, distance_m=distance_m,
                  mean_luminance_cd_m2=mean_luminance_cd_m2,
                  illuminant_photons=ill_p, name=name,
                  metadata={"patch_size": p, "reflectance_source": f"colour-science {_SOURCE}"})
