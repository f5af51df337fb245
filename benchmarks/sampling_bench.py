"""Wall time of the sensor's area sampling (``sample_area``) and of a camera that needs it, this checkout against
another (e.g. the commit before a change), measured in the same run, alternating the two in fresh subprocesses.

Each round starts one subprocess per code version (``PYTHONPATH`` set to that checkout, 2 threads) that times
``sample_area`` on random ``[1, C, N, N]`` planes for OI-spacing-to-pitch ratios below, at and above 1, and one
``Camera.from_config('phone_microlens')`` capture of an sRGB image shown on an LCD (its pixel optics depend on the
wavelength, so every band is sampled; the scene is coarser than the pixels). The table gives each version's median
over rounds (each a median of repeats) and the ratio, and the largest difference between the two versions' outputs.

Usage::

    python benchmarks/sampling_bench.py --other /path/to/old/checkout [--rounds 3] [--markdown] [--camera-only]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

CHILD = r"""
import json, sys, time, torch
torch.set_num_threads(2)
from isettorch.sensor.sampling import sample_area
cases = json.loads(sys.argv[1])
out = {}
def median_s(f, n):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter(); y = f(); ts.append(time.perf_counter() - t0)
    return sorted(ts)[n // 2], y
for n, c, ratio in cases["area"]:
    x = torch.rand(1, c, n, n, generator=torch.Generator().manual_seed(n + c))
    dx = torch.tensor([1e-6])
    rows = int(n / ratio)
    t, y = median_s(lambda: sample_area(x, dx, 1e-6 * ratio, rows, rows), 5)
    out[f"sample_area {n}^2 x {c}, pitch {ratio} x spacing"] = (t, y.double().sum().item())
from isettorch.camera import Camera
from isettorch.scene import from_rgb
cam = Camera.from_config("phone_microlens")
for n in cases["camera"]:
    rgb = torch.rand(1, 3, n, n, generator=torch.Generator().manual_seed(n))
    scene = from_rgb(rgb, mean_luminance_cd_m2=100)
    def run():
        with torch.no_grad():
            return cam(scene, generator=torch.Generator().manual_seed(0))
    run()
    t, y = median_s(run, 3)
    out[f"phone_microlens camera, {n}^2 scene"] = (t, y.double().sum().item())
print(json.dumps(out))
"""

CASES = {"area": [[n, c, r] for n, c in ((512, 3), (1024, 3), (2048, 3), (1024, 31)) for r in (0.6, 1.0, 3.0)],
         "camera": [512, 1024]}


def run(checkout: str, cases: dict) -> dict:
    env = dict(os.environ, PYTHONPATH=checkout, OMP_NUM_THREADS="2", MKL_NUM_THREADS="2", PYTHONWARNINGS="ignore")
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(cases)], env=env, capture_output=True, text=True,
                         check=True, cwd=checkout)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--other", required=True, help="the checkout to compare with (e.g. a worktree of the old commit)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--markdown", action="store_true", help="print a Markdown table")
    p.add_argument("--camera-only", action="store_true", help="only the phone_microlens captures")
    args = p.parse_args()
    cases = dict(CASES, area=[]) if args.camera_only else CASES
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    new, old = [], []
    for _ in range(args.rounds):
        old.append(run(args.other, cases))
        new.append(run(here, cases))
    rows = []
    for key in new[0]:
        t_old = statistics.median(r[key][0] for r in old)
        t_new = statistics.median(r[key][0] for r in new)
        sums = (old[0][key][1], new[0][key][1])
        rows.append((key, t_old, t_new, t_old / t_new, abs(sums[1] - sums[0]) / max(abs(sums[0]), 1e-300)))
    if args.markdown:
        print("| case | other (s) | this (s) | speed-up | relative difference of the sums |")
        print("|---|---|---|---|---|")
        for key, a, b, r, d in rows:
            print(f"| {key} | {a:.3f} | {b:.3f} | {r:.1f}x | {d:.1e} |")
    else:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
