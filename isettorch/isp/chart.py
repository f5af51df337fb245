"""Colour accuracy of a rendered Macbeth chart: patch means and dE against the chart's true colours.

The true colours are computed from the same reflectances the scene uses
(:func:`isettorch.isp.reflectance_set` ``"macbeth"``) under the scene's illuminant, so the comparison measures
only the camera.
Reference: ISETCam ``macbethColorError`` / ``macbethCompareIdeal`` (white-patch scaling, CIELAB dE).
"""

from __future__ import annotations

import math
import warnings

import torch

from .._checks import check_finite, check_window, is_integer, is_real
from .colour import reflectance_set, white_xyz, xyz_responses

__all__ = ["patch_means", "macbeth_true_xyz", "macbeth_delta_e", "gray_patch_snr", "gray_patch_snr_db",
           "snr_channel", "scene_window", "WHITE_PATCH"]

#: Index of the white patch (row 4, column 1) in reading order.
WHITE_PATCH = 18


def patch_means(img: torch.Tensor, grid: tuple[int, int] = (4, 6), fraction: float = 0.5) -> torch.Tensor:
    """Mean of the central ``fraction`` of each cell of a ``grid`` chart filling the image: (B, C, H, W) ->
    (B, P, C), patches in reading order."""
    if not isinstance(img, torch.Tensor) or img.dim() != 4 or not img.is_floating_point():
        raise ValueError(f"img: expected a floating-point tensor (B, C, H, W), got "
                         f"{(img.dtype, tuple(img.shape)) if isinstance(img, torch.Tensor) else type(img).__name__}")
    check_finite(img.detach(), "img")  # (a NaN pixel made NaN patch means)
    if not (is_real(fraction) and 0 < fraction <= 1):
        raise ValueError(f"fraction: expected a number in (0, 1], got {fraction!r}")
    if not (isinstance(grid, (tuple, list)) and len(grid) == 2 and all(is_integer(v) for v in grid)):
        raise ValueError(f"grid: expected (rows, cols) integers, got {grid!r}")  # (4.7 rows were 4)
    rows, cols = (int(v) for v in grid)
    h, w = img.shape[-2:]
    if not (1 <= rows <= h and 1 <= cols <= w):
        raise ValueError(f"grid: expected 1 <= rows <= {h} and 1 <= cols <= {w} (a cell per patch, at least a pixel "
                         f"each), got {grid!r}")
    out = []
    for r in range(rows):
        for c in range(cols):
            cy, cx = (r + 0.5) * h / rows, (c + 0.5) * w / cols
            hy, hx = max(0.5, fraction * h / rows / 2), max(0.5, fraction * w / cols / 2)
            y0, y1 = int(round(cy - hy)), max(int(round(cy - hy)) + 1, int(round(cy + hy)))
            x0, x1 = int(round(cx - hx)), max(int(round(cx - hx)) + 1, int(round(cx + hx)))
            out.append(img[:, :, y0:y1, x0:x1].mean(dim=(-2, -1)))
    return torch.stack(out, dim=1)


def scene_window(result, pixel_size_m: float) -> tuple[int, int, int, int] | None:
    """``(row0, row1, col0, col1)``: the scene's footprint on the sensor (the chart's, for a chart scene), the image
    plane's ``d_i tan(fov / 2)`` either side of the axis in pixels of ``pixel_size_m``; None when the sensor does not
    hold all of it (by more than a pixel a side) or the optical image has no geometry.

    A sensor larger than the scene's image (a config's fixed rows and cols) holds the chart in its middle: patch
    means over the whole image put the dark-skin patch under purplish blue (mean dE2000 73 for 3.7); a smaller one
    crops the chart. ``result`` is a camera's output with ``scene``, ``optical_image`` and ``raw``
    (:class:`isettorch.camera.CameraOutput`); item 0 is measured, on a sensor centred on the optical axis.
    """
    if not (is_real(pixel_size_m) and pixel_size_m > 0):  # (a negative pitch gave an inverted window, 0 a bare
        # ZeroDivisionError)
        raise ValueError(f"pixel_size_m: expected a positive, finite pixel pitch in metres, got {pixel_size_m!r}")
    h, w = result.raw.data.shape[-2:]
    oi = result.optical_image
    d = oi.image_distance_m if oi.image_distance_m is not None else oi.focal_length_m
    if d is None:
        return None
    d = float(torch.as_tensor(d).reshape(-1)[0])
    half_w = d * math.tan(math.radians(float(result.scene.hfov_deg.reshape(-1)[0])) / 2) / pixel_size_m
    half_h = d * math.tan(math.radians(float(result.scene.vfov_deg.reshape(-1)[0])) / 2) / pixel_size_m
    r0, r1, c0, c1 = (round(h / 2 - half_h), round(h / 2 + half_h), round(w / 2 - half_w), round(w / 2 + half_w))
    if r0 < -1 or c0 < -1 or r1 > h + 1 or c1 > w + 1:
        return None
    return max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)


def _chart_grid(wavelengths_nm) -> torch.Tensor:
    """The grid the chart is integrated on: 400-700 nm in 10 nm steps (its reflectances' range) unless given."""
    if wavelengths_nm is None:
        return torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    return torch.as_tensor(wavelengths_nm, dtype=torch.float64)


def macbeth_true_xyz(illuminant="D65", wavelengths_nm=None, observer: str = "1931") -> torch.Tensor:
    """True XYZ (24, 3) of the chart's patches under ``illuminant``, scaled so a perfect white has Y = 1."""
    w = _chart_grid(wavelengths_nm)
    xyz = xyz_responses(w, illuminant, reflectance_set("macbeth", w), observer)
    white = xyz_responses(w, illuminant, torch.ones(1, w.numel(), dtype=torch.float64), observer)[0]
    return xyz / white[1]


LAB_WHITES = ("perfect", "white_patch")


def macbeth_delta_e(rendered_xyz: torch.Tensor, illuminant="D65", method: str = "2000", wavelengths_nm=None,
                    scale_to_white: bool = True, lab_white: str = "perfect"):
    """dE of rendered patch XYZ (..., 24, 3) (e.g. (B, 24, 3) or (24, 3)) against the true chart under ``illuminant``.

    With ``scale_to_white`` the rendered values are scaled so the white patch's Y equals its true Y (the
    camera's exposure is arbitrary). CIELAB white (``lab_white``): ``'perfect'``, the illuminant's perfect white
    (Y = 1) on the chart's grid, so a perfect reflector is (100, 0, 0); or ``'white_patch'``, the chart's true
    white patch (ISETCam ``macbethColorError``'s ``whiteIdealXYZ``: the white patch is L* 100), which reads dE
    about 2 % higher.
    Returns :class:`isettorch.metrics.difference.ColorAccuracy` (per-patch ``delta_e``, ``mean``, ``max``).
    """
    from ..metrics import color_accuracy

    if not isinstance(rendered_xyz, torch.Tensor) or rendered_xyz.dim() < 2 \
            or tuple(rendered_xyz.shape[-2:]) != (24, 3):
        raise ValueError(f"rendered_xyz: expected the 24 patches' XYZ, (..., 24, 3), got "
                         f"{tuple(rendered_xyz.shape) if isinstance(rendered_xyz, torch.Tensor) else rendered_xyz!r}")
    if lab_white not in LAB_WHITES:
        raise ValueError(f"lab_white: expected one of {LAB_WHITES}, got {lab_white!r}")
    x = rendered_xyz.to(torch.float64)
    ref = macbeth_true_xyz(illuminant, wavelengths_nm).to(x.device)
    if scale_to_white:
        y_white = x[..., WHITE_PATCH:WHITE_PATCH + 1, 1:2]
        if not bool((y_white.detach() > 0).all()):  # (a 0 / 0 was reported as NaN XYZ)
            raise ValueError(f"rendered_xyz: scale_to_white needs a white patch (patch {WHITE_PATCH + 1}) with Y > "
                             f"0, got Y = {y_white.detach().reshape(-1).tolist()}")
        x = x * (ref[WHITE_PATCH, 1] / y_white)
    if lab_white == "white_patch":
        # colour_accuracy takes Y_white = 1: both charts on the white patch's scale, its XYZ the white
        x, ref = x / ref[WHITE_PATCH, 1], ref / ref[WHITE_PATCH, 1]
        white = ref[WHITE_PATCH]
    else:
        white = white_xyz(illuminant, _chart_grid(wavelengths_nm)).to(x.device)  # the chart's own grid: L* 100
    with warnings.catch_warnings():  # the reference is under the render's illuminant by construction
        warnings.filterwarnings("ignore", message="rendered: the white patch", category=UserWarning)
        return color_accuracy(x, ref, white=white, method=method)


def snr_channel(cfa) -> int:
    """The CFA channel the gray-patch SNR measures by default: ``'G'`` where the mosaic has one (the luminance-like
    channel of RGB mosaics, RGBW included), else the channel with the most pixels per cell (the first of a tie in
    ``channel_names``): W of RCCB / RCCC / a monochrome sensor, Y of YCMY."""
    names = list(cfa.channel_names)
    if "G" in names:
        return names.index("G")
    counts = [sum(row.count(n) for row in cfa.cell) for n in names]
    return counts.index(max(counts))


def gray_patch_snr(raw, channel: int | str | None = None, fraction: float = 0.5,
                   window: tuple[int, int, int, int] | None = None) -> dict:
    """SNR (dB) of the six gray patches (white -> black) of a Macbeth raw, with what it measured.

    ``20 log10(mean noise-free signal / std(noisy - noise-free))`` over one CFA channel's pixels in each patch's
    central ``fraction``; using the noise-free signal keeps lens shading and blur out of the noise. Needs
    ``raw.noise_free``.

    Args:
        raw: a :class:`~isettorch.sensor.raw.RawImage` (item 0 is measured).
        channel: a channel index or CFA letter (``'G'``); None: :func:`snr_channel` (G, else the most frequent).
        fraction: the central part of each patch measured.
        window: ``(row0, row1, col0, col1)``, the chart's footprint on the sensor (:func:`scene_window`); None: the
            chart fills the sensor.

    Returns:
        ``{"channel": letter, "snr_db": [6 x float or None], "pixels": [6 x int], "notes": [6 x str or None]}``.
        A patch's SNR is None, with a note saying why, where it is undefined: fewer than 2 pixels of the channel
        (no standard deviation: a small sensor), no noise (std 0: the noise-free capture), or no signal (mean <= 0);
        never inf or NaN.
    """
    if raw.noise_free is None:
        raise ValueError("raw: gray_patch_snr needs raw.noise_free (the sensor's noise-free capture)")
    if not (is_real(fraction) and 0 < fraction <= 1):
        raise ValueError(f"fraction: expected a number in (0, 1], got {fraction!r}")
    names = list(raw.cfa.channel_names)
    if channel is None:
        c = snr_channel(raw.cfa)
    elif isinstance(channel, str):
        if channel not in names:
            raise ValueError(f"channel: the CFA has no channel {channel!r}; expected one of {names}")
        c = names.index(channel)
    elif isinstance(channel, int) and not isinstance(channel, bool) and 0 <= channel < len(names):
        c = channel
    else:
        raise ValueError(f"channel: expected None, a CFA letter of {names} or an index in 0..{len(names) - 1}, "
                         f"got {channel!r}")
    h, w = raw.data.shape[-2:]
    r0, r1, c0, c1 = (0, h, 0, w) if window is None else check_window(window, h, w, "window")
    masks = raw.channel_masks()
    sig = (raw.noise_free.double() - raw.levels()[0])[0, 0, r0:r1, c0:c1]
    res = (raw.data[0, 0].double() - raw.noise_free[0, 0].double())[r0:r1, c0:c1]
    mask = masks[c].bool()[r0:r1, c0:c1]
    h, w = sig.shape
    snr, pixels, notes = [], [], []
    for k in range(6):
        r = slice(int((3.5 - fraction / 2) * h / 4), int((3.5 + fraction / 2) * h / 4))
        col = slice(int((k + 0.5 - fraction / 2) * w / 6), int((k + 0.5 + fraction / 2) * w / 6))
        m = mask[r, col]
        n_px = int(m.sum())
        pixels.append(n_px)
        if n_px < 2:
            snr.append(None)
            notes.append(f"{n_px} {names[c]} pixel(s) in the patch: a standard deviation needs at least 2 (a larger "
                         "sensor or fraction)")
            continue
        s_mean, n_std = float(sig[r, col][m].mean()), float(res[r, col][m].std())
        if not n_std > 0:
            snr.append(None)
            notes.append("no noise in the patch (std 0, e.g. a noise-free capture): the SNR is unbounded")
        elif not s_mean > 0:
            snr.append(None)
            notes.append(f"no signal in the patch (mean {s_mean:.3g} above black): the SNR is undefined")
        else:
            snr.append(20 * math.log10(s_mean / n_std))
            notes.append(None)
    return {"channel": names[c], "snr_db": snr, "pixels": pixels, "notes": notes}


def gray_patch_snr_db(raw, channel: int | str | None = None, fraction: float = 0.5) -> list[float | None]:
    """The SNRs (dB) of :func:`gray_patch_snr` (white -> black; None where a patch's SNR is undefined)."""
    return gray_patch_snr(raw, channel, fraction)["snr_db"]
