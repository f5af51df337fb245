"""Camera-specific denoising, one full-size run (issue 35 item 5; ``docs/camera_specific_denoising.md``).

The flow of ``tests/test_camera_specific_flow.py`` at full size, on a camera simulated in plain NumPy with known
truth (``tests/sensor/numpy_capture.py``: Poisson shot noise, PRNU, DSNU, dark current, read noise, the well,
black level, 12-bit ADC), a high-ISO phone-like sensor: 4 DN/e-, 1.5 e- read noise, a 1000 e- well, 768 x 768 px.

    python training/camera_specific_run.py prepare   # capture -> isettorch calibrate -> sensor.yaml, camera.yaml
    python training/camera_specific_run.py train     # train_demosaic.py, the template config, this camera, 1 h
    python training/camera_specific_run.py score --photos DIR  # isettorch process on simulated raw frames

``score`` simulates raw frames of the camera (the same sensor: its PRNU and DSNU patterns) from photographs: each is
lifted to spectra with the library's photo lifter (:func:`isettorch.data.photos.lift_srgb`, Mallett & Yuksel's
basis) under D65 and projected on the camera's spectral QE (the camera config's filters), which gives its noise-free
camera RGB, a 3 x 3 matrix of its linear sRGB (scaled so that a white reads 1 in its brightest channel); each frame
is exposed as the camera config's auto-exposure does (the mosaic's 98th percentile at 0.5 of the span) and two stops
under it. Scores (CPSNR against that camera RGB, crop 10, after dividing by the exposure scale): the camera-specific
network and the shipped joint network, both through ``isettorch process``; the shipped joint model as the library
applies it (its guard and noise gates); and nlmeans + Menon 2007 given the same noise level. Photographs are for
reporting only: nothing is selected on them (the run's checkpoint is its own ``best.pt``, chosen on its synthetic
validation through the camera).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tests" / "sensor"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import numpy as np  # noqa: E402
import numpy_capture as nc  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402

from isettorch._yaml import load_yaml  # noqa: E402

#: the simulated camera (electrons, DN); no row noise (not in the noise model ``process`` gives the network)
TRUTH = dict(gain_dn_per_e=4.0, read_noise_e=1.5, dark_current_e_per_s=20.0, dsnu_e=1.0, prnu_percent=0.8,
             row_noise_e=0.0, full_well_e=1000.0, black_level_dn=64.0, bits=12, qe={"R": 0.45, "G": 0.6, "B": 0.4})
SHAPE = (768, 768)
SEED = 1
EXPOSURE_S = 1.0 / 30
AE_TARGETS = (0.5, 0.125)  # the camera config's auto-exposure level, and two stops under it
TRAIN_SECONDS = 3600


def prepare(out: Path) -> dict:
    from isettorch.cli import main

    dark, flat, _ = nc.simulate(TRUTH, shape=SHAPE, cfa="RGGB", frames=2, seed=SEED, saturate_ms=10.0,
                                exposures_ms=np.round(np.linspace(0.5, 14.0, 16), 3))
    cap = nc.write_capture(out / "capture", dark, flat, bits=TRUTH["bits"], cfa="RGGB", suffix=".npy")
    sensor_yaml = out / "sensor.yaml"
    if main(["calibrate", str(cap), "--out", str(sensor_yaml), "--quiet"]) != 0:
        raise SystemExit("calibrate failed")
    s = load_yaml(sensor_yaml.read_text())["sensor"]
    cg, lsb = s["conversion_gain_v_per_e"], 1.0 / 2 ** s["adc_bits"]
    measured = {"gain_dn_per_e": cg / lsb, "read_noise_e": s["read_noise_v"] / cg,
                "dsnu_e": s.get("dsnu_sigma_v", 0.0) / cg, "prnu_percent": s.get("prnu_sigma_percent", 0.0),
                "dark_current_e_per_s": s.get("dark_current_e_per_s", 0.0), "black_level_dn": s["black_level_dn"]}
    calib = {k: {"truth": TRUTH[k], "measured": float(v)} for k, v in measured.items()}
    cam = {"name": "numpy_high_iso", "optics": {"type": "diffraction_limited", "f_number": 2.8, "focal_length_m": 4e-3},
           "sensor": dict(s, auto_exposure="percentile", ae_percentile=98.0, ae_target=0.5, fpn_mode="per_frame")}
    (out / "camera.yaml").write_text(yaml.safe_dump(cam, sort_keys=False))
    (out / "calibration.json").write_text(json.dumps(calib, indent=1))
    for k, v in calib.items():
        print(f"{k}: truth {v['truth']:g}, calibrated {v['measured']:.4g}")
    return calib


def train(out: Path, seconds: int = TRAIN_SECONDS) -> int:
    cmd = [sys.executable, str(ROOT / "training" / "train_demosaic.py"), "--config",
           str(ROOT / "configs" / "train" / "demosaic_camera_specific.yaml"), "--out", str(out / "run"),
           "--threads", "1", "--device", "cpu", "--no-progress",
           "--set", f"data.camera_config={out / 'camera.yaml'}", f"optim.time_budget_s={seconds}"]
    print(" ".join(cmd), flush=True)
    return subprocess.call(cmd, cwd=ROOT)


def camera_rgb_matrix(sensor) -> np.ndarray:
    """``[3, 3]``: a lifted photograph's noise-free camera RGB from its linear sRGB, under D65 through the sensor's
    spectral QE: ``M_kc = sum_l B_c(l) E(l) QE_k(l)`` (``B`` the lifter's basis), scaled so a white (linear sRGB
    1, 1, 1) reads 1 in its brightest channel."""
    import torch

    from isettorch.data.photos import lift_srgb
    from isettorch.design import illuminant_photons

    lifted = lift_srgb(np.full((1, 1, 3), 255, np.uint8))
    wl = lifted["wavelengths_nm"].to(torch.float64)
    qe = sensor.spectral_qe(wl, dtype=torch.float64, device="cpu")  # [3, L]
    m = (qe[:, None, :] * (lifted["reflectance"] * illuminant_photons(wl, 1.0))[None]).sum(-1)
    return (m / m.sum(1).max()).numpy()


def _frames(images, folder: Path, target: float, to_camera: np.ndarray | None = None):
    """Raw frames (.npy, DN) of the simulated camera for each photograph (its camera RGB: ``to_camera`` times its
    linear sRGB; ``None``: the 8-bit values / 255 as camera RGB), exposed so that the mosaic's 98th percentile is
    ``target`` of the span; returns [(name, path, truth [3, H, W], scale)]."""
    rng, prnu, dsnu = nc.sensor_maps(TRUTH, SHAPE, SEED)
    rng = np.random.default_rng([SEED, int(target * 1000)])
    span = 2 ** TRUTH["bits"] - 1 - TRUTH["black_level_dn"]
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, arr in images:
        truth = arr.astype(np.float64).transpose(2, 0, 1) / 255.0
        if to_camera is not None:
            from isettorch.image import srgb_decode

            truth = np.einsum("kc,chw->khw", to_camera, srgb_decode(torch.from_numpy(truth)).numpy())
        h, w = truth.shape[1:]
        if h > SHAPE[0] or w > SHAPE[1]:
            raise ValueError(f"{name}: {h} x {w} is larger than the simulated sensor {SHAPE}")
        m = np.zeros((h, w))
        m[0::2, 0::2], m[0::2, 1::2] = truth[0, 0::2, 0::2], truth[1, 0::2, 1::2]
        m[1::2, 0::2], m[1::2, 1::2] = truth[1, 1::2, 0::2], truth[2, 1::2, 1::2]
        scale = target / max(np.percentile(m, 98), 1e-6)
        mean_e = (m * scale * span / TRUTH["gain_dn_per_e"] * prnu[:h, :w]
                  + TRUTH["dark_current_e_per_s"] * EXPOSURE_S)
        dn = nc.expose(TRUTH, mean_e, dsnu[:h, :w], rng)
        path = folder / f"{Path(name).stem}.npy"
        np.save(path, dn)
        out.append((name, path, truth, scale))
    return out


def score(out: Path, photos: Path) -> dict:
    from isettorch.camera import Camera
    from isettorch.cli import main
    from isettorch.commands.process import levels, noise_params
    from isettorch.isp import learned
    from isettorch.isp.evaluation import cpsnr, load_images

    torch.set_num_threads(2)
    cam_yaml = out / "camera.yaml"
    sensor = Camera.from_config(str(cam_yaml)).sensor
    black, span = levels(sensor)  # as process normalises (the zero level, the white level at the config's gain)
    a, b = noise_params(sensor, exposure_s=EXPOSURE_S)
    feats = learned.noise_features(a, b).float()
    models = {"camera-specific network": out / "run" / "best.pt",
              "shipped joint network": learned.PRETRAINED["joint_denoise"]}
    images = load_images(photos)
    to_camera = camera_rgb_matrix(sensor)
    result = {"photos": str(photos), "noise": {"a": a, "b": b}, "camera_rgb_from_linear_srgb": to_camera.tolist(),
              "levels": {}}
    for target in AE_TARGETS:
        frames = _frames(images, out / f"frames_{target:g}", target, to_camera)
        rows = {}
        for label, ckpt in models.items():
            dest = out / f"processed_{target:g}" / label.split()[0]
            if main(["process", *[str(f[1]) for f in frames], "--camera", str(cam_yaml), "--model", str(ckpt),
                     "--out", str(dest), "--exposure-s", str(EXPOSURE_S), "--quiet"]) != 0:
                raise SystemExit(f"process failed for {label}")
            rows[label] = [np.load(dest / f"{f[1].stem}.npy") for f in frames]
        gated, classical = [], []
        joint = learned.load_pretrained("joint_denoise")
        for _, path, _, _ in frames:
            x = ((torch.from_numpy(np.load(path).astype(np.float64)) - black) / span)[None, None]
            with torch.no_grad():
                gated.append(learned.demosaic_learned(x.float(), "RGGB", model=joint, noise=feats)[0].numpy())
            classical.append(learned.classical_expert(x, feats)[0].numpy())
        rows["shipped joint model, as the library applies it (guard, noise gates)"] = gated
        rows["nlmeans + menon2007"] = classical
        level = {}
        for label, outs in rows.items():
            scores = [float(cpsnr(torch.from_numpy(o / s).double().clamp(0, 1)[None],
                                  torch.from_numpy(t)[None], 10)[0]) for o, (_, _, t, s) in zip(outs, frames)]
            level[label] = {"mean_cpsnr": float(np.mean(scores)), "images": scores}
            print(f"AE {target:g}: {label}: {np.mean(scores):.2f} dB", flush=True)
        result["levels"][f"{target:g}"] = level
    (out / "scores.json").write_text(json.dumps(result, indent=1))
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("phase", choices=("prepare", "train", "score"))
    ap.add_argument("--out", default="out/camera_specific_full")
    ap.add_argument("--seconds", type=int, default=TRAIN_SECONDS, help="training time budget (train)")
    ap.add_argument("--photos", default=None, help="photographs to simulate raw frames of (score; reporting only)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.phase == "prepare":
        prepare(out)
    elif args.phase == "train":
        return train(out, args.seconds)
    else:
        if args.photos is None:
            ap.error("score: --photos is required")
        score(out, Path(args.photos))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
