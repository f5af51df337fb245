"""Score demosaic networks on held-out camera-pair items (noisy raw -> camera_rgb CPSNR) against Malvar-He-Cutler.

Usage::

    python training/eval_camera_pairs.py --config configs/train/demosaic_joint_denoise_camera_pairs.yaml \\
        --model shipped=isettorch/assets/demosaic_learned_denoise.pt --model new=out/.../best.pt [--items 64]

Items come from :class:`isettorch.data.camera_pairs.CameraPairDataset` with the config's ``data.scene`` /
``data.camera`` and the dataset seed ``seed + TEST_SEED_OFFSET`` (never drawn for training, whose dataset seed is
``seed``, nor for validation, ``seed + VAL_SEED_OFFSET``); each is rendered ``size + 2`` wide and cropped to RGGB
(:func:`train_demosaic.pair_batch`). Input: the noisy raw (``--input noisy``, default) or ``noise_free_raw``;
target ``camera_rgb``; CPSNR after clipping to [0, 1], ``--crop`` border pixels excluded, averaged over items.
Networks with noise inputs get ``noise_features((noise_gain, noise_floor_var))`` from each item's metadata.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._progress import add_quiet_argument, progress  # noqa: E402
from isettorch.isp.demosaicing import demosaic_malvar2004  # noqa: E402
from isettorch.isp.learned import load_checkpoint  # noqa: E402
from training import common, train_demosaic  # noqa: E402


@torch.no_grad()
def evaluate(cfg: dict, models: dict, items: int = 64, size: int = 128, crop: int = 10, noisy: bool = True,
             batch: int = 8, quiet: bool = True) -> dict:
    """Per-method mean CPSNR (dB) over ``items`` held-out camera pairs; also split at the median noise gain."""
    vcfg = dict(cfg, data=dict(cfg.get("data", {}), patch=size), noise={"enabled": noisy})
    src = train_demosaic.CameraPairSource(vcfg, train_demosaic.TEST_SEED_OFFSET)
    scores: dict = {"mhc": []}
    gains = []
    for start in progress(range(0, items, batch), desc="evaluate", unit="batch", quiet=quiet):
        n = min(batch, items - start)
        b = src.ds.get_batch(list(range(start, start + n)))
        raw, rgb, _ = train_demosaic.pair_batch(b, size, noisy)
        ab = torch.stack([b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]], 1).float()
        gains.append(ab[:, 0])
        scores["mhc"].append(common.cpsnr(demosaic_malvar2004(raw), rgb, crop))
        for name, net in models.items():
            feats = train_demosaic.noise_features(ab) if net.noise_inputs else None
            scores.setdefault(name, []).append(common.cpsnr(net(raw, feats), rgb, crop))
    g = torch.cat(gains)
    low = g <= g.median()
    out = {"items": items, "size": size, "crop": crop, "input": "raw (noisy)" if noisy else "noise_free_raw",
           "dataset_seed": int(cfg.get("seed", 0)) + train_demosaic.TEST_SEED_OFFSET,
           "noise_gain_median": float(g.median()), "cpsnr_db": {}}
    for name, vals in scores.items():
        v = torch.cat(vals)
        out["cpsnr_db"][name] = {"mean": round(float(v.mean()), 3), "low_noise_half": round(float(v[low].mean()), 3),
                                 "high_noise_half": round(float(v[~low].mean()), 3)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--model", action="append", default=[], help="NAME=checkpoint.pt (repeatable)")
    ap.add_argument("--items", type=int, default=64)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--crop", type=int, default=10)
    ap.add_argument("--input", choices=("noisy", "noise_free"), default="noisy")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None, help="write the scores as JSON here")
    add_quiet_argument(ap)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    cfg = common.load_config(args.config)
    models = {}
    for spec in args.model:
        name, sep, path = spec.partition("=")
        if not sep:
            raise ValueError(f"--model: expected NAME=PATH, got {spec!r}")
        models[name] = load_checkpoint(path, dtype=torch.float32)[0]
    res = evaluate(cfg, models, args.items, args.size, args.crop, args.input == "noisy", quiet=args.quiet)
    res["models"] = dict(m.split("=", 1) for m in args.model)
    text = json.dumps(res, indent=2)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
