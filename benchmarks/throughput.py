"""Throughput of full-physics 128x128 camera training pairs (scene generation, diffraction optics, sensor with
shot/read/dark/DSNU/PRNU noise and 12-bit ADC, all targets) on CPU.

Two measurements per spectral sampling:

1. per-stage cost, single thread, in-process (``render_pair(..., timings=...)``): what dominates;
2. pairs/s with a DataLoader of ``--workers`` processes (1 thread each; 2 workers = 2 cores), the way a
   training job consumes the dataset.

Usage::

    python benchmarks/throughput.py --count 200 --workers 2 [--bands 31 16 7] [--markdown benchmarks/THROUGHPUT.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import torch

from isettorch.data.camera_pairs import CameraPairDataset, _Cache, collate_pairs, render_pair

STEPS = {31: 10.0, 16: 20.0, 11: 30.0, 7: 50.0}


def scene_cfg(bands: int, size: int) -> dict:
    return {"height": size, "width": size, "wavelengths_nm": [400.0, 700.0, STEPS[bands]]}


def per_stage(bands: int, size: int, count: int, seed: int = 0) -> dict:
    torch.set_num_threads(1)
    ds = CameraPairDataset(count, seed=seed, scene=scene_cfg(bands, size))
    cache = _Cache()
    for i in range(5):  # warm-up: OTF caches, lazy imports
        render_pair(i, seed, ds.scene_config, ds.camera_config, cache=cache)
    timings: dict = {}
    t0 = time.perf_counter()
    c0 = time.process_time()
    for i in range(count):
        render_pair(1000 + i, seed, ds.scene_config, ds.camera_config, cache=cache, timings=timings)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return {"wall_ms": 1e3 * wall / count, "cpu_ms": 1e3 * cpu / count,
            "stages_ms": {k: 1e3 * v / count for k, v in sorted(timings.items(), key=lambda kv: -kv[1])}}


def loader_rate(bands: int, size: int, count: int, workers: int, batch: int = 16, seed: int = 0) -> float:
    ds = CameraPairDataset(count + 4 * batch * max(workers, 1), seed=seed, scene=scene_cfg(bands, size))
    loader = torch.utils.data.DataLoader(ds, batch_size=batch, num_workers=workers, collate_fn=collate_pairs,
                                         persistent_workers=False, prefetch_factor=4 if workers else None)
    it = iter(loader)
    for _ in range(max(workers, 1)):  # warm-up batches (worker start, caches)
        next(it)
    n = 0
    t0 = time.perf_counter()
    for b in it:
        n += b["raw"].shape[0]
        if n >= count:
            break
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--bands", type=int, nargs="+", default=[31, 16, 7], choices=sorted(STEPS))
    ap.add_argument("--markdown", default=None, help="append a results table to this file")
    args = ap.parse_args()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    lines = [f"host: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
             f"load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}, torch {torch.__version__}",
             "", f"| bands | 1 thread: wall ms/pair | CPU ms/pair | {args.workers} workers: pairs/s | "
             f"CPU-bound estimate on {args.workers} cores: pairs/s | stages (CPU ms/pair, 1 thread) |",
             "|---|---|---|---|---|---|"]
    for bands in args.bands:
        st = per_stage(bands, args.size, max(20, args.count // 4))
        rate = loader_rate(bands, args.size, args.count, args.workers)
        stages = ", ".join(f"{k} {v:.1f}" for k, v in st["stages_ms"].items())
        est = args.workers * 1e3 / st["cpu_ms"]
        lines.append(f"| {bands} | {st['wall_ms']:.1f} | {st['cpu_ms']:.1f} | {rate:.1f} | {est:.0f} | {stages} |")
        print(lines[-1], flush=True)
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        with open(args.markdown, "a") as f:
            f.write(f"\n### {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {args.size}x{args.size}\n\n"
                    + text + "\n")


if __name__ == "__main__":
    main()
