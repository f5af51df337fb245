"""`Camera`: scene -> optics -> sensor -> image processor, with every intermediate on request.

Reference: Farrell, Xiao, Catrysse, Wandell, "A simulation tool for evaluating digital camera image quality",
SPIE 5294 (2004): the four ISET modules (scene, optics, sensor, processor), each inspectable and replaceable.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import numbers
from pathlib import Path
from typing import Any

import torch
from torch import nn

from ._autograd import full_precision
from ._checks import check_bool, is_integer, is_real, warn_caller
from ._yaml import load_yaml
from .isp.pipeline import DemosaicStage, ImageProcessor, ISPResult
from .scene.scene import Scene

__all__ = ["Camera", "CameraOutput", "load_config", "load_yaml", "check_config_values", "check_sensor_values",
           "camera_config_names", "CONFIG_SECTIONS"]


@dataclasses.dataclass
class CameraOutput:
    """Everything a camera computed: the final ``image`` (B, 3, H, W) and the intermediates.

    ``scene``, ``optical_image``, ``raw`` (a :class:`~isettorch.sensor.raw.RawImage`) and ``isp`` (an
    :class:`~isettorch.isp.pipeline.ISPResult` with the demosaiced, white-balanced, XYZ and display stages and
    the matrices used); None for the stages a resumed run did not compute.
    """

    image: torch.Tensor
    scene: Any = None
    optical_image: Any = None
    raw: Any = None
    isp: ISPResult | None = None

    def __getattr__(self, name: str):
        # Convenience: out.demosaiced, out.xyz, ... read from the ISP result.
        if name not in ("isp",) and self.isp is not None and hasattr(self.isp, name):
            return getattr(self.isp, name)
        raise AttributeError(f"CameraOutput has no attribute {name!r}")


class Camera(nn.Module):
    """A camera: ``optics`` (scene -> OpticalImage), ``sensor`` (OpticalImage -> RawImage) and ``isp``
    (RawImage -> ISPResult). Each is a submodule that can be replaced (``camera.isp = MyISP()``).

    Args:
        optics, sensor: modules (e.g. :class:`~isettorch.optics.DiffractionLimitedOptics`,
            :class:`~isettorch.sensor.Sensor`).
        isp: an :class:`~isettorch.isp.pipeline.ImageProcessor` (default ISETCam-like).
        noise: simulate sensor noise (False: the noise-free capture).
        crop_to_sensor: compute only the part of the optical image the sensor sees (default True). The result
            agrees with the full computation within the optics' ``psf_tolerance`` (PSF energy beyond the margin;
            measured 6e-4 of the maximum at the default 1e-3, and exactly for ISETCam padding), see
            :meth:`sensor_window`. That is the noise-free signal: with Poisson shot noise the same seed gives
            another noise draw (``torch.poisson`` advances the generator by an amount that depends on the signal, so
            the cropped and full runs draw differently), a draw of the same distribution.
        sensor_window_margin: OI samples kept beyond the sensor footprint (plus the pre-blur reach).

    Example:
        >>> cam = Camera.from_config("default")  # a built-in config (camera_config_names()), or a YAML path
        >>> out = cam(scene, return_intermediates=True)  # doctest: +SKIP
        >>> out.raw.data, out.isp.xyz, out.image  # doctest: +SKIP
        >>> edited = out.optical_image.replace(photons=out.optical_image.photons * 2)  # doctest: +SKIP
        >>> cam.from_optical_image(edited)  # doctest: +SKIP
    """

    def __init__(self, optics: nn.Module, sensor: nn.Module, isp: nn.Module | None = None, noise: bool = True,
                 name: str = "", crop_to_sensor: bool = True, sensor_window_margin: int = 2) -> None:
        super().__init__()
        # flags are True or False ('no' was True) and the margin a whole number of samples (2.7 was 2)
        self.crop_to_sensor = check_bool(crop_to_sensor, "crop_to_sensor")
        if not (is_integer(sensor_window_margin) and sensor_window_margin >= 0):
            raise ValueError(f"sensor_window_margin: expected an integer number of samples >= 0, got "
                             f"{sensor_window_margin!r}")
        self.sensor_window_margin = int(sensor_window_margin)
        for label, module in (("optics", optics), ("sensor", sensor)):
            if not isinstance(module, nn.Module):
                raise TypeError(f"{label}: expected an nn.Module (an optics or sensor stage), got "
                                f"{type(module).__name__}")
        if isp is not None and not isinstance(isp, nn.Module):  # (isp='x' was taken and failed at the first call)
            raise TypeError(f"isp: expected None or an nn.Module (an image processor), got {type(isp).__name__}")
        self.optics = optics
        self.sensor = sensor
        self.isp = isp if isp is not None else ImageProcessor()
        self.noise = check_bool(noise, "noise")
        self.name = name

    # --- pipeline ------------------------------------------------------------------------------
    @full_precision
    def forward(self, scene, return_intermediates: bool = False, *, exposure_s=None, generator=None,
                **sensor_kwargs):
        """Render a :class:`~isettorch.scene.Scene` (dense or factored); returns the image (B, 3, H, W) or a
        :class:`CameraOutput`.

        When the sensor has a fixed size smaller than the optical image and the optics can compute a window
        (``plan()`` and ``crop=``), only the window the sensor sees is computed (see :meth:`sensor_window`).
        A factored scene stays factored through the optics; the sensor projects it on its QE channels.
        ``sensor_kwargs``: per-call sensor settings (``analog_gain``, ``exposure_ev``, noise levels as scalars or
        ``[B]`` tensors: :data:`isettorch.sensor.sensor.PER_CALL_LEVELS`).
        """
        # (a tensor or None raised an AttributeError about 'height'; 'no' read as true)
        if not isinstance(scene, Scene):
            raise TypeError(f"scene: expected an isettorch Scene, got {type(scene).__name__}")
        check_bool(return_intermediates, "return_intermediates")
        oi = self.optical_image(scene, pixel_size_m=sensor_kwargs.get("pixel_size_m"))
        out = self.from_optical_image(oi, True, exposure_s=exposure_s, generator=generator, **sensor_kwargs)
        out.scene = scene
        return out if return_intermediates else out.image

    def optical_image(self, scene, pixel_size_m=None):
        """The optics' output for ``scene``: only the sensor's window when ``crop_to_sensor`` (see
        :meth:`sensor_window`; ``pixel_size_m``: the sensor's per-call pixel pitch, scalar or ``[B]``)."""
        window = self.sensor_window(scene, pixel_size_m) if self.crop_to_sensor else None
        return self.optics(scene) if window is None else self.optics(scene, crop=window)

    def sensor_window(self, scene, pixel_size_m=None) -> tuple[int, int, int, int] | None:
        """The window ``(top, left, height, width)`` of the full optical image that the sensor samples, or None.

        The window is centred on the optical axis (so the cropped image stays centred and the sensor samples the
        same positions) and covers the sensor footprint plus ``sensor_window_margin`` OI samples on each side
        for the sampling kernels (ISETCam's pre-blur reaches ``ceil(pitch / dx)`` samples). None when the sensor
        sizes itself to the optical image, when the optics cannot plan a window, or when it would not be smaller.
        ``pixel_size_m``: a per-call pixel pitch (scalar or ``[B]``, see :meth:`isettorch.sensor.Sensor.channel_rates`)
        instead of the sensor's.
        """
        rows, cols = getattr(self.sensor, "rows", None), getattr(self.sensor, "cols", None)
        plan = getattr(self.optics, "plan", None)
        if rows is None or cols is None or plan is None:
            return None
        info = plan(scene)
        full_h, full_w = info["full_shape"]
        # memoised per spacing tensor (an optics' cached geometry returns the same one for a repeated geometry; the
        # entry keeps it alive, so its id is not reused) and sensor geometry
        if pixel_size_m is None:
            pitch = float(self.sensor.pixel_size_m)
        else:  # per item: a tuple of plain numbers in the key
            pitch = tuple(torch.as_tensor(pixel_size_m, dtype=torch.float64).reshape(-1).tolist())
        key = (id(info["sample_spacing_m"]), full_h, full_w, rows, cols, pitch,
               getattr(self.sensor, "sampling", None), self.sensor_window_margin)
        memo = self.__dict__.setdefault("_window_memo", {})
        hit = memo.get(key)
        if hit is not None and hit[0] is info["sample_spacing_m"]:
            return hit[1]
        window = self._sensor_window(info, rows, cols, pitch)
        if not info["sample_spacing_m"].requires_grad:
            if len(memo) > 64:
                memo.clear()
            memo[key] = (info["sample_spacing_m"], window)
        return window

    def _sensor_window(self, info: dict, rows: int, cols: int, pitches: float | tuple
                       ) -> tuple[int, int, int, int] | None:
        full_h, full_w = info["full_shape"]
        spacing = info["sample_spacing_m"].detach()
        dx = float(spacing.min())
        per_item = torch.as_tensor(pitches, dtype=spacing.dtype, device=spacing.device)
        pitch = max(pitches) if isinstance(pitches, tuple) else float(pitches)  # in float64, as the sensor's
        margin = self.sensor_window_margin + math.ceil(pitch / dx)
        # One OI sample per pixel (the grids coincide to the geometry's float rounding) and area sampling: each
        # pixel reads only its own sample, so the window is the sensor's footprint (no sampling margin)
        same_grid = (getattr(self.sensor, "sampling", None) == "area"
                     and bool(((spacing / per_item - 1).abs() <= 4 * torch.finfo(spacing.dtype).eps).all()))

        def extent(n_pixels: int, full: int) -> tuple[int, int]:
            if same_grid and (full - n_pixels) % 2 == 0:
                return ((full - n_pixels) // 2, n_pixels) if n_pixels < full else (0, full)
            half = math.ceil(n_pixels * pitch / (2 * dx)) + margin
            size = 2 * half + (full % 2)  # same parity as the full axis, so the window is exactly centred
            if size >= full:
                return 0, full
            return (full - size) // 2, size

        top, height = extent(rows, full_h)
        left, width = extent(cols, full_w)
        if height == full_h and width == full_w:
            return None
        return top, left, height, width

    @full_precision
    def from_optical_image(self, oi, return_intermediates: bool = False, *, exposure_s=None, generator=None,
                           **sensor_kwargs):
        """Resume from an optical image (e.g. one a user modified)."""
        check_bool(return_intermediates, "return_intermediates")  # ('no' returned the intermediates)
        kwargs = {"noise": self.noise, **sensor_kwargs}
        if exposure_s is not None:
            kwargs["exposure_s"] = exposure_s
        if generator is not None:
            kwargs["generator"] = generator
        warn_if_coarser_than_pixels(oi, self.sensor, sensor_kwargs.get("pixel_size_m"))
        raw = self.sensor(oi, **kwargs)
        out = self.from_raw(raw, True)
        out.optical_image = oi
        return out if return_intermediates else out.image

    def from_raw(self, raw, return_intermediates: bool = False):
        """Resume from a raw image (the sensor's output, possibly modified)."""
        check_bool(return_intermediates, "return_intermediates")
        # the ISP reads the sensor's QE from the raw (ImageProcessor.fit_raw); a raw without it (made by hand)
        # gets the camera's sensor
        fit = getattr(self.isp, "fit", None)
        if fit is not None and getattr(raw, "spectral_qe", None) is None:
            fit(self.sensor)
        res = self.isp(raw)
        image = res.image if isinstance(res, ISPResult) else res
        out = CameraOutput(image=image, raw=raw, isp=res if isinstance(res, ISPResult) else None)
        return out if return_intermediates else out.image

    def from_demosaiced(self, demosaiced: torch.Tensor, return_intermediates: bool = False):
        """Resume from a demosaiced sensor image (B, C, H, W), relative to the white level."""
        check_bool(return_intermediates, "return_intermediates")
        self.isp.fit(self.sensor)
        res = self.isp.from_demosaiced(demosaiced)
        out = CameraOutput(image=res.image, isp=res)
        return out if return_intermediates else out.image

    def extra_repr(self) -> str:
        return f"name={self.name!r}, noise={self.noise}"

    # --- configuration -------------------------------------------------------------------------
    @classmethod
    def from_config(cls, config) -> Camera:
        """Build a camera from a built-in config name, a YAML file (:func:`load_yaml`: ``yaml.SafeLoader`` with
        YAML 1.2 floats, so ``1e-2`` is a number) or a dict.

        ``config``: a name from :func:`camera_config_names` (``"default"``, ``"imx363"``, ``"paper2004_cds"``:
        the files in ``isettorch/configs/cameras/``, shipped with the package), a path to a YAML file, or a dict
        with the same sections and keys as the YAML (``Camera.from_config(load_yaml(text))`` equals
        ``Camera.from_config(path)``). Keys are the constructor arguments of the stage they configure, with units
        in their names (``focal_length_m``, ``exposure_s``, ``pixel_size_m``).

        Unknown or mistyped keys raise a ``ValueError`` naming the key, its section and the closest valid key; a
        value of the wrong kind (``cds: 'no'``, ``fill_factor: '0.9'``, ``adc_bits: true``, a NaN) an error naming
        the key (:func:`check_config_values`), and so does a key that nothing would use (``ae_target`` without
        ``auto_exposure``, ``isp.gains`` without ``illuminant_correction: manual``, ...).
        """
        return build_camera(load_config(config) if not isinstance(config, dict) else config)


def warn_if_coarser_than_pixels(oi, sensor, pixel_size_m=None) -> None:
    """Warn when the optical image is sampled more coarsely than the sensor's pixel grid.

    The sensor then interpolates between samples that are farther apart than a pixel, which blurs the image
    beyond what the optics do (issue 18: MTF50 0.33 cy/px with a 1024^2 scene against 0.21 with 256^2 on the
    same sensor). ``pixel_size_m``: a per-call pixel pitch (scalar or ``[B]``) instead of the sensor's.
    """
    pitch = getattr(sensor, "pixel_size_m", None) if pixel_size_m is None else pixel_size_m
    dx = getattr(oi, "sample_spacing_m", None)
    if pitch is None or dx is None:
        return
    if pixel_size_m is None:
        dx, pitch = float(torch.as_tensor(dx).max()), float(pitch)
    else:  # per item: the item whose samples are coarsest against its own pitch
        pairs = torch.broadcast_tensors(torch.as_tensor(dx, dtype=torch.float64).detach().cpu().reshape(-1),
                                        torch.as_tensor(pitch, dtype=torch.float64).detach().cpu().reshape(-1))
        k = int((pairs[0] / pairs[1]).argmax())
        dx, pitch = float(pairs[0][k]), float(pairs[1][k])
    if dx > pitch * (1 + 1e-6):
        warn_caller(
            f"the scene is coarser than the pixel grid: optical image samples every {dx * 1e6:.4g} um, pixel pitch "
            f"{pitch * 1e6:.4g} um ({dx / pitch:.4g} pixels per sample); the sensor interpolates, which blurs the "
            f"image beyond the optics (lower MTF). Sample the scene at least {dx / pitch:.4g}x more finely "
            "(more samples across the same field of view).")


# ---------------------------------------------------------------------------------------------
# Configuration


CONFIG_SECTIONS = ("name", "description", "optics", "sensor", "isp", "camera")
ISP_KEYS = {
    "demosaic": str, "demosaic_border": str, "demosaic_fallback": str, "illuminant_correction": str,
    "correction_space": str, "correction_white": str, "gains": list, "sensor_conversion": dict,
    "display": (str, list),
    "encoding": (str, float, int), "scaling": str, "clip_negative_xyz": bool, "monochrome_divisor": str,
    "scaling_percentile": (float, int), "adapt_to_display_white": bool,
}
SENSOR_CONVERSION_KEYS = {"method": str, "illuminant": str, "surfaces": str, "observer": str, "matrix": list,
                          "normalize": bool, "learnable": bool, "white_preserving": bool}
CAMERA_KEYS = {"noise": bool}
DEMOSAIC_ALIASES = {"adaptive": "menon2007"}


def _unknown(key: str, valid, where: str) -> ValueError:
    close = difflib.get_close_matches(str(key), list(valid), n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return ValueError(f"config: unknown key {key!r} in {where}{hint} (valid keys: {sorted(valid)})")


def _check_keys(section: dict, schema: dict, where: str) -> None:
    if not isinstance(section, dict):
        raise TypeError(f"config: {where} must be a mapping, got {type(section).__name__}")
    for key, value in section.items():
        if key not in schema:
            raise _unknown(key, schema, where)
        expected = schema[key]
        if value is None or expected is None:
            continue
        types = expected if isinstance(expected, tuple) else (expected,)
        numeric = any(t in (int, float) for t in types)
        # bool is an int to Python: a number key takes no true/false, a bool key nothing else
        if isinstance(value, bool) and bool not in types or not isinstance(value, types):
            names = "/".join(t.__name__ for t in types)
            raise TypeError(f"config: {where}.{key} must be {names}, got {type(value).__name__} ({value!r})")
        if numeric and isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"config: {where}.{key} must be a finite number, got {value!r}")


def _annotation_kind(annotation) -> tuple[str | None, bool]:
    """(``'bool'``, ``'int'``, ``'number'`` or None, None allowed) of a constructor argument's annotation, read from
    its text (the modules use ``from __future__ import annotations``): ``bool``, ``int``, ``int | None``, ``float``,
    ``float | None``; anything else (tensors, strings, unions of other types) is left to the constructor."""
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    parts = {p.strip() for p in text.split("|")}
    optional = "None" in parts
    parts.discard("None")
    kind = {frozenset({"bool"}): "bool", frozenset({"int"}): "int", frozenset({"float"}): "number"}.get(
        frozenset(parts))
    return kind, optional


def check_config_values(section: dict, functions, where: str) -> None:
    """Check the values of a config section against the annotations of the constructor(s) they go to, so a config
    key is what its argument says (DESIGN.md, principle 5), the same check for every section:

    * ``bool``: a YAML boolean (``true`` / ``false``); ``'no'``, ``'false'``, 0 or 1 are errors, not truthy values;
    * ``int`` (``seed``, ``adc_bits``, ``rows``): an integer, not a bool (``true`` is no bit depth), float or string;
    * ``float`` (every ``..._m``, ``..._v``, ``..._s`` scalar): a real number (int or float, not a bool or a string:
      ``'0.1'`` is no number), finite (infinite only where the argument's default is, e.g. ``focus_distance_m``).

    ``None`` passes where the annotation allows it. TypeError (ValueError for NaN / Inf) naming ``where.key``.
    ``functions``: a callable or several (a class and its bases); the first that has a key annotates it.
    """
    if not isinstance(section, dict):
        raise TypeError(f"config: {where} must be a mapping, got {type(section).__name__}")
    params: dict = {}
    for fn in (functions if isinstance(functions, (list, tuple)) else (functions,)):
        for name, p in inspect.signature(fn).parameters.items():
            params.setdefault(name, p)
    for key, value in section.items():
        p = params.get(key)
        if p is None or p.annotation is inspect.Parameter.empty:
            continue
        kind, optional = _annotation_kind(p.annotation)
        if kind is None or value is None and optional:
            continue
        got = f"got {type(value).__name__} ({value!r})"
        if kind == "bool":
            if not isinstance(value, bool):
                raise TypeError(f"config: {where}.{key} must be true or false (a YAML boolean), {got}")
        elif isinstance(value, bool) or not isinstance(value, numbers.Integral if kind == "int" else numbers.Real):
            what = "an integer" if kind == "int" else "a number (int or float; a quoted '1.5' is a string)"
            raise TypeError(f"config: {where}.{key} must be {what}{' or null' if optional else ''}, {got}")
        elif not math.isfinite(value):
            # infinity only where the argument's own default is infinite (e.g. focus_distance_m: .inf, at infinity)
            if math.isnan(value) or not (isinstance(p.default, float) and math.isinf(p.default)):
                raise ValueError(f"config: {where}.{key} must be a finite number, got {value!r}")


def _signature_keys(fn) -> dict:
    params = inspect.signature(fn).parameters
    return {n: None for n, p in params.items() if n != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}


def _builtin_configs():
    from importlib.resources import files

    return files("isettorch") / "configs" / "cameras"


def camera_config_names() -> list[str]:
    """Names of the camera configs shipped with the package (``Camera.from_config(name)``)."""
    return sorted(f.name[: -len(".yaml")] for f in _builtin_configs().iterdir() if f.name.endswith(".yaml"))


def _is_name(config) -> bool:
    # A bare word (no folder, no suffix) names a built-in config; anything else is a path.
    s = str(config)
    return isinstance(config, str) and "/" not in s and "\\" not in s and not s.endswith((".yaml", ".yml"))


def load_config(path) -> dict:
    """Read a camera config safely (:func:`load_yaml`: ``yaml.SafeLoader`` with YAML 1.2 floats): a built-in name
    (:func:`camera_config_names`) or a path."""
    import yaml

    if _is_name(path):
        names = camera_config_names()
        if path not in names:
            close = difflib.get_close_matches(path, names, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"config: no built-in camera config named {path!r}{hint} (built-in: {names}; "
                             "or give a path to a .yaml file)")
        text = (_builtin_configs() / f"{path}.yaml").read_text()
    else:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"path: camera config {str(path)!r} does not exist "
                                    f"(built-in configs, by name: {camera_config_names()})")
        try:
            text = p.read_bytes().decode("utf-8")
        except UnicodeDecodeError as err:  # (the codec's own message, naming no file)
            raise ValueError(f"path: {str(path)!r}: not UTF-8 text ({err.reason} at byte {err.start})") from err
    try:
        cfg = load_yaml(text)
    except yaml.YAMLError as err:  # a malformed file is bad input: say where, in one line
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"path: {str(path)!r} is not valid YAML{where} ({problem})") from err
    if not isinstance(cfg, dict):
        raise ValueError(f"path: {str(path)!r} must hold a YAML mapping with sections {list(CONFIG_SECTIONS)}")
    if not _is_name(path) and "optics" in cfg:  # its files relative to the YAML's folder, not the current one
        from .optics.factory import resolve_config_paths

        cfg["optics"] = resolve_config_paths(cfg["optics"], Path(path).parent)
    return cfg


def check_sensor_values(cfg: dict, where: str = "sensor") -> None:
    """:func:`check_config_values` of a ``sensor:`` section: the :class:`~isettorch.sensor.Sensor` arguments and
    those of its ``pixel_optics`` mapping (:class:`~isettorch.sensor.microlens.PixelOptics`)."""
    from .sensor import Sensor
    from .sensor.microlens import PixelOptics

    check_config_values(cfg, Sensor.__init__, where)
    if isinstance(cfg.get("pixel_optics"), dict):
        check_config_values(cfg["pixel_optics"], PixelOptics.__init__, f"{where}.pixel_optics")


def _config_tensor(value, where: str, dtype) -> torch.Tensor:
    """A config's nested list of numbers as a tensor; TypeError naming ``where`` for anything else."""
    ok = isinstance(value, list) and all(
        isinstance(row, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
        for row in value)
    if not ok:
        raise TypeError(f"config: {where} must be a matrix (a list of rows of numbers), got {value!r}")
    try:
        return torch.tensor(value, dtype=dtype)
    except (TypeError, ValueError) as err:  # ragged rows
        raise ValueError(f"config: {where} must be a matrix with rows of equal length, got {value!r}") from err


def _build_sensor(cfg: dict) -> nn.Module:
    from .sensor import PRESETS, Sensor

    cfg = dict(cfg)
    preset = cfg.pop("preset", None)
    keys = _signature_keys(Sensor.__init__)
    keys.pop("spectral_qe", None)
    _check_keys(cfg, keys, "sensor")
    check_sensor_values(cfg)
    if isinstance(cfg.get("exposure_s"), list):
        if not all(is_real(v) for v in cfg["exposure_s"]):
            raise ValueError(f"sensor.exposure_s: expected a number or a list of numbers (s), got "
                             f"{cfg['exposure_s']!r}")  # (torch's "new(): invalid data type 'str'")
        cfg["exposure_s"] = torch.tensor(cfg["exposure_s"], dtype=torch.float64)  # (float32 rounded 0.01 by 2e-8)
    if preset is not None and not isinstance(preset, str):  # (5 was reported as an unknown key)
        raise ValueError(f"sensor.preset: expected a preset name (one of {sorted(PRESETS)}), got {preset!r}")
    if preset is not None and preset not in PRESETS:
        raise _unknown(preset, PRESETS, "sensor.preset")
    ae = cfg.get("auto_exposure", None if preset is None else PRESETS[preset].get("auto_exposure"))
    if cfg.get("exposure_s") is not None and ae is not None:  # (accepted; every capture auto-exposed as without it)
        raise ValueError(f"config: sensor.exposure_s {cfg['exposure_s']!r} is not used with sensor.auto_exposure "
                         f"{ae!r} (auto-exposure chooses each capture's exposure); drop one of them")
    return Sensor(**cfg) if preset is None else Sensor.preset(preset, **cfg)


#: the keys of ``isp.sensor_conversion`` that only fitting a matrix uses (``method`` mcc_optimized / multisurface)
_FIT_KEYS = ("illuminant", "surfaces", "observer", "normalize", "white_preserving")


def _build_isp(cfg: dict) -> ImageProcessor:
    from .isp.colour import SensorToXYZ

    _check_keys(cfg, ISP_KEYS, "isp")
    cfg = dict(cfg)
    method = cfg.pop("demosaic", "bilinear")
    method = DEMOSAIC_ALIASES.get(method, method)
    try:  # (the stage's errors named its arguments, method / fallback / border, not the config's keys)
        demosaic = DemosaicStage(method, fallback=cfg.pop("demosaic_fallback", "bilinear"),
                                 border=cfg.pop("demosaic_border", "method"))
    except ValueError as err:
        arg, _, rest = str(err).partition(": ")
        key = {"method": "demosaic", "fallback": "demosaic_fallback", "border": "demosaic_border"}.get(arg)
        if key is None:
            raise
        raise ValueError(f"config: isp.{key}: {rest}") from None
    conv = dict(cfg.pop("sensor_conversion", {}) or {})
    _check_keys(conv, SENSOR_CONVERSION_KEYS, "isp.sensor_conversion")
    method = conv.pop("method", "mcc_optimized")
    if method not in ("mcc_optimized", "multisurface", "matrix"):
        raise _unknown(method, ("mcc_optimized", "multisurface", "matrix"), "isp.sensor_conversion.method")
    if method == "matrix":
        if "matrix" not in conv:
            raise ValueError("config: isp.sensor_conversion.method 'matrix' needs isp.sensor_conversion.matrix "
                             "(3 x C)")
        unused = [k for k in _FIT_KEYS if k in conv]
        if unused:
            raise ValueError(f"config: isp.sensor_conversion.{unused[0]} is not used with method 'matrix' (it sets "
                             f"how a matrix is fitted; the given matrix is used as it is): drop it, or fit with "
                             f"method mcc_optimized / multisurface")
    elif "matrix" in conv:
        raise ValueError(f"config: isp.sensor_conversion.matrix is not used with method {method!r} (which fits the "
                         f"matrix to the sensor): set method: matrix to use it, or drop it")
    if method == "multisurface":
        conv.setdefault("surfaces", "macbeth+rawtoaces190")
    matrix = conv.pop("matrix", None)
    if matrix is not None:
        matrix = _config_tensor(matrix, "isp.sensor_conversion.matrix", torch.get_default_dtype())
    s2x = SensorToXYZ(matrix=matrix, **conv)
    if isinstance(cfg.get("display"), list):  # a display given by its RGB -> XYZ matrix (columns: primaries)
        cfg["display"] = _config_tensor(cfg["display"], "isp.display", torch.float64)
        if cfg["display"].shape != (3, 3):
            raise ValueError(f"config: isp.display as a matrix must be 3 x 3, got {list(cfg['display'].shape)}")
    return ImageProcessor(demosaic=demosaic, sensor_to_xyz=s2x, **cfg)


def _in_section(section: str, scfg: dict, build):
    """``build()``; its ValueError / TypeError that names an argument (``'key: ...'``) given as a key of the config
    section ``scfg``, or of exactly one of its mappings (``sensor.pixel_optics``), is raised again naming the config
    key (``config: sensor.adc_bits: ...``): the modules' errors name their arguments, which a config user does not
    see."""
    try:
        return build()
    except (ValueError, TypeError) as err:
        arg, sep, rest = str(err).partition(": ")
        if not sep or arg == "config" or not arg.isidentifier():
            raise
        where = [arg] if arg in scfg else [f"{k}.{arg}" for k, v in scfg.items() if isinstance(v, dict) and arg in v]
        if len(where) != 1:
            raise
        cls = TypeError if isinstance(err, TypeError) else ValueError
        raise cls(f"config: {section}.{where[0]}: {rest}") from err


def build_camera(cfg: dict) -> Camera:
    """Build a :class:`Camera` from a config mapping (see :meth:`Camera.from_config`)."""
    if not isinstance(cfg, dict):
        raise TypeError(f"config: expected a mapping, got {type(cfg).__name__}")
    for key in cfg:
        if key not in CONFIG_SECTIONS:
            raise _unknown(key, CONFIG_SECTIONS, "the top level")
    for section in ("optics", "sensor"):
        if section not in cfg:
            raise ValueError(f"config: missing section {section!r} (sections: {list(CONFIG_SECTIONS)})")
    for section in ("optics", "sensor", "isp", "camera"):  # (a list, 'sensor: []', built the defaults silently)
        if cfg.get(section) is not None and not isinstance(cfg[section], dict):
            raise ValueError(f"{section}: expected a mapping of settings (or nothing, for the defaults), got "
                             f"{type(cfg[section]).__name__} {cfg[section]!r}")
    cam_cfg = cfg.get("camera") or {}
    _check_keys(cam_cfg, CAMERA_KEYS, "camera")
    from .optics.factory import build_optics  # every optics type (isettorch.optics.factory)

    optics = _in_section("optics", cfg["optics"] or {}, lambda: build_optics(cfg["optics"] or {}))
    sensor = _in_section("sensor", cfg["sensor"] or {}, lambda: _build_sensor(cfg["sensor"] or {}))
    isp = _in_section("isp", cfg.get("isp") or {}, lambda: _build_isp(cfg.get("isp") or {}))
    camera = Camera(optics, sensor, isp, noise=cam_cfg.get("noise", True), name=str(cfg.get("name", "")))
    if cfg.get("isp"):  # (the default ISP fits any colour sensor: no fit at build, e.g. for the camera pairs' cameras)
        _check_isp_for_sensor(camera)
    return camera


def _check_isp_for_sensor(camera: Camera) -> None:
    """What the first render would refuse in the ISP for this sensor, refused at build naming the config key (an
    unknown reflectance set or observer of the colour fit, a mirrored border with a CFA cell over 2x2, a matrix or
    gains of another width failed mid-render, naming an argument of no config): the demosaic border against the CFA
    cell, and the colour matrix fitted (what the first render does; cached, so it costs that render nothing)."""
    isp, cfa = camera.isp, camera.sensor.cfa
    if isp is None:
        return
    border = getattr(isp.demosaic, "border", None)
    if border == "reflect" and max(cfa.shape) > 2:
        raise ValueError(f"config: isp.demosaic_border 'reflect' needs a CFA cell of at most 2x2, and sensor.cfa has "
                         f"a {cfa.shape[0]}x{cfa.shape[1]} cell; use demosaic_border: method")
    try:  # (not for a sensor with learnable parameters: its fit belongs in the training graph; but a learnable
        # matrix is a parameter of its own, its first fit's values, made here so that an optimiser built from the
        # camera's parameters before the first render has it: it had none until that render)
        learnable_matrix = bool(getattr(isp.sensor_to_xyz, "learnable", False))
        if learnable_matrix or not any(p.requires_grad for p in camera.sensor.parameters()):
            with torch.no_grad():
                isp.fit(camera.sensor)
    except (ValueError, TypeError) as err:
        raise ValueError(f"config: isp.sensor_conversion: {err}") from err
    matrix = getattr(isp.sensor_to_xyz, "matrix", None)
    if isinstance(matrix, torch.Tensor) and matrix.dim() == 2 and matrix.shape[1] != cfa.num_channels:
        raise ValueError(f"config: isp.sensor_conversion.matrix has {matrix.shape[1]} columns, and sensor.cfa has "
                         f"{cfa.num_channels} channels ({cfa.channel_names}); give a 3 x {cfa.num_channels} matrix")
    ic = getattr(isp, "illuminant_correction", None)
    gains = getattr(ic, "gains", None)
    if isinstance(gains, torch.Tensor):
        want = cfa.num_channels if ic.space == "sensor" else 3
        if gains.shape[-1] != want:
            raise ValueError(f"config: isp.gains has {gains.shape[-1]} values, and the correction in "
                             f"{ic.space} space (isp.correction_space) takes {want}"
                             f"{f' (sensor.cfa: {cfa.channel_names})' if ic.space == 'sensor' else ' (X, Y, Z)'}")
