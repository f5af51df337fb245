"""``isettorch calibrate``: EMVA 1288 photon-transfer calibration of a camera from dark and flat frames.

Example::

    isettorch calibrate captures/cam1 --json --out cam1_sensor.yaml --report cam1_report/

``DIR`` holds ``capture.yaml`` (bit_depth, pixel_size_m, optional black_level_dn, cfa, photons_per_pixel) and
``dark_<ms>ms/`` / ``flat_<ms>ms/`` folders of >= 2 frames each (8/16-bit greyscale PNG/TIFF, .npy or camera raws), in
DN; the folder's CFA is capture.yaml's (else the raws' metadata) and its black level is measured from the darks.
Given one raw frame instead, it gives a Poisson-Gaussian estimate (Foi et al. 2008); ``--cfa`` and ``--black-level``
are for that mode only, ``--out`` and ``--report`` for the folder mode only.
"""

from __future__ import annotations

import math

from .._progress import add_quiet_argument
from ._outputs import strict_json


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate a sensor's noise and gain from dark and flat frames (EMVA 1288)")
    p.add_argument("directory", metavar="DIR", help="capture folder (capture.yaml, dark_<ms>ms/, flat_<ms>ms/), or one "
                   "raw frame (PNG/TIFF/npy/DNG/camera raw) for a quick Poisson-Gaussian estimate (Foi et al. 2008)")
    p.add_argument("--black-level", type=float, default=None,
                   help="single raw only: black level in DN (default: the raw file's, else 0)")
    p.add_argument("--cfa", default=None, help="single raw only: CFA pattern (default: the raw file's, else mono)")
    p.add_argument("--json", action="store_true", help="print the full result as JSON on stdout")
    p.add_argument("--out", default=None, metavar="SENSOR.yaml",
                   help="capture folder only: write a sensor config (Sensor.from_config / the sensor: section of a "
                   "camera YAML)")
    p.add_argument("--report", default=None, metavar="FOLDER",
                   help="capture folder only: write the EMVA 1288 figures as PNG")
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
    import sys

    import numpy as np

    from ..io.frames import RAW_SUFFIXES, read_frame
    from ..sensor.noise_estimation import estimate_poisson_gaussian

    # errors: ValueError, one line (isettorch.cli); a leading "<dest>:" is shown as the option's spelling
    for dest, what in (("out", "a sensor config"), ("report", "an EMVA 1288 report")):
        if getattr(args, dest) is not None:
            raise ValueError(f"{dest}: {what} needs a capture folder (DIR with capture.yaml, dark_<ms>ms/, "
                             f"flat_<ms>ms/); one raw frame gives only the Poisson-Gaussian noise estimate")
    black, white, cfa = args.black_level, None, args.cfa
    warnings = []
    if args.directory.lower().endswith(RAW_SUFFIXES):
        from ..io.raw import read_raw

        raw = read_raw(args.directory)
        data = raw.data if raw.black_level_delta_dn is None else raw.data - raw.black_level_delta_dn
        black = float(sum(raw.black_level_dn) / len(raw.black_level_dn)) if black is None else black
        white, cfa = raw.white_level_dn, cfa or raw.cfa
    else:
        data = read_frame(args.directory)
    top = float(data.max())
    if args.black_level is not None and not (math.isfinite(black) and 0 <= black < top):
        raise ValueError(f"black_level: expected a finite level in [0, {top:g}) DN (below the frame's maximum), got "
                         f"{args.black_level!r}")
    if black is None:
        black = 0.0
        darkest = float(np.quantile(data, 0.001))
        if darkest > 0:
            warnings.append(f"black level 0 assumed; the frame's darkest values are {darkest:g} DN (0.1 % quantile): "
                            f"pass --black-level")
    try:
        res = estimate_poisson_gaussian(data, cfa=cfa, black_level_dn=black, white_level_dn=white)
    except ValueError as err:  # the library names the CFA's cell ("cell: unknown CFA letter"): here it is --cfa
        head, sep, rest = str(err).partition(":")
        if head == "raw":  # the frame itself (too small, too flat): the file given as DIR
            raise ValueError(f"DIR: {args.directory}:{rest}") from err
        if args.cfa is None or not sep or head not in ("cell", "cfa", "pattern"):
            raise
        raise ValueError(f"cfa: {args.cfa!r}:{rest}") from err
    res["warnings"] = warnings + res.get("warnings", [])
    res.update({"file": args.directory, "cfa": cfa, "black_level_dn": black})
    if args.json:
        print(strict_json(res, indent=2))
        for w in res["warnings"]:
            print(f"isettorch calibrate: warning: {w}", file=sys.stderr)
    else:
        read_e = "n/a" if res["read_noise_e"] is None else f"{res['read_noise_e']:.3g}"
        print(f"{args.directory}: sigma^2 = a y + b with a = {res['a']:.4g} DN/e- (conversion gain), "
              f"b = {res['b']:.4g} DN^2 (read noise {res['read_noise_dn']:.3g} DN = {read_e} e-)")
        for w in res["warnings"]:
            print(f"warning: {w}")
    return 0


def _stage_figures(result: dict, capture, report, out, staged) -> None:
    """The report's figures drawn in a temporary folder inside ``report`` and staged for their final names there
    (``result["report_figures"]``); ``out`` (the sensor YAML) may not be one of them."""
    import os
    import tempfile
    from pathlib import Path

    from ..metrics.emva import calibration_figures

    try:
        with tempfile.TemporaryDirectory(dir=report, prefix=".figures-") as tmp:
            names = []
            for f in calibration_figures(result, capture, tmp):
                final = Path(report) / Path(f).name
                if out and Path(out).resolve() == final.resolve():
                    raise ValueError(f"out: {out} is the --report figure {final.name}; give the sensor YAML a name "
                                     f"of its own")
                os.replace(f, staged.temporary(final))
                names.append(str(final))
    except OSError as err:
        raise OSError(f"report: cannot write the figures into {report} ({err.strerror or err})") from err
    result["report_figures"] = names


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..io.frames import is_exposure_folder_name, read_capture
    from ..sensor.calibration import calibrate_capture, write_sensor_config
    from ._outputs import Outputs, check_dir, check_file

    if not Path(args.directory).exists():
        raise FileNotFoundError(f"DIR: no such capture folder or raw frame {args.directory!r}")
    if Path(args.directory).is_file():
        return _single(args)
    # bad input raises ValueError, which the CLI shows as one line (isettorch.cli)
    if args.cfa is not None:
        raise ValueError("cfa: applies to a single raw frame only; a capture folder's CFA comes from its capture.yaml "
                         "(cfa:), else from its camera raws' metadata")
    if args.black_level is not None:
        raise ValueError("black_level: applies to a single raw frame only; a capture folder's black level is measured "
                         "from its dark frames (capture.yaml's black_level_dn is reported as the nominal value)")
    # both outputs' places checked before the (long) calibration and before either is written; never an input
    inputs = [f for f in Path(args.directory).rglob("*") if f.is_file()]
    if args.out:
        check_file(args.out, "out", inputs=inputs)
    if args.report:
        report, capture_dir = Path(args.report).resolve(), Path(args.directory).resolve()
        # the capture folder itself or one of its exposure folders: the figures became frames there, which every
        # later calibration refused (a report folder of its own inside the capture is skipped, with a warning)
        if report == capture_dir or (capture_dir in report.parents
                                     and is_exposure_folder_name(report.relative_to(capture_dir).parts[0])):
            raise ValueError(f"report: {args.report} is the capture folder {args.directory} or one of its frame "
                             f"folders; its figures would become frames of the capture; give a folder of its own")
        if args.out and Path(args.out).resolve() == report:  # (the report was written, then --out failed)
            raise ValueError(f"out: {args.out} is the --report folder; give the sensor YAML a file name of its own")
        check_dir(args.report, "report")
    capture = read_capture(args.directory, progress=not args.quiet)
    result = calibrate_capture(capture, progress=not args.quiet)
    # the figures and the YAML under temporary names, moved into place together when all are written: a failure
    # leaves neither (and no report folder made for them), and the YAML never replaces a figure (an --out named
    # like one overwrote it, exit 0)
    with Outputs(args.report) as staged:
        if args.report:
            _stage_figures(result, capture, args.report, args.out, staged)
        if args.out:
            try:
                write_sensor_config(result, staged.temporary(args.out))
            except OSError as err:
                raise OSError(f"out: cannot write {args.out} ({err.strerror or err})") from err
    if args.json:
        print(strict_json(result, indent=2))
    else:
        print(_summary(result))
    for w in result["warnings"]:
        if args.json:
            print(f"isettorch calibrate: warning: {w}", file=sys.stderr)
    return 0
