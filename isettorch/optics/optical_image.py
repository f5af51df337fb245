"""`OpticalImage`: spectral irradiance at the sensor plane, in photons/s/m^2/nm."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch

from ..image import SpectralImage, angle_for_extent


@dataclasses.dataclass(eq=False, repr=False)
class OpticalImage(SpectralImage):
    """Spectral irradiance ``photons [B, L, H, W]`` (photons/s/m^2/nm) on the image plane.

    The sample grid is centred on the optical axis: sample (i, j) sits at
    ``((j - (W-1)/2) dx, (i - (H-1)/2) dx)``.

    Args:
        sample_spacing_m: pitch of the irradiance samples on the image plane (m), ``[B]``.
        hfov_deg: horizontal field of view the image covers, as seen from the lens (deg), ``[B]``.
        focal_length_m, f_number, image_distance_m: the optics geometry that produced it (``[B]``),
            optional for images made by hand.
        pad_rows, pad_cols: samples added on each side by the optics beyond the scene's extent
            (ISETCam-compatible padding), so the scene's region is known.
    """

    sample_spacing_m: torch.Tensor | float = 1e-6
    hfov_deg: torch.Tensor | float | None = None
    focal_length_m: torch.Tensor | float | None = None
    f_number: torch.Tensor | float | None = None
    image_distance_m: torch.Tensor | float | None = None
    pad_rows: int = 0
    pad_cols: int = 0

    _batch_fields: ClassVar[tuple[str, ...]] = (
        "sample_spacing_m", "hfov_deg", "focal_length_m", "f_number", "image_distance_m",
    )
    _units: ClassVar[str] = "photons/s/m^2/nm"

    def __post_init__(self, validate: bool = True) -> None:
        super().__post_init__(validate)
        if self.hfov_deg is None:
            d = self.image_distance_m if self.image_distance_m is not None else self.focal_length_m
            if d is not None:
                self.hfov_deg = angle_for_extent(self.width_m, d)

    @property
    def width_m(self) -> torch.Tensor:
        return self.sample_spacing_m * self.width

    @property
    def height_m(self) -> torch.Tensor:
        return self.sample_spacing_m * self.height

    def sample_positions_m(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Sample centres (m) relative to the optical axis: (y [B, H], x [B, W])."""
        dx = self.sample_spacing_m[:, None]
        i = torch.arange(self.height, device=self.device, dtype=self.dtype)
        j = torch.arange(self.width, device=self.device, dtype=self.dtype)
        return (i - (self.height - 1) / 2) * dx, (j - (self.width - 1) / 2) * dx

    def illuminance(self) -> torch.Tensor:
        """Illuminance (lux) [B, 1, H, W]: 683 sum E V dl."""
        return self.photometric()

    def mean_illuminance(self) -> torch.Tensor:
        """Mean illuminance (lux) over the whole image [B]."""
        return self.illuminance().mean(dim=(1, 2, 3))

    def crop(self, top: int, left: int, height: int, width: int) -> OpticalImage:
        """A window of the optical image, keeping the sample spacing.

        The result is re-centred on its own window (the window's centre becomes the axis).
        """
        p = self._crop_photons(top, left, height, width)
        d = self.image_distance_m if self.image_distance_m is not None else self.focal_length_m
        hfov = None if d is None else angle_for_extent(self.sample_spacing_m * width, d)
        return self.replace(photons=p, hfov_deg=hfov, pad_rows=0, pad_cols=0)
