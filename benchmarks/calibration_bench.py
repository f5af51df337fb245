"""Robustness of `isettorch calibrate` (EMVA 1288 photon transfer) over random camera truths and seeds.

Captures are simulated in plain NumPy (tests/sensor/numpy_capture.py: read, dark current, DSNU, PRNU, row noise,
full-well and ADC clipping, black level, quantisation), mono and Bayer, 256 x 256, 15 exposures (dark to past the
saturation of every channel), 3 frames each; the worst-case error of every calibrated quantity is reported against
the issue-17 bounds. Usage::

    OMP_NUM_THREADS=1 python benchmarks/calibration_bench.py --cases 20 --out out/calibration.md

``--out`` replaces its file: benchmarks/CALIBRATION.md (this run and a ``--frames 2`` run, with notes) is curated by
hand from it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "sensor"))
import numpy_capture as nc  # noqa: E402

from isettorch._progress import add_quiet_argument, progress  # noqa: E402
from isettorch.io.frames import Capture  # noqa: E402
from isettorch.sensor.calibration import calibrate_capture  # noqa: E402


def random_truth(rng: np.random.Generator, cfa: str | None) -> dict:
    bits = int(rng.choice([12, 14]))
    gain = float(np.exp(rng.uniform(np.log(0.15), np.log(2.0))))
    read = float(rng.uniform(1.0, 6.0))
    black = float(rng.choice([64, 128, 256, 512]))
    # full well below the ADC range or clipped by it: both are "the level where pixels clip"
    full_well = float(min(rng.uniform(4000, 30000), (2**bits - 1 - black) / gain))
    qe = {"W": float(rng.uniform(0.3, 0.8))} if cfa is None else \
        {"R": float(rng.uniform(0.2, 0.4)), "G": float(rng.uniform(0.45, 0.7)), "B": float(rng.uniform(0.2, 0.4))}
    return dict(gain_dn_per_e=gain, read_noise_e=read, dark_current_e_per_s=float(rng.uniform(20, 300)),
                # DSNU at least a quarter of the read noise: below, 3 frames per level cannot measure it to 10 %
                # (the temporal residue var / N, sampled by the H rows for row noise, swamps it)
                dsnu_e=float(max(rng.uniform(0.5, 6.0), 0.25 * read)), prnu_percent=float(rng.uniform(0.3, 2.0)),
                row_noise_e=float(rng.uniform(0.2, 0.5) * read), full_well_e=full_well, black_level_dn=black,
                bits=bits, qe=qe)


def run_case(truth: dict, cfa: str | None, seed: int, frames: int = 3) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    sat_ms = float(rng.uniform(30, 300))
    # up to past the saturation of the least sensitive channel
    top = max(2.7, 1.3 * max(truth["qe"].values()) / min(truth["qe"].values()))
    exposures = np.round(np.linspace(0.02, top, 15) * sat_ms, 3)
    dark, flat, photons = nc.simulate(truth, cfa=cfa, seed=seed, exposures_ms=exposures, saturate_ms=sat_ms,
                                      frames=frames)
    cap = Capture(truth["bits"], 3.45e-6, cfa, None, photons, {k: v.astype(float) for k, v in dark.items()},
                  {k: v.astype(float) for k, v in flat.items()}, {})
    return nc.relative_errors(calibrate_capture(cap), truth)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=12, help="random truths per CFA (mono, RGGB)")
    ap.add_argument("--frames", type=int, default=3, help="dark and flat frames per exposure")
    ap.add_argument("--out", default=None)
    add_quiet_argument(ap)
    args = ap.parse_args()
    rows, worst = [], {}
    t0 = time.perf_counter()
    for cfa in (None, "RGGB"):
        for i in progress(range(args.cases), desc=cfa or "mono", unit="case", quiet=args.quiet):
            rng = np.random.default_rng(1000 + i + (500 if cfa else 0))
            truth = random_truth(rng, cfa)
            err = run_case(truth, cfa, seed=i, frames=args.frames)
            key = lambda k: "qe" if k.startswith("qe") else k  # noqa: E731
            for k, v in err.items():
                worst[(cfa or "mono", key(k))] = max(worst.get((cfa or "mono", key(k)), 0.0), abs(v))
            bad = [k for k, v in err.items() if abs(v) >= nc.bound(k)]
            rows.append((cfa or "mono", i, truth, err, bad))
            print(cfa or "mono", i, "FAIL " + str(bad) if bad else "ok", flush=True)
    elapsed = time.perf_counter() - t0
    names = ["gain", "read", "dark", "dsnu", "prnu", "row", "full_well", "black_dn", "qe"]
    lines = ["# Calibration robustness (`isettorch calibrate`, EMVA 1288 photon transfer)", "",
             f"{args.cases} random truths per CFA, 256 x 256, 15 exposures x {args.frames} dark + {args.frames} flat "
             f"frames; NumPy truth simulator `tests/sensor/numpy_capture.py`; `{' '.join(sys.argv)}` "
             f"({elapsed:.0f} s).", "",
             "Worst-case |error| (relative; black level in DN) against the issue-17 bounds:", "",
             "| cfa | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for c in ("mono", "RGGB"):
        lines.append(f"| {c} | " + " | ".join(
            (f"{worst[(c, n)]:.4f}" if n == "black_dn" else f"{100 * worst[(c, n)]:.2f} %") for n in names) + " |")
    lines.append("| bound | " + " | ".join((f"{nc.BOUNDS[n]}" if n == "black_dn" else f"{100 * nc.BOUNDS[n]:g} %")
                                           for n in names) + " |")
    fails = [(c, i, bad) for c, i, _, _, bad in rows if bad]
    lines += ["", f"Cases outside a bound: {len(fails)} of {len(rows)}" + (f": {fails}" if fails else ""), ""]
    lines += ["Truth ranges: gain 0.15-2 DN/e-, read 1-6 e-, dark 20-300 e-/s, DSNU 0.5-6 e- (>= read / 4), "
              "PRNU 0.3-2 %, row 0.2-0.5 x read, full well 4000-30000 e- (or the ADC top), black 64-512 DN, 12/14 bit."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
