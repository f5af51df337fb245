"""Sensor: optical-image irradiance -> raw mosaic (`RawImage`), with CFA, spectral QE, pixel
geometry and sampling, exposure, noise and ADC; presets and sensor metrics."""

from . import metrics
from .cfa import CFA, CFA_LIBRARY, KNOWN_LETTERS
from .exposure import AE_METHODS, auto_exposure
from .filter_bank import FilterBank
from .filters import SpectralQE, filter_set, filter_set_names, ir_cut_filter, photodiode_qe, shifted_qe
from .microlens import PixelOptics, microlens_etendue, microlens_radiance
from .mosaic import LearnedMosaic, temperature_schedule
from .noise import quantize_ste, round_half_away, shot_noise
from .raw import RawImage
from .sampling import isetcam_preblur, isetcam_preblur_kernel, sample_area, sample_point
from .sensor import ISETCAM_CONVENTIONS, PRESETS, Sensor

__all__ = [
    "AE_METHODS", "CFA", "CFA_LIBRARY", "FilterBank", "ISETCAM_CONVENTIONS", "KNOWN_LETTERS", "LearnedMosaic",
    "PRESETS", "RawImage", "Sensor", "SpectralQE", "temperature_schedule",
    "auto_exposure", "filter_set", "filter_set_names", "ir_cut_filter", "isetcam_preblur", "isetcam_preblur_kernel",
    "metrics", "microlens_etendue", "microlens_radiance", "photodiode_qe", "PixelOptics",
    "quantize_ste", "round_half_away", "sample_area", "sample_point", "shifted_qe", "shot_noise",
]
