"""isettorch: a physically based, differentiable camera simulator in PyTorch (Scene -> Optics ->
Sensor -> Image processor), after ISETCam (Farrell et al., SPIE 2004)."""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# Public names resolved lazily, so ``import isettorch`` stays light and sub-packages load on use.
_LAZY = {
    "Scene": "isettorch.scene",
    "OpticalImage": "isettorch.optics",
    "DiffractionLimitedOptics": "isettorch.optics",
    "ShiftInvariantOptics": "isettorch.optics",
    "WavefrontOptics": "isettorch.optics",
    "Sensor": "isettorch.sensor",
    "RawImage": "isettorch.sensor",
    "ImageProcessor": "isettorch.isp",
    "Camera": "isettorch.camera",
}
_SUBMODULES = {"constants", "spectral", "scene", "optics", "sensor", "isp", "metrics", "data", "io", "plot",
               "camera"}

__all__ = sorted(_LAZY) + sorted(_SUBMODULES)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _SUBMODULES:
        return importlib.import_module(f"isettorch.{name}")
    raise AttributeError(f"module 'isettorch' has no attribute {name!r}")
