"""File formats: users' RGB images (PNG/TIFF/EXR), spectral OpenEXR (Fichet et al. 2021), ISETCam scene .mat
files, CAVE / KAIST / ICVL / ARAD."""

from .exr import read_scene_exr, read_spectral_exr, write_scene_exr, write_spectral_exr
from .hyperspectral import load_arad, load_cave, load_icvl, load_kaist
from .images import read_image, read_rgb8, write_image
from .isetcam import read_isetcam_scene

__all__ = ["read_image", "read_rgb8", "write_image",
           "read_scene_exr", "read_spectral_exr", "write_scene_exr", "write_spectral_exr", "read_isetcam_scene",
           "load_cave", "load_kaist", "load_icvl", "load_arad"]
