"""Shared argument handling for the scene generators (grids, sizes, illuminants, final scaling)."""

from __future__ import annotations

import numbers

import torch

from .. import spectral
from .._checks import as_tensor, check_finite, check_rank, check_wavelengths
from ..image import SpectralFactors
from .scene import Scene

# ISETCam defaults (sceneCreate): 10 deg field of view, 1.2 m distance, 100 cd/m^2 mean luminance.
DEFAULT_HFOV_DEG = 10.0
DEFAULT_DISTANCE_M = 1.2
DEFAULT_MEAN_LUMINANCE_CD_M2 = 100.0


def resolve_dtype(dtype, wavelengths=None) -> torch.dtype:
    """A scene's dtype: ``dtype``, else the wavelengths' floating dtype, else torch's default; float32 or float64."""
    name = "dtype"
    if dtype is not None:
        if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
            raise TypeError(f"dtype: expected a floating torch.dtype, got {dtype!r}")
    elif isinstance(wavelengths, torch.Tensor) and wavelengths.is_floating_point():
        dtype, name = wavelengths.dtype, "wavelengths (the scene's dtype)"
    else:
        dtype, name = torch.get_default_dtype(), "torch.get_default_dtype() (the scene's dtype)"
    if dtype.itemsize < 4:  # (named as 'spectra: expected finite values, found 744 NaN/Inf entries')
        raise ValueError(f"{name}: expected torch.float32 or torch.float64, got {dtype}: a radiance of about 1e16 "
                         f"photons/s/sr/m^2/nm overflows float16, and bfloat16 rounds the wavelengths (550 nm to "
                         f"552)")
    return dtype


def resolve_grid(wavelengths, dtype=None, device=None) -> torch.Tensor:
    """The wavelength grid [L] (nm) in ``dtype`` on ``device``; ``None`` gives ISETCam's 400:10:700."""
    dtype = resolve_dtype(dtype, wavelengths)
    if wavelengths is None:
        return spectral.default_wavelengths(dtype=dtype, device=device)
    w = check_wavelengths(as_tensor(wavelengths, "wavelengths", dtype=torch.float64), "wavelengths")
    return w.to(dtype=dtype, device=device)


def check_int(value, name: str, minimum: int = 1) -> int:
    """An integer argument >= ``minimum`` (bools and non-integral floats are rejected)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise TypeError(f"{name}: expected an integer, got {type(value).__name__} ({value!r})")
    value = int(value)
    if value < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value}")
    return value


def check_size(size, name: str = "size", minimum: int = 1) -> tuple[int, int]:
    """``size`` as (rows, cols): an int gives a square image."""
    if isinstance(size, (tuple, list)):
        if len(size) != 2:
            raise ValueError(f"{name}: expected an int or a (rows, cols) pair, got {size!r}")
        return check_int(size[0], f"{name}[0]", minimum), check_int(size[1], f"{name}[1]", minimum)
    n = check_int(size, name, minimum)
    return n, n


def check_float(value, name: str, *, low: float | None = None, high: float | None = None,
                low_open: bool = False, high_open: bool = False) -> float:
    """A finite real scalar within optional bounds."""
    if isinstance(value, torch.Tensor):
        if value.numel() != 1:
            raise ValueError(f"{name}: expected a scalar, got shape {tuple(value.shape)}")
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__} ({value!r})")
    v = float(value)
    if v != v or v in (float("inf"), float("-inf")):
        raise ValueError(f"{name}: expected a finite number, got {v}")
    if low is not None and (v < low or (low_open and v == low)):
        raise ValueError(f"{name}: expected a value {'>' if low_open else '>='} {low}, got {v}")
    if high is not None and (v > high or (high_open and v == high)):
        raise ValueError(f"{name}: expected a value {'<' if high_open else '<='} {high}, got {v}")
    return v


def illuminant_energy(illuminant, w: torch.Tensor, name: str = "illuminant") -> torch.Tensor:
    """Relative energy SPD [L] on grid ``w`` from a name (see :func:`spectral.illuminant`) or a tensor [L]."""
    if isinstance(illuminant, str):
        try:
            return spectral.illuminant(illuminant, w, dtype=w.dtype, device=w.device)
        except ValueError as err:
            raise ValueError(f"{name}: {err}") from err
    if not isinstance(illuminant, torch.Tensor):
        raise TypeError(f"{name}: expected an illuminant name (str) or an energy SPD tensor [L], "
                        f"got {type(illuminant).__name__}")
    spd = illuminant.to(dtype=w.dtype, device=w.device)
    check_rank(spd, 1, name, f"[L] with L = {w.numel()}")
    if spd.numel() != w.numel():
        raise ValueError(f"{name}: expected an SPD of {w.numel()} samples (one per wavelength), got {spd.numel()}")
    check_finite(spd.detach(), name)
    if (spd.detach() < 0).any():
        raise ValueError(f"{name}: expected a non-negative SPD, minimum is {spd.min().item():.6g}")
    if not (spd.detach() > 0).any():
        raise ValueError(f"{name}: the SPD is zero everywhere")
    return spd


def finish(photons, w: torch.Tensor, *, hfov_deg, distance_m, mean_luminance_cd_m2,
           illuminant_photons: torch.Tensor | None = None, name: str = "", metadata: dict | None = None) -> Scene:
    """Wrap radiance in a `Scene` and scale it to ``mean_luminance_cd_m2`` (None: as is).

    ``photons``: a dense ``[B, L, H, W]`` tensor, or ``(maps [B, J, H, W], spectra [B, J, L])`` for a factored
    scene (:meth:`Scene.from_factors`).
    """
    if isinstance(photons, tuple):
        factors, photons = SpectralFactors(*photons), None
    else:
        factors = None
    scene = Scene(photons, w, factors=factors, name=name, metadata=dict(metadata or {}), hfov_deg=hfov_deg,
                  distance_m=distance_m,
                  illuminant_photons=illuminant_photons)
    if mean_luminance_cd_m2 is None:
        return scene
    target = as_tensor(mean_luminance_cd_m2, "mean_luminance_cd_m2", dtype=scene.dtype, device=scene.device)
    check_finite(target, "mean_luminance_cd_m2")
    if (target <= 0).any():
        raise ValueError(f"mean_luminance_cd_m2: expected a positive luminance (or None), got {target.tolist()}")
    if (scene.mean_luminance().detach() <= 0).any():
        raise ValueError(f"{name or 'scene'}: the radiance has zero luminance on this wavelength grid "
                         f"({w[0].item():g}..{w[-1].item():g} nm), it cannot be scaled to "
                         f"mean_luminance_cd_m2={target.tolist()}; pass mean_luminance_cd_m2=None")
    return scene.set_mean_luminance(target, name="mean_luminance_cd_m2")


def pattern_scene(pattern: torch.Tensor, illuminant, w: torch.Tensor, *, hfov_deg, distance_m,
                  mean_luminance_cd_m2, name: str, metadata: dict | None = None) -> Scene:
    """A spectrally neutral pattern (relative reflectance [H, W] or [B, H, W]) lit by ``illuminant``."""
    if pattern.dim() == 2:
        pattern = pattern.unsqueeze(0)
    ill_e = illuminant_energy(illuminant, w)
    ill_p = spectral.energy_to_photons(ill_e, w, dim=0)
    # rank 1: the pattern's map x the illuminant's spectrum
    return finish((pattern[:, None], ill_p.reshape(1, 1, -1)), w, hfov_deg=hfov_deg, distance_m=distance_m,
                  mean_luminance_cd_m2=mean_luminance_cd_m2,
                  illuminant_photons=ill_p, name=name, metadata=metadata)


def pixel_coords(rows: int, cols: int, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Coordinates (y, x) [H, W] in pixels relative to the image centre ((n - 1) / 2); y grows downwards."""
    y = torch.arange(rows, dtype=dtype, device=device) - (rows - 1) / 2
    x = torch.arange(cols, dtype=dtype, device=device) - (cols - 1) / 2
    return torch.meshgrid(y, x, indexing="ij")
