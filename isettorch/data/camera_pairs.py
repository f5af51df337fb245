"""Camera training pairs: random scene -> a `Camera`'s diffraction-limited optics and noisy sensor, with targets.

This module samples scenes and cameras, batches, and keeps the targets' bookkeeping; every piece of physics is the
camera modules' (:class:`isettorch.Camera`: :class:`~isettorch.optics.DiffractionLimitedOptics` and
:class:`~isettorch.sensor.Sensor`), see :func:`camera_for`. For each index:

1. a random camera: f-number and pixel pitch from discrete lists (so OTFs are cached), full well, read
   noise, dark current, DSNU, PRNU, analog gain (log-uniform), exposure compensation (EV), CFA phase,
   optionally shifted QE curves. Spectral QE: the Nikon D5100 camera sensitivities measured by NPL (Darrodi
   et al., "Reference data set for camera spectral sensitivity estimation", JOSA A 32(3), 2015; shipped by
   colour-science), scaled to a random peak QE. The continuous draws are per-call sensor settings ([B] levels),
   so one `Sensor` serves every item of a discrete camera.
2. a random **factored** scene (:func:`generate_scene`: maps x spectra) rendered ``margin_px`` samples beyond the
   sensor on each side, with its FOV chosen so that one scene sample maps to one pixel; the optics compute only
   the sensor's window (:meth:`Camera.sensor_window`), transforming the J maps once (OTFs cached per f-number,
   pitch and grid), and the sensor projects them on its QE channels (and CIE XYZ for colour targets).
3. the sensor: auto-exposure (98th percentile of the mosaic at 80 % of the swing, at most 10 s, x 2^EV), Poisson
   shot noise, dark current, read noise, DSNU/PRNU drawn per item, 12-bit ADC.

:func:`render_pair` renders the **dense** scene through the same modules (the reference the factored default is
tested against: equal to float rounding).

Outputs (a dict of tensors; images in **normalised raw units**: 0 = black level, 1 = white level):

* ``raw`` ``[1, H, W]``: noisy, quantised mosaic ``(DN - black) / (white - black)``.
* ``noise_free_raw`` ``[1, H, W]``: the sensor's ``noise_free`` output in the same units (not quantised).
* ``camera_rgb`` ``[3, H, W]``: every channel at every pixel (R, G, B), the same chain without the CFA
  (clipped at white like the raw): what a demosaic network should recover. Mosaicking it gives
  ``noise_free_raw``.
* ``xyz`` ``[3, H, W]``: CIE 1931 XYZ of the optical image at sensor resolution, scaled by the exposure so that
  a perfect white under the main light has ``Y`` equal to its ``camera_rgb`` green value (not clipped) before the
  pixel optics' etendue and the sensor's vignetting (``Sensor.collecting_area_m2``): a camera with either records
  less than ``Y`` (with microlenses in the physical convention, on axis too: the etendue holds the photodiode's
  share of the pixel), and a network mapping ``raw`` to this target corrects that shading too.
* ``linear_srgb`` ``[3, H, W]``: ``xyz`` adapted from the main light's white to D65 (Bradford CAT) and
  converted with the IEC 61966-2-1 matrix (not clipped); ``srgb``: clipped to [0, 1] and encoded.
* ``meta``: a dict of tensors (see :data:`META_KEYS`), batched by :func:`collate_pairs`.

Noise metadata: ``noise_gain`` ``a`` (normalised units per electron) and ``noise_floor_var`` ``b`` give the
Poisson-Gaussian model ``var(x) = a x + b`` of ``raw`` about ``noise_free_raw`` = x (Foi et al., IEEE TIP 17(10),
2008), the capture's own sensor's (:meth:`isettorch.sensor.Sensor.poisson_gaussian` of its raw, divided by the span
and its square): ``a x`` photon shot noise, ``b`` read noise (twice with CDS), DSNU (none with CDS), dark-current
shot noise and, for a DN readout, the quantisation of one DN step. It leaves out PRNU: a fixed pattern (a
per-pixel gain ``1 + prnu_sigma_percent / 100 * n``, n ~ N(0, 1), drawn per item), which adds
``(prnu_sigma_percent / 100 * x)^2`` to the variance across the pixels of one signal level, so the full
per-pixel variance is ``a x + b + (prnu_sigma_percent x / 100)^2`` (about, for x below white and well above
black: clipping at the white level is not modelled either, nor clipping at zero of a readout without a pedestal,
black level 0 and no analog offset, where at 2 electrons of signal and 3 of read noise 29 % of the raw is 0, its mean
0.6 electrons high and its variance 0.61 of the model's; the drawn cameras' black level of 64 DN keeps them clear).
``a`` and ``b`` are what networks with noise inputs are fed; PRNU is in
``prnu_sigma_percent``. The mean of ``raw`` is not ``noise_free_raw``: it carries the dark signal,
``dark_current_e_per_s * exposure_s * noise_gain`` above it (median 3e-5 of the span, 1.4e-2 at the 99th
percentile and 5.3e-2 at most over 512 default items, whose dim scenes reach auto-exposure's 10 s limit;
``noise_free_raw`` and the targets have no dark signal), which a network mapping ``raw`` to a
target learns to subtract (its inputs are in the metadata).
"""

from __future__ import annotations

import math
import threading
import time

import torch

from .. import spectral
from .._autograd import tensor_cache
from .._checks import dataset_index, item_index
from ..image import SRGB_WHITE_XYZ, XYZ_TO_LINEAR_SRGB, angle_for_extent, bradford_matrix, srgb_encode
from ..optics.geometry import image_distance
from .config import (
    TARGETS,
    check_integer,
    check_seed,
    check_targets,
    one_thread,
    pair_config,
    randint_scalar,
    seed_for,
    tune_allocator,
)
from .scenes import _uniform, generate_scene
from .shm_slots import EpochLoader, SlotArena, SlotBatchSampler, SlotLoader, SlotRequest

__all__ = ["CameraPairDataset", "collate_pairs", "render_pair", "render_pairs", "batch_loader", "META_KEYS",
           "TARGETS", "GENERATOR_VERSION", "check_targets", "nikon_d5100_qe", "camera_for"]

CHANNELS = ("R", "G", "B")
ILLUMINANT_CODES = {"daylight": 0, "blackbody": 1, "led": 2}  # F<n> -> 10 + n
META_KEYS = ("index", "exposure_s", "analog_gain", "iso", "f_number", "focal_length_m", "pixel_size_m",
             "full_well_e", "read_noise_e", "dark_current_e_per_s", "dsnu_sigma_e", "prnu_sigma_percent",
             "black_level_dn", "white_level_dn", "noise_gain", "noise_floor_var", "cfa", "cct_k", "illuminant_code",
             "white_camera_rgb", "white_xyz", "qe", "wavelengths_nm", "hdr_decades", "mean_luminance_cd_m2")

# Bumped whenever the item of a given (seed, index, config) changes (draw order, layouts, spectra, physics), so
# that `isettorch synth` never resumes a dataset with shards of another version (it enters the config hash).
# 2: 2026-11-22 third speed round (inverse-CDF choices, one-draw leaf parameters, on-locus LEDs, camera distance).
# 3: 2026-11-25 pairs rendered by the Camera modules (the sensor's auto-exposure on the mosaic, its sampling).
# 4: 2026-11-26 natural scenes: fine detail mostly achromatic (small leaves keep the material under them, detail
#    items and leaf textures change material with probability 0.25), 2-8 materials, leaf brightness 0.1-1.
# 5: 2026-11-26 natural scenes: colour changes at finer scales (chromatic radius 8 px, detail items and leaf
#    textures change material with probability 0.5) and independent three-layer grain (component "grain").
# 6: 2026-11-30 the colour targets (linear sRGB, sRGB) through the library's one sRGB matrix and its D65 white
#    (IEC 61966-2-1 primaries and white chromaticity; before, a 7-decimal matrix and the tabulated D65 white: 3e-4).
# 7: 2026-11-30 the camera pairs' one-sample-per-pixel field of view through optics.geometry.image_distance and
#    image.angle_for_extent (1 ulp in about 0.1 % of draws); the XYZ weights, Planck spectra (in log space) and
#    light normalisation through the spectral module (equal to 1e-14).
# 8: 2026-11-30 the optics' FFT buffer twice the scene's margin, the scene's edge continued (the diffraction tail
#    wrapped onto the opposite border: up to 183 % of an item's darkest border pixel; _diffraction_config).
# 9: 2026-12-02 the diffraction (and wavefront) blur at the working f-number N d_i / f, not N (the converging
#    wave's radius is d_i: Goodman 6.3.2); 0.3 % wider at 1.2 m for a 4 mm lens.
GENERATOR_VERSION = 9
_TARGET_CHANNELS = {"noise_free_raw": 1, "camera_rgb": 3, "xyz": 3, "linear_srgb": 3, "srgb": 3}


def nikon_d5100_qe(wavelengths_nm, peak_qe: float = 0.5, shift_nm=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Spectral QE ``[3, L]`` (R, G, B) of the Nikon D5100 (NPL data), peak ``peak_qe``, each channel shifted."""
    from ..sensor.filters import filter_set

    w = torch.as_tensor(wavelengths_nm, dtype=torch.float64)  # the one loader: sensor.filters.filter_set
    return torch.stack([filter_set("nikon_5100", w - float(s), dtype=torch.float64)[1][c]
                        for c, s in enumerate(shift_nm)]) * peak_qe


@tensor_cache(maxsize=16)
def _xyz_weights(grid: tuple) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(W [3, L], dl [L], W.T)`` in float64 with ``XYZ = W @ photons``: 683 cmf(l) h c / l dl (CIE 015:2018)
    (``W.T``: the same tensor object on every call, so the sensor's memo of its joint weightings hits)."""
    w = torch.tensor(grid, dtype=torch.float64)
    dl = spectral.wavelength_weights(w)
    xyz = spectral.xyz(torch.eye(w.numel(), dtype=torch.float64), w, dim=-1).T.contiguous()  # XYZ of each sample
    return xyz, dl, xyz.T


def _pick(values, g: torch.Generator):
    if isinstance(values, (int, float)):
        return float(values)
    return values[randint_scalar(0, len(values), g)]


class _Clock:
    """Adds the CPU time (``time.process_time``: robust to other processes sharing the cores) since the previous
    call to ``timings[stage]`` (no-op without a dict)."""

    def __init__(self, timings: dict | None):
        self.timings = timings
        self.last = time.process_time()

    def __call__(self, stage: str) -> None:
        if self.timings is not None:
            now = time.process_time()
            self.timings[stage] = self.timings.get(stage, 0.0) + now - self.last
            self.last = now


def _diffraction_config(f_number: float, focal_length_m: float, margin: int) -> dict:
    """The ``optics:`` section of a camera config for the pairs' default optics (diffraction-limited). The scene
    reaches ``margin`` samples beyond the sensor; the optics' FFT buffer reaches twice as far, the scene's edge
    continued (``pad_mode='edge'``). With the buffer the scene alone (before version 8), the FFT took the scene as
    periodic: the diffraction tail beyond ``margin`` wrapped onto the opposite border. Against the same scenes drawn
    64 samples wider (64-px scenes, 32 items): the largest error of an item (of Y per unit exposure) had median
    6.7 % and reached 183 % (a bright border lit the dark opposite one), the median pixel 0.51 %; with the buffer
    twice the margin, edge-continued: 2.9 %, 81 % and 0.33 % (what is left is the scene's own light from beyond its
    margin, which it does not have). It costs 18 % more time per PairStream batch (16 items of 128 px, one thread,
    medians of interleaved batches, 2026-11-30). The buffer is at least :data:`MIN_FFT_BUFFER_PX` samples: with
    ``margin_px`` 0 it was none, and the blur circular again (at f/8, 1.4 um, a lit left border put 47 % of its
    level on the raw's right border)."""
    return {"type": "diffraction_limited", "f_number": f_number, "focal_length_m": focal_length_m,
            "margin": max(2 * int(margin), MIN_FFT_BUFFER_PX), "pad_mode": "edge"}


#: the pairs' optics' smallest FFT buffer (samples beyond the scene, edge-continued): the default margin's (2 x 8)
MIN_FFT_BUFFER_PX = 16


def _sensor_config(d: dict) -> dict:
    """The ``sensor:`` section of a camera config for the discrete camera ``d`` (its QE module and per-call levels are
    set per item: the D5100 curves here only make a valid sensor). Auto-exposure: the 98th percentile of the mosaic
    at 80 % of the usable swing (after analog gain), times ``2^EV`` per item."""
    return {"rows": d["h"], "cols": d["w"], "pixel_size_m": d["pitch"], "fill_factor": d["fill"], "cfa": d["pattern"],
            "filters": "nikon_5100", "conversion_gain_v_per_e": 1.0 / d["full_well"], "voltage_swing_v": 1.0,
            "adc_bits": d["bits"], "black_level_dn": d["black"], "shot_noise": "poisson", "fpn_mode": "per_frame",
            "auto_exposure": "percentile", "ae_percentile": 98.0, "ae_target": 0.8}


def _config_key(config: dict) -> str:
    import json

    return json.dumps(config, sort_keys=True, default=str)


class _Cache:
    """Per-process caches of camera modules, all built by the camera's own config factory
    (:meth:`isettorch.Camera.from_config` of an ``optics:`` and a ``sensor:`` section): ``optics`` one module per
    optics config (shared by every camera that has it, with its OTF cache; a ray-traced lens plans its PSFs once),
    ``sensors`` one `Sensor` per discrete camera (pitch, fill, CFA, ADC, size) and thread (its QE module and per-call
    levels are set per item, so threads sharing a dataset must not share it), ``cameras`` one `Camera` per pair."""

    def __init__(self):
        self.optics = {}
        self.sensors = {}
        self.cameras = {}

    @staticmethod
    def _sensor_key(d: dict) -> tuple:
        return (d["pitch"], d["fill"], d["pattern"], d["bits"], d["black"], d["h"], d["w"], threading.get_ident())

    def config_camera(self, optics_config: dict, d: dict):
        """The `Camera` of ``optics_config`` and the discrete camera ``d`` (no ISP: the pairs' targets are spectral
        projections), from ``Camera.from_config``, with the cached optics and sensor when they were built before."""
        from ..camera import Camera

        okey, skey = _config_key(optics_config), self._sensor_key(d)
        camera = self.cameras.get((okey, skey))
        if camera is None:
            for cache in (self.sensors, self.cameras):
                if len(cache) > 256:  # bounded
                    cache.clear()
            config = {"optics": optics_config, "sensor": _sensor_config(d), "camera": {"noise": True}}
            camera = Camera.from_config(config)
            camera.optics = self.optics.setdefault(okey, camera.optics)
            camera.sensor = self.sensors.setdefault(skey, camera.sensor)
            camera.isp = _NoISP()
            self.cameras[(okey, skey)] = camera
        return camera

    # One module at a time (isettorch.data.stream, benchmarks): the same caches, the same factory.
    def get_optics(self, f_number: float, focal_length_m: float, margin: int):
        """The default diffraction-limited optics of (f-number, focal length, margin)."""
        return self.get_built_optics(_diffraction_config(f_number, focal_length_m, margin))

    def get_built_optics(self, config: dict):
        """The optics of a ``camera.optics`` mapping (``Camera.from_config``'s ``optics:`` section), built once per
        process and config."""
        from ..camera import Camera

        key = _config_key(config)
        if key not in self.optics:
            self.optics[key] = Camera.from_config({"optics": config, "sensor": {}}).optics
        return self.optics[key]

    def get_sensor(self, d: dict):
        """The `Sensor` of a discrete camera ``d`` (``Camera.from_config``'s ``sensor:`` section), once per thread."""
        from ..camera import Camera

        key = self._sensor_key(d)
        if key not in self.sensors:
            if len(self.sensors) > 256:  # bounded
                self.sensors.clear()
            self.sensors[key] = Camera.from_config({"optics": {}, "sensor": _sensor_config(d)}).sensor
        return self.sensors[key]

    def get_camera(self, optics, sensor):
        """The `Camera` of these modules (no ISP: the pairs' targets are spectral projections), kept when the optics
        are this cache's own (built once per config). Optics built for one group (PairStream's drawn diffraction
        optics, a new module per group) get a new Camera that is not kept: kept, each held its optics and their
        assembled OTF until 257 had gathered (on the device path 3.1 MiB per 128^2 pair per batch: 88 MiB per pair
        after the 27 batches of a throughput run, the 92 MB per pair measured on an H200)."""
        from ..camera import Camera

        if not any(o is optics for o in self.optics.values()):
            return Camera(optics, sensor, isp=_NoISP(), noise=True)
        key = (id(optics), id(sensor))
        camera = self.cameras.get(key)
        if camera is None or camera.optics is not optics or camera.sensor is not sensor:
            if len(self.cameras) > 256:
                self.cameras.clear()
            camera = self.cameras[key] = Camera(optics, sensor, isp=_NoISP(), noise=True)
        return camera


def _draw_camera(index: int, seed: int, scene_cfg: dict, cam: dict) -> dict:
    """The camera draws of item ``(seed, index)`` (fixed order), and the scene FOV that puts one scene sample on
    one pixel. Shared by the reference and the factored paths."""
    g = torch.Generator().manual_seed(seed_for(seed, index, stream=1))
    h, w = int(scene_cfg["height"]), int(scene_cfg["width"])
    m = int(cam["margin_px"])
    d = {"h": h, "w": w, "m": m}
    d["f_number"] = float(_pick(cam["f_number"], g))
    d["pitch"] = float(_pick(cam["pixel_size_m"], g))
    d["focal"] = float(_pick(cam["focal_length_m"], g))
    d["fill"] = float(cam["fill_factor"])
    d["full_well"] = _uniform(cam["full_well_e"], g, log=True)
    d["read_e"] = _uniform(cam["read_noise_e"], g)
    d["dark"] = _uniform(cam["dark_current_e_per_s"], g, log=True)
    d["dsnu_e"] = _uniform(cam["dsnu_sigma_e"], g)
    d["prnu"] = _uniform(cam["prnu_sigma_percent"], g)
    d["gain"] = _uniform(cam["analog_gain"], g, log=True)
    d["ev"] = _uniform(cam["exposure_ev"], g)
    d["peak"] = _uniform(cam["peak_qe"], g)
    d["pattern"] = str(_pick(cam["cfa_patterns"], g))
    var = float(cam["qe_variation"])
    d["shifts"] = ((torch.rand(3, generator=g, dtype=torch.float64) * 2 - 1) * 10.0 * var).tolist()
    d["bits"], d["black"] = int(cam["bits"]), float(cam["black_level_dn"])
    d["noise_seed"] = seed_for(seed, index, stream=2)
    # The object distance is drawn here (camera stream, last) and imposed on the scene, so the FOV below and the
    # scene's geometry agree for a distance range too. Scene FOV so that one scene sample lands on one pixel:
    # pitch = 2 d_i tan(hfov / 2) / W_s.
    d["distance"] = _uniform(scene_cfg["distance_m"], g)
    d["ws"] = w + 2 * m
    _set_fov(d)
    return d


def _set_fov(d: dict, image_distance_m: float | None = None) -> None:
    """``d["hfov"]``: the scene FOV that puts one scene sample on one pixel, ``pitch = 2 d_i tan(hfov / 2) / W_s``,
    with ``d_i`` the thin-lens image distance of the object distance (Hecht 5.17, as
    ``optics.geometry.image_distance``) unless the optics give their own (a ray-traced lens: its
    ``image_distance_m``, the image height per tan(angle))."""
    focal, distance = d["focal"], d["distance"]
    if image_distance_m is None:
        try:
            image_distance_m = float(image_distance(focal, distance))
        except ValueError as err:  # named with the config key
            raise ValueError(f"scene.distance_m: expected object distances beyond the focal length {focal} m, "
                             f"got {distance}") from err
    d["hfov"] = float(angle_for_extent(torch.tensor(d["pitch"] * d["ws"], dtype=torch.float64),
                                       torch.tensor(image_distance_m, dtype=torch.float64)))


def _scene_for(index: int, seed: int, scene_cfg: dict, d: dict, dtype):
    """The factored scene of item ``(seed, index)`` from ``scene.generator``, ``(h + 2 m) x (w + 2 m)`` samples at
    the FOV and distance of the camera draws ``d``."""
    size = (d["h"] + 2 * d["m"], d["ws"])
    if scene_cfg.get("generator", "layouts") == "layouts":
        return generate_scene(index, seed, scene_cfg, dtype=dtype, hfov_deg=d["hfov"], size=size,
                              distance_m=d["distance"])
    return _natural_scene(index, seed, scene_cfg, size, d["hfov"], d["distance"], dtype)


def _natural_scene(index: int, seed: int, scene_cfg: dict, size: tuple, hfov_deg: float, distance_m: float, dtype):
    """A :func:`isettorch.data.natural.generate_natural` scene (options ``scene.natural``, the scene's wavelength
    grid) as a factored Scene: generated square at the larger side (the generator's draws depend on its size),
    cropped to ``size`` about the centre, and scaled to a mean luminance drawn log-uniformly from
    ``scene.mean_luminance_cd_m2`` (its own stream, 3, so the scene's draws are the generator's)."""
    from .natural import generate_natural, natural_config, to_scene

    n = max(16, *size)
    cfg = dict(natural_config(dict(scene_cfg["natural"], size=n,
                                   wavelengths_nm=list(scene_cfg["wavelengths_nm"]))), _checked=True)
    item = generate_natural(index, seed, cfg)
    top, left = (n - size[0]) // 2, (n - size[1]) // 2
    g = torch.Generator().manual_seed(seed_for(seed, index, stream=3))
    target = _uniform(scene_cfg["mean_luminance_cd_m2"], g, log=True)
    item = dict(item, maps=item["maps"][:, top:top + size[0], left:left + size[1]],
                meta=dict(item["meta"], hdr_decades=0.0, mean_luminance_cd_m2=target))
    scene = to_scene(item, hfov_deg=hfov_deg, distance_m=distance_m, dtype=dtype)
    return scene.set_mean_luminance(target)


def _d5100_qe(pattern: str, shifts_nm: torch.Tensor):
    """The D5100 `SpectralQE` with peak QE 1 for a CFA pattern, each channel shifted by ``shifts_nm`` (R, G, B):
    ``[3]`` (one QE) or ``[B, 3]`` (a per-item QE, :class:`~isettorch.data.stream.PairStream`), built by the
    sensor's :func:`~isettorch.sensor.filters.shifted_qe`; an item's QE is this times its peak QE."""
    from ..sensor import CFA, shifted_qe

    cfa = CFA(pattern)
    return shifted_qe(cfa, "nikon_5100", shifts_nm[..., [CHANNELS.index(c) for c in cfa.channel_names]])


@tensor_cache(maxsize=64)
def _unit_qe(pattern: str, shifts: tuple):
    """:func:`_d5100_qe` of one item's shifts (a tuple, R G B), cached: the module resamples once per grid."""
    return _d5100_qe(pattern, torch.tensor([float(v) for v in shifts], dtype=torch.float64))


def camera_for(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
               cache: _Cache | None = None) -> tuple:
    """The camera of item ``(seed, index)``: ``(camera, scene, sensor_kwargs)`` with ``camera`` an
    :class:`isettorch.Camera` (diffraction-limited optics, or ``camera.optics`` built by
    :func:`isettorch.optics.factory.build_optics`, and a `Sensor` with the item's QE), the item's factored
    scene (``scene.generator``: ``layouts`` or ``natural``; one scene sample per pixel, ``margin_px`` beyond the
    sensor on each side) and the per-call sensor
    settings (analog gain, exposure compensation, noise levels; :data:`isettorch.sensor.sensor.PER_CALL_LEVELS`).

    ``camera(scene, return_intermediates=True, generator=torch.Generator().manual_seed(kw.pop("noise_seed")), **kw)``
    gives the item's raw (``raw.data``, ``raw.noise_free``): the dataset renders pairs by exactly these calls.
    """
    cache = cache or _Cache()
    d = _draw_camera(index, seed, scene_cfg, camera_cfg)
    optics_cfg = camera_cfg.get("optics") or {}
    # the camera from its config (Camera.from_config): a configured optics module, or diffraction-limited optics at
    # the drawn f-number and focal length
    camera = cache.config_camera(optics_cfg or _diffraction_config(d["f_number"], d["focal"], d["m"]), d)
    if optics_cfg:  # a configured optics module: its own f-number and focal length (the drawn ones are unused)
        d["f_number"], d["focal"] = float(camera.optics.f_number), float(camera.optics.focal_length_m)
        # a ray-traced lens images objects at infinity at its image height per tan(angle) (LensOptics.image_distance_m:
        # the focal length focused at infinity; focused nearer, the focal length put the scene 4.2 % off one sample
        # per pixel at 1.2 m for a 50 mm lens)
        _set_fov(d, camera.optics.image_distance_m if optics_cfg.get("type") == "lens" else None)
    scene = _scene_for(index, seed, scene_cfg, d, dtype)
    camera.sensor.spectral_qe = _unit_qe(d["pattern"], tuple(d["shifts"]))  # peak 1; the item's peak is qe_scale
    cg = 1.0 / d["full_well"]  # volts per electron with a 1 V swing: well capacity = full_well
    kwargs = {"analog_gain": d["gain"], "exposure_ev": d["ev"], "qe_scale": d["peak"], "conversion_gain_v_per_e": cg,
              "read_noise_v": d["read_e"] * cg, "dark_current_e_per_s": d["dark"], "dsnu_sigma_v": d["dsnu_e"] * cg,
              "prnu_sigma_percent": d["prnu"], "noise_seed": d["noise_seed"]}
    return camera, scene, kwargs


class _NoISP(torch.nn.Module):
    """The pairs' targets are spectral projections, not an ISP's output: `Camera.from_raw` gets this no-op."""

    def forward(self, raw):
        return raw.data


def render_pair(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
                cache: _Cache | None = None, timings: dict | None = None, targets=TARGETS) -> dict:
    """One camera training pair for ``(seed, index)`` (see the module notes), from the **dense** scene (the
    ``[L, H, W]`` cube) through the same camera modules: the reference the factored default is tested against.

    ``timings``: optional dict accumulating the CPU seconds spent per stage. Runs single-threaded.
    """
    targets = check_targets(targets)
    with one_thread():
        batch = _render_pairs([item_index(index)], seed, scene_cfg, camera_cfg, dtype=dtype, cache=cache,
                              timings=timings, targets=targets, dense=True)
    return {k: ({m: t[0] for m, t in v.items()} if isinstance(v, dict) else v[0]) for k, v in batch.items()}


def render_pairs(indices, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
                 cache: _Cache | None = None, timings: dict | None = None, targets=TARGETS) -> dict:
    """Camera training pairs for ``(seed, i)``, ``i`` in ``indices``, batched (the format of :func:`collate_pairs`).

    Each item is the item's :func:`camera_for` camera applied to its factored scene: the optics transform the J
    scene maps once and keep the OTFs (J forward FFTs), the sensor projects on its 3 QE channels (and, when a
    colour target is asked, the 3 CIE XYZ weightings) in the Fourier domain (3 or 6 inverse FFTs), auto-exposes,
    adds noise and digitises. Targets are the same projections read out without the CFA (``camera_rgb``) or
    scaled colorimetrically (``xyz``). Deterministic: an item depends only on ``(seed, index)``, not on the batch
    it is in, the number of threads or workers (bitwise, tested).

    Example:
        >>> from isettorch.data.config import pair_config
        >>> scene, camera = pair_config({"height": 16, "width": 16}, {})
        >>> render_pairs([3, 1], 0, scene, camera)["camera_rgb"].shape
        torch.Size([2, 3, 16, 16])
    """
    targets = check_targets(targets)
    with one_thread():
        # (1.7 rendered item 1, '0' item 0, True item 1)
        return _render_pairs([item_index(i, "indices") for i in indices], seed, scene_cfg, camera_cfg, dtype=dtype,
                             cache=cache, timings=timings, targets=targets)


def _render_pairs(indices, seed, scene_cfg, camera_cfg, *, dtype, cache, timings, targets=TARGETS,
                  dense: bool = False, alloc=None) -> dict:
    if not indices:
        raise ValueError("indices: expected at least one index")
    clock = _Clock(timings)
    cache = cache or _Cache()
    nb = len(indices)
    colour = bool({"xyz", "linear_srgb", "srgb"} & set(targets))
    # In phases over the batch (all scenes, then all optics, then all captures, then the targets), as the previous
    # generator did: the same per-item calls in another order (values unchanged, each item keeps its own noise
    # generator), but each phase's code and caches stay warm across the batch (measured 7.3-7.5 -> 6.3 CPU ms per
    # 128^2 pair, one thread, against item by item: benchmarks/pair_cost.py).
    items = []
    for index in indices:
        camera, scene, kw = camera_for(index, seed, scene_cfg, camera_cfg, dtype=dtype, cache=cache)
        if dense:
            scene = scene.to_dense()
        # the sensor module is shared by the items of a discrete camera: remember this item's QE module
        items.append({"index": index, "camera": camera, "scene": scene, "kw": kw, "qe": camera.sensor.spectral_qe,
                      "g": torch.Generator().manual_seed(kw.pop("noise_seed"))})
    clock("scene")
    with torch.no_grad():
        for it in items:
            camera, scene, kw = it["camera"], it["scene"], it["kw"]
            sensor = camera.sensor
            sensor.spectral_qe = it["qe"]
            oi = camera.optical_image(scene)
            xyz_w, _, xyz_wt = _xyz_weights(tuple(scene.wavelengths_nm.tolist()))
            peak = kw.pop("qe_scale")
            it["rates"], it["xyz_d"] = sensor.channel_rates(oi, xyz_wt if colour else None, qe_scale=peak)
            # the main light's white: its camera response (QE dl projection) and XYZ, for the colour targets
            white_p = scene.illuminant_photons[0].to(torch.float64)
            it["white_cam"] = (white_p @ sensor.spectral_weights(oi).to(torch.float64)) * peak
            it["white_xyz"] = xyz_w @ white_p
            it["qe_meta"] = sensor.qe(oi) * peak
        clock("optics")
        img = None
        raws, noise_free = [], []
        for it in items:
            sensor, kw = it["camera"].sensor, it["kw"]
            sensor.spectral_qe = it["qe"]
            gain, ev, cg = kw.pop("analog_gain"), kw.pop("exposure_ev"), kw["conversion_gain_v_per_e"]
            mosaic = sensor.cfa.mosaic(it["rates"])
            exposure = sensor.exposure_for(None, mosaic, gain, exposure_ev=ev, conversion_gain_v_per_e=cg)
            raw = sensor.capture(mosaic, exposure_s=exposure, analog_gain=gain, noise=True, generator=it["g"], **kw)
            if img is None:
                h, w = raw.height, raw.width
                img = _views({k: (nb, c, h, w) for k, c in (("raw", 1), *((t, _TARGET_CHANNELS[t])
                                                                          for t in targets))}, dtype, alloc)
            raws.append(raw.data)
            noise_free.append(raw.noise_free)
            black, span = raw.black_level, raw.white_level - raw.black_level
            a, b = sensor.poisson_gaussian(raw)  # the capture's noise model, in DN
            it.update(gain=gain, exposure=exposure, black=black, span=span, white_level=raw.white_level,
                      noise_gain=float(a[0]) / span, noise_floor=float(b[0]) / span ** 2)
        # normalised raw units, (DN - black) / (white - black), over the whole batch at once when the items share
        # the levels (the same elementwise operations as item by item)
        _normalise(img["raw"], raws, items)
        if "noise_free_raw" in img:
            _normalise(img["noise_free_raw"], noise_free, items)
        clock("sensor")
        metas = []
        white_xyz_all, scales, cams = [], [], []
        for it in items:
            camera, scene, kw = it["camera"], it["scene"], it["kw"]
            sensor = camera.sensor
            gain, exposure, cg = it["gain"], it["exposure"], kw["conversion_gain_v_per_e"]
            black, span = it["black"], it["span"]
            if "camera_rgb" in img:  # the sensor chain without the CFA: every channel read out at every pixel
                cams.append(sensor.readout(it["rates"], exposure, gain, conversion_gain_v_per_e=cg))
            # output units per electron / span: the normalised response (Foi et al. noise gain, XYZ scale)
            to_norm = float(sensor.gain_per_electron(gain, conversion_gain_v_per_e=cg)) / span
            white_cam, white_xyz = it["white_cam"], it["white_xyz"]
            # XYZ scaled so a perfect white under light 1 has Y = its normalised green camera value: the camera's
            # electrons/m^2 per unit Y of that white x pixel area x fill x exposure x normalised units per electron
            k_white = white_cam[1].item() / white_xyz[1].item()  # float64: the same division as in torch
            scale = k_white * sensor.collecting_area_m2() * exposure[0].item() * to_norm
            d = {"gain": gain, "read_e": kw["read_noise_v"] / cg, "dsnu_e": kw["dsnu_sigma_v"] / cg,
                 "dark": kw["dark_current_e_per_s"], "f_number": float(camera.optics.f_number),
                 "focal": float(camera.optics.focal_length_m), "pitch": sensor.pixel_size_m,
                 "full_well": sensor.saturation_e(cg), "prnu": kw["prnu_sigma_percent"], "black": black}
            metas.append(_meta_values(it["index"], d, scene.metadata, float(exposure[0]), it["noise_gain"],
                                      it["noise_floor"], it["white_level"], sensor.cfa, white_cam, white_xyz,
                                      it["qe_meta"], scene.wavelengths_nm))
            white_xyz_all.append(white_xyz)
            scales.append(scale)
        if cams:
            _normalise(img["camera_rgb"], cams, items)
        if colour:  # x the items' scales (each rounded to the image dtype, as a Python scalar factor would be)
            xyz = img["xyz"] if "xyz" in img else img.setdefault("_xyz", torch.empty(nb, 3, h, w, dtype=dtype))
            torch.cat([it["xyz_d"] for it in items], out=xyz).mul_(torch.tensor(scales, dtype=dtype).view(-1, 1, 1, 1))
    clock("targets")
    if colour:
        xyz = img.get("xyz", img.get("_xyz"))
        white_xyz = torch.stack(white_xyz_all)
        cat = bradford_matrix(white_xyz / white_xyz[:, 1:2], torch.tensor(SRGB_WHITE_XYZ, dtype=torch.float64))
        m_srgb = (torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ cat).to(dtype)[..., None]  # [B, 3, 3, 1]
        x3 = xyz.reshape(nb, 3, -1)
        lin = img["linear_srgb"].view(nb, 3, -1) if "linear_srgb" in img else torch.empty_like(x3)
        torch.mul(m_srgb[:, :, 0], x3[:, :1], out=lin)  # a fixed summation order (bitwise for any thread count)
        for c in (1, 2):
            lin.addcmul_(m_srgb[:, :, c], x3[:, c:c + 1])
        if "srgb" in img:
            srgb_encode(lin.view(nb, 3, h, w).clamp(0, 1), out=img["srgb"])
    img.pop("_xyz", None)
    out = dict(img)
    out["meta"] = _batch_meta(metas, dtype, alloc)
    clock("targets")
    return out


def _normalise(dst: torch.Tensor, values: list, items: list) -> None:
    """``dst[b] = (values[b] - black_b) / span_b``: one subtraction and division for the batch when every item has
    the same black level and span (the same operations, so the same values, as item by item)."""
    black, span = items[0]["black"], items[0]["span"]
    if all(it["black"] == black and it["span"] == span for it in items):
        torch.cat(values, out=dst).sub_(black).div_(span)
        return
    for b, (v, it) in enumerate(zip(values, items)):
        torch.sub(v, it["black"], out=dst[b:b + 1]).div_(it["span"])


def _views(shapes: dict, dtype, alloc=None) -> dict:
    """Contiguous tensors ``{key: [shape]}`` that are views of **one** storage: a DataLoader worker then ships the
    whole batch as one shared-memory block instead of one per tensor (measured with 2 workers on 2 cores: the main
    process's CPU per pair 0.57 -> 0.21 ms, 217 -> 234 pairs/s). ``alloc(numel, dtype)``: where that storage comes
    from (a worker's shared-memory slot, :mod:`isettorch.data.shm_slots`); a fresh tensor by default."""
    sizes = [math.prod(shape) for shape in shapes.values()]
    flat = torch.empty(sum(sizes), dtype=dtype) if alloc is None else alloc(sum(sizes), dtype)
    out, start = {}, 0
    for (key, shape), size in zip(shapes.items(), sizes):
        out[key] = flat[start:start + size].view(shape)
        start += size
    return out


def _meta_values(index, d, meta_s, exposure, noise_gain, noise_floor, white, cfa, white_cam, white_xyz, qe,
                 wave) -> dict:
    """The metadata of one item (:data:`META_KEYS`) as Python numbers and tensors; ``noise_gain``,
    ``noise_floor``: the item's Poisson-Gaussian ``a`` and ``b`` in normalised units (module notes)."""
    name = meta_s["illuminant"]
    code = ILLUMINANT_CODES.get(name, 10 + int(name[1:]) if name.startswith("F") else -1)
    gain, read_e, dsnu_e, dark = d["gain"], d["read_e"], d["dsnu_e"], d["dark"]
    return {
        "index": int(index),
        "exposure_s": exposure, "analog_gain": gain, "iso": 100.0 * gain, "f_number": d["f_number"],
        "focal_length_m": d["focal"], "pixel_size_m": d["pitch"], "full_well_e": d["full_well"],
        "read_noise_e": read_e, "dark_current_e_per_s": dark, "dsnu_sigma_e": dsnu_e,
        "prnu_sigma_percent": d["prnu"], "black_level_dn": d["black"], "white_level_dn": white,
        # Poisson-Gaussian noise model in normalised units: var(x) = noise_gain * x + noise_floor_var
        # (Foi et al., "Practical Poissonian-Gaussian noise modeling", IEEE TIP 17(10), 2008; the sensor's
        # Sensor.poisson_gaussian); without PRNU, which adds (prnu_sigma_percent / 100 * x)^2 across pixels
        "noise_gain": noise_gain,
        "noise_floor_var": noise_floor,
        "cfa": cfa.index_map,
        "cct_k": meta_s["cct_k"], "illuminant_code": int(code),
        "white_camera_rgb": white_cam / white_cam[1],
        "white_xyz": white_xyz / white_xyz[1],
        "qe": qe, "wavelengths_nm": wave,
        "hdr_decades": meta_s["hdr_decades"], "mean_luminance_cd_m2": meta_s["mean_luminance_cd_m2"],
    }


_LONG_META = ("index", "illuminant_code", "cfa")


def _batch_meta(metas: list[dict], dtype, alloc=None) -> dict:
    """Per-item metadata values -> ``[B, ...]`` tensors (long for ``index``, ``illuminant_code``, ``cfa``; ``dtype``
    otherwise), in one storage per dtype (scalars converted once per key for the whole batch)."""
    nb = len(metas)
    shapes = {k: (nb, *(tuple(v.shape) if isinstance(v, torch.Tensor) else ())) for k, v in metas[0].items()}
    floats = _views({k: s for k, s in shapes.items() if k not in _LONG_META}, dtype, alloc)
    longs = _views({k: shapes[k] for k in _LONG_META}, torch.long, alloc)
    out = {}
    for key in metas[0]:
        dst = longs[key] if key in _LONG_META else floats[key]
        first = metas[0][key]
        if isinstance(first, torch.Tensor):
            dst.copy_(torch.stack([m[key] for m in metas]))
        else:
            dst.copy_(torch.tensor([m[key] for m in metas], dtype=dst.dtype))
        out[key] = dst
    return out


_WORKER_TUNED: bool | None = None  # this (worker) process: None = not tried, else tune_allocator's result


class CameraPairDataset(torch.utils.data.Dataset):
    """Map-style dataset of camera training pairs; item ``i`` depends only on ``(seed, i)``.

    Args:
        length: number of items.
        seed: dataset seed.
        scene: scene config (keys of ``SCENE_DEFAULTS``; not ``hfov_deg``: the sensor sets the field of view),
            camera: camera config (keys of ``CAMERA_DEFAULTS``); both validated by
            :func:`~isettorch.data.config.pair_config`, as ``isettorch synth`` and ``PairStream`` validate them.
        dtype: float32 (default) or float64.
        method: ``'factored'`` (default: the factored scene through the camera) or ``'reference'`` (the same scene
            as a dense ``[L, H, W]`` cube through the same camera). They agree to float rounding.
        targets: the targets to compute, from :data:`TARGETS` (default all; ``raw`` and ``meta`` are always
            there). Only what is asked is computed: without ``xyz``/``linear_srgb``/``srgb`` the sensor projects
            on 3 weightings instead of 6 (3 fewer inverse FFTs); fewer targets also mean less data to move
            between DataLoader workers and the main process.
        tune_worker_allocator: inside a DataLoader worker process, apply
            :func:`isettorch.data.config.tune_allocator` once before the first item (freed tensors stay in the
            worker's heap instead of being unmapped and page-faulted again: ~13 % less CPU per pair; the worker's
            resident memory stays at its peak). Never applied in the main process. Values are unaffected.

    ``ds[i]`` is one item; ``ds[[i, j, ...]]`` (or :meth:`get_batch`) a whole batch in the format of
    :func:`collate_pairs`, computed batched (the same values as collating ``ds[i]``, bitwise), which is how
    :func:`batch_loader` feeds a ``DataLoader``. The images of a batch (and of an item) are contiguous views of one
    storage, the metadata of one per dtype, so DataLoader workers ship few shared-memory blocks; ``torch.save`` of
    a single field stores that whole storage: ``.clone()`` it first.

    Example:
        >>> ds = CameraPairDataset(8, seed=0, scene={"height": 32, "width": 32})
        >>> batch = collate_pairs([ds[0], ds[1]])
        >>> batch["raw"].shape, batch["meta"]["exposure_s"].shape
        (torch.Size([2, 1, 32, 32]), torch.Size([2]))
        >>> ds.get_batch([0, 1])["raw"].shape
        torch.Size([2, 1, 32, 32])
    """

    METHODS = ("factored", "reference")

    def __init__(self, length: int, seed: int = 0, scene: dict | None = None, camera: dict | None = None, *,
                 dtype=torch.float32, method: str = "factored", targets=TARGETS, tune_worker_allocator: bool = True):
        if method not in self.METHODS:
            raise ValueError(f"method: expected one of {self.METHODS}, got {method!r}")
        self.length, self.seed = check_integer(length, "length", 0), check_seed(seed)
        self.dtype, self.method = dtype, method
        self.scene_config, self.camera_config = pair_config(scene, camera)
        self._cache = _Cache()
        self.targets = check_targets(targets)
        self.tune_worker_allocator = bool(tune_worker_allocator)

    def __len__(self) -> int:
        return self.length

    def _maybe_tune(self) -> None:
        global _WORKER_TUNED
        if self.tune_worker_allocator and _WORKER_TUNED is None and torch.utils.data.get_worker_info() is not None:
            _WORKER_TUNED = tune_allocator()

    def _check_index(self, index) -> int:
        return dataset_index(index, self.length)

    def __getitem__(self, index):
        if isinstance(index, (list, tuple, range)) or (isinstance(index, torch.Tensor) and index.dim() == 1):
            return self.get_batch(index)
        index = self._check_index(index)
        self._maybe_tune()
        with one_thread():
            batch = _render_pairs([index], self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                                  cache=self._cache, timings=None, targets=self.targets,
                                  dense=self.method == "reference")
        return {k: ({m: t[0] for m, t in v.items()} if isinstance(v, dict) else v[0]) for k, v in batch.items()}

    def get_batch(self, indices) -> dict:
        """Items ``indices`` as one batch (``collate_pairs`` format), generated together (targets and exposure
        vectorised over the batch, one collation); bitwise equal to ``collate_pairs([self[i] for i in indices])``."""
        idx = [self._check_index(i) for i in (indices.tolist() if isinstance(indices, torch.Tensor) else indices)]
        if not idx:
            raise ValueError("indices: expected at least one index")
        self._maybe_tune()
        if self.method == "reference":
            return collate_pairs([self[i] for i in idx])
        if isinstance(indices, SlotRequest) and torch.utils.data.get_worker_info() is not None:
            return self._slot_batch(idx, indices.slots, indices.epoch)
        return render_pairs(idx, self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                            cache=self._cache, targets=self.targets)

    def _slot_batch(self, idx: list[int], slots: int, epoch: int = 0):
        """In a worker of :func:`batch_loader`: the batch rendered into one of this worker's shared-memory slots,
        returned as a :class:`~isettorch.data.shm_slots.SlotBatch` handle (or the batch itself, without a free
        slot); the loader copies it out in the main process."""
        arena = self.__dict__.get("_arena")
        if arena is None:
            arena = self._arena = SlotArena(slots)
        bump = arena.acquire(epoch)
        try:
            with one_thread():
                batch = _render_pairs(idx, self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                                      cache=self._cache, timings=None, targets=self.targets, alloc=bump)
        except BaseException:
            if bump.storage is not None:
                arena.abandon(bump)
            raise
        return arena.finish(batch, bump)


def batch_loader(dataset: CameraPairDataset, batch_size: int, *, shuffle: bool = False, sampler=None,
                 generator: torch.Generator | None = None, drop_last: bool = False, num_workers: int = 0,
                 shm_slots: bool = True, **loader_kwargs) -> torch.utils.data.DataLoader:
    """A ``DataLoader`` whose workers generate whole batches (:meth:`CameraPairDataset.get_batch`).

    Yields the same batches, bitwise, as ``DataLoader(dataset, batch_size, sampler=..., collate_fn=collate_pairs)``
    with the same sampler (items depend only on ``(seed, index)``), for any ``num_workers``.

    Args:
        batch_size: items per batch. shuffle / generator: a ``RandomSampler`` (seeded by ``generator``) instead
            of the sequential order; ``sampler``: any index sampler (e.g. ``DistributedSampler``) instead.
        drop_last, num_workers, loader_kwargs: passed on (``BatchSampler`` / ``DataLoader``). With workers,
            ``persistent_workers`` defaults to True: the workers, their camera caches (OTFs, sensors) and their
            shared-memory slots live across epochs instead of being started again for each one.
        shm_slots: with workers, ship batches through per-worker shared-memory slots that are reused, copied out
            in the main process (:mod:`isettorch.data.shm_slots`; the same values, bitwise): measured 300 -> 355
            pairs/s at 128^2, batch 16, 2 workers on 2 cores (``benchmarks/THROUGHPUT.md``). Not used with
            ``pin_memory`` or a ``collate_fn`` (they would see the slot handles); False: the stock transport.

    Example:
        >>> ds = CameraPairDataset(8, seed=0, scene={"height": 16, "width": 16})
        >>> [b["raw"].shape[0] for b in batch_loader(ds, 3)]
        [3, 3, 2]
    """
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size: expected a positive integer, got {batch_size!r}")
    if sampler is None:
        sampler = (torch.utils.data.RandomSampler(dataset, generator=generator) if shuffle
                   else torch.utils.data.SequentialSampler(dataset))
    elif shuffle:
        raise ValueError("shuffle: expected False when a sampler is given (the sampler sets the order)")
    # With workers, each renders into shared-memory slots it reuses and the main process copies batches out
    # (isettorch.data.shm_slots: no fresh shared memory per batch); not with a user's collate_fn or pinned memory,
    # which would see the slot handles.
    slots = shm_slots and num_workers > 0 and not loader_kwargs.get("pin_memory") and "collate_fn" not in loader_kwargs
    if num_workers > 0:  # keep the workers (and their caches and slots) across epochs, unless the user says otherwise
        loader_kwargs.setdefault("persistent_workers", True)
    if slots:
        batches = SlotBatchSampler(sampler, batch_size, drop_last, int(loader_kwargs.get("prefetch_factor") or 2) + 1)
    else:
        batches = torch.utils.data.BatchSampler(sampler, batch_size, drop_last)
    # the loader draws its workers' base seed from the same generator first, exactly as DataLoader(shuffle=True)
    return (SlotLoader if slots else EpochLoader)(
        dataset, sampler=batches, batch_size=None, num_workers=num_workers, generator=generator, **loader_kwargs)


def collate_pairs(items: list[dict]) -> dict:
    """Stack items into batched tensors: images ``[B, C, H, W]``, every metadata field ``[B, ...]``."""
    if not items:
        raise ValueError("items: expected at least one item")
    # like the batched path, one storage per dtype (a DataLoader worker ships one shared-memory block each)
    flat = {(key, k): v for key, value in items[0].items()
            for k, v in (value.items() if isinstance(value, dict) else [(None, value)])}
    groups: dict = {}
    for name, v in flat.items():
        groups.setdefault((v.dtype, v.device), {})[name] = (len(items), *v.shape)
    out: dict = {}
    for (dtype, device), shapes in groups.items():
        views = _views(shapes, dtype) if device.type == "cpu" else {n: None for n in shapes}
        for (key, k), dst in views.items():
            vals = [it[key] if k is None else it[key][k] for it in items]
            stacked = torch.stack(vals, out=dst) if dst is not None else torch.stack(vals)
            if k is None:
                out[key] = stacked
            else:
                out.setdefault(key, {})[k] = stacked
    return {key: ({k: out[key][k] for k in value} if isinstance(value, dict) else out[key])
            for key, value in items[0].items()}
