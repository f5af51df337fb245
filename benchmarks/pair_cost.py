"""CPU time per camera training pair, one thread, in process: this checkout against another (e.g. the old
second-simulator code), measured in the same run, alternating the two in fresh subprocesses.

Each round starts one subprocess per code version (``PYTHONPATH`` set to that checkout, ``OMP_NUM_THREADS=1``,
``torch.set_num_threads(1)``), which warms up and then times ``render_pairs`` of ``--batches`` batches of
``--batch`` items at ``--size``^2 with all targets, reporting ``time.process_time`` per pair (CPU time is far less
sensitive than wall time to other processes sharing the cores). The rounds alternate old/new; the table gives each
version's median over rounds and the new/old ratio per round.

Usage::

    python benchmarks/pair_cost.py --other /path/to/old/checkout [--rounds 6] [--batches 6] [--markdown]
        [--tune-allocator]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, sys, time, torch
torch.set_num_threads(1)
from isettorch.data.camera_pairs import TARGETS, _Cache, render_pairs
from isettorch.data.config import CAMERA_DEFAULTS, SCENE_DEFAULTS, merge_config
size, batch, batches, start, tune = (int(a) for a in sys.argv[1:6])
if tune:  # as in a DataLoader worker (CameraPairDataset's tune_worker_allocator)
    from isettorch.data.config import tune_allocator
    tune_allocator()
scene = merge_config({"height": size, "width": size}, SCENE_DEFAULTS, "scene")
camera = merge_config({}, CAMERA_DEFAULTS, "camera")
cache = _Cache()
render_pairs(list(range(10**6, 10**6 + 2 * batch)), 0, scene, camera, cache=cache, targets=TARGETS)  # warm-up
per, stages = [], {}
for k in range(batches):
    idx = list(range(start + k * batch, start + (k + 1) * batch))
    t0 = time.process_time()
    render_pairs(idx, 0, scene, camera, cache=cache, targets=TARGETS, timings=stages)
    per.append((time.process_time() - t0) / batch)
print(json.dumps([per, {key: 1e3 * v / (batch * batches) for key, v in stages.items()}]))
"""


def run(checkout: str, size: int, batch: int, batches: int, start: int, tune: bool = False) -> tuple[float, dict]:
    env = dict(os.environ, PYTHONPATH=checkout, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    args = [str(v) for v in (size, batch, batches, start, int(tune))]
    out = subprocess.run([sys.executable, "-c", CHILD, *args], env=env,
                         capture_output=True, text=True, check=True, cwd=checkout)
    per, stages = json.loads(out.stdout.strip().splitlines()[-1])
    return statistics.median(per) * 1e3, stages


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--other", required=True, help="the checkout to compare with (e.g. a worktree of old main)")
    p.add_argument("--this", default=str(Path(__file__).resolve().parents[1]), help="this checkout")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--batches", type=int, default=6, help="timed batches per subprocess")
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--tune-allocator", action="store_true",
                   help="apply isettorch.data.config.tune_allocator in each subprocess first, as CameraPairDataset "
                        "does in DataLoader workers (freed tensors stay in the heap: no page faults per fresh tensor)")
    p.add_argument("--markdown", action="store_true")
    a = p.parse_args()
    rows = []
    for r in range(a.rounds):
        start = r * a.batches * a.batch
        order = [("other", a.other), ("this", a.this)] if r % 2 == 0 else [("this", a.this), ("other", a.other)]
        runs = {name: run(path, a.size, a.batch, a.batches, start, a.tune_allocator) for name, path in order}
        res = {name: v[0] for name, v in runs.items()}
        rows.append(res)
        stages = {name: ", ".join(f"{k} {v:.2f}" for k, v in runs[name][1].items()) for name in runs}
        print(f"round {r}: other {res['other']:.2f} ms/pair ({stages['other']}), this {res['this']:.2f} ms/pair "
              f"({stages['this']}), ratio {res['this'] / res['other']:.3f}", flush=True)
    med_o = statistics.median(r["other"] for r in rows)
    med_t = statistics.median(r["this"] for r in rows)
    ratio = statistics.median(r["this"] / r["other"] for r in rows)
    load = os.getloadavg()
    print(f"median: other {med_o:.2f} ms/pair, this {med_t:.2f} ms/pair, this/other {ratio:.3f} "
          f"(load {load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f})")
    if a.markdown:
        print(f"\n| code | CPU ms/pair per round (batch {a.batch}, {a.size}^2, all targets, 1 thread) | median |")
        print("|---|---|---|")
        for name, label in (("other", a.other), ("this", a.this)):
            vals = ", ".join(f"{r[name]:.2f}" for r in rows)
            print(f"| {label} | {vals} | **{statistics.median(r[name] for r in rows):.2f}** |")
        ratios = ", ".join(f"{r['this'] / r['other']:.3f}" for r in rows)
        print(f"| this / other | {ratios} | **{ratio:.3f}** |")


if __name__ == "__main__":
    main()
