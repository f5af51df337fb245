"""Scenes: the `Scene` container and its generators (charts, test patterns, spectral images)."""

from .dead_leaves import dead_leaves
from .display import Display, display_names
from .macbeth import macbeth, macbeth_patch_names, macbeth_patch_slices, macbeth_reflectances
from .patterns import (
    checkerboard,
    frequency_sweep,
    grid_lines,
    hdr_chart,
    monochromatic,
    point_array,
    ramp,
    slanted_edge,
    star,
    uniform,
    zone_plate,
)
from .reflectance import from_rgb, reflectance_scene
from .scene import Scene

__all__ = [
    "Scene",
    "macbeth",
    "macbeth_reflectances",
    "macbeth_patch_names",
    "macbeth_patch_slices",
    "uniform",
    "monochromatic",
    "ramp",
    "frequency_sweep",
    "slanted_edge",
    "point_array",
    "grid_lines",
    "star",
    "checkerboard",
    "zone_plate",
    "hdr_chart",
    "dead_leaves",
    "reflectance_scene",
    "from_rgb",
    "Display",
    "display_names",
]
