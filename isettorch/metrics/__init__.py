"""Image-quality metrics: colorimetry (CIELAB, chromaticity, dE76/94/2000, S-CIELAB), PSNR/SSIM,
ISO 12233 e-SFR, SNR and dynamic range, EMVA 1288 sensor characterisation."""

from __future__ import annotations

import importlib

_LAZY = {
    # colour
    "xyz_to_lab": "color", "lab_to_xyz": "color", "xyz_to_xy": "color", "xyz_to_uv": "color",
    "xy_to_xyz": "color", "srgb_to_xyz": "color", "xyz_to_srgb": "color", "WHITE_POINTS": "color",
    "delta_e": "difference", "delta_e_76": "difference", "delta_e_94": "difference", "delta_e_2000": "difference",
    "DeltaE": "difference", "color_accuracy": "difference", "ColorAccuracy": "difference",
    "macbeth_reference_xyz": "difference",
    "scielab": "spatial_cielab", "SCIELAB": "spatial_cielab", "scielab_filters": "spatial_cielab",
    "scielab_filter": "spatial_cielab", "samples_per_degree": "spatial_cielab",
    # image fidelity
    "psnr": "fidelity", "cpsnr": "fidelity", "ssim": "fidelity", "mse": "fidelity", "PSNR": "fidelity",
    "SSIM": "fidelity",
    # sharpness
    "esfr": "sfr", "esfr_cfa": "sfr", "ESFR": "sfr", "SFRResult": "sfr", "find_edge_roi": "sfr",
    # noise
    "snr_uniform": "snr", "snr_curve": "snr", "dynamic_range_db": "snr", "pixel_snr": "snr",
    "dynamic_range_from_curve": "snr",
    "emva1288": "emva", "EMVA1288Result": "emva",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"isettorch.metrics.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'isettorch.metrics' has no attribute {name!r}")


def __dir__():
    return __all__
