"""``isettorch parity CASE.npz [...]``: check optics and sensor against ISETCam reference cases.

Each case (``isetcam-parity/FORMAT.md``) is run with its own parameters and ISETCam's conventions
(fixed exposure, noise off, Gaussian pre-blur + point sampling, analog gain divides, N-bit ADC without
clamp), and every stage is compared with the case's arrays:

=========================  ==================================================================  ===========
stage                      compared quantity                                                    tolerance
=========================  ==================================================================  ===========
``oi_photons``             our ISETCam-compatible OI vs ``oi_photons`` (relative, pixels above  1e-4
                           1 % of the max)
``mean_illuminance``       mean illuminance of our OI vs ``oi_mean_illuminance_lux`` (relative)  2e-3
``sensor_current``         pixel current (A) from the case OI vs ``sensor_signal_current_a``    1e-4 rel.
``sensor_volts``           volts from the **case** OI vs ``sensor_volts`` (absolute V)          1e-5 V
``sensor_dv``              DN from the case OI vs ``sensor_dv``: exact at >= 99.9 % of pixels,  1 DN
                           within 1 elsewhere
``*_from_our_oi``          the same sensor stages run on our OI (informational: not in verdict)
=========================  ==================================================================  ===========

``mean_rel_err`` is the mean of ``|ours - ref| / |ref|`` over reference values above 1 % of the max;
``max_err`` is the stage's tolerance quantity (max relative error for OI/current/illuminance, max
absolute volts, max absolute DN). Stages without data in a case are reported as skipped.
Exit code 0 when every checked stage is within tolerance, 1 otherwise, 2 when a case cannot be read.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

TOL = {"oi_photons": 1e-4, "mean_illuminance": 2e-3, "sensor_current": 1e-4, "sensor_volts": 1e-5,
       "sensor_dv": 1.0}
DV_EXACT_FRACTION = 0.999


def register(sub) -> None:
    p = sub.add_parser("parity", help="check optics and sensor stages against ISETCam parity cases (.npz)")
    p.add_argument("cases", nargs="+", help="parity case files (isetcam-parity/FORMAT.md)")
    p.add_argument("--json", action="store_true", help="print a JSON report instead of a table")
    p.add_argument("--repeat", type=int, default=0, metavar="N",
                   help="time each stage N times after a warm-up and report the median seconds")
    p.set_defaults(func=run)


# --- comparisons ---------------------------------------------------------------------------------


def _paired(ours, ref):
    """(ours, ref) as float64 arrays, and the failure record when their shapes differ (else None)."""
    import numpy as np

    ours, ref = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    if ours.shape != ref.shape:
        return ours, ref, {"ok": False, "error": f"shape {ours.shape} != reference {ref.shape}",
                           "mean_rel_err": None, "max_err": None}
    return ours, ref, None


def _rel_stats(ours, ref, tol):
    import numpy as np

    ours, ref, failed = _paired(ours, ref)
    if failed:
        return failed
    mask = np.abs(ref) > 0.01 * np.abs(ref).max() if np.abs(ref).max() > 0 else np.ones(ref.shape, bool)
    rel = np.abs(ours - ref)[mask] / np.abs(ref)[mask] if np.abs(ref).max() > 0 else np.abs(ours - ref)[mask]
    mx = float(rel.max()) if rel.size else 0.0
    return {"mean_rel_err": float(rel.mean()) if rel.size else 0.0, "max_err": mx, "tolerance": tol,
            "ok": bool(mx <= tol)}


def _abs_stats(ours, ref, tol):
    import numpy as np

    ours, ref, failed = _paired(ours, ref)
    if failed:
        return failed
    err = np.abs(ours - ref)
    big = np.abs(ref) > 0.01 * np.abs(ref).max() if np.abs(ref).max() > 0 else np.zeros(ref.shape, bool)
    mean_rel = float((err[big] / np.abs(ref[big])).mean()) if big.any() else 0.0
    return {"mean_rel_err": mean_rel, "max_err": float(err.max()), "mean_abs_err": float(err.mean()),
            "tolerance": tol, "ok": bool(err.max() <= tol)}


def _dv_stats(ours, ref):
    import numpy as np

    out = _abs_stats(ours, ref, TOL["sensor_dv"])
    if "error" in out:
        return out
    exact = float((np.asarray(ours, np.float64) == np.asarray(ref, np.float64)).mean())
    out["exact_fraction"] = exact
    out["ok"] = bool(out["max_err"] <= 1.0 and exact >= DV_EXACT_FRACTION)
    return out


def _median_seconds(fn, repeat: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run_case(path: str | Path, repeat: int = 0) -> dict:
    """Run one case; returns ``{"name", "path", "stages": {stage: {...}}, "ok"}``."""
    import numpy as np
    import torch

    from .. import constants, spectral
    from ..io.isetcam import SCENE_KEYS, case_optical_image, case_scene_oi, case_sensor, read_parity_case
    from ..optics.isetcam import mean_illuminance

    case = read_parity_case(path)
    name = str(case.get("case_name", Path(path).stem))
    stages: dict[str, dict] = {}
    notes: list[str] = []
    w = torch.as_tensor(case["wavelengths_nm"], dtype=torch.float64).reshape(-1)
    vl = torch.as_tensor(case["vlambda"], dtype=torch.float64).reshape(-1) if "vlambda" in case else \
        spectral.luminosity(w, dtype=torch.float64)

    # Optics stage
    our_oi = None
    missing = [key for key in SCENE_KEYS if key not in case]
    if missing:
        stages["oi_photons"] = {"skipped": f"case lacks {', '.join(missing)}", "ok": None}
    else:
        our_oi = case_scene_oi(case)
        stages["oi_photons"] = _rel_stats(our_oi.photons[0].numpy(), case["oi_photons"], TOL["oi_photons"])
        if repeat > 0:
            stages["oi_photons"]["seconds"] = _median_seconds(lambda: case_scene_oi(case), repeat)
        dx = float(our_oi.sample_spacing_m[0])
        ref_dx = float(case["oi_sample_spacing_m"])
        if abs(dx - ref_dx) > 1e-9 * ref_dx:
            notes.append(f"our OI sample spacing {dx:.10g} m differs from the case's {ref_dx:.10g} m")
    if "oi_mean_illuminance_lux" in case:
        src = our_oi.photons[0] if our_oi is not None else torch.as_tensor(case["oi_photons"], dtype=torch.float64)
        lux = float(mean_illuminance(src[None], w, vl)[0])
        ref = float(case["oi_mean_illuminance_lux"])
        rel = abs(lux - ref) / abs(ref) if ref else abs(lux)
        stages["mean_illuminance"] = {"mean_rel_err": rel, "max_err": rel, "tolerance": TOL["mean_illuminance"],
                                      "ok": bool(rel <= TOL["mean_illuminance"]), "value_lux": lux, "ref_lux": ref,
                                      "source": "our OI" if our_oi is not None else "case OI"}
    else:
        stages["mean_illuminance"] = {"skipped": "no oi_mean_illuminance_lux", "ok": None}

    # Sensor stage: ISETCam's pre-blur size from the case kernel when stored (FORMAT 4.6 step 2).
    from ..sensor.sampling import isetcam_preblur_kernel, isetcam_preblur_size

    k_ours = isetcam_preblur_size(float(case["sensor_pixel_size_m"]), float(case["oi_sample_spacing_m"]))
    k = k_ours
    if "sensor_regrid_kernel" in case:
        k = int(np.atleast_2d(case["sensor_regrid_kernel"]).shape[0])
        if k != k_ours:
            notes.append(f"pre-blur kernel: case has k={k}, ceil(pitch/dx) gives {k_ours}; using the case's")
        kern = np.atleast_2d(np.asarray(case["sensor_regrid_kernel"], np.float64))
        if kern.shape == (k, k) and np.abs(kern - isetcam_preblur_kernel(k).numpy()).max() > 1e-9:
            notes.append(f"pre-blur kernel values differ from fspecial('gaussian', {k}, {k}/4) by "
                         f"{np.abs(kern - isetcam_preblur_kernel(k).numpy()).max():.3g}")
    sensor = case_sensor(case, preblur_size=k)
    for label, oi in (("", case_optical_image(case)), ("_from_our_oi", our_oi)):
        if oi is None:
            for st in ("sensor_current", "sensor_volts", "sensor_dv"):
                stages[st + label] = {"skipped": "no OI of our own (optics unavailable)", "ok": None}
            continue
        with torch.no_grad():
            raw = sensor(oi, noise=False)
        volts = raw.data[0, 0]
        res = {}
        if "sensor_signal_current_a" in case:
            current = (sensor.electron_rate(oi) * constants.ISETCAM["q"])[0, 0]
            res["sensor_current"] = _rel_stats(current.numpy(), case["sensor_signal_current_a"],
                                               TOL["sensor_current"])
        else:
            res["sensor_current"] = {"skipped": "no sensor_signal_current_a", "ok": None}
        res["sensor_volts"] = _abs_stats(volts.numpy(), case["sensor_volts"], TOL["sensor_volts"])
        if repeat > 0 and not label:
            def _sensor_once(oi=oi):
                with torch.no_grad():
                    sensor(oi, noise=False)
            res["sensor_volts"]["seconds"] = _median_seconds(_sensor_once, repeat)
        if "sensor_dv" in case:
            if sensor.adc_bits is None:
                res["sensor_dv"] = {"ok": False, "error": "case has sensor_dv but quantization is analog",
                                    "mean_rel_err": None, "max_err": None}
            else:
                # ISETCam quantizes its single-precision volts (FORMAT 4.7)
                dn = sensor.volts_to_dn(volts.to(torch.float32).to(torch.float64))
                res["sensor_dv"] = _dv_stats(dn.numpy(), case["sensor_dv"])
        else:
            res["sensor_dv"] = {"skipped": "analog sensor (no sensor_dv)", "ok": None}
        for st, v in res.items():
            if label and "skipped" not in v:
                v["informational"] = True
            stages[st + label] = v
    if "noise_resid_std_v" in case:
        stages["noise_stats"] = noise_stats(case, sensor, case_optical_image(case))
    ok = all(v["ok"] for v in stages.values() if v.get("ok") is not None and not v.get("informational"))
    return {"name": name, "path": str(path), "stages": stages, "notes": notes, "ok": ok}


NOISE_STD_TOL = 0.03  # relative, per channel (statistics of different random streams)


def noise_stats(case: dict, sensor, oi) -> dict:
    """Informational: per-channel residual (noisy - noise-free volts) mean and std over ``noise_nruns`` frames
    with ISETCam's noise model (FORMAT 4.8, DSNU/PRNU redrawn per frame), against ``noise_resid_*``."""
    import numpy as np
    import torch

    cg = sensor.conversion_gain_v_per_e
    sensor.read_noise_v = float(case.get("sensor_read_noise_v", 0.0))
    sensor.dark_current_e_per_s = float(case.get("sensor_dark_voltage_v_per_s", 0.0)) / cg
    sensor.dsnu_sigma_v = float(case.get("sensor_dsnu_sigma_v", 0.0))
    sensor.prnu_sigma_percent = float(case.get("sensor_prnu_sigma_percent", 0.0))
    sensor.shot_noise = "poisson"  # noise model and per-frame DSNU/PRNU: ISETCAM_CONVENTIONS
    runs = int(case.get("noise_nruns", 20))
    g = torch.Generator().manual_seed(0)
    idx = sensor.cfa.channel_index(sensor.rows, sensor.cols).numpy()
    resid = []
    with torch.no_grad():
        for _ in range(runs):
            raw = sensor(oi, generator=g)
            resid.append((raw.data - raw.noise_free)[0, 0].numpy())
    resid = np.stack(resid)
    ref_std = np.atleast_1d(np.asarray(case["noise_resid_std_v"], np.float64))
    ref_mean = np.atleast_1d(np.asarray(case.get("noise_resid_mean_v", np.full_like(ref_std, np.nan)), np.float64))
    std = np.array([resid[:, idx == c].std(ddof=1) for c in range(sensor.cfa.num_channels)])
    mean = np.array([resid[:, idx == c].mean() for c in range(sensor.cfa.num_channels)])
    rel = np.abs(std - ref_std) / ref_std
    out = {"mean_rel_err": float(rel.mean()), "max_err": float(rel.max()), "tolerance": NOISE_STD_TOL,
           "ok": bool(rel.max() <= NOISE_STD_TOL), "informational": True, "resid_std_v": std.tolist(),
           "ref_resid_std_v": ref_std.tolist(), "resid_mean_v": mean.tolist(), "ref_resid_mean_v": ref_mean.tolist()}
    return out


def _fmt(x, spec=".3e"):
    return "-" if x is None else format(x, spec)


def _table(results: list[dict], out) -> None:
    print(f"{'case / stage':<42} {'mean_rel_err':>12} {'max_err':>10} {'tol':>8} {'seconds':>9}  verdict", file=out)
    for r in results:
        print(f"{r['name']}  ({r['path']})", file=out)
        if "error" in r:
            print(f"  ERROR: {r['error']}", file=out)
            continue
        for st, v in r["stages"].items():
            if "skipped" in v:
                print(f"  {st:<40} {'':>12} {'':>10} {'':>8} {'':>9}  skipped: {v['skipped']}", file=out)
                continue
            verdict = "ok" if v["ok"] else "FAIL"
            if v.get("informational"):
                verdict += " (info)"
            if "exact_fraction" in v:
                verdict += f"  exact {100 * v['exact_fraction']:.3f}%"
            if "error" in v:
                verdict += f"  {v['error']}"
            secs = _fmt(v.get("seconds"), ".4f")
            print(f"  {st:<40} {_fmt(v.get('mean_rel_err')):>12} {_fmt(v.get('max_err')):>10} "
                  f"{_fmt(v.get('tolerance'), '.0e'):>8} {secs:>9}  {verdict}", file=out)
        for n in r.get("notes", []):
            print(f"  note: {n}", file=out)
    ok = all(r.get("ok") for r in results)
    print(f"overall: {'ok' if ok else 'FAIL'}", file=out)


def run(args) -> int:
    if args.repeat < 0:
        raise ValueError(f"--repeat: expected a non-negative count, got {args.repeat}")
    results = []
    code = 0
    for path in args.cases:
        try:
            results.append(run_case(path, repeat=args.repeat))
        except (OSError, KeyError, ValueError, TypeError) as err:  # unreadable or malformed case: exit 2
            results.append({"name": Path(path).stem, "path": str(path), "error": f"{type(err).__name__}: {err}",
                            "stages": {}, "ok": False})
            # the CLI's convention, one line per bad case on stderr (the report on stdout keeps the others)
            print(f"isettorch parity: CASE {path}: {type(err).__name__}: " + " ".join(str(err).split()),
                  file=sys.stderr)
            code = 2
    ok = all(r["ok"] for r in results)
    if args.json:
        print(json.dumps({"cases": results, "ok": ok}, indent=2))
    else:
        _table(results, sys.stdout)
    if code:
        return code
    return 0 if ok else 1
