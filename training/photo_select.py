"""Score candidate correction scales of a noise-free network on the selection photographs and the stress set.

The selection rounds of ``docs/training_log.md`` (from ``#tiny_norefine_2026-11-29``) decide on two sets that are not
Kodak or McMaster: the 30 selection photographs (``training/selection_photos.py``; mean CPSNR, crop 10, RGGB, and how
many are more than 0.1 dB below Malvar-He-Cutler) and the stress set (``training/stress_set.py``, ``stress_set(128)``,
170 images; how many are more than 0.1 dB below MHC). This script scores a checkpoint under a shipped variant's guard
and blend (``isettorch.isp.learned.apply_shipped_settings``) at each correction scale asked for, beside the shipped
network of that variant, and writes the rows to ``--out``. It prints no Kodak or McMaster score.

    python training/photo_select.py CKPT --variant tiny --photos out/selection_photos --scales 0.375 0.5 0.625 \
        [--guard KEY=VALUE ...] [--start CKPT0 --alphas A ...] [--out result.json] [--threads 2]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from isettorch._yaml import load_yaml  # noqa: E402
from training import common  # noqa: E402

#: how far below MHC an image may be before it counts against a candidate (dB)
FLOOR_DB = 0.1


def _candidates(ckpt: str, variant: str, scales: list[float], guard: dict | None = None, start: str | None = None,
                alphas: list[float] | None = None) -> dict:
    """The shipped network of ``variant`` and the candidates: ``ckpt`` at each correction scale (with ``start`` and
    ``alphas``: each weight interpolation ``(1 - alpha) start + alpha ckpt`` at each scale), under the variant's
    shipped guard and blend, the guard's options changed by ``guard``."""
    from isettorch.isp.evaluation import load_demosaic_model
    from isettorch.isp.learned import DemosaicNet, apply_shipped_settings, load_pretrained
    from training.heldout_screen import interpolate_checkpoints

    if (start is None) != (alphas is None):
        raise ValueError("start, alphas: expected both (weight interpolation) or neither")
    if alphas is None:
        networks = {None: load_demosaic_model(ckpt)}
    else:  # each checkpoint read once, one network per alpha
        ends = [torch.load(p, map_location="cpu", weights_only=True) for p in (start, ckpt)]
        networks = {}
        for a in alphas:
            ck = interpolate_checkpoints(a, *ends)
            networks[a] = DemosaicNet(**ck["net_config"])
            networks[a].load_state_dict(ck["model"])
            networks[a].eval().requires_grad_(False)
    nets = {"shipped": load_pretrained(variant)}  # (each call its own copy)
    for a, network in networks.items():
        for s in scales:
            net = apply_shipped_settings(copy.deepcopy(network), variant)
            net.correction_scale = float(s)
            if guard:  # the shipped guard with these options changed
                net.guard = {**net.guard, **guard}
            nets[f"scale {s:g}" if a is None else f"alpha {a:g} scale {s:g}"] = net
    return nets


def score(nets: dict, photos: str, stress: bool = True) -> dict:
    """Each network's row: the photographs' mean CPSNR and count below MHC by more than :data:`FLOOR_DB`, and the
    stress set's count (``stress``)."""
    from isettorch.isp.demosaicing import demosaic
    from isettorch.isp.evaluation import evaluate_demosaic
    from isettorch.isp.learned import demosaic_learned
    from training import stress_set

    mhc = [i["cpsnr"] for i in evaluate_demosaic(photos, "malvar2004", "RGGB", 10)["images"]]
    rows = {"malvar2004": {"photos_mean": sum(mhc) / len(mhc)}}
    images = stress_set.stress_set(128) if stress else []
    floor = stress_set.score(images, {"m": lambda raw, p: demosaic(raw, p, method="malvar2004")})["m"] if stress \
        else {}
    for name, net in nets.items():
        r = evaluate_demosaic(photos, "learned", "RGGB", 10, model=net)
        v = [i["cpsnr"] for i in r["images"]]
        row = {"photos_mean": r["mean_cpsnr"], "photos_below_mhc": sum(a < b - FLOOR_DB for a, b in zip(v, mhc)),
               "per_photo": {i["name"]: i["cpsnr"] for i in r["images"]}}
        if stress:
            s = stress_set.score(images, {"n": lambda raw, p, net=net: demosaic_learned(raw, p, model=net)})["n"]
            row["stress_below_mhc"] = sum(s[k] < floor[k] - FLOOR_DB for k in s)
        rows[name] = row
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--variant", required=True, help="the shipped variant whose guard and blend apply (tiny, small, "
                                                     "noise_free)")
    ap.add_argument("--photos", required=True, help="the selection photographs' folder (training/selection_photos.py)")
    ap.add_argument("--scales", type=float, nargs="+", required=True)
    ap.add_argument("--guard", nargs="*", default=[], metavar="KEY=VALUE",
                    help="change the shipped guard's options for the candidates (values read as YAML), e.g. "
                         "reference=base rel=0.2")
    ap.add_argument("--start", default=None, help="with --alphas: interpolate from this checkpoint to CHECKPOINT")
    ap.add_argument("--alphas", type=float, nargs="+", default=None, help="weights of CHECKPOINT in the interpolation")
    ap.add_argument("--no-stress", action="store_true", help="skip the stress set")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    guard = {}
    for item in args.guard:
        if "=" not in item:
            ap.error(f"--guard: expected KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        guard[key] = load_yaml(value)
    if (args.start is None) != (args.alphas is None):
        ap.error("--start, --alphas: expected both (weight interpolation) or neither")
    common.refuse_test_images(args.photos, "--photos")  # (the ship rule selects on these: never a test image)
    rows = score(_candidates(args.checkpoint, args.variant, args.scales, guard, args.start, args.alphas), args.photos,
                 not args.no_stress)
    for name, row in rows.items():
        extra = "" if "photos_below_mhc" not in row else (
            f"  photos below MHC {row['photos_below_mhc']}"
            + (f"  stress below MHC {row['stress_below_mhc']}" if "stress_below_mhc" in row else ""))
        print(f"{name:22s} {row['photos_mean']:.3f}{extra}")
    if args.out:
        Path(args.out).write_text(json.dumps({"checkpoint": args.checkpoint, "variant": args.variant, "guard": guard,
                                              "rows": rows},
                                             indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
