"""Re-render latency of ``isettorch view`` at 256^2: time from a control change to every window's data ready
(camera render + images + ROI analyses + PSF/MTF), i.e. the server-side work of one browser update.

Median of ``--repeats`` changes per control, alternating between two values (so each change is a real change
and the viewer's stage caches behave as in use). Run: ``OMP_NUM_THREADS=2 python benchmarks/viewer_latency.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from isettorch.viewer.session import ROI, ViewerSession

CHANGES = {
    "f_number": (8.0, 4.0),
    "exposure_ms": (10.0, 30.0),
    "pixel_size_um": (2.0, 2.8),
    "cfa": ("RGGB", "GRBG"),
    "noise": (False, True),
    "demosaic": ("malvar2004", "bilinear"),
}


def one_update(s: ViewerSession) -> None:
    """What the page does after a change: every image, every window's ROI analysis, PSF and MTF."""
    for w in ("scene", "oi", "sensor", "ip"):
        s.image(w)
    s.spectrum("scene", ROI.centre(*s.shape("scene")))
    s.spectrum("oi", ROI.centre(*s.shape("oi")))
    s.sensor_stats(ROI.centre(*s.shape("sensor")))
    s.colour_stats(ROI.centre(*s.shape("ip")))
    s.optics_curves()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    s = ViewerSession("default", "macbeth", args.size)
    one_update(s)
    print(f"isettorch view latency, scene {args.size}^2 macbeth, sensor {s.shape('sensor')}, "
          f"{args.threads} threads; median (min, max) over {args.repeats} changes")
    print("| control | median s | min s | max s |\n|---|---|---|---|")
    for key, values in CHANGES.items():
        times = []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            s.update(**{key: values[i % 2]})
            one_update(s)
            times.append(time.perf_counter() - t0)
        print(f"| {key} | {statistics.median(times):.3f} | {min(times):.3f} | {max(times):.3f} |")
        s.update(**{key: None})


if __name__ == "__main__":
    main()
