"""Optics: scene radiance -> sensor-plane irradiance (`OpticalImage`)."""

from . import geometry, isetcam
from .base import ShiftInvariantLens
from .diffraction import DiffractionLimitedOptics, dl_mtf_1d, dl_otf
from .optical_image import OpticalImage

__all__ = [
    "OpticalImage",
    "ShiftInvariantLens",
    "DiffractionLimitedOptics",
    "dl_otf",
    "dl_mtf_1d",
    "geometry",
    "isetcam",
]
