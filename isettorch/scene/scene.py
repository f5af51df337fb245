"""`Scene`: spectral radiance of a planar scene at a distance, in photons/s/sr/m^2/nm."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch

from .. import spectral
from .._checks import as_tensor, check_nonnegative, check_rank
from ..image import SpectralFactors, SpectralImage, angle_for_extent, extent_for_angle


@dataclasses.dataclass(eq=False, repr=False)
class Scene(SpectralImage):
    """Spectral radiance ``photons [B, L, H, W]`` (photons/s/sr/m^2/nm) of a plane at ``distance_m``.

    Args:
        photons: radiance, non-negative and finite; ``[L, H, W]`` is taken as a batch of one.
        wavelengths_nm: grid ``[L]`` (nm), strictly increasing.
        hfov_deg: horizontal field of view (deg), scalar or ``[B]``.
        distance_m: distance of the scene plane (m), scalar or ``[B]``; default 1.2 (ISETCam).
        illuminant_photons: optional ``[B, L]`` (or ``[L]``) radiance of a perfect white under the
            scene's light, in the photons' units (so reflectance = photons / illuminant).

    Example:
        >>> s = Scene(torch.ones(1, 31, 8, 8), torch.arange(400., 701., 10.), hfov_deg=10.0)
        >>> s.sample_spacing_m.shape
        torch.Size([1])
    """

    hfov_deg: torch.Tensor | float = 10.0
    distance_m: torch.Tensor | float = 1.2
    illuminant_photons: torch.Tensor | None = None

    _batch_fields: ClassVar[tuple[str, ...]] = ("hfov_deg", "distance_m")
    _units: ClassVar[str] = "photons/s/sr/m^2/nm"

    def __post_init__(self, validate: bool = True) -> None:
        for name in ("hfov_deg", "distance_m"):  # the geometry needs both (a None would fail later, unnamed)
            if getattr(self, name) is None:
                raise ValueError(f"{name}: expected a positive number or [B] tensor (a scene's geometry needs it), "
                                 "got None")
        super().__post_init__(validate)
        if (self.hfov_deg >= 180).any():
            raise ValueError(f"hfov_deg: expected a field of view below 180 deg, got {self.hfov_deg.tolist()}")
        ill = self.illuminant_photons
        if ill is not None:
            ill = as_tensor(ill, "illuminant_photons", dtype=self.dtype, device=self.device)
            if ill.dim() == 1:
                ill = ill.unsqueeze(0)
            check_rank(ill, 2, "illuminant_photons", "[B, L] or [L]")
            if ill.shape[-1] != self.num_wavelengths or ill.shape[0] not in (1, self.batch_size):
                raise ValueError(
                    f"illuminant_photons: expected shape [{self.batch_size}, {self.num_wavelengths}] (or [L]), "
                    f"got {tuple(ill.shape)}"
                )
            if validate:
                check_nonnegative(ill.detach(), "illuminant_photons")
                self._check_lit(ill.detach().expand(self.batch_size, -1))
            self.illuminant_photons = ill.expand(self.batch_size, -1)

    def _check_lit(self, ill: torch.Tensor) -> None:
        """An illuminant is the light the radiance reflects: some light, and light in every band that holds
        radiance (reflectance = radiance / illuminant gave inf there, and an unlit scene an sRGB preview of NaN)."""
        if not bool((ill > 0).any(dim=-1).all()):
            raise ValueError("illuminant_photons: expected some light (a positive value) in each scene's "
                             "illuminant, got all zeros")
        dark = ill == 0
        if bool(dark.any()):
            peak = (self.factors.spectra.detach().abs().amax(dim=1) if self.factors is not None
                    else self.photons.detach().amax(dim=(2, 3)))  # [B, L]
            bad = dark & (peak > 0)
            if bool(bad.any()):
                b, lam = (int(v) for v in torch.nonzero(bad)[0])
                raise ValueError(f"illuminant_photons: 0 at {float(self.wavelengths_nm[lam]):g} nm (scene {b}), where "
                                 f"the radiance is not: expected light in every band the scene reflects (the "
                                 f"reflectance there would be infinite)")

    def replace(self, **changes) -> Scene:
        """A copy with some fields changed, checked like a new scene (NaN, inf or negative radiance raise).

        ``validate=False`` skips the value checks; the library passes it only for changes derived from
        already-checked data (crops, dtype/device moves, batch selection), where a check would only cost time.
        Changes that touch neither ``photons`` nor ``illuminant_photons`` (metadata, name) check nothing.
        """
        changes.setdefault("validate", any(k in changes for k in ("photons", "factors", "illuminant_photons")))
        return super().replace(**changes)  # keeps the dense/factored bookkeeping of SpectralImage.replace

    # --- geometry ------------------------------------------------------------------------
    @property
    def width_m(self) -> torch.Tensor:
        """Width of the scene plane (m) [B]: 2 d tan(hfov / 2)."""
        return extent_for_angle(self.hfov_deg, self.distance_m)

    @property
    def sample_spacing_m(self) -> torch.Tensor:
        """Spacing of the samples on the scene plane (m) [B]; samples are square."""
        return self.width_m / self.width

    @property
    def height_m(self) -> torch.Tensor:
        return self.sample_spacing_m * self.height

    @property
    def vfov_deg(self) -> torch.Tensor:
        """Vertical field of view (deg) [B]."""
        return angle_for_extent(self.height_m, self.distance_m)

    def crop(self, top: int, left: int, height: int, width: int) -> Scene:
        """A window of the scene; the sample spacing is kept, so the FOV shrinks accordingly."""
        hfov = angle_for_extent(self.sample_spacing_m * width, self.distance_m)
        return self.replace(**self._crop_changes(top, left, height, width), hfov_deg=hfov, validate=False)

    # --- photometry ------------------------------------------------------------------------
    def luminance(self) -> torch.Tensor:
        """Luminance image (cd/m^2) [B, 1, H, W]."""
        return self.photometric()

    def mean_luminance(self) -> torch.Tensor:
        """Mean luminance (cd/m^2) [B]."""
        return self.luminance().mean(dim=(1, 2, 3))

    def set_mean_luminance(self, cd_m2, *, name: str = "cd_m2") -> Scene:
        """Scale radiance (and illuminant) so the mean luminance is ``cd_m2`` (scalar or [B]); ``name``: the
        argument's name in errors (a caller's own, e.g. ``mean_luminance_cd_m2``)."""
        current = self._current()
        if current is not self:
            return current.set_mean_luminance(cd_m2, name=name)
        target = as_tensor(cd_m2, name, dtype=self.dtype, device=self.device).reshape(-1)
        if target.numel() not in (1, self.batch_size):
            raise ValueError(f"{name}: expected a scalar or one luminance per scene ({self.batch_size}), got "
                             f"{target.numel()} values")
        if (target <= 0).any() or not torch.isfinite(target).all():  # (0 zeroed the illuminant too)
            raise ValueError(f"{name}: expected a positive finite luminance, got {target.tolist()}")
        current = self.mean_luminance()
        if (current <= 0).any():
            # (a scene of 850 nm light alone was called black: its light is where V(lambda) is 0)
            raise ValueError(f"set_mean_luminance: the scene has no luminance (mean 0 cd/m^2: black, or light only "
                             f"where V(lambda) is 0, here {self.wavelengths_nm.min().item():g}-"
                             f"{self.wavelengths_nm.max().item():g} nm), so it cannot be scaled to a luminance")
        k = (target / current).reshape(-1, 1, 1, 1)
        # the radiance must stay in the dtype's range (float32 returned inf or NaN radiance for 3e24 cd/m^2): the
        # peak, or for factors the bound sum_j max(map_j) max(spectrum_j), times k
        f = self.factors
        if isinstance(f, SpectralFactors):
            peak = (f.maps.detach().abs().amax(dim=(-2, -1)) * f.spectra.detach().abs().amax(dim=-1)).sum(-1)
        else:
            peak = self.photons.detach().abs().flatten(1).amax(1)
        if not bool(torch.isfinite(peak * k.detach().reshape(-1)).all()):
            raise ValueError(f"{name}: {target.tolist()} cd/m^2 puts this scene's radiance beyond the range of "
                             f"{self.dtype} (peak {peak.max().item():.3g} photons/s/sr/m^2/nm at its present "
                             f"{current.max().item():.3g} cd/m^2); ask a smaller luminance or render in float64")
        ill = None if self.illuminant_photons is None else self.illuminant_photons * k.reshape(-1, 1)
        if self.factors is not None:
            return self.replace(factors=self.factors.scale(k.reshape(-1)), illuminant_photons=ill, validate=False)
        return self.replace(photons=self.photons * k, illuminant_photons=ill, validate=False)  # k finite, >= 0

    def illuminant_luminance(self) -> torch.Tensor | None:
        """Luminance (cd/m^2) of a perfect white under the scene's illuminant [B], or None."""
        if self.illuminant_photons is None:
            return None
        return spectral.luminance(self.illuminant_photons, self.wavelengths_nm, dim=-1).squeeze(-1)

    def reflectance(self) -> torch.Tensor:
        """photons / illuminant [B, L, H, W] (needs an illuminant)."""
        if self.illuminant_photons is None:
            raise ValueError("reflectance: this scene has no illuminant_photons")
        ill = self.illuminant_photons[:, :, None, None]
        return self.photons / ill.clamp_min(torch.finfo(self.dtype).tiny)

    def _preview_white_y(self, xyz_img: torch.Tensor) -> torch.Tensor:
        y = self.illuminant_luminance()
        return super()._preview_white_y(xyz_img) if y is None else y

    @staticmethod
    def cat(scenes: list[Scene]) -> Scene:
        """Concatenate scenes of the same size and wavelength grid along the batch."""
        if not scenes:
            raise ValueError("scenes: expected at least one Scene")
        if not all(isinstance(s, Scene) for s in scenes):
            bad = next(i for i, s in enumerate(scenes) if not isinstance(s, Scene))
            raise TypeError(f"scenes[{bad}]: expected a Scene, got {type(scenes[bad]).__name__}")
        scenes = [s._current() for s in scenes]  # (a factored scene's changed cube is the scene)
        first = scenes[0]

        def shape(s):
            return (s.num_wavelengths, s.height, s.width)
        for i, s in enumerate(scenes[1:], 1):
            if shape(s) != shape(first) or not torch.equal(s.wavelengths_nm, first.wavelengths_nm):
                raise ValueError(f"scenes[{i}]: expected shape {shape(first)} and the same "
                                 f"wavelengths, got {shape(s)}")
        has_ill = [s.illuminant_photons is not None for s in scenes]
        if any(has_ill) and not all(has_ill):  # the result would silently lose every scene's illuminant
            raise ValueError(f"scenes[{has_ill.index(not has_ill[0])}]: expected every scene with an illuminant or "
                             "none (reflectance() needs one for the whole batch); set or drop illuminant_photons")
        ill = torch.cat([s.illuminant_photons for s in scenes]) if all(has_ill) else None
        from ..image import SpectralFactors

        if all(isinstance(s.factors, SpectralFactors) for s in scenes):
            data = {"factors": SpectralFactors.cat([s.factors for s in scenes])}
        else:
            data = {"photons": torch.cat([s.photons for s in scenes])}
        return first.replace(
            **data,
            hfov_deg=torch.cat([s.hfov_deg for s in scenes]),
            distance_m=torch.cat([s.distance_m for s in scenes]),
            illuminant_photons=ill,
            validate=False,  # every part was checked
        )
