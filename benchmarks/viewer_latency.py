"""Re-render latency of ``isettorch view`` at 256^2: time from a control change to every window's data ready
(camera render + images + ROI analyses + PSF/MTF), i.e. the server-side work of one browser update.

Median of ``--repeats`` changes per control, alternating between two values, each timed twice: ``new`` with the
viewer's stage caches (optical images, raws, pictures) emptied first, so the whole camera re-runs (an upper bound:
a control downstream of the optics reuses the optical image in use), and ``seen`` with them as the previous
changes left them (from the third change on the value was seen before: only the stages its caches do not hold;
the plain alternation timed mostly these). Run: ``OMP_NUM_THREADS=2 python benchmarks/viewer_latency.py``.

``--browser`` measures end to end instead: ``isettorch view`` is started on a loopback port, Debian's Chromium
(playwright, ``/usr/bin/chromium``) clicks each control, and the time runs from the click until the page holds
the new render's data (the server's render counter, sent last, has changed).
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


def browser_latency(size: int, repeats: int, threads: int) -> None:
    import os
    import socket
    import subprocess
    import sys
    import tempfile
    import urllib.request
    from pathlib import Path

    from playwright.sync_api import sync_playwright

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    proc = subprocess.Popen([sys.executable, "-m", "isettorch.cli", "view", "--port", str(port), "--no-browser",
                             "--size", str(size)], env=env, cwd=Path(__file__).resolve().parents[1])
    url = f"http://127.0.0.1:{port}/"
    try:
        for _ in range(240):
            try:
                urllib.request.urlopen(url, timeout=5).read()
                break
            except OSError:
                time.sleep(0.5)
        args = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync"]
        with sync_playwright() as p, tempfile.TemporaryDirectory() as profile:
            ctx = p.chromium.launch_persistent_context(profile, executable_path="/usr/bin/chromium", headless=True,
                                                       args=args, viewport={"width": 1400, "height": 1300})
            page = ctx.new_page()
            page.goto(url)
            renders = "Bokeh.documents[0].get_model_by_name('status').data.renders[0]"
            page.wait_for_function(f"() => window.Bokeh && Bokeh.documents.length && {renders} >= 1", timeout=120_000)
            selects = page.locator("select")
            controls = {
                "f_number (select)": lambda i: selects.nth(1).select_option("8" if i % 2 == 0 else "4"),
                "exposure (select)": lambda i: selects.nth(2).select_option("10" if i % 2 == 0 else "30"),
                "pixel size (select)": lambda i: selects.nth(3).select_option("2" if i % 2 == 0 else "2.8"),
                "cfa (button)": lambda i: page.get_by_role("button", name="RGGB" if i % 2 == 0 else "GRBG").click(),
                "noise (toggle)": lambda i: page.get_by_role("button", name="noise").click(),
                "demosaic (button)": lambda i: page.get_by_role(
                    "button", name="malvar2004" if i % 2 == 0 else "bilinear").click(),
            }
            print(f"isettorch view, browser end to end (click -> new data in the page), scene {size}^2 macbeth, "
                  f"server {threads} threads; median (min, max) over {repeats} clicks")
            print("| control | median s | min s | max s |\n|---|---|---|---|")
            for name, act in controls.items():
                times = []
                for i in range(repeats):
                    before = page.evaluate(f"() => {renders}")
                    t0 = time.perf_counter()
                    act(i)
                    page.wait_for_function(f"() => {renders} > {before}", timeout=60_000)
                    times.append(time.perf_counter() - t0)
                print(f"| {name} | {statistics.median(times):.3f} | {min(times):.3f} | {max(times):.3f} |")
            ctx.close()
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--browser", action="store_true", help="end to end in headless Chromium (see above)")
    args = ap.parse_args()
    if args.browser:
        browser_latency(args.size, args.repeats, args.threads)
        return
    torch.set_num_threads(args.threads)
    s = ViewerSession("default", "macbeth", args.size)
    one_update(s)
    print(f"isettorch view latency, scene {args.size}^2 macbeth, sensor {s.shape('sensor')}, "
          f"{args.threads} threads; median (min, max) over {args.repeats} changes")
    print("| control | new: median s | min s | max s | seen: median s | min s | max s |\n|---|---|---|---|---|---|---|")
    for key, values in CHANGES.items():
        times = {"new": [], "seen": []}
        for kind in times:
            for i in range(args.repeats):
                if kind == "new":  # (alternating two values, the caches held both from the third change on)
                    for cache in (s._ois, s._raws, s._images):
                        cache.clear()
                t0 = time.perf_counter()
                s.update(**{key: values[i % 2]})
                one_update(s)
                times[kind].append(time.perf_counter() - t0)
        cells = " | ".join(f"{statistics.median(t):.3f} | {min(t):.3f} | {max(t):.3f}" for t in times.values())
        print(f"| {key} | {cells} |")
        s.update(**{key: None})


if __name__ == "__main__":
    main()
