"""Image processor: demosaic, colour, pipelines. One import line per module; ``__all__`` lists the public names.

Demosaic: the function ``demosaic(raw, "RGGB", "menon2007")`` and its module ``Demosaic("menon2007")``, with the
method registry (``METHODS``, ``register_method``) of :mod:`isettorch.isp.demosaicing`.
"""

from .demosaicing import (
    BAYER_PATTERNS,
    METHODS,
    Demosaic,
    bayer_index_map,
    demosaic,
    demosaic_bilinear,
    demosaic_bilinear_colour,
    demosaic_generic,
    demosaic_malvar2004,
    demosaic_menon2007,
    demosaic_nearest,
    demosaic_nearest_cfa,
    get_method,
    mosaic,
    register_method,
)
from .evaluation import cpsnr, evaluate_demosaic

__all__ = [
    # demosaic
    "BAYER_PATTERNS", "METHODS", "Demosaic", "bayer_index_map", "demosaic", "demosaic_bilinear",
    "demosaic_bilinear_colour", "demosaic_generic",
    "demosaic_malvar2004", "demosaic_menon2007", "demosaic_nearest", "demosaic_nearest_cfa", "get_method",
    "mosaic", "register_method",
    # evaluation
    "cpsnr", "evaluate_demosaic",
]

# colour stages, pipeline and chart evaluation (appended by the colour/camera engineer)
from .chart import macbeth_delta_e, macbeth_true_xyz, patch_means  # noqa: E402
from .colour import (  # noqa: E402
    DisplayEncode,
    IlluminantCorrection,
    SensorToXYZ,
    XYZToDisplay,
    apply_gains,
    apply_matrix,
    fit_colour_matrix,
    gray_world_gains,
    illuminant_gains,
    reflectance_set,
    sensor_responses,
    sensor_to_xyz_matrix,
    srgb_decode,
    srgb_encode,
    white_world_gains,
    white_xyz,
    xyz_responses,
)
from .pipeline import DemosaicStage, ImageProcessor, ISPResult  # noqa: E402

__all__ += [
    "DisplayEncode", "IlluminantCorrection", "SensorToXYZ", "XYZToDisplay", "apply_gains", "apply_matrix",
    "fit_colour_matrix", "gray_world_gains", "illuminant_gains", "reflectance_set", "sensor_responses",
    "sensor_to_xyz_matrix", "srgb_decode", "srgb_encode", "white_world_gains", "white_xyz", "xyz_responses",
    "DemosaicStage", "ImageProcessor", "ISPResult", "macbeth_delta_e", "macbeth_true_xyz", "patch_means",
]
from .isetcam import ip_result_from_case, isetcam_image_processor  # noqa: E402

__all__ += ["ip_result_from_case", "isetcam_image_processor"]
