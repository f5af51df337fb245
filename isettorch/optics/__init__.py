"""Optics: scene radiance -> sensor-plane irradiance (`OpticalImage`)."""

from .optical_image import OpticalImage

__all__ = ["OpticalImage"]
