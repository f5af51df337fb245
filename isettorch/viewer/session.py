"""The state behind ``isettorch view``: a camera built from a config plus the user's overrides, a scene, the
last render, and the region-of-interest analyses of ISET's four windows. No browser code here (the Bokeh
document lives in :mod:`isettorch.viewer.app`), and no physics: every number comes from the library's modules
(:class:`~isettorch.camera.Camera`, :mod:`isettorch.optics.analysis`, :mod:`isettorch.metrics`,
:mod:`isettorch.isp.chart`).

Reference: Farrell, Xiao, Catrysse, Wandell, "A simulation tool for evaluating digital camera image quality",
SPIE 5294 (2004): ISET's scene, optical image, sensor and processor windows.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import torch

from .._checks import check_seed
from ..io.images import PHOTO_SUFFIXES

__all__ = ["ViewerSession", "Settings", "ROI", "SCENES", "WINDOWS", "F_NUMBERS", "PIXEL_SIZES_UM", "EXPOSURES_MS",
           "CFAS", "resolve_config"]

#: The four windows, in pipeline order.
WINDOWS = ("scene", "oi", "sensor", "ip")
#: Standard f-stops offered by the viewer.
F_NUMBERS = (1.4, 2.0, 2.8, 4.0, 5.6, 8.0, 11.0, 16.0, 22.0)
PIXEL_SIZES_UM = (1.0, 1.4, 2.0, 2.8, 4.0, 5.6)
#: Exposure choices; None is the config's (auto-exposure in the default camera).
EXPOSURES_MS = (None, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
#: CFA layouts offered (2 x 2 cells the ISP demosaics; see ``isettorch.sensor.CFA_LIBRARY``).
CFAS = ("GRBG", "RGGB", "BGGR", "GBRG")


def _scene_builders():
    from ..scene import (
        checkerboard,
        dead_leaves,
        frequency_sweep,
        grid_lines,
        macbeth,
        point_array,
        slanted_edge,
        star,
        uniform,
        zone_plate,
    )

    return {
        "macbeth": lambda n, hfov, seed: macbeth("D65", patch_size=max(2, -(-n // 6)), hfov_deg=hfov),  # >= n wide
        "slanted_edge": lambda n, hfov, seed: slanted_edge(n, hfov_deg=hfov),
        "frequency_sweep": lambda n, hfov, seed: frequency_sweep(n, hfov_deg=hfov),
        "zone_plate": lambda n, hfov, seed: zone_plate(n, hfov_deg=hfov),
        "star": lambda n, hfov, seed: star(n, hfov_deg=hfov),
        "dead_leaves": lambda n, hfov, seed: dead_leaves(n, seed=seed, hfov_deg=hfov),
        "point_array": lambda n, hfov, seed: point_array(n, hfov_deg=hfov),
        "grid_lines": lambda n, hfov, seed: grid_lines(n, hfov_deg=hfov),
        "checkerboard": lambda n, hfov, seed: checkerboard(n, hfov_deg=hfov),
        "uniform_d65": lambda n, hfov, seed: uniform("D65", n, hfov_deg=hfov),
    }


#: Built-in scene names (``--scene``); anything else is read as a file.
SCENES = ("macbeth", "slanted_edge", "frequency_sweep", "zone_plate", "star", "dead_leaves", "point_array",
          "grid_lines", "checkerboard", "uniform_d65")


def resolve_config(config) -> Path | dict:
    """A camera config given as a dict, a YAML path, or a preset name (``"default"`` ->
    ``configs/cameras/default.yaml``, looked up beside the package and in the package's data)."""
    if isinstance(config, dict):
        return config
    p = Path(str(config))
    if p.is_file():
        return p
    name = p.name if p.suffix in (".yaml", ".yml") else f"{p.name}.yaml"
    here = Path(__file__).resolve().parents[1]
    for folder in (here / "configs" / "cameras", here.parent / "configs" / "cameras"):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"config: {str(config)!r} is neither a YAML file nor a camera preset name "
                            f"(looked for {name} in the package's configs/cameras)")


def _read_scene_file(path: Path, hfov_deg: float):
    """A user's scene file: ISETCam ``.mat``, spectral ``.exr``, or an RGB image shown on an sRGB LCD, at the
    viewer's field of view ``hfov_deg`` (the file's own is replaced: the scene's width fits the sensor)."""
    suffix = path.suffix.lower()
    if suffix == ".mat":
        from ..io.isetcam import read_isetcam_scene

        scene = read_isetcam_scene(path)
    elif suffix == ".exr":
        from ..io.exr import read_scene_exr

        scene = read_scene_exr(path, hfov_deg=hfov_deg)
    elif suffix in PHOTO_SUFFIXES:  # (the photo folders' list: a .webp or .jfif was 'not a readable file')
        from ..io.images import read_rgb8, rgb8_to_tensor
        from ..scene import from_rgb

        # the library's photograph reader: EXIF orientation applied, 16-bit or transparent images refused by name
        # (Pillow's convert('RGB') kept 8 of 16 bits and dropped transparency silently)
        scene = from_rgb(rgb8_to_tensor(read_rgb8(path)).float())
    else:
        raise ValueError(f"scene: {str(path)!r} is not a built-in scene {list(SCENES)} nor a readable file "
                         f"(.mat, .exr, {', '.join(PHOTO_SUFFIXES)})")
    return scene.replace(hfov_deg=hfov_deg)


@dataclasses.dataclass(frozen=True)
class ROI:
    """A region of interest in one window's pixel grid: rows ``[row0, row1)``, columns ``[col0, col1)``."""

    row0: int
    row1: int
    col0: int
    col1: int

    @classmethod
    def from_box(cls, x0: float, x1: float, y0: float, y1: float, height: int, width: int) -> ROI:
        """From a box drawn on an image shown with x = column and y = height - row (Bokeh's y points up);
        the box is limited to the image and covers at least one pixel."""
        c0, c1 = sorted((x0, x1))
        r0, r1 = sorted((height - y1, height - y0))
        c0, r0 = min(max(int(math.floor(c0)), 0), width - 1), min(max(int(math.floor(r0)), 0), height - 1)
        c1, r1 = min(max(int(math.ceil(c1)), c0 + 1), width), min(max(int(math.ceil(r1)), r0 + 1), height)
        return cls(r0, r1, c0, c1)

    @classmethod
    def centre(cls, height: int, width: int, fraction: float = 0.25) -> ROI:
        h, w = max(1, round(height * fraction)), max(1, round(width * fraction))
        r0, c0 = (height - h) // 2, (width - w) // 2
        return cls(r0, r0 + h, c0, c0 + w)

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.row0, self.row1), slice(self.col0, self.col1)

    def fit(self, height: int, width: int) -> ROI:
        """The same region limited to an image of ``height x width`` (after a re-render changed its size)."""
        r0, c0 = min(self.row0, height - 1), min(self.col0, width - 1)
        return ROI(r0, max(r0 + 1, min(self.row1, height)), c0, max(c0 + 1, min(self.col1, width)))


@dataclasses.dataclass
class Settings:
    """What the user can change; None keeps the config's value."""

    scene: str = "macbeth"
    f_number: float | None = None
    exposure_ms: float | None = None
    pixel_size_um: float | None = None
    cfa: str | None = None
    noise: bool | None = None
    demosaic: str | None = None


class ViewerSession:
    """A camera config, a scene and the last render, with the analyses the viewer plots.

    Args:
        config: camera config (preset name, YAML path or dict; see :meth:`Camera.from_config`).
        scene: a built-in scene name (:data:`SCENES`) or a file (``.mat``, ``.exr``, RGB image).
        size: scene size in samples; the field of view is chosen so a sensor with the config's pixel size is
            about ``size`` pixels wide (as ``isettorch demo``), and stays fixed when the pixel size changes.
        seed: seed of the temporal noise (every render of the same settings gives the same image).
    """

    def __init__(self, config="default", scene: str = "macbeth", size: int = 256, seed: int = 0) -> None:
        from ..camera import load_config

        if not isinstance(size, int) or size < 16:
            raise ValueError(f"size: expected an integer of at least 16 samples, got {size!r}")
        source = resolve_config(config)
        self.base_config = copy.deepcopy(source) if isinstance(source, dict) else load_config(source)
        self.config_name = str(self.base_config.get("name") or (Path(source).stem if not isinstance(source, dict)
                                                                else "camera"))
        self.size = size
        self.seed = check_seed(seed)  # (int() took 1.5 and -1)
        self.settings = Settings(scene=scene)
        self._scenes: dict[str, object] = {}
        self._cameras: dict[tuple, object] = {}
        self._ois: dict[tuple, object] = {}
        self._raws: dict[tuple, object] = {}
        self._images: dict[tuple, tuple] = {}
        self.cache_size = 4
        self.camera = None
        self.output = None
        self.timings: dict[str, float] = {}
        base = self._camera_for(self._config_key(Settings()))
        f = float(base.optics.focal_length_m.reshape(-1)[0])
        # Field of view for a sensor about `size` pixels wide with one optical-image sample per pixel at the
        # built-in scenes' distance: the image-plane pitch 2 d_i tan(hfov / 2) / n (optics.geometry.
        # image_sample_spacing, thin-lens d_i) equal to 0.999 pixel, never coarser than the pixel grid.
        from ..optics.geometry import image_distance
        from ..scene._common import DEFAULT_DISTANCE_M

        d_i = float(image_distance(f, DEFAULT_DISTANCE_M))
        self.hfov_deg = math.degrees(2 * math.atan(0.999 * size * base.sensor.pixel_size_m / (2 * d_i)))
        self.defaults = {"f_number": float(base.optics.f_number.reshape(-1)[0]),
                         "pixel_size_um": base.sensor.pixel_size_m * 1e6, "cfa": base.sensor.cfa.pattern,
                         "noise": base.noise, "demosaic": base.isp.demosaic.method,
                         "exposure": "auto" if base.sensor.auto_exposure else f"{base.sensor.exposure_s}"}
        self.render()

    # --- building ----------------------------------------------------------------------
    @property
    def f_number_settable(self) -> bool:
        """False for a lens config: its aperture is the prescription's stop (its optics take no f_number key)."""
        return (self.base_config.get("optics") or {}).get("type") != "lens"

    def _config_key(self, s: Settings) -> tuple:
        return (s.f_number, s.exposure_ms, s.pixel_size_um, s.cfa, s.noise, s.demosaic)

    def camera_config(self, s: Settings | None = None) -> dict:
        """The config dict of the camera for ``s`` (default the current settings): the base config with the
        user's overrides in the config's own keys."""
        s = s or self.settings
        cfg = copy.deepcopy(self.base_config)
        optics, sensor = cfg.setdefault("optics", {}), cfg.setdefault("sensor", {})
        isp, camera = cfg.setdefault("isp", {}) or {}, cfg.setdefault("camera", {}) or {}
        cfg["isp"], cfg["camera"] = isp, camera
        if s.f_number is not None:
            if not self.f_number_settable:
                raise ValueError(f"f_number: the camera's optics are a lens prescription ({optics.get('lens')!r}), "
                                 f"whose stop sets the f-number; choose a config with diffraction-limited or "
                                 f"wavefront optics to vary it")
            optics["f_number"] = float(s.f_number)
        if s.pixel_size_um is not None:
            sensor["pixel_size_m"] = float(s.pixel_size_um) * 1e-6
        if s.cfa is not None:
            sensor["cfa"] = s.cfa
        if s.exposure_ms is not None:
            sensor["auto_exposure"] = None
            for key in ("ae_target", "ae_percentile"):  # auto-exposure's options: an error without it
                sensor.pop(key, None)
            sensor["exposure_s"] = float(s.exposure_ms) * 1e-3
        if s.noise is not None:
            camera["noise"] = s.noise  # (checked as the config's camera.noise: bool("no") was True)
        if s.demosaic is not None:
            isp["demosaic"] = s.demosaic
        return cfg

    def _camera_for(self, key: tuple, s: Settings | None = None):
        if key not in self._cameras:
            from ..camera import Camera

            self._cameras[key] = Camera.from_config(self.camera_config(s or Settings()))
        return self._cameras[key]

    def scene_for(self, name: str):
        """The scene ``name`` (built-in or file), built once and cached."""
        if name not in self._scenes:
            builders = _scene_builders()
            if name in builders:
                self._scenes[name] = builders[name](self.size, self.hfov_deg, self.seed)
            else:
                self._scenes[name] = _read_scene_file(Path(name), self.hfov_deg)
        return self._scenes[name]

    def update(self, **changes) -> dict[str, float]:
        """Change settings (fields of :class:`Settings`) and re-render; returns the timings (s)."""
        for key in changes:
            if not hasattr(self.settings, key):
                names = [f.name for f in dataclasses.fields(Settings)]
                raise ValueError(f"{key}: not a viewer setting (settings: {names})")
        before, camera = self.settings, self.camera
        self.settings = dataclasses.replace(self.settings, **changes)
        try:
            return self.render()
        except Exception:  # a rejected change leaves the session as it was (it stayed, and failed every later one)
            self.settings, self.camera = before, camera
            raise

    def render(self) -> dict[str, float]:
        """Render the scene through the camera, keeping every intermediate.

        Like ISET's windows, only the stages downstream of a change are recomputed: the optical image is reused
        while the scene, the optics and the sensor's window on the optical image are unchanged
        (:meth:`Camera.from_optical_image`), the raw while the sensor is also unchanged (:meth:`Camera.from_raw`).
        """
        t0 = time.perf_counter()
        s = self.settings
        scene = self.scene_for(s.scene)
        t1 = time.perf_counter()
        cam = self.camera = self._camera_for(self._config_key(s), s)
        gen = torch.Generator().manual_seed(self.seed)
        window = cam.sensor_window(scene) if cam.crop_to_sensor else None
        oi_key = (s.scene, s.f_number, window)
        raw_key = (oi_key, s.pixel_size_um, s.cfa, s.exposure_ms, s.noise)
        with torch.no_grad():
            if raw_key in self._raws:  # (kept with its optical image: the two caches are trimmed apart)
                oi, raw = self._raws[raw_key]
                out = cam.from_raw(raw, True)
                out.optical_image = oi
            elif oi_key in self._ois:
                out = cam.from_optical_image(self._ois[oi_key], True, generator=gen)
            else:
                out = cam(scene, return_intermediates=True, generator=gen)
        out.scene = scene
        for cache, key, value in ((self._ois, oi_key, out.optical_image),
                                  (self._raws, raw_key, (out.optical_image, out.raw))):
            cache[key] = value
            while len(cache) > self.cache_size:
                cache.pop(next(iter(cache)))
        self.output = out
        t2 = time.perf_counter()
        self.timings = {"scene_s": t1 - t0, "camera_s": t2 - t1}
        return self.timings

    # --- what the windows show -----------------------------------------------------------
    def shape(self, window: str) -> tuple[int, int]:
        """(height, width) of a window's image."""
        return tuple(self.image(window).shape[:2])

    def image(self, window: str) -> np.ndarray:
        """A window's picture, ``[H, W, 3]`` in [0, 1]: the scene's and optical image's sRGB previews, the raw
        mosaic (0 at black, 1 at saturation; shown with a 1/2.2 display gamma) and the processed image. Cached
        per intermediate, so a change downstream does not recompute the pictures upstream."""
        out = self.output
        sources = {"scene": out.scene, "oi": out.optical_image, "sensor": out.raw, "ip": out.image}
        if window not in sources:
            raise ValueError(f"window: expected one of {WINDOWS}, got {window!r}")
        key = (window, id(sources[window]))
        if key not in self._images:
            if window in ("scene", "oi"):
                img = sources[window].srgb()[0]
            elif window == "sensor":
                img = out.raw.normalized()[0].clamp(0, 1).pow(1 / 2.2).expand(3, -1, -1)
            else:
                img = out.image[0]
            if len(self._images) >= 4 * len(WINDOWS):
                self._images.clear()
            # keep the source alive with its picture, so its id() is not reused while cached
            self._images[key] = (sources[window], img.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy())
        return self._images[key][1]

    def etendue_map(self) -> dict | None:
        """The sensor's pixel-optics etendue over the array for the current optical image
        (:meth:`Sensor.etendue_map`, ISETCam ``plotSensorEtendue``): ``map [rows, cols]`` (the mean over the
        wavelengths when it depends on them), its ``method``, ``min``, ``max``, ``centre`` and ``corner`` values, and
        the chief-ray angle at the corner (``corner_cra_deg``); None when the sensor has no pixel optics."""
        sensor = self.camera.sensor
        po = getattr(sensor, "pixel_optics", None)
        if po is None:
            return None
        oi = self.output.optical_image
        with torch.no_grad():
            m = sensor.etendue_map(oi)[0]
            if m.dim() == 3:
                m = m.mean(0)
            rows, cols = m.shape
            cra = po.chief_ray_angle_deg(oi, rows, cols, sensor.pixel_size_m)[0]
        m = m.double().cpu().numpy()
        return {"map": m, "method": po.method, "min": float(m.min()), "max": float(m.max()),
                "centre": float(m[rows // 2, cols // 2]), "corner": float(m[0, 0]),
                "corner_cra_deg": float(cra[0, 0])}

    def spectrum(self, window: str, roi: ROI) -> dict[str, np.ndarray]:
        """Mean spectral radiance (scene, photons/s/sr/m^2/nm) or irradiance (optical image, photons/s/m^2/nm)
        of a region, from :meth:`SpectralImage.mean_spectrum`."""
        img = {"scene": self.output.scene, "oi": self.output.optical_image}.get(window)
        if img is None:
            raise ValueError(f"window: a spectrum needs 'scene' or 'oi', got {window!r}")
        rows, cols = roi.slices
        return {"wavelength_nm": img.wavelengths_nm.cpu().numpy(),
                "photons": img.mean_spectrum(rows, cols)[0].double().cpu().numpy()}

    def optics_curves(self, wavelengths_nm=(450.0, 550.0, 650.0), psf_wavelength_nm: float = 550.0,
                      psf_size: int = 64) -> dict:
        """PSF at ``psf_wavelength_nm`` and MTF along x at ``wavelengths_nm``, from
        :mod:`isettorch.optics.analysis` (the OTF the optics applies). Frequencies in cycles/mm up to the
        diffraction cutoff of the shortest wavelength; PSF spacing λN/4. None for a ray-traced lens, whose PSF
        varies over the field (``isettorch lens-report`` gives its MTF per field)."""
        from ..optics import analysis

        optics = self.camera.optics
        if not hasattr(optics, "otf"):  # shift-variant (LensOptics): no one OTF
            return None
        n = float(optics.f_number.reshape(-1)[0])
        f_max_cpm = 1.0 / (min(wavelengths_nm) * 1e-9 * n)
        freqs = np.linspace(0.0, f_max_cpm, 101)
        m = analysis.mtf(optics, torch.tensor(wavelengths_nm, dtype=torch.float64), torch.from_numpy(freqs))[0]
        spacing = psf_wavelength_nm * 1e-9 * n / 4
        p = analysis.psf(optics, torch.tensor([psf_wavelength_nm], dtype=torch.float64), spacing, psf_size)[0, 0]
        return {"frequency_cpmm": freqs * 1e-3, "mtf": {w: m[i].cpu().numpy() for i, w in enumerate(wavelengths_nm)},
                "psf": p.cpu().numpy(), "psf_spacing_um": spacing * 1e6, "f_number": n,
                "sensor_nyquist_cpmm": 1e-3 / (2 * self.camera.sensor.pixel_size_m)}

    def sensor_stats(self, roi: ROI, bins: int = 40) -> dict:
        """Pixel values of a raw region by CFA channel: histogram (from the lower of the black level and the darkest
        value, so no value falls outside it), mean and standard deviation of the values (black level included) and SNR
        of the signal above the black level
        (:func:`isettorch.metrics.snr_uniform` of the values less the raw's zero level, mean / std with ddof = 1, in
        dB: a DN raw's black level of 64 had been counted as signal, 39.6 dB for 6.6)."""
        from ..metrics import snr_uniform

        raw = self.output.raw
        rows, cols = roi.slices
        data = raw.data[0, 0, rows, cols].double()
        masks = raw.channel_masks()[:, rows, cols].bool()
        black = float(raw.black_level)
        lo = min(black, float(data.min()))  # (noise below the black level fell outside the histogram, uncounted)
        hi = float(raw.white_level if raw.white_level is not None else data.max())
        edges = np.linspace(lo, max(hi, lo + 1e-12), bins + 1)
        out = {"units": raw.units, "edges": edges, "channels": []}
        for c, name in enumerate(raw.cfa.channel_names):
            v = data[masks[c]]
            if v.numel() == 0:
                continue
            counts, _ = np.histogram(v.cpu().numpy(), bins=edges)
            # (NaN, shown as such, for one value or a mean below the black level: no SNR in dB there)
            above = (v - black).reshape(1, -1)
            snr_db = float(snr_uniform(above, db=True)) if v.numel() >= 2 and float(above.mean()) >= 0 \
                else float("nan")
            out["channels"].append({"name": name, "n": int(v.numel()), "mean": float(v.mean()),
                                    "std": float(v.std()) if v.numel() >= 2 else float("nan"), "snr_db": snr_db,
                                    "counts": counts})
        out["exposure_ms"] = float(raw.exposure_s.reshape(-1)[0]) * 1e3
        return out

    def chart_window(self) -> tuple[int, int, int, int] | None:
        """``(row0, row1, col0, col1)``: the scene's footprint in the processed image (the chart's, for the Macbeth
        scene; :func:`isettorch.isp.chart.scene_window`); None when the sensor does not hold all of it."""
        from ..isp.chart import scene_window

        return scene_window(self.output, float(self.camera.sensor.pixel_size_m))

    def colour_stats(self, roi: ROI) -> dict:
        """Chromaticity of a processed-image region (mean of the ISP's XYZ, :func:`isettorch.metrics.xyz_to_xy`),
        the spectral locus, and, for the Macbeth scene, CIEDE2000 per patch against the chart's true colours
        under D65 (:func:`isettorch.isp.chart.macbeth_delta_e`, white-patch scaled) and the patch under the ROI, when
        the sensor holds the whole chart (:meth:`chart_window`; ``roi_patch`` None for a ROI centred off the chart).
        """
        from .. import spectral
        from ..isp.chart import macbeth_delta_e, macbeth_true_xyz, patch_means
        from ..metrics import xyz_to_xy
        from ..scene import macbeth_patch_names

        xyz = self.output.isp.xyz
        rows, cols = roi.slices
        roi_xyz = xyz[0, :, rows, cols].double().mean(dim=(-2, -1))
        w = torch.arange(380.0, 701.0, 5.0, dtype=torch.float64)
        locus = xyz_to_xy(spectral.cmfs(w, dtype=torch.float64), dim=0).T.cpu().numpy()  # [L, 2]
        out = {"roi_xy": xyz_to_xy(roi_xyz, dim=0).cpu().numpy(), "locus_xy": locus}
        window = self.chart_window() if self.settings.scene == "macbeth" else None
        if window is not None:  # (a chart the sensor crops has no patch means)
            r0, r1, c0, c1 = window
            rendered = patch_means(xyz[..., r0:r1, c0:c1].double())
            acc = macbeth_delta_e(rendered, "D65")
            h, w_px = r1 - r0, c1 - c0
            cy, cx = (roi.row0 + roi.row1) / 2 - r0, (roi.col0 + roi.col1) / 2 - c0
            # None when the ROI's centre is outside the chart (it was clamped to the nearest edge patch: the black
            # surround was shown as 'dark skin' with that patch's delta E)
            patch = int(cy * 4 // h) * 6 + int(cx * 6 // w_px) if 0 <= cy < h and 0 <= cx < w_px else None
            out.update({"delta_e": acc.delta_e[0].cpu().numpy(), "delta_e_mean": float(acc.mean[0]),
                        "delta_e_max": float(acc.max[0]), "patch_names": macbeth_patch_names(),
                        "roi_patch": patch,
                        "true_xy": xyz_to_xy(macbeth_true_xyz("D65"), dim=-1).cpu().numpy(),
                        "rendered_xy": xyz_to_xy(rendered[0], dim=-1).cpu().numpy()})
        return out
