"""`ImageProcessor`: raw mosaic -> display image, as a composition of replaceable stages.

    demosaic -> [illuminant correction in sensor space] -> sensor -> XYZ -> [illuminant correction in XYZ]
             -> XYZ -> display -> scaling -> encoding

Every stage is a submodule (``ip.demosaic``, ``ip.illuminant_correction``, ``ip.sensor_to_xyz``,
``ip.xyz_to_display``, ``ip.encode``) and can be replaced by any module with the same call signature.
``forward(raw)`` returns an :class:`ISPResult` with every stage's output and the matrices used.

Reference: ISETCam ``ipCompute`` (``ipComputeSingle``: Demosaic, imageSensorCorrection,
imageIlluminantCorrection, displayRender); Farrell et al., SPIE 2004, section 2.4.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn

from .._autograd import full_precision
from .._checks import batch_param, check_bool, check_finite, check_wavelengths
from ..sensor.exposure import percentile_linear
from .colour import (
    DisplayEncode,
    ExactConstants,
    IlluminantCorrection,
    SensorToXYZ,
    XYZToDisplay,
    check_illuminant_name,
    white_xyz,
)

__all__ = ["ImageProcessor", "ISPResult", "DemosaicStage", "SCALINGS"]

#: How linear display RGB is scaled before encoding.
#: ``"adaptive"``: ISETCam ``displayRender``: for an analog (volts/electrons) raw the image maximum becomes the
#: ratio of the raw maximum to the white level (a dark capture stays dark); for a quantized (DN) raw it becomes 1.
#: ``"exposure"``: no image-dependent scaling; the sensor -> XYZ matrix maps a white at the white level to Y = 1
#: (needs a normalised SensorToXYZ). A gray- or white-world correction's gains keep one channel at 1 (ISETCam, which
#: then rescales to the image maximum), so under "exposure" the image's brightness follows the scene's colours: a
#: Macbeth chart's warm mean made gray world lift its white patch to Y = 1.23 through the imx363 config (8 % of the
#: pixels clipped; an audit of 2026-12-01), a D65 white at the white level rendered at Y = 0.90. Use "percentile"
#: (or "max") where the white balance is estimated from the image.
#: ``"max"``: the image maximum becomes 1. ``"percentile"``: the ``scaling_percentile`` (default 99) of the
#: linear display values becomes 1 (robust to noise and demosaic outliers).
SCALINGS = ("adaptive", "exposure", "max", "percentile")


@dataclasses.dataclass
class ISPResult:
    """Outputs of every :class:`ImageProcessor` stage (tensors (B, C, H, W); None where a stage did not run).

    ``input``: the mosaic scaled to 0 at the black level and 1 at the white level (B, 1, H, W).
    ``demosaiced``: sensor channels in CFA channel order. ``sensor_balanced``: after a sensor-space
    illuminant correction (else the demosaiced image). ``xyz``: relative XYZ before, ``xyz_balanced`` after an
    XYZ-space correction. ``display_linear``: linear display RGB after scaling, not clipped. ``image``: the
    encoded output (B, 3, H, W). Matrices: ``gains`` (B, C), ``sensor_to_xyz`` (3, C), ``xyz_to_display``
    (3, 3), ``scale`` (B,) the factor of the scaling stage.
    """

    image: torch.Tensor
    input: torch.Tensor | None = None
    demosaiced: torch.Tensor | None = None
    sensor_balanced: torch.Tensor | None = None
    xyz: torch.Tensor | None = None
    xyz_balanced: torch.Tensor | None = None
    display_linear: torch.Tensor | None = None
    gains: torch.Tensor | None = None
    sensor_to_xyz: torch.Tensor | None = None
    xyz_to_display: torch.Tensor | None = None
    scale: torch.Tensor | None = None

    def stages(self) -> dict[str, torch.Tensor]:
        """The image stages that ran, in pipeline order."""
        names = ("input", "demosaiced", "sensor_balanced", "xyz", "xyz_balanced", "display_linear", "image")
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}


class DemosaicStage(nn.Module):
    """Demosaic for any CFA: Bayer-like 2x2 layouts (RGB Bayer, and 3-filter cells with one filter on a
    diagonal such as CMY 'YCMY', mapped onto a Bayer pattern) use ``method`` of
    :func:`isettorch.isp.demosaic`; other CFAs (RGBW, X-Trans, ...) use the generic method on the
    CFA's index map (``fallback``, bilinear by default).

    ``border="reflect"`` mirrors the mosaic first (whole-sample, by two pixels, which keeps a 2x2 CFA's phase and
    covers 5 x 5 kernels; by one on a mosaic 2 pixels high or wide) and crops the result, as ISETCam
    ``ieBilinear`` does with one; ``border="method"`` leaves the borders to the method. Malvar-He-Cutler gets its
    phase-keeping ``boundary="mirror"`` here unless ``boundary`` is given: the function's default (colour-demosaicing's
    half-sample border) turned a constant (0.1, 0.5, 0.9) into (0.10, 0.20, 0.35) at a corner.

    ``forward(mosaic (B, 1, H, W), cfa) -> (B, C, H, W)`` in the CFA's channel order.
    """

    def __init__(self, method="bilinear", fallback: str = "bilinear", border: str = "method", **kwargs) -> None:
        super().__init__()
        from .demosaicing import _GENERIC, Demosaic

        if border not in ("method", "reflect"):
            raise ValueError(f"border: expected 'method' or 'reflect', got {border!r}")
        if not isinstance(fallback, str) or fallback not in _GENERIC:  # (refused only at an RGBW sensor's render)
            raise ValueError(f"fallback: expected a method for index-map CFAs, one of {sorted(_GENERIC)}, got "
                             f"{fallback!r}")
        self.method = method if isinstance(method, str) else type(method).__name__
        if method == "malvar2004":
            kwargs.setdefault("boundary", "mirror")
        self.bayer = Demosaic(method, **kwargs)
        self.fallback = fallback
        self.border = border

    def forward(self, mosaic: torch.Tensor, cfa) -> torch.Tensor:
        from ..sensor.cfa import CFA
        from .demosaicing import demosaic

        pad = 0
        if self.border == "reflect" and min(mosaic.shape[-2:]) > 1:
            ph, pw = cfa.shape
            # Whole-sample mirroring keeps the CFA only for cells of period <= 2
            if ph > 2 or pw > 2:
                raise ValueError(f"border: 'reflect' needs a CFA cell of at most 2x2, got {cfa.shape}")
            pad = 2 if min(mosaic.shape[-2:]) > 2 else 1
            mosaic = nn.functional.pad(mosaic, (pad, pad, pad, pad), mode="reflect")
            if pad == 1:  # the padded image starts at cell position (-1, -1), i.e. (ph - 1, pw - 1)
                cell = [[cfa.cell[(i - 1) % ph][(j - 1) % pw] for j in range(pw)] for i in range(ph)]
                cfa = CFA(cell, cfa.channel_names)
        pseudo = _pseudo_bayer(cfa)
        if cfa.is_bayer and cfa.channel_names == ["R", "G", "B"]:
            out = self.bayer(mosaic, cfa.bayer_pattern)
        elif pseudo is not None:
            pattern, order = pseudo
            out = self.bayer(mosaic, pattern)[:, order]
        else:
            out = demosaic(mosaic, cfa.index_map.to(mosaic.device), self.fallback, num_channels=cfa.num_channels)
        return out[..., pad:out.shape[-2] - pad, pad:out.shape[-1] - pad] if pad else out

    def extra_repr(self) -> str:
        return f"method={self.method!r}, fallback={self.fallback!r}, border={self.border!r}"


def _pseudo_bayer(cfa) -> tuple[str, list[int]] | None:
    """A 2x2 CFA of 3 channels with one filter on a diagonal (Bayer RGB, CMY 'YCMY', ...) as a Bayer pattern
    string (the diagonal filter as G, the others as R then B in reading order) and the index of each CFA
    channel in the Bayer method's RGB output; None for other CFAs."""
    if cfa.shape != (2, 2) or cfa.num_channels != 3:
        return None
    cell = cfa.index_map.tolist()
    if cell[0][0] == cell[1][1] and cell[0][1] != cell[1][0] != cell[0][0]:
        diag, others = cell[0][0], [cell[0][1], cell[1][0]]
    elif cell[0][1] == cell[1][0] and cell[0][0] != cell[1][1] != cell[0][1]:
        diag, others = cell[0][1], [cell[0][0], cell[1][1]]
    else:
        return None
    letter = {diag: "G", others[0]: "R", others[1]: "B"}
    pattern = "".join(letter[i] for row in cell for i in row)
    rgb_index = {"R": 0, "G": 1, "B": 2}
    return pattern, [rgb_index[letter[c]] for c in range(3)]


def _sensor_qe(sensor, wavelengths_nm: torch.Tensor) -> torch.Tensor:
    """Spectral QE (C, L) of a sensor-like object on a grid (adapter over the sensor package's API)."""
    from ..sensor.filters import SpectralQE

    if isinstance(sensor, SpectralQE):
        return sensor(wavelengths_nm)
    for name in ("spectral_qe", "qe"):
        attr = getattr(sensor, name, None)
        if attr is None:
            continue
        qe = attr(wavelengths_nm) if callable(attr) else attr
        if isinstance(qe, torch.Tensor) and qe.dim() == 2 and qe.shape[-1] == wavelengths_nm.numel():
            return qe
    raise TypeError(f"sensor: expected an object whose spectral_qe(wavelengths_nm) gives (C, L), got "
                    f"{type(sensor).__name__}")


class ImageProcessor(ExactConstants):
    """Image processor: raw mosaic -> encoded display image.

    Args:
        demosaic: a method name (``"bilinear"``, ``"malvar2004"``, ``"menon2007"``, ...) or a module
            ``(mosaic, cfa) -> (B, C, H, W)``.
        illuminant_correction: ``"none"``, ``"gray_world"``, ``"white_world"``, ``"manual"`` or an
            :class:`IlluminantCorrection`.
        correction_space: ``"xyz"`` (ISETCam) or ``"sensor"``.
        correction_white: the illuminant whose white the correction targets (ISETCam: D65). In sensor space
            the target is the sensor value that the colour matrix renders as that white.
        gains: manual gains for ``"manual"``.
        sensor_to_xyz: a :class:`SensorToXYZ` (default: MCC optimised under D65, ISETCam's default) or a
            (3, C) matrix.
        display: ``"srgb"``, a display preset name (``"lcd"``, ``"crt"``, ``"apple"``), a display object with
            primaries' SPDs, a (3, 3) RGB -> XYZ matrix, or an :class:`XYZToDisplay`.
        encoding: ``"srgb"``, ``"linear"``, a gamma, or ``"display"`` (the display's own transfer function).
        scaling: one of ``SCALINGS``.
        clip_negative_xyz: clip XYZ at 0 after the matrix (ISETCam ``imageSensorCorrection``).
        fit_wavelengths_nm: grid on which the colour matrix is fitted from the sensor's QE (400:10:700).
        scaling_percentile: the percentile used by ``scaling="percentile"`` (default 99; an error with another
            scaling, which would ignore it).
        adapt_to_display_white: adapt XYZ from ``correction_white`` to the display's white (Bradford), so a
            display whose white is not D65 still renders white as RGB (1, 1, 1) (ISETCam does not).
        monochrome_divisor: ``"white_level"`` or ``"voltage_swing"`` (ISETCam: input / voltage swing; ISETCam's
            ``ipCompute`` subtracts no zero level for a monochrome sensor, so an analog offset stays in the image).

    Example:
        >>> ip = ImageProcessor(illuminant_correction="gray_world")
        >>> ip.sensor_to_xyz.set_matrix(torch.eye(3))  # doctest: +ELLIPSIS
        SensorToXYZ(...)
        >>> from isettorch.sensor.raw import RawImage
        >>> out = ip(RawImage(torch.rand(1, 1, 8, 8), "volts", "GBRG", white_level=1.0))
        >>> out.image.shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(self, demosaic="bilinear", illuminant_correction="none", correction_space: str = "xyz",
                 correction_white="D65", gains=None, sensor_to_xyz=None, display="srgb", encoding="srgb",
                 scaling: str = "adaptive", clip_negative_xyz: bool = True, fit_wavelengths_nm=None,
                 monochrome_divisor: str = "white_level", scaling_percentile: float | None = None,
                 adapt_to_display_white: bool = False) -> None:
        super().__init__()
        check_illuminant_name(correction_white, "correction_white")
        self.demosaic = demosaic if isinstance(demosaic, nn.Module) else DemosaicStage(demosaic)
        if isinstance(illuminant_correction, nn.Module):
            self.illuminant_correction = illuminant_correction
        else:
            try:
                self.illuminant_correction = IlluminantCorrection(illuminant_correction, correction_space, gains)
            except ValueError as err:  # (the stage's arguments are method / space: name this one's)
                arg, _, rest = str(err).partition(": ")
                ours = {"method": "illuminant_correction", "space": "correction_space"}.get(arg)
                if ours is None:
                    raise
                raise ValueError(f"{ours}: {rest}") from None
        if sensor_to_xyz is None:
            sensor_to_xyz = SensorToXYZ()
        elif not isinstance(sensor_to_xyz, nn.Module):
            sensor_to_xyz = SensorToXYZ(matrix=sensor_to_xyz)
        self.sensor_to_xyz = sensor_to_xyz
        adapt = check_bool(adapt_to_display_white, "adapt_to_display_white")  # ('no' had turned it on)
        try:  # (a bad SPD was reported as 'illuminant: ...', an argument the caller never passed)
            correction_xyz = white_xyz(correction_white)
        except ValueError as err:
            raise ValueError(f"correction_white: {str(err).partition(': ')[2]}") from err
        # the white's XYZ (an SPD given as correction_white had been passed on as if it were an XYZ)
        self.xyz_to_display = display if isinstance(display, nn.Module) else XYZToDisplay(
            display, adapt_from=correction_xyz if adapt else None)
        if isinstance(encoding, str) and encoding == "display":  # the display's own transfer function
            encoding = DisplayEncode(getattr(self.xyz_to_display, "display", None) or "srgb")
        self.encode = encoding if isinstance(encoding, nn.Module) else DisplayEncode(encoding)
        if scaling not in SCALINGS:
            raise ValueError(f"scaling: expected one of {list(SCALINGS)}, got {scaling!r}")
        if monochrome_divisor not in ("white_level", "voltage_swing"):
            raise ValueError(f"monochrome_divisor: expected 'white_level' or 'voltage_swing', got "
                             f"{monochrome_divisor!r}")
        if scaling_percentile is not None:
            if not (isinstance(scaling_percentile, (int, float)) and not isinstance(scaling_percentile, bool)
                    and 0 < scaling_percentile <= 100):
                raise ValueError(f"scaling_percentile: expected a value in (0, 100], got {scaling_percentile!r}")
            if scaling != "percentile":
                raise ValueError(f"scaling_percentile: only scaling 'percentile' uses it, got scaling {scaling!r} "
                                 f"(set scaling: percentile, or drop scaling_percentile)")
        self.scaling = scaling
        self.scaling_percentile = 99.0 if scaling_percentile is None else float(scaling_percentile)
        self.clip_negative_xyz = check_bool(clip_negative_xyz, "clip_negative_xyz")
        self.monochrome_divisor = monochrome_divisor
        self.correction_white = correction_white
        self.register_constant("white_xyz", correction_xyz)
        w = torch.arange(400.0, 701.0, 10.0) if fit_wavelengths_nm is None else torch.as_tensor(fit_wavelengths_nm)
        self.fit_wavelengths_nm = check_wavelengths(w.to(torch.float64))

    # --- preparation ---------------------------------------------------------------------------
    def fit(self, sensor) -> ImageProcessor:
        """Fit the colour matrix to a sensor (anything with ``spectral_qe(wavelengths_nm)``) or a QE (C, L)
        on ``fit_wavelengths_nm``. Cached: refitting the same sensor is free."""
        fit = getattr(self.sensor_to_xyz, "fit", None)
        if fit is None:
            return self
        qe = sensor if isinstance(sensor, torch.Tensor) else _sensor_qe(sensor, self.fit_wavelengths_nm)
        dev = self.white_xyz.device
        # Fitted in float64 on the processor's device; apply_matrix casts to the image's dtype. A QE that requires
        # grad keeps its graph: SensorToXYZ.fit then fits inside it (the filters' total derivative).
        fit(qe.to(device=dev, dtype=torch.float64), self.fit_wavelengths_nm.to(dev))
        return self

    # --- stages ------------------------------------------------------------------------------
    def _normalized_input(self, raw) -> torch.Tensor:
        from ..sensor.raw import RawImage

        if not isinstance(raw, RawImage):  # (a bare mosaic failed with "'Tensor' object has no attribute ...")
            raise TypeError(f"raw: expected a RawImage (a sensor's capture; a demosaiced image goes to "
                            f"from_demosaiced), got {type(raw).__name__}")
        if raw.white_level is None:
            raise ValueError("raw: the image processor needs raw.white_level (the saturation value) to scale the "
                             "mosaic, got None")
        # (checked here, not only by the built-in demosaics: through a user's demosaic module a NaN raw came out as a
        # black image with NaN pixels and scale 0, no error)
        check_finite(raw.data.detach(), "raw")
        return raw.normalized()

    def _sensor_white_target(self, matrix: torch.Tensor) -> torch.Tensor:
        """The sensor value that the colour matrix renders as the correction white. Unique for C = 3 channels;
        with more (RGBW, 4 channels) the sensor's own white under the fit's illuminant (``sensor_white``) moved the
        least to map to it, ``s + pinv(M) (k w - M s)``: the minimum-norm solution alone had negative channels
        (no sensor responds so; the correction refused it)."""
        m = matrix.double()
        target = self.white_xyz.to(device=matrix.device, dtype=torch.float64)
        if m.shape[1] <= 3:
            return torch.linalg.lstsq(m, target[:, None]).solution[:, 0].to(matrix.dtype)
        s = getattr(self.sensor_to_xyz, "sensor_white", None)
        if s is None:
            raise ValueError(f"correction_space: 'sensor' with a colour matrix of {m.shape[1]} channels needs the "
                             f"sensor's own white to choose among the sensor values rendered as the correction white "
                             f"(a matrix fitted to the sensor records it); fit the matrix, or use correction_space="
                             f"'xyz'")
        s = s.to(m)
        y = m @ s
        t = s + torch.linalg.pinv(m) @ (y[1] / target[1] * target - y)  # M t = (Y of M s) x the white, exactly
        return t.to(matrix.dtype)

    def fit_raw(self, raw) -> ImageProcessor:
        """Fit the colour matrix to the sensor that made ``raw`` (its ``spectral_qe``), once per QE module: what
        :meth:`forward` does, so a processor needs no separate ``fit(sensor)``. No-op for a raw without QE or a
        fixed matrix. A raw with one QE per item (a per-call ``spectral_qe`` of batch size B) cannot be fitted one
        matrix: ValueError, unless the matrix is fixed."""
        qe = getattr(raw, "spectral_qe", None)
        s2x = self.sensor_to_xyz
        if qe is None or getattr(s2x, "fit", None) is None or getattr(s2x, "_fit_key", None) == "fixed":
            return self
        if getattr(qe, "batch_size", None) is not None:
            raise ValueError(f"raw: its spectral_qe holds one QE per item ({qe.batch_size}), and the image processor "
                             f"fits one colour matrix; render the items with one shared QE, or give the processor a "
                             f"fixed sensor_to_xyz matrix")
        # the QE's tensors' identity and version (a new or edited tensor is refitted), and the matrix's own fit key
        # (a fit of another sensor in between replaced the matrix)
        cacheable = getattr(qe, "cacheable", False)
        token, tensors = qe.cache_state() if cacheable else (None, ())
        last = self.__dict__.get("_raw_fit")
        if (not cacheable or last is None or last[0] != (id(qe), token) or last[1] is not qe
                or last[3] != getattr(s2x, "_fit_key", None)):
            self.fit(qe)
            # (the module and tensors kept: their ids are not reused)
            self.__dict__["_raw_fit"] = ((id(qe), token), qe, tensors, getattr(s2x, "_fit_key", None))
        return self

    @full_precision
    def forward(self, raw) -> ISPResult:
        """Process a :class:`~isettorch.sensor.raw.RawImage`; returns an :class:`ISPResult`. The colour matrix is
        fitted from the raw's ``spectral_qe`` when it carries one (:meth:`fit_raw`); a matrix fitted inside the
        graph (learnable filters) is kept in the result's graph only, the module keeps its detached value (so it can
        be copied and saved like any module)."""
        self.fit_raw(raw)
        try:
            return self._process(raw)
        finally:
            release = getattr(self.sensor_to_xyz, "release_graph", None)
            if release is not None:
                release()

    def _process(self, raw) -> ISPResult:
        x = self._normalized_input(raw)
        if raw.cfa.is_monochrome:
            # ISETCam ipCompute: a monochrome sensor skips the colour pipeline (FORMAT.md 4.10).
            if self.monochrome_divisor == "voltage_swing":
                if raw.voltage_swing_v is None:
                    raise ValueError("raw: monochrome_divisor='voltage_swing' needs raw.voltage_swing_v")
                # the black level without the offset (ipComputeSingle)
                mono = (raw.data - raw.broadcast(raw.black_level - raw.offset_level)) / raw.voltage_swing_v
            else:
                mono = x
            # encoded as a colour image is (a linear, unclipped image from an sRGB processor: 0.25 for 0.537); ISETCam's
            # ip_result, unclipped input / voltage swing, is display_linear
            mono3 = mono.expand(-1, 3, -1, -1)
            return ISPResult(image=self.encode(mono3), input=x, display_linear=mono3)
        sensor = self.demosaic(x, raw.cfa)
        if raw.units == "dn":
            # ISETCam displayRender, quantized sensor ('linear'): the image maximum becomes 1.
            peak = torch.ones(x.shape[0], dtype=x.dtype, device=x.device)
        else:
            # ISETCam displayRender, analog sensor: the image maximum becomes max volts / voltage swing
            # ('volts 2 max ratio': of the raw volts, an analog offset included, not of the input above the zero level)
            peak = (raw.data / raw.levels()[1]).flatten(1).amax(1)
        return self.from_demosaiced(sensor, input_max=peak, _input=x)

    def from_demosaiced(self, sensor: torch.Tensor, input_max: torch.Tensor | None = None,
                        _input: torch.Tensor | None = None) -> ISPResult:
        """Run the colour stages on a demosaiced image (B, C, H, W) relative to the white level (resume point
        for a user-modified or externally demosaiced image). ``input_max`` (B,) is the raw maximum used by
        the ``"adaptive"`` scaling (default: the image maximum)."""
        if sensor.dim() != 4:
            raise ValueError(f"sensor: expected a demosaiced image (B, C, H, W), got shape {tuple(sensor.shape)}")
        if _input is None:  # the raw path checked its input; a user's image is checked here (a NaN would spread)
            check_finite(sensor.detach(), "sensor")
            if input_max is not None:  # (a [3] input_max for one image returned three; NaN gave a NaN image)
                input_max = batch_param(input_max, "input_max", sensor.shape[0], dtype=sensor.dtype,
                                        device=sensor.device)
                if bool((input_max.detach() < 0).any()):
                    raise ValueError(f"input_max: expected raw maxima >= 0, got {input_max.detach().tolist()}")
        m = self.sensor_to_xyz.matrix if hasattr(self.sensor_to_xyz, "matrix") else None
        if m is None:
            raise RuntimeError("ImageProcessor: the sensor -> XYZ matrix is not set; call ip.fit(sensor) (Camera "
                               "does it) or pass sensor_to_xyz=matrix")
        ic = self.illuminant_correction
        space = getattr(ic, "space", "xyz")
        balanced = sensor
        gains = None
        if space == "sensor":
            # only gray and white world use the white ('none' and 'manual' refused a 4-channel sensor for want of one;
            # ISETCam imageIlluminantCorrection 'none': D = eye(N), for N ~= 3 too)
            uses_white = getattr(ic, "method", None) not in ("none", "manual")  # (a user's module: given it)
            balanced = ic(sensor, white=self._sensor_white_target(m) if uses_white else None)
            gains = getattr(ic, "last_gains", None)
        xyz = self.sensor_to_xyz(balanced)
        if self.clip_negative_xyz:
            xyz = xyz.clamp_min(0)
        xyz_bal = xyz
        if space == "xyz":
            xyz_bal = ic(xyz, white=self.white_xyz.to(device=xyz.device, dtype=xyz.dtype))
            gains = getattr(ic, "last_gains", None)
        rgb = self.xyz_to_display(xyz_bal)
        scale = self._scale(rgb, sensor, input_max)
        display = rgb * scale[:, None, None, None]
        return ISPResult(image=self.encode(display), input=_input, demosaiced=sensor, sensor_balanced=balanced,
                         xyz=xyz, xyz_balanced=xyz_bal, display_linear=display, gains=gains,
                         sensor_to_xyz=m, xyz_to_display=getattr(self.xyz_to_display, "matrix", None), scale=scale)

    def _scale(self, rgb: torch.Tensor, sensor: torch.Tensor, input_max: torch.Tensor | None) -> torch.Tensor:
        ones = torch.ones(rgb.shape[0], dtype=rgb.dtype, device=rgb.device)
        if self.scaling == "exposure":
            return ones
        if self.scaling == "percentile":
            # differentiable (the scale divides the signal level out: exposure, gain and f-number leave the image
            # alone, and their gradients say so)
            peak = percentile_linear(rgb.flatten(1), self.scaling_percentile)
        else:
            peak = rgb.flatten(1).amax(1)
        # A black render (peak <= 0: no light, or everything outside the display gamut) stays black: scale 0.
        # The [B] scale is computed in float64: a float32 peak below ~5e-20 (a nearly black render) overflowed the
        # reciprocal's derivative, 1 / peak^2, to inf, and the gradient to the scene was NaN
        lit = peak > 0
        safe = torch.where(lit, peak, torch.ones_like(peak)).double()
        if self.scaling in ("max", "percentile"):
            return torch.where(lit, 1.0 / safe, 0.0).to(rgb.dtype)
        # ISETCam displayRender ('analog'): img / max(img) * (max volts / voltage swing).
        ratio = sensor.flatten(1).amax(1) if input_max is None else input_max.to(device=rgb.device, dtype=rgb.dtype)
        return torch.where(lit, ratio.double().clamp_min(0) / safe, 0.0).to(rgb.dtype)

    def extra_repr(self) -> str:
        return f"scaling={self.scaling!r}, clip_negative_xyz={self.clip_negative_xyz}"
