"""``isettorch demo``: render the built-in scenes through a camera and write images and a short report.

Scenes: Macbeth ColorChecker (D65), slanted edge, frequency sweep and dead leaves, each with a field of view
chosen so the sensor is about ``--size`` pixels wide (a config that fixes the sensor's rows and cols is resized to
``--size`` columns, its aspect kept, so that the scenes fill it). Outputs in ``--out``: ``<scene>.png`` (the camera's
sRGB image), ``<scene>_scene.png`` (the scene's ideal sRGB preview), ``report.json`` and ``report.md``
(Macbeth mean/max dE2000, exposure, per-scene sensor illuminance, and the SNR of the gray patches, measured in the
chart's footprint on the sensor: :func:`isettorch.isp.chart.scene_window`). A monochrome
camera has no colour: its report has no colour error (``colour_error`` says so) and the rest as for colour.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from .._checks import check_seed
from .._progress import add_quiet_argument, progress
from ._outputs import strict_json

#: --size bounds: below 16 px the charts have no patches; above 2048 px the 31-band scenes (2 samples per pixel,
#: float32: 31 x 4096^2 x 4 B = 2 GB each, four of them) no longer fit a workstation's memory
MIN_SIZE, MAX_SIZE = 16, 2048
DEFAULT_CONFIG = "default"  # the built-in camera config (isettorch/configs/cameras/default.yaml)


def register(sub) -> None:
    p = sub.add_parser("demo", help="render built-in scenes through a camera; write images and a report to --out")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--size", type=int, default=256,
                   help=f"sensor width in pixels (about; {MIN_SIZE} to {MAX_SIZE}; default 256)")
    from ..camera import camera_config_names

    p.add_argument("--config", default=DEFAULT_CONFIG,
                   help=f"camera: a built-in name ({', '.join(camera_config_names())}) or a YAML path "
                        "(default: default)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    add_quiet_argument(p)
    p.set_defaults(func=run)


def _save_png(img, path: Path) -> None:
    import torch
    from PIL import Image

    a = (img.detach().clamp(0, 1) * 255).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    Image.fromarray(a).save(path)


def _inner(oi):
    """The optical image without the optics' padding (the scene's area, which the sensor sees)."""
    return oi.crop(oi.pad_rows, oi.pad_cols, oi.height - 2 * oi.pad_rows, oi.width - 2 * oi.pad_cols)


def run(args) -> int:
    import yaml

    from ..camera import Camera
    from ._outputs import Outputs, check_dir

    if not MIN_SIZE <= args.size <= MAX_SIZE:
        raise ValueError(f"--size: expected {MIN_SIZE} to {MAX_SIZE} pixels, got {args.size}")
    check_seed(args.seed, "--seed")  # (-1 failed in torch's manual_seed, unnamed)
    out = check_dir(args.out, "out")
    config = args.config
    try:  # a user's config error is one line and exit code 2 (isettorch.cli), not a traceback
        cam = Camera.from_config(config)
    except (ValueError, TypeError, OSError, yaml.YAMLError) as err:
        raise ValueError(f"--config {config}: {str(err).removeprefix('path: ')}") from err  # (the path is named)
    with Outputs(out) as staged:  # on an error: no files, and no folder made for them
        return _render(args, cam, config, out, staged)


def _render(args, cam, config, out, staged) -> int:
    import torch

    from ..isp.chart import gray_patch_snr, macbeth_delta_e, patch_means, scene_window
    from ..scene import frequency_sweep, macbeth, slanted_edge
    from ..scene.dead_leaves import dead_leaves

    n = args.size
    rows, cols = getattr(cam.sensor, "rows", None), getattr(cam.sensor, "cols", None)
    if rows and cols:  # a fixed sensor: resized to about n columns (aspect kept), so the scenes below fill it
        cam.sensor.rows, cam.sensor.cols = max(2, 2 * round(n * rows / cols / 2)), n
        if cam.sensor.rows < 4:  # (patch_means' error named its 'grid')
            need = 2 * math.ceil(4 * cols / rows / 2)
            raise ValueError(f"--size: {n} columns give this config's {rows} x {cols} sensor {cam.sensor.rows} "
                             f"rows; the Macbeth chart needs at least 4 (--size {need} or more)")
    # Field of view for a sensor about n pixels wide: 2 atan(n p / 2 f).
    f = float(cam.optics.focal_length_m.reshape(-1)[0])
    hfov = math.degrees(2 * math.atan(n * cam.sensor.pixel_size_m / (2 * f)))
    # Two scene samples per pixel: a scene coarser than the pixel grid would be interpolated by the sensor
    # (and Camera warns); the optical image keeps the scene's sampling, the sensor has about n pixels across.
    s = 2 * n
    # The 6:4 chart fills the sensor's width, or its height on a sensor wider than 6:4 (a fixed 16:9 one)
    aspect = cam.sensor.rows / cam.sensor.cols if rows and cols else None
    chart_hfov = hfov if aspect is None or aspect >= 4 / 6 else math.degrees(
        2 * math.atan(n * aspect * 1.5 * cam.sensor.pixel_size_m / (2 * f)))
    scenes = {
        "macbeth": macbeth("D65", patch_size=max(4, s // 6), hfov_deg=chart_hfov),
        "slanted_edge": slanted_edge(s, hfov_deg=hfov),
        "frequency_sweep": frequency_sweep(s, hfov_deg=hfov),
        "dead_leaves": dead_leaves(s, seed=args.seed, hfov_deg=hfov),
    }
    gen = torch.Generator().manual_seed(args.seed)
    report = {"camera": cam.name or Path(config).stem, "config": str(config), "size": n, "hfov_deg": hfov,
              "scenes": {}}
    for name, scene in progress(scenes.items(), total=len(scenes), desc="demo", quiet=args.quiet, unit="scene"):
        t0 = time.perf_counter()
        res = cam(scene, return_intermediates=True, generator=gen)
        elapsed = time.perf_counter() - t0
        _save_png(res.image[0], staged.temporary(out / f"{name}.png"))
        _save_png(scene.srgb()[0], staged.temporary(out / f"{name}_scene.png"))
        entry = {
            "image": f"{name}.png",
            "sensor_pixels": list(res.raw.data.shape[-2:]),
            "scene_mean_luminance_cd_m2": float(scene.mean_luminance()[0]),
            "sensor_mean_illuminance_lux": float(_inner(res.optical_image).mean_illuminance()[0]),
            "exposure_s": float(res.raw.exposure_s[0]),
            "render_seconds": round(elapsed, 3),
        }
        if name == "macbeth":
            # the chart's footprint: the sensor keeps its aspect, so a near-square one holds the 6:4 chart in its
            # middle rows (patch windows over the whole image measured the border)
            window = scene_window(res, float(cam.sensor.pixel_size_m))
            if window is None:
                raise ValueError(f"--config {config}: the sensor does not hold the whole Macbeth chart, whose colour "
                                 "error needs every patch")
            r0, r1, c0, c1 = window
            if res.raw.cfa.is_monochrome or res.isp is None or res.isp.xyz is None:
                # a monochrome sensor: the ISP renders gray (no XYZ), so there is no colour to compare
                entry["colour_error"] = "not measured: a monochrome sensor has no colour"
            else:
                acc = macbeth_delta_e(patch_means(res.isp.xyz[..., r0:r1, c0:c1]), "D65")
                entry.update({"delta_e2000_mean": float(acc.mean[0]), "delta_e2000_max": float(acc.max[0]),
                              "delta_e2000_per_patch": [round(float(v), 3) for v in acc.delta_e[0]]})
            snr = gray_patch_snr(res.raw, window=window)
            entry.update({"gray_patch_snr_db": [None if v is None else round(v, 2) for v in snr["snr_db"]],
                          "gray_patch_snr_channel": snr["channel"], "gray_patch_pixels": snr["pixels"]})
            if any(snr["notes"]):
                entry["gray_patch_snr_notes"] = snr["notes"]
        report["scenes"][name] = entry
    staged.temporary(out / "report.json").write_text(strict_json(report, indent=2))
    m = report["scenes"]["macbeth"]
    if "delta_e2000_mean" in m:
        colour = ("- colour error (CIEDE2000, white-patch scaled, vs the true XYZ): "
                  f"mean **{m['delta_e2000_mean']:.2f}**, max **{m['delta_e2000_max']:.2f}**")
    else:
        colour = f"- colour error: {m['colour_error']}"
    snr_text = ", ".join("n/a" if v is None else f"{v:.1f}" for v in m["gray_patch_snr_db"])
    notes = sorted({v for v in m.get("gray_patch_snr_notes", []) if v})
    lines = [
        f"# isettorch demo: camera `{report['camera']}`",
        "",
        f"Config `{config}`; sensor about {n} pixels wide; scene field of view {hfov:.2f} deg.",
        "",
        "## Macbeth ColorChecker under D65",
        "",
        colour,
        f"- exposure {m['exposure_s'] * 1e3:.2f} ms at {m['sensor_mean_illuminance_lux']:.2f} lux mean sensor "
        "illuminance",
        f"- SNR of the gray patches (white -> black, {m['gray_patch_snr_channel']} pixels, noise-free mean / noise "
        f"std, dB): {snr_text}" + (f" (n/a: {'; '.join(notes)})" if notes else ""),
        "",
        "## Scenes",
        "",
        "| scene | image | sensor px | exposure (ms) | illuminance (lux) | render (s) |",
        "|---|---|---|---|---|---|",
    ]
    for name, e in report["scenes"].items():
        lines.append(f"| {name} | {e['image']} | {e['sensor_pixels'][0]}x{e['sensor_pixels'][1]} | "
                     f"{e['exposure_s'] * 1e3:.2f} | {e['sensor_mean_illuminance_lux']:.2f} | {e['render_seconds']} |")
    staged.temporary(out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0
