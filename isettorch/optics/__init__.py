"""Optics: scene radiance -> sensor-plane irradiance (`OpticalImage`)."""

from . import analysis, geometry, isetcam
from .base import ShiftInvariantLens
from .diffraction import DiffractionLimitedOptics, dl_mtf_1d, dl_otf
from .factory import build_optics
from .optical_image import OpticalImage
from .psf_otf import otf_from_psf
from .shift_invariant import ShiftInvariantOptics
from .wavefront import WavefrontOptics, defocus_diopters_to_zernike_um, zernike_basis, zernike_nm

__all__ = [
    "OpticalImage",
    "build_optics",
    "ShiftInvariantLens",
    "DiffractionLimitedOptics",
    "dl_otf",
    "dl_mtf_1d",
    "ShiftInvariantOptics",
    "WavefrontOptics",
    "zernike_nm",
    "zernike_basis",
    "defocus_diopters_to_zernike_um",
    "otf_from_psf",
    "analysis",
    "geometry",
    "isetcam",
]
