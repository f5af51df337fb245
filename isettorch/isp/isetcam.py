"""ISETCam's default image processor (``ipCompute(ipCreate, sensor)``) and an IP stage for the parity cases.

``isetcam_image_processor()`` configures :class:`~isettorch.isp.pipeline.ImageProcessor` as ISETCam's default
``ipCreate`` (FORMAT.md 4.10): bilinear demosaic with ISETCam's mirrored border (``ieBilinear``), 'MCC
optimized' sensor -> XYZ (clipped at 0), no illuminant correction, XYZ -> display, 'adaptive' scaling
(``displayRender``: max = max volts / swing for analog sensors, 1 for quantized ones), linear output (ISETCam's
``ip.data.result`` is linear display RGB), and a monochrome sensor copied as ``input / voltage swing``.

``ip_result_from_case(case)`` runs it on a parity case's sensor data and returns ours and ISETCam's
``ip_result`` (both ``[rows, cols, 3]``).
"""

from __future__ import annotations

import torch

from .pipeline import DemosaicStage, ImageProcessor

__all__ = ["isetcam_image_processor", "ip_result_from_case"]


def isetcam_image_processor(display="srgb", sensor_to_xyz=None) -> ImageProcessor:
    """ISETCam's default processor. ``display``: ``"srgb"``, a display, or a (3, 3) RGB -> XYZ matrix (ISETCam's
    default is the 'LCD-Apple' display, whose spectra we do not ship; parity cases carry its matrix).
    ``sensor_to_xyz``: a fixed (3, C) matrix, else fitted on the Macbeth chart under D65 by ``fit``."""
    return ImageProcessor(demosaic=DemosaicStage("bilinear", border="reflect"), illuminant_correction="none",
                          correction_space="xyz", sensor_to_xyz=sensor_to_xyz, display=display, encoding="linear",
                          scaling="adaptive", clip_negative_xyz=True, monochrome_divisor="voltage_swing")


def ip_result_from_case(case, use_case_matrices: bool = True, dtype=torch.float64):
    """Run ISETCam's default processor on a parity case (a dict or ``np.load`` result, FORMAT.md).

    With ``use_case_matrices`` the case's ``ip_T_sensor`` and ``ip_T_display`` are used (so only our stages
    are tested); otherwise the sensor matrix is fitted from ``sensor_spectral_qe`` (and the display matrix
    still comes from the case when present, as we do not ship ISETCam's LCD-Apple spectra).
    Returns ``(ours, reference)``, numpy ``[rows, cols, 3]`` (reference None when the case has no ``ip_result``).
    """
    import numpy as np

    from .._checks import round_half_away
    from ..io.isetcam import _scalar, _wavelengths, case_adc_bits, case_cfa
    from ..sensor.raw import RawImage

    case = {k: case[k] for k in (case.files if hasattr(case, "files") else case.keys())}
    get = case.get
    # scalars as a MATLAB export writes them too (1 x 1 arrays: float() of them failed), the case reader's rule
    scalar = lambda key, default: _scalar(case, key) if key in case else default  # noqa: E731
    swing = scalar("sensor_voltage_swing_v", 1.0)
    dv = get("sensor_dv")
    bits = case_adc_bits(case)
    if bits is not None and dv is not None:
        data, units, white = np.asarray(dv, float), "dn", float(2 ** bits)
    else:
        data, units, white = np.asarray(get("sensor_volts"), float), "volts", swing
    cfa = case_cfa(case)
    # ISETCam's ipCompute subtracts a colour sensor's zero level (sensorGet 'zero level': a noise-free black capture,
    # the analog offset after gain, clipped and quantised) before demosaicking; a monochrome one keeps it
    zero = 0.0
    offset = scalar("sensor_analog_offset", 0.0)
    if offset != 0 and not cfa.is_monochrome:
        volts = min(max(offset / scalar("sensor_analog_gain", 1.0), 0.0), swing)
        zero = float(round_half_away(volts / (swing / 2 ** bits))) if units == "dn" else volts
    raw = RawImage(torch.as_tensor(data, dtype=dtype)[None, None], units, cfa, black_level=zero, white_level=white,
                   voltage_swing_v=swing)
    t_display = get("ip_T_display")
    display = "srgb" if t_display is None else torch.linalg.inv(torch.as_tensor(t_display, dtype=torch.float64).T)
    t_sensor = get("ip_T_sensor") if use_case_matrices else None
    ip = isetcam_image_processor(display, None if t_sensor is None else
                                 torch.as_tensor(t_sensor, dtype=torch.float64).T).to(dtype)
    if t_sensor is None and not cfa.is_monochrome:
        w = torch.as_tensor(_wavelengths(case), dtype=torch.float64)
        qe = torch.as_tensor(get("sensor_spectral_qe"), dtype=torch.float64)
        ip.fit_wavelengths_nm = w
        ip.fit(qe)
    res = ip(raw)
    # a monochrome sensor's ip_result is input / voltage swing, unclipped (FORMAT.md 4.10): the display-linear image
    ours = (res.display_linear if cfa.is_monochrome else res.image)[0].permute(1, 2, 0).detach().cpu().numpy()
    ref = get("ip_result")
    return ours, None if ref is None else np.asarray(ref)
