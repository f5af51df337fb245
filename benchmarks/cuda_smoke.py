"""CUDA smoke checks of the library's device paths that the test suite's CUDA cases do not reach: each runs one
small workload on ``--device`` and prints PASS or FAIL with the error's last line (run by ``gpu_checks.sh`` on a
lent GPU; ``--device cpu`` is the dry run here). Reporting only: what a check finds becomes a test.

Usage::

    python benchmarks/cuda_smoke.py --device cuda [--out FILE]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _finite_on(t: torch.Tensor, device: torch.device) -> None:
    if t.device.type != device.type:
        raise AssertionError(f"result on {t.device}, expected {device}")
    if not bool(torch.isfinite(t).all()):
        raise AssertionError("non-finite values")


def stream_natural(dev):
    from isettorch.data import PairStream

    b = PairStream(8, seed=1, device=dev, scene={"generator": "natural", "height": 64, "width": 64}).batch(0)
    _finite_on(b["camera_rgb"], dev)
    _finite_on(b["raw"], dev)


def stream_grad(dev):
    from isettorch.data import PairStream

    st = PairStream(4, seed=2, device=dev, scene={"height": 48, "width": 48}, grad=True)
    b = st.batch(0)
    _finite_on(b["camera_rgb"], dev)


def stream_chunked_targets(dev):
    from isettorch.data import PairStream

    st = PairStream(16, seed=3, device=dev, scene={"height": 64, "width": 64}, targets=("camera_rgb",), parts=2)
    b = st.batch(5)
    _finite_on(b["camera_rgb"], dev)


def camera_configs(dev):
    from isettorch.camera import Camera
    from isettorch.scene.macbeth import macbeth

    for name in ("default", "imx363", "phone_microlens", "isetcam_microlens", "paper2004_cds"):
        cam = Camera.from_config(name).to(dev)
        scene = macbeth(patch_size=8, device=dev, dtype=torch.float64)
        out = cam(scene, generator=torch.Generator(device=dev).manual_seed(0))
        _finite_on(out, dev)


def configured_optics(dev):
    """Paths a device audit of 2026-12-01 found building CPU tensors (fixed; the CPU-side tests are
    tests/test_device_paths.py): a wavefront defocus, a stream's configured optics, the lens' full-PSF path, e-SFR."""
    from isettorch import metrics
    from isettorch.camera import Camera
    from isettorch.data import PairStream
    from isettorch.optics import WavefrontOptics
    from isettorch.scene import slanted_edge
    from isettorch.scene.macbeth import macbeth

    wf = WavefrontOptics(zernike_um=torch.zeros(15), f_number=4.0, focal_length_m=3.86e-3, defocus_diopters=2.0)
    _finite_on(wf.to(dev)(macbeth(patch_size=4, device=dev)).photons, dev)
    b = PairStream(2, seed=0, device=dev, scene={"height": 32, "width": 32}, targets=("camera_rgb",),
                   camera={"optics": {"type": "wavefront", "zernike_um": [0, 0, 0, 0, 0.2], "defocus_diopters": 1.0}}
                   ).batch(0)
    _finite_on(b["camera_rgb"], dev)
    cam = Camera.from_config("cooke_lens").to(dev)
    _finite_on(cam(macbeth(patch_size=8, device=dev, dtype=torch.float64),
                   generator=torch.Generator(device=dev).manual_seed(0)), dev)
    _finite_on(metrics.esfr(slanted_edge(size=96, device=dev).photons[0].sum(0)).mtf50, dev)


def camera_gradients(dev):
    from isettorch.camera import Camera
    from isettorch.scene.macbeth import macbeth

    cam = Camera.from_config("default").to(dev)
    scene = macbeth(patch_size=8, device=dev, dtype=torch.float64)
    exposure = torch.tensor([0.01], dtype=torch.float64, device=dev, requires_grad=True)
    out = cam(scene, exposure_s=exposure, generator=torch.Generator(device=dev).manual_seed(0))
    (g,) = torch.autograd.grad(out.sum(), exposure)
    _finite_on(g, dev)


def _photos(folder: Path, n: int = 2, size: int = 96) -> Path:
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    g = np.random.default_rng(0)
    for i in range(n):
        yy, xx = np.mgrid[0:size, 0:size] / size
        img = np.stack([yy, xx, 0.5 + 0.4 * np.sin(6 * xx + 3 * yy)], -1) * 0.8 + 0.1 * g.random((size, size, 3))
        Image.fromarray((img.clip(0, 1) * 255).astype(np.uint8)).save(folder / f"p{i}.png")
    return folder


def _cli(args: list[str]) -> None:
    code = "import sys; from isettorch.cli import main; sys.exit(main(sys.argv[1:]))"
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise AssertionError(f"exit {r.returncode}: {(r.stderr or r.stdout).strip().splitlines()[-1:]}")


def design_eval(dev):
    with tempfile.TemporaryDirectory() as tmp:
        folder = _photos(Path(tmp) / "photos")
        for design in ("learned", "rgbw"):
            _cli(["design-eval", design, str(folder), "--device", str(dev), "--lux", "1", "100", "--crop", "4"])


def demosaic_eval(dev):
    with tempfile.TemporaryDirectory() as tmp:
        folder = _photos(Path(tmp) / "photos")
        for method in ("learned", "learned_tiny", "learned_small", "menon2007"):
            _cli(["demosaic-eval", str(folder), "--method", method, "--device", str(dev)])
        _cli(["demosaic-eval", str(folder), "--method", "learned", "--noise-sigma", "0.02", "--device", str(dev)])


def train_stream(dev):
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "training/train_demosaic.py", "--config",
                            "configs/train/demosaic_stream_smoke.yaml", "--device", str(dev), "--out", tmp,
                            "--set", f"data.device={dev}"], capture_output=True, text=True, cwd=ROOT)
        if r.returncode != 0:
            raise AssertionError(f"exit {r.returncode}: {(r.stderr or r.stdout).strip().splitlines()[-1:]}")


def codesign_sources(dev):
    from training import codesign

    with tempfile.TemporaryDirectory() as tmp:
        folder = _photos(Path(tmp) / "photos", size=64)
        for source in ("natural", "photos"):
            codesign.train({"device": str(dev), "threads": 4, "lux": [1, 100], "out": f"{tmp}/{source}",
                            "design": {"filters": ["learned", "learned", "learned", "W"], "mosaic_shape": [2, 2]},
                            "camera": {"network": {"width": 8, "depth": 2}},
                            "data": {"source": source, "size": 32, "batch": 4, "folder": str(folder)},
                            "optim": {"steps": 4, "design_warmup": 0.25}, "val": {"batches": 1, "every": 2}},
                           quiet=True)


CHECKS = [stream_natural, stream_grad, stream_chunked_targets, camera_configs, camera_gradients, design_eval,
          demosaic_eval, train_stream, codesign_sources, configured_optics]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--out", default=None,
                    help="also write the lines to this file, each as its check ends (a timeout keeps the finished)")
    args = ap.parse_args(argv)
    dev = torch.device(args.device)
    if args.out:
        Path(args.out).write_text("")
    for check in CHECKS:
        t0 = time.perf_counter()
        try:
            check(dev)
            line = f"PASS {check.__name__} ({time.perf_counter() - t0:.1f} s)"
        except Exception as err:  # noqa: BLE001 - a smoke run reports every failure and goes on
            tb = traceback.extract_tb(err.__traceback__)[-1]
            line = (f"FAIL {check.__name__}: {type(err).__name__}: {str(err).splitlines()[0][:300] if str(err) else ''}"
                    f" [{Path(tb.filename).name}:{tb.lineno}]")
        print(line, flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
