"""``isettorch calibrate``: EMVA 1288 photon-transfer calibration of a camera from dark and flat frames.

Example::

    isettorch calibrate captures/cam1 --json --out cam1_sensor.yaml --report cam1_report/

``DIR`` holds ``capture.yaml`` (bit_depth, pixel_size_m, optional black_level_dn, cfa, photons_per_pixel) and
``dark_<ms>ms/`` / ``flat_<ms>ms/`` folders of >= 2 frames each (16-bit PNG/TIFF, .npy or camera raws), in DN.
"""

from __future__ import annotations

from .._progress import add_quiet_argument


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate a sensor's noise and gain from dark and flat frames (EMVA 1288)")
    p.add_argument("directory", metavar="DIR", help="capture folder (capture.yaml, dark_<ms>ms/, flat_<ms>ms/), or one "
                   "raw frame (PNG/TIFF/npy/DNG/camera raw) for a quick Poisson-Gaussian estimate (Foi et al. 2008)")
    p.add_argument("--black-level", type=float, default=None,
                   help="single raw: black level in DN (default: the raw file's, else 0)")
    p.add_argument("--cfa", default=None, help="single raw: CFA pattern (default: the raw file's, else mono)")
    p.add_argument("--json", action="store_true", help="print the full result as JSON on stdout")
    p.add_argument("--out", default=None, metavar="SENSOR.yaml",
                   help="write a sensor config (Sensor.from_config / the sensor: section of a camera YAML)")
    p.add_argument("--report", default=None, metavar="FOLDER", help="write the EMVA 1288 figures as PNG")
    add_quiet_argument(p)
    p.set_defaults(func=run)


def _summary(result: dict) -> str:
    from ..sensor.calibration import CALIBRATION_FIELDS

    lines = [f"calibration of {result['frame_shape'][0]}x{result['frame_shape'][1]} frames, "
             f"{result['bit_depth']} bit, cfa {result['cfa'] or 'mono'}"]
    for k in CALIBRATION_FIELDS:
        v = result[k]
        if isinstance(v, dict):
            v = ", ".join(f"{n} {x:.4g}" if x is not None else f"{n} n/a" for n, x in v.items())
        elif v is not None:
            v = f"{v:.4g}"
        lines.append(f"  {k:<26} {v}")
    lines += [f"warning: {w}" for w in result["warnings"]]
    return "\n".join(lines)


def _single(args) -> int:
    import json

    from ..io.frames import RAW_SUFFIXES, read_frame
    from ..sensor.noise_estimation import estimate_poisson_gaussian

    black, white, cfa = args.black_level, None, args.cfa  # errors: ValueError, one line (isettorch.cli)
    if args.directory.lower().endswith(RAW_SUFFIXES):
        from ..io.raw import read_raw

        raw = read_raw(args.directory)
        data = raw.data
        black = float(sum(raw.black_level_dn) / len(raw.black_level_dn)) if black is None else black
        white, cfa = raw.white_level_dn, cfa or raw.cfa
    else:
        data = read_frame(args.directory)
    res = estimate_poisson_gaussian(data, cfa=cfa, black_level_dn=black or 0.0, white_level_dn=white)
    res.update({"file": args.directory, "cfa": cfa, "black_level_dn": black or 0.0})
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(f"{args.directory}: sigma^2 = a y + b with a = {res['a']:.4g} DN/e- (conversion gain), "
              f"b = {res['b']:.4g} DN^2 (read noise {res['read_noise_dn']:.3g} DN = {res['read_noise_e']:.3g} e-)")
    return 0


def run(args) -> int:
    import json
    import sys
    from pathlib import Path

    from ..io.frames import read_capture
    from ..sensor.calibration import calibrate_capture, write_sensor_config

    if not Path(args.directory).exists():
        raise FileNotFoundError(f"DIR: no such capture folder or raw frame {args.directory!r}")
    if Path(args.directory).is_file():
        return _single(args)
    # bad input raises ValueError, which the CLI shows as one line (isettorch.cli)
    capture = read_capture(args.directory, progress=not args.quiet)
    result = calibrate_capture(capture, progress=not args.quiet)
    if args.out:
        write_sensor_config(result, args.out)
    if args.report:
        from ..metrics.emva import calibration_figures

        result["report_figures"] = calibration_figures(result, capture, args.report)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(_summary(result))
    for w in result["warnings"]:
        if args.json:
            print(f"isettorch calibrate: warning: {w}", file=sys.stderr)
    return 0
