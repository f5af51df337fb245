"""Camera training pairs: random scene -> diffraction-limited optics -> noisy sensor, with aligned targets.

Built on :class:`isettorch.optics.DiffractionLimitedOptics` and :class:`isettorch.sensor.Sensor` directly
(a local adapter until ``isettorch.Camera`` is available). Two exact ways to compute a pair:
:func:`render_pair` (``method="reference"``: the Scene -> optics -> Sensor modules on the full spectral cube) and
:func:`render_pairs` (``method="factored"``, the default, ~2x faster: the same draws and physics reordered by
linearity; see its docstring and ``benchmarks/THROUGHPUT.md``). For each index:

1. a random camera: f-number and pixel pitch from discrete lists (so OTFs are cached), full well, read
   noise, dark current, DSNU, PRNU, analog gain (log-uniform), exposure (auto-exposure x 2^EV), CFA phase,
   optionally shifted QE curves. Spectral QE: the Nikon D5100 camera sensitivities measured by NPL (Darrodi
   et al., "Reference data set for camera spectral sensitivity estimation", JOSA A 32(3), 2015; shipped by
   colour-science), scaled to a random peak QE.
2. a random scene (:func:`generate_scene`) rendered ``margin_px`` samples beyond the sensor on each side,
   with its FOV chosen so that one scene sample maps to one pixel (no resampling); the optics blur only
   the sensor's window plus that margin (``crop``) with OTFs cached per (f-number, pitch, grid).
3. the sensor (area sampling, Poisson shot noise, dark current, read noise, DSNU/PRNU drawn per item).

Outputs (a dict of tensors; images in **normalised raw units**: 0 = black level, 1 = white level):

* ``raw`` ``[1, H, W]``: noisy, quantised mosaic ``(DN - black) / (white - black)``.
* ``noise_free_raw`` ``[1, H, W]``: the sensor's ``noise_free`` output in the same units (not quantised).
* ``camera_rgb`` ``[3, H, W]``: every channel at every pixel (R, G, B), the same chain without the CFA
  (clipped at white like the raw): what a demosaic network should recover. Mosaicking it gives
  ``noise_free_raw``.
* ``xyz`` ``[3, H, W]``: CIE 1931 XYZ of the optical image at sensor resolution, scaled by the exposure so that
  a perfect white under the main light has ``Y`` equal to its ``camera_rgb`` green value (not clipped).
* ``linear_srgb`` ``[3, H, W]``: ``xyz`` adapted from the main light's white to D65 (Bradford CAT) and
  converted with the IEC 61966-2-1 matrix (not clipped); ``srgb``: clipped to [0, 1] and encoded.
* ``meta``: a dict of tensors (see :data:`META_KEYS`), batched by :func:`collate_pairs`.
"""

from __future__ import annotations

import functools
import math
import threading
import time

import numpy as np
import torch

from .. import constants, spectral
from .._checks import dataset_index
from ..image import XYZ_TO_LINEAR_SRGB, srgb_encode
from ..isp.colour import bradford_matrix
from .config import CAMERA_DEFAULTS, SCENE_DEFAULTS, merge_config, one_thread, seed_for, tune_allocator
from .scenes import _uniform, generate_scene

__all__ = ["CameraPairDataset", "collate_pairs", "render_pair", "render_pairs", "batch_loader", "META_KEYS",
           "TARGETS", "GENERATOR_VERSION", "check_targets", "nikon_d5100_qe"]

CHANNELS = ("R", "G", "B")
ILLUMINANT_CODES = {"daylight": 0, "blackbody": 1, "led": 2}  # F<n> -> 10 + n
META_KEYS = ("index", "exposure_s", "analog_gain", "iso", "f_number", "focal_length_m", "pixel_size_m",
             "full_well_e", "read_noise_e", "dark_current_e_per_s", "dsnu_sigma_e", "prnu_sigma_percent",
             "black_level_dn", "white_level_dn", "noise_gain", "noise_floor_var", "cfa", "cct_k", "illuminant_code",
             "white_camera_rgb", "white_xyz", "qe", "wavelengths_nm", "hdr_decades", "mean_luminance_cd_m2")

_D65_XYZ = (0.95047, 1.0, 1.08883)  # IEC 61966-2-1 white, Y = 1
TARGETS = ("noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb")  # besides "raw" and "meta"
# Bumped whenever the item of a given (seed, index, config) changes (draw order, layouts, spectra, physics), so
# that `isettorch synth` never resumes a dataset with shards of another version (it enters the config hash).
# 2: 2026-11-22 third speed round (inverse-CDF choices, one-draw leaf parameters, on-locus LEDs, camera distance).
GENERATOR_VERSION = 2
_TARGET_CHANNELS = {"noise_free_raw": 1, "camera_rgb": 3, "xyz": 3, "linear_srgb": 3, "srgb": 3}


def check_targets(targets) -> tuple[str, ...]:
    """``targets`` (names from :data:`TARGETS`, any order) in canonical order; ValueError naming a bad one."""
    if isinstance(targets, str):
        targets = (targets,)
    names = tuple(targets)
    bad = [t for t in names if t not in TARGETS]
    if bad:
        raise ValueError(f"targets: expected names from {TARGETS}, got {bad[0]!r}")
    return tuple(t for t in TARGETS if t in names)


@functools.cache
def _nikon_native() -> tuple[np.ndarray, np.ndarray]:
    import colour

    m = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    vals = np.asarray(m.values, float).T  # [3, Ln] R, G, B
    return np.asarray(m.wavelengths, float), vals / vals.max()


def nikon_d5100_qe(wavelengths_nm, peak_qe: float = 0.5, shift_nm=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Spectral QE ``[3, L]`` (R, G, B) of the Nikon D5100 (NPL data), peak ``peak_qe``, each channel shifted."""
    from ..sensor.filters import filter_set

    w = torch.as_tensor(wavelengths_nm, dtype=torch.float64)  # the one loader: sensor.filters.filter_set
    return torch.stack([filter_set("nikon_5100", w - float(s), dtype=torch.float64)[1][c]
                        for c, s in enumerate(shift_nm)]) * peak_qe


@functools.lru_cache(maxsize=16)
def _xyz_weights(grid: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    """``(W [3, L], dl [L])`` in float64 with ``XYZ = W @ photons``: 683 cmf(l) h c / l dl (CIE 015:2018)."""
    w = torch.tensor(grid, dtype=torch.float64)
    dl = spectral.wavelength_weights(w)
    to_watts = (constants.PLANCK_J_S * constants.SPEED_OF_LIGHT_M_PER_S) / (w * 1e-9)
    return constants.KM_LM_PER_W * spectral.cmfs(w, dtype=torch.float64) * to_watts * dl, dl


def _matmul_fixed_order(a: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``a [K, C] @ x [C, N]`` summed in a fixed order, so results are bitwise identical whatever the number
    of threads (a multi-threaded GEMM may split the sum differently in the main process and in DataLoader
    workers, which would break bitwise reproducibility by (seed, index))."""
    out = a[:, :1] * x[:1]
    for c in range(1, a.shape[1]):
        out = out.addcmul_(a[:, c:c + 1], x[c:c + 1])
    return out


def _pick(values, g: torch.Generator):
    if isinstance(values, (int, float)):
        return float(values)
    return values[int(torch.randint(len(values), (), generator=g))]


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


class _Cache:
    """Per-process caches: ``optics`` holds the optics modules (one per f-number and focal length, each with its OTF
    cache) and the factored path's geometry / OTF tables; ``sensors`` one `Sensor` per discrete camera and thread."""

    def __init__(self):
        self.optics = {}
        self.sensors = {}

    def get_optics(self, f_number: float, focal_length_m: float, margin: int):
        from ..optics import DiffractionLimitedOptics

        key = (f_number, focal_length_m, margin)
        if key not in self.optics:
            self.optics[key] = DiffractionLimitedOptics(f_number=f_number, focal_length_m=focal_length_m,
                                                        margin=margin, pad_mode="zero")
        return self.optics[key]


def _draw_camera(index: int, seed: int, scene_cfg: dict, cam: dict) -> dict:
    """The camera draws of item ``(seed, index)`` (fixed order), and the scene FOV that puts one scene sample on
    one pixel. Shared by the reference and the factored paths."""
    g = torch.Generator().manual_seed(seed_for(seed, index, stream=1))
    h, w = int(scene_cfg["height"]), int(scene_cfg["width"])
    m = int(cam["margin_px"])
    d = {"h": h, "w": w, "m": m}
    d["f_number"] = float(_pick(cam["f_number"], g))
    d["pitch"] = pitch = float(_pick(cam["pixel_size_m"], g))
    d["focal"] = focal = float(_pick(cam["focal_length_m"], g))
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
    d["distance"] = distance = _uniform(scene_cfg["distance_m"], g)
    if not distance > focal:
        raise ValueError(f"scene.distance_m: expected object distances beyond the focal length {focal} m, "
                         f"got {distance}")
    d_i = 1.0 / (1.0 / focal - 1.0 / distance)  # thin lens, as optics.geometry.image_distance (Hecht 5.17)
    d["ws"] = ws = w + 2 * m
    d["hfov"] = math.degrees(2 * math.atan(pitch * ws / (2 * d_i)))
    return d


def render_pair(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
                cache: _Cache | None = None, timings: dict | None = None) -> dict:
    """One camera training pair for ``(seed, index)`` (see the module notes for the outputs).

    ``timings``: optional dict accumulating the CPU seconds spent per stage (scene, optics, sensor, targets,
    setup), for benchmarks. Runs single-threaded (see :func:`config.one_thread`).
    """
    with one_thread():
        return _render_pair(index, seed, scene_cfg, camera_cfg, dtype=dtype, cache=cache, timings=timings)


def _render_pair(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype, cache, timings) -> dict:
    clock = _Clock(timings)
    from ..optics.blur import full_padding
    from ..sensor import CFA, Sensor, SpectralQE
    from ..sensor.sampling import sample_area

    cache = cache or _Cache()
    d = _draw_camera(index, seed, scene_cfg, camera_cfg)
    h, w, m = d["h"], d["w"], d["m"]
    f_number, pitch, focal, fill = d["f_number"], d["pitch"], d["focal"], d["fill"]
    full_well, read_e, dark, dsnu_e, prnu = d["full_well"], d["read_e"], d["dark"], d["dsnu_e"], d["prnu"]
    gain, ev, peak, pattern, shifts = d["gain"], d["ev"], d["peak"], d["pattern"], d["shifts"]
    bits, black, noise_seed, hfov, ws = d["bits"], d["black"], d["noise_seed"], d["hfov"], d["ws"]
    clock("setup")
    scene = generate_scene(index, seed, scene_cfg, dtype=dtype, hfov_deg=hfov, size=(h + 2 * m, ws),
                           distance_m=d["distance"])
    clock("scene")
    optics = cache.get_optics(f_number, focal, m)
    pr, pc = full_padding(h + 2 * m, m), full_padding(ws, m)
    with torch.no_grad():
        oi = optics(scene, crop=(pr + m, pc + m, h, w))
    wave = scene.wavelengths_nm
    clock("optics")

    cfa = CFA(pattern)
    qe_native = nikon_d5100_qe(_nikon_native()[0], peak, shifts)
    qe_module = SpectralQE(qe_native, _nikon_native()[0], cfa.channel_names)
    cg = 1.0 / full_well  # volts per electron with a 1 V swing: well capacity = full_well
    sensor = Sensor(rows=h, cols=w, pixel_size_m=pitch, fill_factor=fill, cfa=cfa, spectral_qe=qe_module,
                    conversion_gain_v_per_e=cg, voltage_swing_v=1.0, analog_gain=gain, adc_bits=bits,
                    black_level_dn=black, shot_noise="poisson", read_noise_v=read_e * cg,
                    dark_current_e_per_s=dark, dsnu_sigma_v=dsnu_e * cg, prnu_sigma_percent=prnu,
                    fpn_mode="per_frame", seed=noise_seed)
    qe = sensor.qe(oi)  # [3, L]
    clock("setup")
    # One pass over the spectral cube: per-channel electron-rate density (e-/s/m^2, as the sensor's
    # electron_rate_density) and absolute XYZ (683 sum E cmf dl, CIE 015:2018) at every OI sample.
    xyz_w, dl = _xyz_weights(tuple(wave.tolist()))
    weights = torch.cat([qe.to(dtype) * dl.to(dtype), xyz_w.to(dtype)])
    dens6 = _matmul_fixed_order(weights, oi.photons.reshape(oi.num_wavelengths, -1)).reshape(1, 6, h, w)
    if abs(float(oi.sample_spacing_m[0]) / pitch - 1) < 1e-4:
        # One OI sample per pixel and the photodiode (side pitch sqrt(fill)) inside it: area sampling of a
        # piecewise-constant irradiance returns the sample itself.
        sampled6 = dens6
    else:  # pragma: no cover - the dataset always matches the grids
        sampled6 = sample_area(dens6, oi.sample_spacing_m, pitch, h, w, fill)
    rate_rgb = sampled6[:, :3] * (fill * pitch * pitch)  # e-/s per pixel and channel
    xyz_img = sampled6[:, 3:]
    # Auto-exposure: the 98th percentile of the brightest channel at 80 % of full scale (after gain), x 2^EV.
    peak = rate_rgb.amax(dim=1).flatten()
    p98 = peak.kthvalue(max(1, math.ceil(0.98 * peak.numel()))).values.double().clamp_min(1e-30)
    exposure = float(0.8 * full_well / gain / p98) * 2.0**ev
    lsb = 1.0 / 2**bits
    white = float(2**bits - 1)
    span = white - black
    ng = torch.Generator().manual_seed(noise_seed)
    clock("targets")
    with torch.no_grad():
        raw = sensor(oi, exposure_s=exposure, analog_gain=gain, noise=True, generator=ng)
    clock("sensor")
    # electrons -> normalised units: e * cg * gain / lsb / span (Sensor: volts = e cg, x gain, / lsb, + black)
    to_norm = cg * gain / lsb / span
    cam_rgb = (rate_rgb * exposure * cg * gain).clamp(max=1.0) / lsb
    cam_rgb = cam_rgb.clamp(max=span) / span

    # XYZ at sensor resolution, exposure-matched: white under light 1 has Y = its green camera value.
    white_p = scene.illuminant_photons[0].to(torch.float64)
    white_xyz = (xyz_w * white_p).sum(dim=1)
    white_cam = (qe.to(torch.float64) * dl * white_p).sum(dim=1)
    k_white = white_cam[1] / white_xyz[1]  # e-/s/m^2 per (cd/m^2-equivalent) on both sides of the optics
    scale = float(k_white) * fill * pitch * pitch * exposure * to_norm
    xyz = xyz_img * scale
    cat = bradford_matrix(white_xyz / white_xyz[1], torch.tensor(_D65_XYZ, dtype=torch.float64))
    m_srgb = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ cat
    lin = _matmul_fixed_order(m_srgb.to(dtype), xyz.reshape(3, -1)).reshape(1, 3, h, w)
    srgb = srgb_encode(lin.clamp(0, 1))

    d = {"gain": gain, "read_e": read_e, "dsnu_e": dsnu_e, "dark": dark, "f_number": f_number, "focal": focal,
         "pitch": pitch, "full_well": full_well, "prnu": prnu, "black": black}
    meta = _meta(index, d, scene.metadata, exposure, to_norm, span, white, cfa, white_cam, white_xyz, qe, wave, dtype)
    clock("targets")
    return {
        "raw": ((raw.data[0] - black) / span).to(dtype),
        "noise_free_raw": ((raw.noise_free[0] - black) / span).to(dtype),
        "camera_rgb": cam_rgb[0].to(dtype),
        "xyz": xyz[0].to(dtype),
        "linear_srgb": lin[0].to(dtype),
        "srgb": srgb[0].to(dtype),
        "meta": meta,
    }


@functools.lru_cache(maxsize=64)
def _nikon_unit_on(grid: tuple, shifts: tuple) -> torch.Tensor:
    w_src, vals = _nikon_native()
    w = torch.tensor(grid, dtype=torch.float64)
    return torch.stack([spectral.resample(torch.from_numpy(vals[c]), torch.from_numpy(w_src) + float(shifts[c]), w)
                        for c in range(3)])


@functools.lru_cache(maxsize=64)
def _unit_qe(pattern: str, shifts: tuple):
    """The D5100 `SpectralQE` with peak QE 1 for a CFA pattern and channel shifts (cached: it resamples once per
    grid); an item's QE is this times its peak QE."""
    from ..sensor import CFA, SpectralQE

    native = _nikon_native()[0]
    return SpectralQE(_nikon_unit_on(tuple(native.tolist()), shifts), native, CFA(pattern).channel_names)


@functools.lru_cache(maxsize=64)
def _camera_parts(pattern: str, shifts: tuple, grid: tuple):
    """``(CFA, SpectralQE with peak 1, its QE [3, L] float64 on grid)`` of a pattern and channel shifts (cached:
    a few discrete cameras repeat; the CFA and QE modules are not modified by a capture)."""
    from ..sensor import CFA

    qe_module = _unit_qe(pattern, shifts)
    return CFA(pattern), qe_module, qe_module(torch.tensor(grid, dtype=torch.float64), dtype=torch.float64)


def _factored_radiance(f: dict, dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The scene of :func:`scenes._draw_scene` factors as ``L(x, l) = sum_j maps_j(x) spectra_j(l)``:

    ``R = (1 - t) P[ia] + t P[ib]`` is linear in the K palette reflectances and the light is ``a E1 + b E2``, so
    ``maps = gain [(1 - t) 1(ia = k) + t 1(ib = k)] x (a | b)`` ``[J, H, W]`` (J = K for one light, 2K for two)
    and ``spectra = scale P_k E1 | scale P_k E2`` ``[J, L]`` (float64), with ``scale`` setting the mean luminance
    exactly as :func:`generate_scene` does; terms whose map is 0 everywhere are left out (J <= K, 2K). Returns
    ``(maps, spectra, white [L])`` (white: light 1, scaled).
    """
    from .scenes import _luminance_weights

    t, ia, ib = f["t"], f["ia"], f["ib"]
    h, w = t.shape
    k = f["palette"].shape[0]
    coef = torch.zeros(k, h * w, dtype=dtype)
    coef.scatter_add_(0, ia.reshape(1, -1), (1 - t).reshape(1, -1).to(dtype))
    coef.scatter_add_(0, ib.reshape(1, -1), t.reshape(1, -1).to(dtype))
    coef.mul_(f["gain"].reshape(1, -1).to(dtype))
    pal = f["palette"].to(torch.float64)
    if f["a"] is not None:
        maps = torch.empty(2 * k, h * w, dtype=dtype)
        torch.mul(coef, f["a"].reshape(1, -1).to(dtype), out=maps[:k])
        torch.mul(coef, f["b"].reshape(1, -1).to(dtype), out=maps[k:])
        spectra = torch.cat([pal * f["e1"], pal * f["e2"]])
    else:
        maps, spectra = coef, pal * f["e1"]
    # mean luminance = sum_j (v . spectra_j) mean_x maps_j (CIE 015:2018 via _luminance_weights), in float64
    lum = spectra @ _luminance_weights(f["wl"])
    # (per-map sums accumulated in the maps' dtype: torch's cascade sum, ~1e-7 relative in float32, 5x faster
    # than converting every pixel to float64)
    mean_lum = float((maps.sum(dim=1).to(torch.float64) * lum).sum()) / (h * w)
    scale = f["target"] / max(mean_lum, torch.finfo(dtype).tiny)
    # Terms whose map is 0 everywhere (palette entries the layout does not use: ~40 % of them, as most layouts
    # but dead leaves use 2-4 of the 8 colours) add exactly 0 to the radiance: dropped, so the optics do fewer FFTs.
    used = maps.amax(dim=1) > 0  # maps >= 0
    if not bool(used.all()):
        idx = used.nonzero().reshape(-1)
        maps, spectra = maps.index_select(0, idx), spectra.index_select(0, idx)
    return maps.reshape(-1, h, w), spectra * scale, f["e1"] * scale


def render_pairs(indices, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
                 cache: _Cache | None = None, timings: dict | None = None, targets=TARGETS) -> dict:
    """Camera training pairs for ``(seed, i)``, ``i`` in ``indices``, batched (the format of :func:`collate_pairs`).

    The same draws and the same physics as :func:`render_pair` (the reference, which runs the `Scene` ->
    `DiffractionLimitedOptics` -> `Sensor` modules), computed in a different order, exactly (no approximation):

    * the radiance is never built as an ``[L, H, W]`` cube: it is ``sum_j maps_j(x) spectra_j(l)`` with J <= 8
      (one light) or 16 (two lights) terms, the palette colours the layout uses (:func:`_factored_radiance`);
    * optics, by linearity: ``FFT(L_l) = sum_j spectra_j(l) FFT(maps_j)`` (J FFTs instead of L), times the
      diffraction OTF of each wavelength, then projected on the 6 spectral weightings needed downstream (camera
      R, G, B electron rates and CIE XYZ) **in the Fourier domain**, so only 6 inverse FFTs are done;
    * the sensor takes those electron rates directly (:meth:`Sensor.capture`): with one OI sample per pixel,
      area sampling is the identity, so it is not recomputed.

    Results differ from :func:`render_pair` only by float rounding (measured 7e-7 of the image maximum in float32,
    1e-15 in float64; in the noisy raw ~0.1 % of pixels get another Poisson or ADC draw where a rate moved by a
    rounding error). Deterministic: an item depends only on ``(seed, index)``, not on the batch it is in, the
    number of threads or workers (bitwise, tested), as each item's FFTs, matrix products and noise draws are
    computed on their own (one intra-op thread).

    Example:
        >>> from isettorch.data.config import CAMERA_DEFAULTS, SCENE_DEFAULTS, merge_config
        >>> scene = merge_config({"height": 16, "width": 16}, SCENE_DEFAULTS, "scene")
        >>> camera = merge_config({}, CAMERA_DEFAULTS, "camera")
        >>> render_pairs([3, 1], 0, scene, camera)["camera_rgb"].shape
        torch.Size([2, 3, 16, 16])
    """
    targets = check_targets(targets)
    with one_thread():
        return _render_pairs([int(i) for i in indices], seed, scene_cfg, camera_cfg, dtype=dtype, cache=cache,
                             timings=timings, targets=targets)


def _render_pairs(indices, seed, scene_cfg, camera_cfg, *, dtype, cache, timings, targets=TARGETS) -> dict:
    from ..optics import geometry
    from ..optics.blur import next_fast_size
    from ..optics.diffraction import dl_otf
    from ..sensor import Sensor
    from .scenes import _draw_scene

    if not indices:
        raise ValueError("indices: expected at least one index")
    clock = _Clock(timings)
    cache = cache or _Cache()
    draws = [_draw_camera(i, seed, scene_cfg, camera_cfg) for i in indices]
    h, w, m = draws[0]["h"], draws[0]["w"], draws[0]["m"]
    hs, ws = h + 2 * m, w + 2 * m
    my, mx = next_fast_size(hs), next_fast_size(ws)
    clock("setup")
    scenes = []
    for i, d in zip(indices, draws):
        f = _draw_scene(i, seed, scene_cfg, device=None, dtype=dtype, hfov_deg=d["hfov"], size=(hs, ws),
                        distance_m=d["distance"])
        scenes.append((f, *_factored_radiance(f, dtype)))
    wave64 = scenes[0][0]["wl"]
    wave = wave64.to(dtype)
    grid = tuple(wave64.tolist())
    xyz_w, dl = _xyz_weights(grid)
    clock("scene")

    # Optics: camera equation and cos^4 (spatial, so they multiply the maps), then the OTF per wavelength.
    spatial, otfs = [], []
    for d, (f, _, _, _) in zip(draws, scenes):
        geo_key = ("geometry", d["f_number"], d["focal"], f["distance"], f["hfov"], hs, ws, grid, dtype)
        geo = cache.optics.get(geo_key)  # a few discrete cameras: the spatial factor and OTF repeat
        if geo is None:
            n = torch.tensor([d["f_number"]], dtype=dtype)
            fl = torch.tensor([d["focal"]], dtype=dtype)
            dist = torch.tensor([f["distance"]], dtype=dtype)
            d_i = geometry.image_distance(fl, dist)
            dx = geometry.image_sample_spacing(torch.tensor([f["hfov"]], dtype=dtype), ws, d_i)
            mag = -d_i / dist
            k_cam = geometry.camera_equation_factor(n, mag)  # ISETCam oiCalculateIrradiance
            ys = (torch.arange(hs, dtype=dtype) - (hs - 1) / 2)[None, :] * dx[:, None]
            xs = (torch.arange(ws, dtype=dtype) - (ws - 1) / 2)[None, :] * dx[:, None]
            q = geometry.cos4th(ys, xs, d_i)[0, 0] * k_cam[0]
            if cache.get_optics(d["f_number"], d["focal"], m).blur_negligible(dx, wave, n):
                otf = torch.ones(len(grid), my * (mx // 2 + 1), 2, dtype=dtype)  # as the optics: blur skipped
            else:
                fy = torch.fft.fftfreq(my, dtype=dtype)[None, :] / dx.reshape(-1, 1)
                fx = torch.fft.rfftfreq(mx, dtype=dtype)[None, :] / dx.reshape(-1, 1)
                # [L, My*Mx', 2]: the same real OTF for the real and imaginary parts (a contiguous multiply)
                otf = dl_otf(fy, fx, wave, n)[0].reshape(len(grid), -1, 1).expand(-1, -1, 2).contiguous()
            geo = cache.optics[geo_key] = (q, otf, dx)
            if len(cache.optics) > 256:  # bounded (continuous distance or FOV ranges would never repeat)
                cache.optics.clear()
        spatial.append(geo[0])
        otfs.append((geo[1], geo[2]))
    # One item at a time: the FFT buffers of a whole batch (~J x 144 x 144 complex per item) do not stay in cache,
    # which made batched transforms ~2x slower per item on CPU; per item, results are the same bitwise.
    cfas, qes = [], []
    nf = my * (mx // 2 + 1) * 2  # real and imaginary parts of the rFFT grid
    # camera R, G, B, then CIE XYZ only when a colour target is asked (fewer projections and inverse FFTs)
    nch = 6 if {"xyz", "linear_srgb", "srgb"} & set(targets) else 3
    cube_buf, proj_buf = torch.empty(len(grid), nf, dtype=dtype), torch.empty(nch, nf, dtype=dtype)
    dens6 = torch.empty(len(draws), nch, h, w, dtype=dtype)
    for b, (d, (_, maps, spectra, _), q, (otf, _)) in enumerate(zip(draws, scenes, spatial, otfs)):
        cfa, qe_module, unit_qe = _camera_parts(d["pattern"], tuple(d["shifts"]), grid)
        qe = (unit_qe * d["peak"]).to(dtype)  # linear resampling commutes with the peak scale
        weights = torch.cat([qe * dl.to(dtype), xyz_w.to(dtype)])[:nch]  # [6 or 3, L]
        src = maps.mul_(q)  # in place: the maps are not used after the optics
        if (my, mx) != (hs, ws):
            src = torch.nn.functional.pad(src, (0, mx - ws, 0, my - hs))
        spec = torch.view_as_real(torch.fft.rfft2(src)).reshape(src.shape[0], -1)  # [J, My*Mx'*2]
        # the [L, F, 2] spectrum of the radiance and its 6 projections in buffers reused across the batch (fresh
        # multi-MB tensors per item cost page faults: ~25 % of this loop)
        torch.mm(spectra.T.to(dtype), spec, out=cube_buf)
        cube_buf.mul_(otf.view(len(grid), -1))
        torch.mm(weights, cube_buf, out=proj_buf)  # 6 (or 3) weightings
        proj = torch.view_as_complex(proj_buf.view(nch, my, mx // 2 + 1, 2))
        dens6[b] = torch.fft.irfft2(proj, s=(my, mx))[:, m:m + h, m:m + w]
        cfas.append(cfa)
        qes.append((qe_module, qe))
    clock("optics")
    return _targets_and_capture(indices, draws, scenes, dens6, cfas, qes, wave, xyz_w, dl, dtype, clock, Sensor,
                                cache, targets)


def _sensor_for(cache: _Cache, d: dict, cfa, qe_module, sensor_cls):
    """The `Sensor` of item ``d``: one module per discrete camera (pixel pitch, fill factor, CFA, QE curves, ADC),
    built and validated once, then given the item's continuous parameters (conversion gain from the full well,
    read noise, dark current, DSNU, PRNU, analog gain: plain float attributes read at capture time). Building a
    `Sensor` per item cost ~0.2 ms (nn.Module set-up and argument checks); the values are the same."""
    # per thread: the module's noise attributes are set per item, so threads sharing a dataset must not share it;
    # not per QE shift (continuous with qe_variation > 0): the item's QE module is set like the noise parameters
    key = (d["pitch"], d["fill"], d["pattern"], d["bits"], d["black"], threading.get_ident())
    sensor = cache.sensors.get(key)
    if sensor is None:
        if len(cache.sensors) > 256:  # bounded
            cache.sensors.clear()
        sensor = cache.sensors[key] = sensor_cls(
            rows=d["h"], cols=d["w"], pixel_size_m=d["pitch"], fill_factor=d["fill"], cfa=cfa, spectral_qe=qe_module,
            conversion_gain_v_per_e=1.0 / d["full_well"], voltage_swing_v=1.0, analog_gain=d["gain"],
            adc_bits=d["bits"], black_level_dn=d["black"], shot_noise="poisson", fpn_mode="per_frame")
    cg = 1.0 / d["full_well"]  # volts per electron with a 1 V swing: well capacity = full_well
    sensor.spectral_qe = qe_module
    sensor.conversion_gain_v_per_e = cg
    sensor.analog_gain = d["gain"]
    sensor.read_noise_v = d["read_e"] * cg
    sensor.dark_current_e_per_s = d["dark"]
    sensor.dsnu_sigma_v = d["dsnu_e"] * cg
    sensor.prnu_sigma_percent = d["prnu"]
    sensor.seed = d["noise_seed"]
    return sensor


def _views(shapes: dict, dtype) -> dict:
    """Contiguous tensors ``{key: [shape]}`` that are views of **one** storage: a DataLoader worker then ships the
    whole batch as one shared-memory block instead of one per tensor (measured with 2 workers on 2 cores: the main
    process's CPU per pair 0.57 -> 0.21 ms, 217 -> 234 pairs/s)."""
    sizes = [math.prod(shape) for shape in shapes.values()]
    flat = torch.empty(sum(sizes), dtype=dtype)
    out, start = {}, 0
    for (key, shape), size in zip(shapes.items(), sizes):
        out[key] = flat[start:start + size].view(shape)
        start += size
    return out


def _targets_and_capture(indices, draws, scenes, dens, cfas, qes, wave, xyz_w, dl, dtype, clock, sensor_cls,
                         cache, targets=TARGETS):
    """Exposure, the sensor capture (per item: its own noise generator) and the requested targets, batched;
    returns the batch dict (the format of :func:`collate_pairs`; every image and float field in one storage).
    ``dens``: ``[B, 3 or 6, H, W]`` camera R, G, B electron-rate densities, then XYZ when a colour target is asked."""
    nb = len(indices)
    h, w, bits, black = draws[0]["h"], draws[0]["w"], draws[0]["bits"], draws[0]["black"]
    img = _views({k: (nb, c, h, w) for k, c in (("raw", 1), *((t, _TARGET_CHANNELS[t]) for t in targets))}, dtype)

    def col(values, dt=dtype):  # per-item scalars as a [B, 1, 1, 1] tensor
        return torch.tensor(values, dtype=dt).reshape(nb, 1, 1, 1)

    rate_rgb = dens[:, :3] * col([d["fill"] * d["pitch"] * d["pitch"] for d in draws])  # e-/s per pixel
    # Auto-exposure: the 98th percentile of the brightest channel at 80 % of full scale (after gain), x 2^EV.
    peak = rate_rgb.amax(dim=1).flatten(1)
    p98 = peak.kthvalue(max(1, math.ceil(0.98 * peak.shape[1])), dim=1).values.double().clamp_min(1e-30)
    exposure = [float(0.8 * d["full_well"] / d["gain"] / p98[b]) * 2.0 ** d["ev"] for b, d in enumerate(draws)]
    lsb = 1.0 / 2**bits
    white = float(2**bits - 1)
    span = white - black
    cg = [1.0 / d["full_well"] for d in draws]  # volts per electron with a 1 V swing: well capacity = full_well
    clock("targets")
    for b, d in enumerate(draws):
        sensor = _sensor_for(cache, d, cfas[b], qes[b][0], sensor_cls)
        ng = torch.Generator().manual_seed(d["noise_seed"])
        with torch.no_grad():
            raw = sensor.capture(cfas[b].mosaic(rate_rgb[b:b + 1]), exposure_s=exposure[b], analog_gain=d["gain"],
                                 noise=True, generator=ng)
        torch.sub(raw.data, black, out=img["raw"][b:b + 1]).div_(span)
        if "noise_free_raw" in img:
            torch.sub(raw.noise_free, black, out=img["noise_free_raw"][b:b + 1]).div_(span)
    clock("sensor")
    gain = [d["gain"] for d in draws]
    to_norm = [cg[b] * gain[b] / lsb / span for b in range(nb)]
    if "camera_rgb" in img:
        # (x clamped at 1) / lsb, clamped at span, / span, in place: lsb = 2^-bits makes x / lsb exact and span <
        # 2^bits, so min(min(x, 1) / lsb, span) = min(x 2^bits, span), bitwise.
        cam_rgb = (rate_rgb * col(exposure)).mul_(col(cg)).mul_(col(gain))
        torch.div(cam_rgb.mul_(2.0**bits).clamp_(max=span), span, out=img["camera_rgb"])
    # the main light's white (per item, rows of one batched reduction each): XYZ, camera response, adaptation
    white_p = torch.stack([sc[3] for sc in scenes]).to(torch.float64)  # [B, L]
    white_xyz = (xyz_w * white_p[:, None]).sum(dim=-1)  # [B, 3]
    white_cam = (torch.stack([q[1] for q in qes]).to(torch.float64) * dl * white_p[:, None]).sum(dim=-1)
    k_white = (white_cam[:, 1] / white_xyz[:, 1]).tolist()  # e-/s/m^2 per (cd/m^2-equivalent), both sides
    scales = [k_white[b] * d["fill"] * d["pitch"] * d["pitch"] * exposure[b] * to_norm[b] for b, d in enumerate(draws)]
    cat = bradford_matrix(white_xyz / white_xyz[:, 1:2], torch.tensor(_D65_XYZ, dtype=torch.float64))  # [B, 3, 3]
    mats = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ cat
    metas = [_meta_values(indices[b], d, scenes[b][0]["meta"], exposure[b], to_norm[b], span, white, cfas[b],
                          white_cam[b], white_xyz[b], qes[b][1], wave) for b, d in enumerate(draws)]
    if dens.shape[1] == 6:
        xyz = torch.mul(dens[:, 3:], col(scales), out=img.get("xyz"))
        if "linear_srgb" in img or "srgb" in img:
            m_srgb = mats.to(dtype)[..., None]  # [B, 3, 3, 1]
            x3 = xyz.reshape(nb, 3, -1)
            lin = img["linear_srgb"].view(nb, 3, -1) if "linear_srgb" in img else torch.empty_like(x3)
            torch.mul(m_srgb[:, :, 0], x3[:, :1], out=lin)  # fixed summation order, as _matmul_fixed_order
            for c in (1, 2):
                lin.addcmul_(m_srgb[:, :, c], x3[:, c:c + 1])
            if "srgb" in img:
                srgb_encode(lin.view(nb, 3, h, w).clamp(0, 1), out=img["srgb"])
    out = dict(img)
    out["meta"] = _batch_meta(metas, dtype)
    clock("targets")
    return out


def _meta_values(index, d, meta_s, exposure, to_norm, span, white, cfa, white_cam, white_xyz, qe, wave) -> dict:
    """The metadata of one item (:data:`META_KEYS`) as Python numbers and tensors (see :func:`_meta`)."""
    name = meta_s["illuminant"]
    code = ILLUMINANT_CODES.get(name, 10 + int(name[1:]) if name.startswith("F") else -1)
    quant_var = 1.0 / 12.0 / span**2
    gain, read_e, dsnu_e, dark = d["gain"], d["read_e"], d["dsnu_e"], d["dark"]
    return {
        "index": int(index),
        "exposure_s": exposure, "analog_gain": gain, "iso": 100.0 * gain, "f_number": d["f_number"],
        "focal_length_m": d["focal"], "pixel_size_m": d["pitch"], "full_well_e": d["full_well"],
        "read_noise_e": read_e, "dark_current_e_per_s": dark, "dsnu_sigma_e": dsnu_e,
        "prnu_sigma_percent": d["prnu"], "black_level_dn": d["black"], "white_level_dn": white,
        # Poisson-Gaussian noise model in normalised units: var(x) = noise_gain * x + noise_floor_var
        # (Foi et al., "Practical Poissonian-Gaussian noise modeling", IEEE TIP 17(10), 2008).
        "noise_gain": to_norm,
        "noise_floor_var": (read_e**2 + dsnu_e**2 + dark * exposure) * to_norm**2 + quant_var,
        "cfa": cfa.index_map,
        "cct_k": meta_s["cct_k"], "illuminant_code": int(code),
        "white_camera_rgb": white_cam / white_cam[1],
        "white_xyz": white_xyz / white_xyz[1],
        "qe": qe, "wavelengths_nm": wave,
        "hdr_decades": meta_s["hdr_decades"], "mean_luminance_cd_m2": meta_s["mean_luminance_cd_m2"],
    }


_LONG_META = ("index", "illuminant_code", "cfa")


def _meta(index, d, meta_s, exposure, to_norm, span, white, cfa, white_cam, white_xyz, qe, wave, dtype) -> dict:
    """One item's metadata as tensors: long for ``index``, ``illuminant_code``, ``cfa``; ``dtype`` otherwise."""
    values = _meta_values(index, d, meta_s, exposure, to_norm, span, white, cfa, white_cam, white_xyz, qe, wave)
    return {k: (v.to(torch.long if k in _LONG_META else dtype).clone() if isinstance(v, torch.Tensor)
                else torch.tensor(v, dtype=torch.long if k in _LONG_META else dtype)) for k, v in values.items()}


def _batch_meta(metas: list[dict], dtype) -> dict:
    """Per-item metadata values -> ``[B, ...]`` tensors, the same values as stacking :func:`_meta` items, in one
    storage per dtype (scalars converted once per key for the whole batch)."""
    nb = len(metas)
    shapes = {k: (nb, *(tuple(v.shape) if isinstance(v, torch.Tensor) else ())) for k, v in metas[0].items()}
    floats = _views({k: s for k, s in shapes.items() if k not in _LONG_META}, dtype)
    longs = _views({k: shapes[k] for k in _LONG_META}, torch.long)
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
        scene: scene config (keys of ``SCENE_DEFAULTS``), camera: camera config (keys of ``CAMERA_DEFAULTS``).
        dtype: float32 (default) or float64.
        method: ``'factored'`` (default, :func:`render_pairs`: the same physics computed in a faster, exact order)
            or ``'reference'`` (:func:`render_pair`: the `Scene` -> optics -> `Sensor` modules, one item at a
            time). They agree to float rounding (see :func:`render_pairs`).
        targets: the targets to compute, from :data:`TARGETS` (default all; ``raw`` and ``meta`` are always
            there). The factored path computes only what is asked: without ``xyz``/``linear_srgb``/``srgb`` the
            optics project on 3 weightings instead of 6 (3 fewer inverse FFTs); fewer targets also mean less
            data to move between DataLoader workers and the main process.
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
        if int(length) < 0:
            raise ValueError(f"length: expected a non-negative number of items, got {length}")
        if method not in self.METHODS:
            raise ValueError(f"method: expected one of {self.METHODS}, got {method!r}")
        self.length, self.seed, self.dtype, self.method = int(length), int(seed), dtype, method
        self.scene_config = merge_config(scene, SCENE_DEFAULTS, "scene")
        self.camera_config = merge_config(camera, CAMERA_DEFAULTS, "camera")
        if self.scene_config["height"] % 2 or self.scene_config["width"] % 2:
            raise ValueError(f"scene.height/width: expected even sizes (whole Bayer cells), got "
                             f"{self.scene_config['height']}x{self.scene_config['width']}")
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
        if self.method == "reference":
            item = render_pair(index, self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                               cache=self._cache)
            return {k: v for k, v in item.items() if k in ("raw", "meta", *self.targets)}
        with one_thread():
            batch = _render_pairs([index], self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                                  cache=self._cache, timings=None, targets=self.targets)
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
        return render_pairs(idx, self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                            cache=self._cache, targets=self.targets)


def batch_loader(dataset: CameraPairDataset, batch_size: int, *, shuffle: bool = False, sampler=None,
                 generator: torch.Generator | None = None, drop_last: bool = False, num_workers: int = 0,
                 **loader_kwargs) -> torch.utils.data.DataLoader:
    """A ``DataLoader`` whose workers generate whole batches (:meth:`CameraPairDataset.get_batch`).

    Yields the same batches, bitwise, as ``DataLoader(dataset, batch_size, sampler=..., collate_fn=collate_pairs)``
    with the same sampler (items depend only on ``(seed, index)``), for any ``num_workers``.

    Args:
        batch_size: items per batch. shuffle / generator: a ``RandomSampler`` (seeded by ``generator``) instead
            of the sequential order; ``sampler``: any index sampler (e.g. ``DistributedSampler``) instead.
        drop_last, num_workers, loader_kwargs: passed on (``BatchSampler`` / ``DataLoader``).

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
    batches = torch.utils.data.BatchSampler(sampler, batch_size, drop_last)
    # the loader draws its workers' base seed from the same generator first, exactly as DataLoader(shuffle=True)
    return torch.utils.data.DataLoader(dataset, sampler=batches, batch_size=None, num_workers=num_workers,
                                       generator=generator, **loader_kwargs)


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
