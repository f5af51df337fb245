"""Image processor: demosaic, colour, pipelines. One import line per module; ``__all__`` lists the public names."""

from .demosaic import (
    METHODS,
    Demosaic,
    bayer_index_map,
    demosaic,
    demosaic_bilinear,
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
    "METHODS", "Demosaic", "bayer_index_map", "demosaic", "demosaic_bilinear", "demosaic_generic",
    "demosaic_malvar2004", "demosaic_menon2007", "demosaic_nearest", "demosaic_nearest_cfa", "get_method",
    "mosaic", "register_method",
    # evaluation
    "cpsnr", "evaluate_demosaic",
]
