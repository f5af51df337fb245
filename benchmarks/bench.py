"""Speed against error: timings of scene -> optics -> sensor -> ISP and of the knobs that trade accuracy for
speed, each with its error against the most accurate setting, plus peers (NumPy reference, colour-demosaicing,
kornia) measured in the same run.

Every result is a row ``{"name", "group", "seconds_median", "error", "error_unit", ...}``:

* ``seconds_median``: median wall time of ``repeats`` runs after ``warmup`` runs (CUDA synchronised).
* ``error``: the primary error of the row against the reference of its group, in ``error_unit``; ``None``
  only for pure timing rows (stage timings) that have nothing to be compared with. Knob rows also carry
  ``errors = {"volts_rel", "de2000_mean", "cpsnr_db"}`` (sensor volts relative RMS, mean CIEDE2000 of the
  rendered sRGB images, colour PSNR of the rendered images; CPSNR is None when the images are identical).
* ``reference: True`` marks the most accurate setting of a group (its error is 0 by construction).
* ``ratio``: for the "model only what the scene needs" rows, time / time of the full-work row.

Knob groups (each varies one knob from the most accurate setting of that knob, with the others at the
library defaults, on a scene made of a Macbeth chart next to a frequency sweep, fixed exposure, noise off):
wavelength step (ISETCam's rectangle rule, and the trapezoid rule emulated), OTF wavelength grouping
(emulated with the library optics), padding, spatial sampling (4 x 4 OI samples per pixel), dtype
(float64/float32; bfloat16/float16 after a float32 optics stage because CPU FFTs have no half kernels),
shot-noise mode at normal and low light (error: relative difference of the noise standard deviation against
exact Poisson, pooled over frames).

Every timed row calls the library's own modules (``Camera``'s optics, sensor and ISP, or the ISETCam-compatible
functions that ``isettorch parity`` checks); peers (NumPy reference, colour-demosaicing, kornia) run on the same
inputs. This file is the implementation of ``isettorch bench``, which runs it as a script from a source
checkout (the package never imports ``benchmarks/``).

Example:
    >>> from bench import run_benchmarks, format_report  # with benchmarks/ on sys.path
    >>> result = run_benchmarks(quick=True)  # doctest: +SKIP
    >>> print(format_report(result))  # doctest: +SKIP

Reference: the timing conventions of ``torch.utils.benchmark`` (warm-up excluded, CUDA synchronised, median).
"""

from __future__ import annotations

import importlib.util
import math
import os
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from isettorch._machine import machine_info  # the one record of the machine (re-exported)

__all__ = ["Seconds", "run_benchmarks", "format_table", "format_report", "plot_pareto", "time_call", "machine_info",
           "ROW_KEYS"]

ROW_KEYS = ("name", "seconds_median", "error", "error_unit")
PITCH_M = 2.8e-6  # ISETCam default pixel
FOCAL_M = 3.862755099e-3  # ISETCam default focal length
DISTANCE_M = 1.2
REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------------------------------------------
# timing


def _sync(device) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


class Seconds(float):
    """A median time (s) that also carries the fastest run (``.min``), the less load-sensitive estimate, and the
    median CPU time of the process per run (``.cpu``, all threads; None where not measured): on a machine shared
    with other jobs wall time grows with the load, CPU time much less."""

    def __new__(cls, median: float, fastest: float, cpu: float | None = None):
        obj = super().__new__(cls, median)
        obj.min = float(fastest)
        obj.cpu = None if cpu is None else float(cpu)
        return obj


_TIMING = {"min_time_s": 0.0}  # set by run_benchmarks (0.5 s in the standard run, 0 in --quick)


def time_call(fn: Callable[[], Any], repeats: int = 3, warmup: int = 1, device="cpu", *,
              min_time_s: float | None = None, max_repeats: int = 30) -> tuple[float, Any, list]:
    """Median wall time of ``fn()`` over at least ``repeats`` runs after ``warmup`` runs (synchronised on CUDA).

    Short calls are repeated until they have run ``min_time_s`` in total (at most ``max_repeats`` runs; default:
    the benchmark's setting), so a median of a few milliseconds is not decided by one scheduler hiccup on a
    shared machine.

    Returns ``(median_s, last_result, times_s)``.
    """
    min_time_s = _TIMING["min_time_s"] if min_time_s is None else min_time_s
    out = None
    for _ in range(warmup):
        out = fn()
        _sync(device)
    times, cpu = [], []
    while len(times) < max(1, repeats) or (sum(times) < min_time_s and len(times) < max_repeats):
        _sync(device)
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return Seconds(statistics.median(times), min(times), statistics.median(cpu)), out, times


# --------------------------------------------------------------------------------------------------------------
# the standard camera


def hfov_for(n_cols: int, pitch_m: float = PITCH_M) -> float:
    """Horizontal FOV (deg) at which one scene sample lands on one pixel: 2 atan(pitch W / (2 d_i)), ``d_i`` the
    thin-lens image distance (the library's ``optics.geometry.image_distance`` and ``image.angle_for_extent``)."""
    from isettorch.image import angle_for_extent
    from isettorch.optics.geometry import image_distance

    d_i = image_distance(FOCAL_M, DISTANCE_M)
    return float(angle_for_extent(torch.tensor(pitch_m * n_cols, dtype=torch.float64), d_i))


def wavelengths(step_nm: float, dtype=torch.float64) -> torch.Tensor:
    return torch.arange(400.0, 700.0 + step_nm / 2, step_nm, dtype=dtype)


def sweep_scene(n: int, w: torch.Tensor | None = None, dtype=torch.float32, device="cpu"):
    from isettorch.scene import frequency_sweep

    w = wavelengths(10.0) if w is None else w
    return frequency_sweep(n, wavelengths=w, hfov_deg=hfov_for(n), dtype=dtype, device=device)


def knob_scene(patch: int, w: torch.Tensor, dtype=torch.float64, device="cpu"):
    """A Macbeth chart (4 x 6 patches of ``patch`` px) next to a frequency sweep of the same height (D65):
    colour for dE, edges and fine detail for the spatial knobs, a black surround for the padding."""
    from isettorch.scene import Scene, frequency_sweep, macbeth

    h = 4 * patch
    mb = macbeth(patch_size=patch, wavelengths=w, dtype=torch.float64)
    sw = frequency_sweep((h, h), wavelengths=w, dtype=torch.float64, contrast_ramp=False)
    sw_ph = sw.photons * (mb.photons.mean() / sw.photons.mean())
    photons = torch.cat([mb.photons, sw_ph], dim=-1)
    return Scene(photons.to(dtype), w.to(dtype), hfov_deg=hfov_for(photons.shape[-1]), distance_m=DISTANCE_M,
                 name="macbeth+sweep").to(device=device)


def make_optics(**kw):
    from isettorch.optics import DiffractionLimitedOptics

    return DiffractionLimitedOptics(f_number=4.0, focal_length_m=FOCAL_M, **kw)


def make_sensor(rows: int, cols: int, *, exposure_s: float = 0.01, noise: bool = False, **kw):
    """ISETCam default preset (GRBG, 2.8 um, fill 0.75); noise parameters zeroed unless ``noise``."""
    from isettorch.sensor import Sensor

    quiet = {} if noise else {"read_noise_v": 0.0, "dark_current_e_per_s": 0.0, "shot_noise": "off"}
    quiet.update(kw)
    return Sensor.preset("isetcam_default", rows=rows, cols=cols, exposure_s=exposure_s, **quiet)


def make_isp(sensor, device="cpu"):
    from isettorch.isp import ImageProcessor

    ip = ImageProcessor().to(device)
    ip.fit(sensor)
    return ip


def fixed_exposure(sensor, oi, fraction: float = 0.8) -> float:
    """Exposure (s) that puts the brightest noise-free pixel at ``fraction`` of saturation: the sensor's own
    luminance auto-exposure (``Sensor.exposure_for``: black level, full well, analog gain and offset included),
    computed once so that the timed runs use one fixed exposure."""
    import copy

    ae = copy.deepcopy(sensor)
    ae.auto_exposure, ae.ae_target = "luminance", fraction
    t = ae.exposure_for(oi).double()
    if t.numel() != 1:
        raise ValueError(f"oi: expected one optical image for one exposure, got a batch of {t.numel()}")
    return float(t)


# --------------------------------------------------------------------------------------------------------------
# errors


def volts_rel(v: torch.Tensor, ref: torch.Tensor) -> float:
    """Relative RMS difference ||v - ref|| / ||ref|| (float64)."""
    v, ref = v.detach().double().cpu(), ref.detach().double().cpu()
    return float(torch.linalg.vector_norm(v - ref) / torch.linalg.vector_norm(ref))


def render_errors(img: torch.Tensor, ref: torch.Tensor) -> dict:
    """Mean CIEDE2000 and CPSNR (dB) between two encoded sRGB renders (B, 3, H, W) in [0, 1]."""
    from isettorch.metrics import cpsnr, delta_e_2000, srgb_to_xyz, xyz_to_lab

    a = img.detach().double().cpu().clamp(0, 1)
    b = ref.detach().double().cpu().clamp(0, 1)
    de = delta_e_2000(xyz_to_lab(srgb_to_xyz(b)), xyz_to_lab(srgb_to_xyz(a)))
    mse = float(((a - b) ** 2).mean())
    return {"de2000_mean": float(de.mean()), "cpsnr_db": None if mse == 0 else float(cpsnr(a, b))}


def _row(name: str, group: str, seconds: float | None, error: float | None, unit: str | None, **extra) -> dict:
    row = {"name": name, "group": group, "seconds_median": None if seconds is None else float(seconds),
           "error": None if error is None else float(error), "error_unit": unit}
    if hasattr(seconds, "min"):
        row["seconds_min"] = seconds.min
    if getattr(seconds, "cpu", None) is not None:
        row["cpu_seconds_median"] = seconds.cpu
    row.update(extra)
    return row


# --------------------------------------------------------------------------------------------------------------
# 1. end-to-end stage timings


def pipeline_rows(sizes, repeats: int, device, dtype=torch.float32, log=print) -> list[dict]:
    """Scene -> optics -> sensor (noise on) -> ISP at each size (31 bands), per stage."""
    rows = []
    for n in sizes:
        log(f"  pipeline {n}x{n}x31")
        w = wavelengths(10.0)
        optics = make_optics().to(device)
        sensor = make_sensor(n, n, noise=True, read_noise_v=1e-3, dark_current_e_per_s=10.0, shot_noise="poisson")
        sensor = sensor.to(device)
        isp = make_isp(sensor, device)
        scene0 = sweep_scene(n, w, dtype, device)
        with torch.no_grad():
            t_exp = fixed_exposure(sensor, optics(scene0))
        stages = {"scene": [], "optics": [], "sensor": [], "isp": []}
        reps = repeats if n <= 128 else max(2, repeats - 2) if n <= 512 else max(2, repeats - 3)
        for i in range(reps + 1):  # first run is the warm-up
            with torch.no_grad():
                marks = [time.perf_counter()]
                scene = sweep_scene(n, w, dtype, device)
                _sync(device)
                marks.append(time.perf_counter())
                oi = optics(scene)
                _sync(device)
                marks.append(time.perf_counter())
                raw = sensor(oi, exposure_s=t_exp)
                _sync(device)
                marks.append(time.perf_counter())
                isp(raw)
                _sync(device)
                marks.append(time.perf_counter())
            if i:
                for k, (a, b) in zip(stages, zip(marks[:-1], marks[1:])):
                    stages[k].append(b - a)
            del scene, oi, raw
        total = [sum(v) for v in zip(*stages.values())]
        tag = f"{n}x{n}x31"
        for k, v in stages.items():
            rows.append(_row(f"pipeline_{k}_{tag}", "pipeline", Seconds(statistics.median(v), min(v)), None, None,
                             note=f"{str(dtype).replace('torch.', '')}, {len(v)} runs"))
        rows.append(_row(f"pipeline_total_{tag}", "pipeline", Seconds(statistics.median(total), min(total)), None, None,
                         note="scene + optics + sensor (Poisson, read, dark noise) + ISP (bilinear, MCC, sRGB)"))
        del optics, sensor, isp, scene0
    return rows


# --------------------------------------------------------------------------------------------------------------
# 2. stable rows to compare with ISETCam


def rank1_factors(photons: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(maps [B, 1, H, W], spectra [B, 1, L])`` of a rank-1 cube ``photons [B, L, H, W]`` (a pattern times one
    spectrum, as every ``pattern_scene``): the band sum as the map, the spectrum read at its brightest pixel.
    Raises if the cube is not rank 1 to float32 rounding (a factored Scene gives its factors directly)."""
    maps = photons.sum(1, keepdim=True)
    flat = maps.flatten(1)
    i = flat.argmax(1)
    b = torch.arange(photons.shape[0])
    spectra = (photons.flatten(2)[b, :, i] / flat[b, i][:, None])[:, None, :]  # [B, 1, L]
    dense = torch.einsum("bjhw,bjl->blhw", maps, spectra)
    err = float((dense - photons).abs().max() / photons.abs().max())
    if err > 1e-5:
        raise ValueError(f"photons: expected a rank-1 cube (pattern x spectrum), reconstruction error {err:.2e}")
    return maps, spectra


def _rel_max(ours: torch.Tensor, ref: torch.Tensor) -> float:
    """Max |ours - ref| / ref over reference values above 1 % of the max (the ``isettorch parity`` statistic)."""
    ours, ref = ours.detach().double().cpu(), ref.detach().double().cpu()
    m = ref.abs() > 0.01 * ref.abs().max()
    return float(((ours - ref).abs()[m] / ref.abs()[m]).max())


def isetcam_sensor(hfov_deg: float, image_distance_m: float, exposure_s: float = 0.01):
    """The sensor of the ISETCam comparison: ``sensorCreate`` defaults (isetcam_default preset) with ISETCam's
    conventions (``ISETCAM_CONVENTIONS``, as ``isettorch parity`` builds it), noise off, sized to the OI as
    ``sensorSetSizeToFOV`` (198 x 242 px for the 10 deg sweep)."""
    from isettorch.sensor import ISETCAM_CONVENTIONS, Sensor

    sensor = Sensor.preset("isetcam_default", read_noise_v=0.0, dark_current_e_per_s=0.0, shot_noise="off",
                           exposure_s=exposure_s, **ISETCAM_CONVENTIONS)
    sensor.set_size_to_fov(hfov_deg, image_distance_m)
    return sensor


def stable_rows(n: int, repeats: int, device, log=print) -> list[dict]:
    """``optics_{n}x{n}x31`` and ``sensor_{n}x{n}x31``: exactly the ISETCam-compatible configuration that
    ``isettorch parity`` passes with, on ISETCam's ``sceneCreate('sweep frequency', n)`` work (10 deg, 31 bands):
    :func:`isettorch.optics.isetcam.compute_oi_factored` (``oiCompute``, diffraction limited f/4, the sweep as
    its rank-1 factors) and a Sensor with ``ISETCAM_CONVENTIONS`` (``sensorCompute``, noise off, 0.01 s), both in
    float32 (ISETCam's single precision). ``error``: max relative error against the float64 result of the same
    functions on the dense cube, over values above 1 % of the max. ``optics_dense_*`` times the dense input."""
    from isettorch.optics.isetcam import compute_oi, compute_oi_factored
    from isettorch.scene import frequency_sweep

    log(f"  stable rows {n}x{n}x31")
    w = wavelengths(10.0)
    sc64 = frequency_sweep(n, wavelengths=w, dtype=torch.float64, device=device)
    geo = (float(sc64.hfov_deg[0]), float(sc64.distance_m[0]), 4.0, FOCAL_M)
    with torch.no_grad():
        t_r, ref_oi, _ = time_call(lambda: compute_oi(sc64.photons, w, *geo), max(1, repeats // 2), 1, device)
        sensor = isetcam_sensor(geo[0], float(ref_oi.image_distance_m[0])).to(device)
        t_rs, raw64, _ = time_call(lambda: sensor(ref_oi, noise=False), max(1, repeats // 2), 1, device)
        ref_v = raw64.data
        sc = sc64.to(dtype=torch.float32)
        maps, spectra = rank1_factors(sc.photons)
        # lazy: the OI stays in the Fourier domain (J + 1 forward FFTs); the sensor's K = 3 inverse FFTs of its
        # QE projections are in the sensor row (the OI's dense cube is read only after the timings, for `error`)
        t_o, oi, _ = time_call(lambda: compute_oi_factored(maps, spectra, w, *geo, lazy=True), repeats, 1, device)
        t_d, oi_d, _ = time_call(lambda: compute_oi(sc.photons, w, *geo), repeats, 1, device)
        t_s, raw, _ = time_call(lambda: sensor(oi, noise=False), repeats, 1, device)
        t_os, raw_os, _ = time_call(lambda: sensor(compute_oi_factored(maps, spectra, w, *geo, lazy=True),
                                                   noise=False), repeats, 1, device)
    tag = f"{n}x{n}x31"
    unit = "max rel. error vs float64 (values > 1 % of max)"
    shape = tuple(oi.photons.shape[-2:])
    return [
        _row(f"optics_{tag}", "isetcam_compare", t_o, _rel_max(oi.photons, ref_oi.photons), unit,
             note=f"optics.isetcam.compute_oi_factored(lazy=True) (rank-1 sweep), f/4 -> Fourier-domain OI {shape}, "
                  f"float32; error of its dense (abs-ed) cube"),
        _row(f"sensor_{tag}", "isetcam_compare", t_s, _rel_max(raw.data, ref_v), unit,
             note=f"isetcam_default {raw.data.shape[-2]}x{raw.data.shape[-1]} px, ISETCAM_CONVENTIONS, noise off, "
                  f"exposure 0.01 s, on the lazy float32 OI (its 3 QE-projected planes: 3 inverse FFTs); error of "
                  f"volts after the float32 optics"),
        _row(f"optics_sensor_{tag}", "isetcam_compare", t_os, _rel_max(raw_os.data, ref_v), unit,
             note="the two rows above in one call (what ISETCam's oiCompute + sensorCompute do)"),
        _row(f"optics_dense_{tag}", "isetcam_compare", t_d, _rel_max(oi_d.photons, ref_oi.photons), unit,
             note=f"optics.isetcam.compute_oi on the dense {tag} cube -> OI {shape}, float32"),
        _row(f"optics_float64_{tag}", "isetcam_compare", t_r, 0.0, unit, reference=True,
             note="the reference: optics.isetcam.compute_oi on the dense cube in float64 (what isettorch parity runs)"),
        _row(f"sensor_float64_{tag}", "isetcam_compare", t_rs, 0.0, unit, reference=True,
             note="the reference: the same sensor on the float64 OI"),
    ]


# --------------------------------------------------------------------------------------------------------------
# 3. knobs


class _GroupedOTFOptics:
    """Emulated OTF wavelength grouping: each band uses the OTF of its group's centre wavelength."""

    @staticmethod
    def make(n_groups: int, **kw):
        from isettorch.optics import DiffractionLimitedOptics, dl_otf

        class Grouped(DiffractionLimitedOptics):
            def otf(self, fy, fx, wavelengths_nm, f_number):
                return dl_otf(fy, fx, group_centres(wavelengths_nm, n_groups), f_number)

        return Grouped(f_number=4.0, focal_length_m=FOCAL_M, **kw)


def wavelength_groups(n_bands: int, n_groups: int) -> list[torch.Tensor]:
    """Band indices split into ``n_groups`` contiguous groups of (nearly) equal size."""
    if not 1 <= n_groups <= n_bands:
        raise ValueError(f"n_groups: expected 1..{n_bands}, got {n_groups}")
    return list(torch.tensor_split(torch.arange(n_bands), n_groups))


def group_centres(w: torch.Tensor, n_groups: int) -> torch.Tensor:
    """Each wavelength replaced by the mean wavelength of its group (``n_groups`` contiguous groups)."""
    out = torch.empty_like(w)
    for sel in wavelength_groups(w.numel(), n_groups):
        out[sel] = w[sel].mean()
    return out


def knob_rows(patch: int, repeats: int, device, log=print) -> tuple[list[dict], list[dict]]:
    """Every accuracy-for-speed knob with its measured error; returns (rows, skipped)."""
    rows, skipped = [], []
    f64 = torch.float64

    def setup(w, dtype=f64):
        scene = knob_scene(patch, w, dtype=dtype, device=device)
        h, wd = scene.photons.shape[-2:]
        return scene, h, wd

    # reference geometry and exposure (10 nm, float64, defaults)
    scene10, h, wd = setup(wavelengths(10.0))
    sensor = make_sensor(h, wd).to(device)
    isp = make_isp(sensor, device)
    with torch.no_grad():
        t_exp = fixed_exposure(sensor, make_optics().to(device)(scene10))

    last = {}

    def run(optics, scene, sens=None, noise=False):
        sens = sens or sensor
        with torch.no_grad():
            oi = optics(scene)
            last["shape"] = tuple(oi.photons.shape[-2:])
            raw = sens(oi, exposure_s=t_exp, noise=noise)
            return raw, isp(raw).image

    def measure(name, group, fn, ref, ref_flag=False, note=""):
        try:
            t, (volts, img), times = time_call(fn, repeats, 1, device)
        except (RuntimeError, NotImplementedError, TypeError, ValueError) as exc:
            msg = str(exc).splitlines()[0][:160]
            skipped.append({"name": name, "group": group, "reason": msg})
            log(f"    {name}: skipped ({msg})")
            return None
        bad = int((~torch.isfinite(volts.float())).sum()) + int((~torch.isfinite(img.float())).sum())
        if bad:
            skipped.append({"name": name, "group": group, "reason": f"{bad} non-finite values in the volts/image"})
            log(f"    {name}: skipped ({bad} non-finite values)")
            return None
        if ref is None:
            ref = (volts, img)
        errs = {"volts_rel": volts_rel(volts, ref[0]), **render_errors(img, ref[1])}
        if not all(math.isfinite(v) for v in errs.values() if v is not None):
            skipped.append({"name": name, "group": group, "reason": f"non-finite result {errs}"})
            log(f"    {name}: skipped (non-finite)")
            return None
        if "shape" in last:
            note = f"{note}; OI {last.pop('shape')}"
        rows.append(_row(name, group, t, errs["volts_rel"], "volts (rel RMS)", errors=errs, reference=ref_flag,
                         note=note, runs=len(times)))
        log(f"    {name}: {t:.3f} s, volts rel {errs['volts_rel']:.2e}, dE {errs['de2000_mean']:.3g}")
        return ref

    def vi(raw_img):
        raw, img = raw_img
        return raw.data, img

    # wavelength step (the scene is generated on each grid; reference 1 nm)
    log("  knob: wavelength step")
    ref = None
    for step in (1.0, 5.0, 10.0, 20.0):
        sc, _, _ = setup(wavelengths(step))
        optics = make_optics().to(device)
        ref = measure(f"wavelength_step_{int(step)}nm", "wavelength_step", lambda o=optics, s=sc: vi(run(o, s)), ref,
                      step == 1.0, f"{sc.num_wavelengths} bands") or ref
        if step >= 10:
            # the same grid integrated with the trapezoid rule (half-width end bins, 400-700 nm) instead of
            # ISETCam's rectangle rule (full-width end bins: 395-705 nm on a 10 nm grid); emulated by halving the
            # end bands' radiance, which is exact for the sensor's linear QE integral
            half = torch.ones(sc.num_wavelengths, dtype=sc.dtype, device=sc.device)
            half[0] = half[-1] = 0.5
            sct = sc.replace(photons=sc.photons * half[None, :, None, None])
            measure(f"wavelength_step_{int(step)}nm_trapezoid", "wavelength_step",
                    lambda o=optics, s=sct: vi(run(o, s)), ref, False,
                    f"{sc.num_wavelengths} bands, trapezoid rule (emulated: end bands x 0.5)")
        del sc

    # OTF wavelength grouping (emulated: the library optics with the OTF of each group's centre wavelength)
    log("  knob: OTF grouping")
    optics = make_optics().to(device)
    ref = measure("otf_per_band_10nm", "otf_grouping", lambda: vi(run(optics, scene10)), None, True,
                  "31 OTFs, 31 FFT planes")
    for ng in (8, 4, 2, 1):
        gopt = _GroupedOTFOptics.make(ng).to(device)
        spans = ", ".join(f"{int(scene10.wavelengths_nm[i[0]])}-{int(scene10.wavelengths_nm[i[-1]])}"
                          for i in wavelength_groups(scene10.num_wavelengths, ng))
        measure(f"otf_groups_{ng}_emulated", "otf_grouping", lambda o=gopt: vi(run(o, scene10)), ref, False,
                f"{ng} OTFs ({spans} nm) applied per band (31 FFT planes): the error of grouping, no speed-up")


    # padding width (reference: psf_tolerance 1e-5)
    log("  knob: padding")
    ref = None
    for label, kw in (("pad_tol_1e-5", {"psf_tolerance": 1e-5}), ("pad_tol_1e-3_default", {}),
                      ("pad_tol_1e-2", {"psf_tolerance": 1e-2}), ("pad_margin_4px", {"margin": 4}),
                      ("pad_margin_0px", {"margin": 0}), ("pad_isetcam", {"pad_mode": "isetcam"})):
        optics = make_optics(**kw).to(device)
        note = str(kw or "default")
        if label == "pad_isetcam":
            note += " (round(size/8) pad; also ISETCam's grid, abs() and cos4th conventions)"
        with warnings.catch_warnings():
            if label == "pad_tol_1e-5":  # the reference: its margin warning is this note, not a stray line on stderr
                note += (" (the margin is capped at max_margin_factor 2 x the scene's side: the diffraction PSF's "
                         "1e-5 tail reaches further, and that light wraps)")
                warnings.filterwarnings("ignore", message="optics: the PSF reaches")
            ref = measure(label, "padding", lambda o=optics: vi(run(o, scene10)), ref, ref is None, note) or ref

    # spatial sampling: pixels 4x the OI sample pitch (reference: area integration over the photodiode)
    log("  knob: sampling")
    optics = make_optics(psf_tolerance=1e-2).to(device)  # padding is not this knob; keep the OI small
    ref = None
    sub = 4
    sc_fine = scene10.replace(hfov_deg=torch.full_like(scene10.hfov_deg, hfov_for(wd // sub)))
    for label, kw in (("area", {"sampling": "area"}), ("isetcam", {"sampling": "isetcam"}),
                      ("point", {"sampling": "isetcam", "preblur_size": 1})):
        sens = make_sensor(h // sub, wd // sub, **kw).to(device)
        note = {"area": "photodiode area integral (exact for the OI's piecewise-constant samples)",
                "isetcam": "ISETCam: Gaussian pre-blur (k = 4) + bilinear point sampling at pixel centres",
                "point": "bilinear point sampling at pixel centres, no pre-blur"}[label]
        ref = measure(f"sampling_{label}", "sampling", lambda s=sens: vi(run(optics, sc_fine, s)), ref,
                      label == "area", f"{note}; {sub}x{sub} OI samples per pixel; optics psf_tolerance 1e-2") or ref

    # dtype (reference float64)
    log("  knob: dtype")
    ref = None
    for dt in (torch.float64, torch.float32, torch.bfloat16, torch.float16):
        sc = scene10.to(dtype=dt)
        optics = make_optics().to(device)
        name = f"dtype_{str(dt).replace('torch.', '')}"
        ref = measure(name, "dtype", lambda o=optics, s=sc: vi(run(o, s)), ref, dt == torch.float64,
                      "scene, optics, sensor and ISP in this dtype") or ref
    # half precisions after a float32 optics stage (CPU FFTs have no half-precision kernels)
    optics = make_optics().to(device)
    sc32 = scene10.to(dtype=torch.float32)
    for dt in (torch.bfloat16, torch.float16):
        def mixed(dt=dt):
            with torch.no_grad():
                oi = optics(sc32).to(dtype=dt)
                raw = sensor(oi, exposure_s=t_exp, noise=False)
                return raw.data, isp(raw).image
        name = f"dtype_{str(dt).replace('torch.', '')}_sensor_isp"
        # (the sensor refuses half precisions, naming the argument: the skip says so; the reason appended here,
        # float16's overflow, was the pre-2026-11-30 one)
        measure(name, "dtype", mixed, ref, False, "optics in float32, then OI, sensor and ISP in this dtype")

    # shot-noise mode: error = relative difference of the noise std (pooled over frames) against exact Poisson;
    # at normal exposure (~3000 e- at the brightest pixel) and at 1/1000 of it (a few electrons)
    log("  knob: shot noise")
    optics = make_optics().to(device)
    frames = 4
    with torch.no_grad():
        oi = optics(scene10)
    for group, scale in (("shot_noise", 1.0), ("shot_noise_low_light", 1e-3)):
        t_e = t_exp * scale
        with torch.no_grad():
            clean = sensor(oi, exposure_s=t_e, noise=False).data.double()
        std_ref = None
        for mode in ("poisson", "gaussian", "off"):
            sens = make_sensor(h, wd, noise=True, shot_noise=mode, read_noise_v=0.0,
                               dark_current_e_per_s=0.0).to(device)
            with torch.no_grad():
                t, _, _ = time_call(lambda s=sens, t_e=t_e: s(oi, exposure_s=t_e, noise=True), repeats, 1, device)
                g = torch.Generator(device=device).manual_seed(1)
                resid = torch.cat([sens(oi, exposure_s=t_e, noise=True, generator=g).data.double() - clean
                                   for _ in range(frames)])
            std = float(resid.std())
            bias = float(resid.mean() / clean.mean())
            std_ref = std if std_ref is None else std_ref
            err = abs(std / std_ref - 1)
            rows.append(_row(f"{group}_{mode}", group, t, err, "noise std (rel)", reference=mode == "poisson",
                             note=f"sensor stage only; exposure x {scale:g}; noise std {std:.3e} V over {frames} "
                                  f"frames; mean bias {bias:+.2e} (rel)"))
            log(f"    {group}_{mode}: {t:.3f} s, std err {err:.2e}, bias {bias:+.1e}")
    return rows, skipped


# --------------------------------------------------------------------------------------------------------------
# 4. model only what the scene needs


def proportional_rows(n: int, repeats: int, device, log=print) -> list[dict]:
    """3 bands vs 31, a small sensor on a large OI (crop before blur), zero-noise settings."""
    rows = []
    log(f"  proportional cost ({n}x{n})")
    optics = make_optics().to(device)
    sensor = make_sensor(n, n).to(device)
    w31, w3 = wavelengths(10.0), torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)
    times, parts = {}, {}
    for label, w in (("31", w31), ("3", w3)):
        sc = sweep_scene(n, w, torch.float32, device)
        with torch.no_grad():
            times[label], _, _ = time_call(lambda s=sc: sensor(optics(s), noise=False), repeats, 1, device)
            t_o, oi, _ = time_call(lambda s=sc: optics(s), repeats, 1, device)
            t_s, _, _ = time_call(lambda o=oi: sensor(o, noise=False), repeats, 1, device)
        parts[label] = (t_o, t_s)
    rows.append(_row(f"bands_31_{n}x{n}", "proportional", times["31"], None, None, ratio=1.0,
                     note=f"optics + sensor, 31-band scene (optics {parts['31'][0]:.3f} s, sensor "
                          f"{parts['31'][1]:.3f} s)"))
    rows.append(_row(f"bands_3_{n}x{n}", "proportional", times["3"], None, None, ratio=times["3"] / times["31"],
                     note=f"optics + sensor, 3-band scene (ideal ratio 3/31 = 0.097); optics alone "
                          f"{parts['3'][0] / parts['31'][0]:.3f}, sensor alone {parts['3'][1] / parts['31'][1]:.3f} "
                          f"of the 31-band times"))

    # small sensor (n/8 px) at the centre of a large optical image: crop before blur vs blur everything
    sc = sweep_scene(n, w31, torch.float32, device)
    small = max(16, n // 8) // 2 * 2
    sens_small = make_sensor(small, small).to(device)
    with torch.no_grad():
        full_oi = optics(sc)
    ph, pw = full_oi.photons.shape[-2:]
    dx_ratio = PITCH_M / float(full_oi.sample_spacing_m[0])
    win = int(math.ceil(small * dx_ratio)) + 4
    win += (ph - win) % 2  # keep the window centred on the axis
    top, left = (ph - win) // 2, (pw - win) // 2
    with torch.no_grad():
        t_full, raw_full, _ = time_call(lambda: sens_small(optics(sc), noise=False), repeats, 1, device)
        t_crop, raw_crop, _ = time_call(lambda: sens_small(optics(sc, crop=(top, left, win, win)), noise=False),
                                        repeats, 1, device)
    err = volts_rel(raw_crop.data, raw_full.data)
    area = (win * win) / (ph * pw)
    rows.append(_row(f"crop_off_{small}px_sensor_on_{n}x{n}", "proportional", t_full, 0.0, "volts (rel RMS)",
                     ratio=1.0, reference=True, note="blur the whole padded OI, then sample the small sensor"))
    rows.append(_row(f"crop_on_{small}px_sensor_on_{n}x{n}", "proportional", t_crop, err, "volts (rel RMS)",
                     ratio=t_crop / t_full, note=f"optics(crop=window {win}x{win}); window/OI area {area:.3f}"))

    # zero-noise settings: every noise stage skipped vs all of them on
    with torch.no_grad():
        oi = optics(sc)
    noisy = make_sensor(n, n, noise=True, shot_noise="poisson", read_noise_v=1e-3, dark_current_e_per_s=10.0,
                        dsnu_sigma_v=1e-3, prnu_sigma_percent=0.5, column_fpn_sigma_v=1e-4).to(device)
    quiet = make_sensor(n, n, noise=True, shot_noise="off").to(device)
    with torch.no_grad():
        t_noisy, _, _ = time_call(lambda: noisy(oi, noise=True), repeats, 1, device)
        t_quiet, _, _ = time_call(lambda: quiet(oi, noise=True), repeats, 1, device)
    rows.append(_row(f"noise_all_on_{n}x{n}", "proportional", t_noisy, None, None, ratio=1.0,
                     note="sensor stage: Poisson shot, read, dark, DSNU, PRNU, column FPN"))
    rows.append(_row(f"noise_all_zero_{n}x{n}", "proportional", t_quiet, None, None, ratio=t_quiet / t_noisy,
                     note="sensor stage with every noise parameter 0 (stages skipped)"))
    return rows


# --------------------------------------------------------------------------------------------------------------
# 5. peers


def load_numpy_reference():
    path = REPO / "benchmarks" / "numpy_reference.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("isettorch_numpy_reference", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def numpy_reference_rows(sizes, repeats: int, log=print) -> tuple[list[dict], list[dict]]:
    """The NumPy reference against isettorch (float64, CPU) on the same optics + sensor work."""
    ref = load_numpy_reference()
    if ref is None:
        return [], [{"name": "numpy_reference", "group": "peer_pipeline", "reason": "benchmarks/numpy_reference.py "
                     "not found (not a source checkout)"}]
    rows = []
    for n in sizes:
        log(f"  numpy reference {n}x{n}x31")
        sc = sweep_scene(n, wavelengths(10.0), torch.float64, "cpu")
        optics = make_optics()
        sensor = make_sensor(n, n)
        with torch.no_grad():
            t_i, raw, _ = time_call(lambda s=sc, o=optics, se=sensor: se(o(s), noise=False), repeats, 1, "cpu")
            oi = optics(sc)
        qe = sensor.qe(oi).numpy()
        cell = sensor.cfa.index_map.numpy()
        kw = dict(hfov_deg=float(sc.hfov_deg[0]), distance_m=DISTANCE_M, f_number=4.0, focal_length_m=FOCAL_M,
                  pad=(oi.pad_rows, oi.pad_cols), qe=qe, cfa_index=cell, rows=n, cols=n, pixel_size_m=PITCH_M,
                  fill_factor=sensor.fill_factor, exposure_s=0.01,
                  conversion_gain_v_per_e=sensor.conversion_gain_v_per_e,
                  voltage_swing_v=sensor.voltage_swing_v)
        photons = sc.photons[0].numpy()
        w = sc.wavelengths_nm.numpy()
        t_n, v_np, _ = time_call(lambda p=photons, w=w, kw=kw: ref.simulate(p, w, **kw), max(1, repeats - 1), 1, "cpu")
        err = volts_rel(raw.data[0, 0], torch.from_numpy(v_np))
        tag = f"{n}x{n}x31"
        rows.append(_row(f"isettorch_optics_sensor_{tag}", "peer_pipeline", t_i, 0.0, "volts (rel RMS)",
                         reference=True, note="float64, noise off, area sampling"))
        rows.append(_row(f"numpy_reference_{tag}", "peer_pipeline", t_n, err, "volts (rel RMS)",
                         ratio=t_n / t_i, note="benchmarks/numpy_reference.py, float64, same padding"))
    return rows, []


def demosaic_rows(n: int, repeats: int, device, log=print) -> tuple[list[dict], list[dict]]:
    """Demosaic: isettorch methods vs colour-demosaicing and kornia on a generated image (dead leaves with
    Macbeth reflectances, its ideal sRGB preview): median time and CPSNR (dB) against the full-colour truth."""
    import numpy as np

    from isettorch.isp import demosaic, mosaic
    from isettorch.metrics import cpsnr
    from isettorch.scene import dead_leaves

    log(f"  demosaic peers {n}x{n}")
    truth = dead_leaves(n, reflectances="macbeth", seed=0, dtype=torch.float32).srgb().clamp(0, 1)
    truth = truth.to(device)
    raw = mosaic(truth, "RGGB")
    rows, skipped = [], []
    unit = "CPSNR dB vs truth (higher is better)"

    def add(name, fn, out_to_tensor, note):
        try:
            t, out, _ = time_call(fn, repeats, 1, device)
        except Exception as exc:  # noqa: BLE001 - a peer that fails is reported, not fatal
            skipped.append({"name": name, "group": "peer_demosaic", "reason": repr(exc)[:160]})
            return
        score = float(cpsnr(out_to_tensor(out).clamp(0, 1).double().cpu(), truth.double().cpu(), crop=10))
        rows.append(_row(name, "peer_demosaic", t, score, unit, note=note))
        log(f"    {name}: {t * 1e3:.1f} ms, {score:.2f} dB")

    for m in ("bilinear", "malvar2004", "menon2007"):
        add(f"demosaic_isettorch_{m}_{n}", lambda m=m: demosaic(raw, "RGGB", m), lambda x: x,
            f"isettorch.isp.demosaic, float32, {device}")
    try:
        import colour_demosaicing as cd

        raw_np = raw[0, 0].double().cpu().numpy()
        for m, fn in (("bilinear", cd.demosaicing_CFA_Bayer_bilinear),
                      ("malvar2004", cd.demosaicing_CFA_Bayer_Malvar2004),
                      ("menon2007", cd.demosaicing_CFA_Bayer_Menon2007)):
            add(f"demosaic_colour_{m}_{n}", lambda fn=fn: fn(raw_np, "RGGB"),
                lambda x: torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1)[None],
                "colour-demosaicing (NumPy, float64, CPU)")
    except ImportError:
        skipped.append({"name": "demosaic_colour", "group": "peer_demosaic", "reason": "colour-demosaicing missing"})
    try:
        import kornia

        add(f"demosaic_kornia_bilinear_{n}", lambda: kornia.color.raw_to_rgb(raw, kornia.color.CFA.BG),
            lambda x: x, f"kornia.color.raw_to_rgb (CFA.BG = RGGB cell), float32, {device}")
    except ImportError:
        skipped.append({"name": "demosaic_kornia", "group": "peer_demosaic", "reason": "kornia missing"})
    return rows, skipped


def pairs_per_second(n_items: int, log=print) -> tuple[float | None, str]:
    """Training-pair throughput of ``isettorch.data`` CameraPairDataset at 128 x 128 (one process)."""
    try:
        from isettorch.data.camera_pairs import CameraPairDataset
    except ImportError as exc:
        return None, f"CameraPairDataset unavailable ({exc})"
    rounds = 3
    log(f"  CameraPairDataset 128x128, {rounds} rounds of {n_items} items")
    ds = CameraPairDataset(rounds * n_items + 1, seed=0, scene={"height": 128, "width": 128})
    ds[0]  # warm-up (caches)
    index = iter(range(1, rounds * n_items + 1))  # every round renders new items

    def one_round():
        for _ in range(n_items):
            ds[next(index)]

    dt, _, _ = time_call(one_round, repeats=rounds, warmup=0, min_time_s=0.0, max_repeats=rounds)
    return n_items / dt, (f"CameraPairDataset(128x128, 31 bands), single process, median of {rounds} rounds of "
                          f"{n_items} items after 1 warm-up item")


# --------------------------------------------------------------------------------------------------------------
# driver, table and plot


SECTION_NAMES = ("pipeline", "isetcam", "knobs", "proportional", "numpy_reference", "demosaic", "pairs")


def run_benchmarks(*, quick: bool = False, device="cpu", sizes=None, stable_size: int | None = None,
                   knob_patch: int | None = None, repeats: int | None = None, peers: bool = True,
                   pairs: bool = True, min_time_s: float | None = None, only=None,
                   log: Callable[[str], None] | None = None) -> dict:
    """Run the standard set; returns ``{"rows": [...], "skipped": [...], "pairs_per_s", "pairs_note",
    "machine", "settings", "seconds_total"}``.

    ``quick`` skips 1024^2 and uses fewer repeats and smaller knob scenes. ``sizes`` (pipeline sizes),
    ``stable_size`` (the ISETCam-comparison rows), ``knob_patch`` (Macbeth patch size of the knob scene),
    ``repeats`` and ``min_time_s`` (short calls repeat until they have run this long; 0.5 s, 0 in quick mode)
    override the defaults. ``only``: run just these sections of ``SECTION_NAMES`` (e.g. ``{"isetcam",
    "numpy_reference"}`` for the ISETCam-comparison and NumPy-reference rows).
    """
    only = set(SECTION_NAMES) if only is None else set(only)
    unknown = only - set(SECTION_NAMES)
    if unknown:
        raise ValueError(f"only: unknown sections {sorted(unknown)}; expected some of {list(SECTION_NAMES)}")
    log = log or (lambda s: None)
    device = torch.device(device)
    t_start = time.perf_counter()
    sizes = list(sizes or ((128, 512) if quick else (128, 512, 1024)))
    stable_size = stable_size or 512
    knob_patch = knob_patch or (8 if quick else 16)
    repeats = repeats or (2 if quick else 5)
    _TIMING["min_time_s"] = (0.0 if quick else 0.5) if min_time_s is None else float(min_time_s)
    info = machine_info(device)
    rows, skipped = [], []
    if "pipeline" in only:
        log("pipeline stages")
        rows += pipeline_rows(sizes, repeats, device, log=log)
    if "isetcam" in only:
        rows += stable_rows(stable_size, max(2, repeats - 2), device, log=log)
    if "knobs" in only:
        log("knobs")
        r, s = knob_rows(knob_patch, max(1, repeats - 2), device, log=log)
        rows += r
        skipped += s
    if "proportional" in only:
        log("model only what the scene needs")
        rows += proportional_rows(min(512, max(sizes)), max(1, repeats - 2), device, log=log)
    if peers and "numpy_reference" in only:
        log("peers")
        r, s = numpy_reference_rows([min(sizes), min(512, max(sizes))] if not quick else [min(sizes)],
                                    max(1, repeats - 2), log=log)
        rows += r
        skipped += s
    if peers and "demosaic" in only:
        r, s = demosaic_rows(min(512, max(sizes)), max(1, repeats - 2), device, log=log)
        rows += r
        skipped += s
    pps, note = (None, "skipped (pairs=False)")
    if pairs and "pairs" in only:
        pps, note = pairs_per_second(2 if quick else 6, log=log)
    if hasattr(os, "getloadavg"):
        info["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    return {"rows": rows, "skipped": skipped, "pairs_per_s": pps, "pairs_note": note, "machine": info,
            "settings": {"only": sorted(only), "quick": quick, "sizes": sizes, "stable_size": stable_size,
                         "knob_patch": knob_patch, "repeats": repeats, "min_time_s": _TIMING["min_time_s"],
                         "device": str(device)},
            "seconds_total": time.perf_counter() - t_start}


def _fmt(x, spec=".3g") -> str:
    if x is None:
        return "-"
    return format(x, spec)


def format_table(result: dict) -> str:
    """A Markdown table of every row (time, error, unit, ratio, note)."""
    lines = ["| name | group | median s | error | unit | dE2000 | CPSNR dB | ratio | note |",
             "|---|---|---:|---:|---|---:|---:|---:|---|"]
    for r in result["rows"]:
        e = r.get("errors") or {}
        lines.append(f"| {r['name']}{' (ref)' if r.get('reference') else ''} | {r['group']} | "
                     f"{_fmt(r['seconds_median'], '.4f')} | {_fmt(r['error'], '.3g')} | {r['error_unit'] or '-'} | "
                     f"{_fmt(e.get('de2000_mean'), '.3g')} | {_fmt(e.get('cpsnr_db'), '.1f')} | "
                     f"{_fmt(r.get('ratio'), '.3f')} | {r.get('note', '')} |")
    pps = result.get("pairs_per_s")
    lines.append("")
    lines.append(f"training pairs/s: {_fmt(pps, '.2f')} ({result.get('pairs_note', '')})")
    for s in result.get("skipped", []):
        lines.append(f"skipped: {s['name']} ({s['reason']})")
    return "\n".join(lines)


SECTIONS = (
    ("End-to-end stage timings (frequency sweep, 31 bands, float32)", ("pipeline",)),
    ("Rows to compare with ISETCam doing the same work", ("isetcam_compare",)),
    ("Knobs: speed against error (Macbeth + sweep scene, noise off, fixed exposure)",
     ("wavelength_step", "otf_grouping", "padding", "sampling", "dtype")),
    ("Shot-noise mode (error: relative difference of the noise std against exact Poisson)",
     ("shot_noise", "shot_noise_low_light")),
    ("Model only what the scene needs (ratio = time / time of the full-work row)", ("proportional",)),
    ("Peer: NumPy reference pipeline (same physics, float64)", ("peer_pipeline",)),
    ("Peers: demosaic on a generated image (dead leaves, Macbeth reflectances, 10 px border excluded)",
     ("peer_demosaic",)),
)


def format_report(result: dict) -> str:
    """The rows as one Markdown table per section (what RESULTS.md shows)."""
    out = []
    m = result.get("machine", {})
    out.append(f"Machine: {m.get('processor')}, {m.get('cpu_count')} CPUs, {m.get('torch_threads')} torch threads, "
               f"torch {m.get('torch')}, device {m.get('device')}; load average {m.get('load_average_start')} at "
               f"start, {m.get('load_average_end')} at the end; total {result.get('seconds_total', 0):.0f} s.")
    for title, groups in SECTIONS:
        rows = [r for r in result["rows"] if r["group"] in groups]
        if not rows:
            continue
        out += ["", f"### {title}", ""]
        knob = any("errors" in r for r in rows)
        if knob:
            out += ["| row | median s | min s | volts err (rel RMS) | mean dE2000 | CPSNR dB | note |",
                    "|---|---:|---:|---:|---:|---:|---|"]
        else:
            out += ["| row | median s | min s | error | unit | ratio | note |", "|---|---:|---:|---:|---|---:|---|"]
        for r in rows:
            name = f"{r['name']}{' (ref)' if r.get('reference') else ''}"
            if knob:
                e = r.get("errors") or {}
                out.append(f"| {name} | {_fmt(r['seconds_median'], '.3f')} | {_fmt(r.get('seconds_min'), '.3f')} | "
                           f"{_fmt(r['error'], '.2e')} | "
                           f"{_fmt(e.get('de2000_mean'), '.3g')} | {_fmt(e.get('cpsnr_db'), '.1f')} | "
                           f"{r.get('note', '')} |")
            else:
                out.append(f"| {name} | {_fmt(r['seconds_median'], '.3f')} | {_fmt(r.get('seconds_min'), '.3f')} | "
                           f"{_fmt(r['error'], '.3g')} | "
                           f"{r['error_unit'] or '-'} | {_fmt(r.get('ratio'), '.3f')} | {r.get('note', '')} |")
    out += ["", f"Training pairs/s: {_fmt(result.get('pairs_per_s'), '.2f')} ({result.get('pairs_note', '')})"]
    for s in result.get("skipped", []):
        out.append(f"- skipped {s['name']}: {s['reason']}")
    return "\n".join(out)


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated in (time, error), both to be minimised, sorted by time."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def plot_pareto(result: dict, path) -> Path:
    """Time vs sensor-volts error of the knob rows (log-log), one colour per knob with its own Pareto front
    (each knob is measured against its own most accurate setting, drawn on the "0 (ref)" line). Returns the
    path of the PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    knob_groups = ("wavelength_step", "otf_grouping", "padding", "sampling", "dtype")
    rows = [r for r in result["rows"] if r["group"] in knob_groups and r["error"] is not None]
    floor = 1e-9
    fig, ax = plt.subplots(figsize=(9, 6))
    markers = dict(zip(knob_groups, "osD^v"))
    colours = dict(zip(knob_groups, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for g in knob_groups:
        sel = [r for r in rows if r["group"] == g]
        if not sel:
            continue
        pts = [(r["seconds_median"], max(r["error"], floor)) for r in sel]
        ax.scatter(*zip(*pts), label=g, marker=markers[g], s=42, color=colours[g], zorder=3)
        front = pareto_front(pts)
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], "--", lw=1, color=colours[g], zorder=2)
        for r, p in zip(sel, pts):
            label = r["name"].removeprefix(g + "_").removeprefix("wavelength_step_").removeprefix("otf_")
            ax.annotate(label, p, fontsize=6.5, xytext=(4, 3), textcoords="offset points", color=colours[g])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(floor / 3, 1)
    ticks = [floor] + [10.0**k for k in range(-8, 1, 2)]
    ax.set_yticks(ticks, ["0 (ref)"] + [f"1e{k}" for k in range(-8, 1, 2)])
    ax.axhline(floor * 1.8, color="0.7", lw=0.8)
    ax.set_xlabel("median time, optics + sensor + ISP (s)")
    ax.set_ylabel("sensor volts error vs the knob's most accurate setting (relative RMS)")
    m = result.get("machine", {})
    ax.set_title(f"isettorch speed against error (dashed: Pareto front per knob; {m.get('cpu_count')} CPUs, "
                 f"{m.get('device')})", fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------------------------
# command line (``isettorch bench`` runs this file as a script with the same arguments)


def _sizes(text: str) -> list[int]:
    try:
        out = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--sizes: expected comma-separated integers such as 128,512, got {text!r}") from None
    if not out or any(not MIN_SIZE <= n <= MAX_SIZE for n in out):
        raise ValueError(f"--sizes: expected sizes from {MIN_SIZE} to {MAX_SIZE}, got {text!r}")
    return out


#: --sizes bounds: below 16 px there is no image to time; above 4096 px the 31-band pipeline's cubes (31 x 4096^2
#: float32 = 2 GB each, several alive at once) exhaust a workstation's memory
MIN_SIZE, MAX_SIZE = 16, 4096


def add_arguments(p) -> None:
    """The options of ``isettorch bench`` (shared by the CLI's parser and this script's)."""
    from isettorch._progress import add_quiet_argument

    p.add_argument("--json", action="store_true", help="print every row as JSON instead of a table")
    add_quiet_argument(p)
    p.add_argument("--quick", action="store_true", help="fewer repeats, no 1024^2, smaller knob scene")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1, ...; default cpu)")
    p.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's choice)")
    p.add_argument("--sizes", default=None, help="pipeline sizes, e.g. 128,512,1024 (default per --quick)")
    p.add_argument("--stable-size", type=int, default=None, help="size of the optics_/sensor_ rows (default 512)")
    p.add_argument("--knob-patch", type=int, default=None,
                   help="Macbeth patch size of the knob scene, in pixels (default 16, 8 with --quick)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats per measurement (default 5, quick 2)")
    p.add_argument("--no-peers", action="store_true", help="skip the NumPy, colour-demosaicing and kornia peers")
    p.add_argument("--no-pairs", action="store_true", help="skip the CameraPairDataset throughput")
    p.add_argument("--plot", default=None, help="write the time-vs-error PNG here")
    p.add_argument("--only", default=None, help=f"comma-separated sections to run, of {','.join(SECTION_NAMES)} "
                                                "(default all)")


def check_arguments(args) -> str | None:
    """The first problem with the options, as an error line naming the option, or None."""
    for name in ("sizes", "only", "plot"):  # an empty value was read as the option not given (all sections ran)
        value = getattr(args, name, None)
        if value is not None and not str(value).strip():
            return f"--{name}: expected a value, got {value!r}"
    try:
        if args.sizes:
            _sizes(args.sizes)
    except ValueError as exc:
        return str(exc)
    if args.only and not set(args.only.split(",")) <= set(SECTION_NAMES):
        return f"--only: expected sections from {','.join(SECTION_NAMES)}, got {args.only!r}"
    from isettorch._checks import check_device
    from isettorch.cli import max_threads

    if args.threads is not None and not 1 <= args.threads <= max_threads():
        return f"--threads: expected a positive integer up to {max_threads()} (4 per core, at least 64), got " \
               f"{args.threads}"
    if args.repeats is not None and args.repeats < 1:
        return f"--repeats: expected a positive number of timed repeats, got {args.repeats}"
    # the --sizes bounds for the stable rows' image, the knob scene's 6 x 4 patches within them (1 px made an empty
    # image, 10^8 px a failed allocation: tracebacks)
    for name, value, lo, hi in (("--stable-size", args.stable_size, MIN_SIZE, MAX_SIZE),
                                ("--knob-patch", args.knob_patch, 1, MAX_SIZE // 6)):
        if value is not None and not lo <= value <= hi:
            return f"{name}: expected an integer in {lo}..{hi}, got {value}"
    try:
        check_device(args.device)
    except ValueError as exc:
        return f"--{exc}"  # "device: ..." -> "--device: ..."
    if args.plot:  # before the (long) run: a folder that exists and is writable, a .png name that is not a folder
        plot = Path(args.plot)
        if plot.is_dir():
            return f"--plot: expected a PNG file name, {args.plot} is a folder"
        parent = plot.parent
        if not parent.is_dir():
            return f"--plot: cannot write {args.plot}: no such folder {str(parent)!r}"
        if not os.access(parent, os.W_OK | os.X_OK) or (plot.exists() and not os.access(plot, os.W_OK)):
            return f"--plot: cannot write {args.plot}: no permission"
    return None


def main(argv=None) -> int:
    import json

    from isettorch.cli import OneLineParser  # argparse's errors as one line, as every isettorch command's

    ap = OneLineParser(prog="isettorch bench", description=__doc__.splitlines()[0])
    add_arguments(ap)
    args = ap.parse_args(argv)
    problem = check_arguments(args)
    if problem:
        print(f"isettorch bench: {problem}", file=sys.stderr)  # the CLI's one-line convention (isettorch.cli)
        return 2
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    from isettorch._progress import progress

    # one step per stage the benchmarks announce (stderr; --quiet: nothing, as every long isettorch job)
    n_stages = len(args.only.split(",")) if args.only else len(SECTION_NAMES)
    bar = progress(total=n_stages, desc="bench", unit="stage", quiet=args.quiet)

    def log(stage: str) -> None:
        bar.set_postfix_str(stage)
        bar.update(1)

    result = run_benchmarks(quick=args.quick, device=torch.device(args.device),
                            sizes=_sizes(args.sizes) if args.sizes else None, stable_size=args.stable_size,
                            knob_patch=args.knob_patch, repeats=args.repeats, peers=not args.no_peers,
                            pairs=not args.no_pairs, only=args.only.split(",") if args.only else None, log=log)
    bar.close()
    if args.plot:
        result["plot"] = str(plot_pareto(result, args.plot))
    if args.json:
        print(json.dumps(result, indent=1, allow_nan=False))
    else:
        print(format_report(result))
        m = result["machine"]
        print(f"\ntotal {result['seconds_total']:.1f} s on {m['processor']} ({m['cpu_count']} CPUs, "
              f"{m['torch_threads']} torch threads)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
