"""Scenes: the `Scene` container and its generators (charts, test patterns, spectral images)."""

from .scene import Scene

__all__ = ["Scene"]
