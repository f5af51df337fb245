"""Export a trained DemosaicNet checkpoint to ``isettorch/assets`` with its training record and benchmark scores.

Usage::

    python training/export_demosaic.py --run out/train_demosaic_noise_free [--which best] [--crops 0 10]

Writes ``demosaic_learned.pt`` (weights + net config only, float32; read with ``torch.load(weights_only=True)``),
``demosaic_learned.json`` (command, config, data, wall time, hardware, validation and benchmark CPSNR) and
``demosaic_learned.md`` (the same, for people). Benchmarks are scored with ``isettorch.isp.evaluation`` (the
``isettorch demosaic-eval`` convention: RGGB, noise-free, clipped, CPSNR averaged over images).
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

from isettorch._checks import first_line  # noqa: E402
from isettorch.isp import learned  # noqa: E402
from isettorch.paths import data_path  # noqa: E402

# the shared benchmark folders under $ISETTORCH_DATA (isettorch.paths.data_path); scored for reporting only
BENCHMARKS = ("kodak24", "mcmaster18")
# shared/data/README.md anchors (colour-demosaicing 0.2.7), CPSNR dB: crop0 / crop10
ANCHORS = {"bilinear": {"kodak24": (29.21, 30.25), "mcmaster18": (30.73, 32.31)},
           "malvar2004": {"kodak24": (35.36, 35.79), "mcmaster18": (33.93, 34.45)},
           "menon2007": {"kodak24": (39.24, 39.31), "mcmaster18": (34.24, 34.21)}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="training output folder (best.pt, last.pt, record.json)")
    ap.add_argument("--which", default="best", choices=("best", "last"))
    ap.add_argument("--crops", type=int, nargs="*", default=[0, 10])
    ap.add_argument("--out", default=str(learned.ASSETS))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--data", default="", help="text describing the training data for the record")
    ap.add_argument("--variant", default=None, choices=sorted(learned.PRETRAINED),
                    help="the shipped variant this checkpoint becomes: its file name and the guard it is scored under "
                         "(learned.PRETRAINED_GUARDS); default joint_denoise for a network with noise inputs, else "
                         "noise_free")
    ap.add_argument("--name", default=None, help="file stem in the assets folder (default: the variant's)")
    ap.add_argument("--half", action="store_true", help="store the weights as float16 (half the size)")
    ap.add_argument("--no-bench", action="store_true", help="skip the Kodak/McMaster scores")
    ap.add_argument("--noise-sigmas", type=float, nargs="*", default=[],
                    help="also score the benchmarks (crop 10) with white Gaussian noise of these stds on the [0, 1] "
                         "mosaic (demosaic-eval --noise-sigma, seed 0; a joint network is given the level)")
    ap.add_argument("--command", default=None,
                    help="the command that made the checkpoint, for the record (default: the run's record.json); "
                         "e.g. a weight interpolation's script")
    ap.add_argument("--selected-by", default=None, help="how the checkpoint was chosen, for the record")
    ap.add_argument("--heldout", default=None,
                    help="JSON written by training/eval_camera_pairs.py, added to the record (held-out camera pairs)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    run = Path(args.run)
    if not (run / f"{args.which}.pt").is_file():  # (a traceback)
        ap.error(f"--run: no {args.which}.pt in {str(run)!r} (a train_demosaic.py output folder)")
    try:
        ck = torch.load(run / f"{args.which}.pt", map_location="cpu", weights_only=True)
        net = learned.DemosaicNet(**ck["net_config"])
    except Exception as err:  # noqa: BLE001 - any unreadable or foreign file is the same user error
        ap.error(f"--run: {run / f'{args.which}.pt'} is not a train_demosaic.py checkpoint "
                 f"({type(err).__name__}: {first_line(err)})")
    store = torch.float16 if args.half else torch.float32
    # scored as stored: with --half the card's scores were the float32 network's
    net.load_state_dict({k: v.to(store).to(v.dtype) for k, v in ck["model"].items()})
    net.eval().requires_grad_(False)
    noisy = bool(ck["net_config"].get("noise_inputs", 0))
    variant = args.variant or ("joint_denoise" if noisy else "noise_free")
    if noisy != (variant == "joint_denoise"):  # (a noise-free network exported as the joint model broke it)
        ap.error(f"--variant: {variant} needs a network {'with' if variant == 'joint_denoise' else 'without'} "
                 f"noise inputs; this one has noise_inputs={ck['net_config'].get('noise_inputs', 0)}")
    args.name = args.name or learned.PRETRAINED[variant].stem
    # scored as it ships: the variant's guard, correction scale and classical blend (load_pretrained sets them; the
    # joint network's noise gates are load_pretrained's alone)
    learned.apply_shipped_settings(net, variant)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pt = out / f"{args.name}.pt"
    # the file holds the settings it is scored with (a --model load of it ran the bare network its card does not
    # score; the registry's load_pretrained sets the same)
    net_config = net.config()
    torch.save({"model": {k: v.to(store).contiguous() for k, v in net.state_dict().items()},
                "net_config": net_config, "step": int(ck["step"]),
                "best_val_cpsnr": float(ck["best_val_cpsnr"])}, pt)

    from isettorch.isp.evaluation import evaluate_demosaic

    def method(raw, pattern):
        return learned.demosaic_learned(raw, pattern, model=net)

    scores: dict = {}
    for name, folder in ((n, data_path(n, must_exist=False)) for n in BENCHMARKS):
        if args.no_bench or not Path(folder).is_dir():
            continue
        for crop in args.crops:
            res = evaluate_demosaic(folder, method, "RGGB", crop, dtype=torch.float32)
            scores.setdefault(name, {})[f"crop{crop}"] = round(res["mean_cpsnr"], 3)
            scores[name].setdefault("ms_per_image", round(res["ms_per_image"], 1))
            print(name, crop, scores[name], flush=True)
        for sigma in args.noise_sigmas:
            res = evaluate_demosaic(folder, "learned", "RGGB", 10, model=net, noise_sigma=sigma, seed=0)
            scores.setdefault(name, {})[f"sigma{sigma:g}_crop10"] = round(res["mean_cpsnr"], 3)
            print(name, sigma, scores[name], flush=True)
    history = json.loads(ck["history"])
    interpolated = ck.get("interpolated")  # (heldout_screen.interpolate_checkpoints)
    rec_path = run / "record.json"
    rec = json.loads(rec_path.read_text()) if rec_path.is_file() else {}
    cfg = json.loads(ck["train_config"])
    selected_by = args.selected_by or ("held-out camera-pair validation CPSNR"
                                       if cfg.get("data", {}).get("source") == "camera_pairs"
                                       else "synthetic validation CPSNR")
    heldout = json.loads(Path(args.heldout).read_text()) if args.heldout else None
    command = args.command or rec.get("command", "train_demosaic.py --config configs/train/demosaic_noise_free.yaml")
    if isinstance(command, str) and command.startswith("train_demosaic.py"):
        command = "python training/" + command
    info = {
        "file": pt.name,
        "stored_dtype": str(store),
        "command": command,
        "config": cfg,
        "net_config": net_config,
        "parameters": sum(p.numel() for p in net.parameters()),
        "data": args.data or cfg.get("data"),
        "checkpoint": {"which": args.which, "step": int(ck["step"]), "selected_by": selected_by,
                       **({"interpolated": interpolated} if interpolated else {})},
        "wall_s": round(float(ck.get("wall_s", 0.0)), 1),
        "total_run_wall_s": rec.get("wall_s"),
        "hardware": rec.get("hardware"),
        # the training run's validation rows score the network as trained, before the variant's guard, correction
        # scale and blend (the benchmarks score it as it ships); an interpolated checkpoint has none of its own
        "validation_synthetic": {} if interpolated else {k: v for k, v in (history[-1] if history else {}).items()
                                                         if k.startswith("val_")},
        "validation_of": ("none: weights interpolated between two checkpoints, whose runs' validation rows do not "
                          "describe them" if interpolated else
                          "the network as trained (bare: before the shipped guard, correction scale and blend)"),
        "best_val_cpsnr": None if interpolated else float(ck["best_val_cpsnr"]),
        "benchmarks_cpsnr_db": scores,
        "benchmark_convention": "shared/data/README.md: RGGB, noise-free, 8-bit/255 as linear, clip, CPSNR per "
                                "image averaged; Kodak/McMaster were never used for training or selection",
        "anchors_cpsnr_db_crop0_crop10": ANCHORS,
    }
    if heldout:
        info["heldout_camera_pairs"] = heldout
    (out / f"{args.name}.json").write_text(json.dumps(info, indent=2, default=str))
    shown = "" if variant == "noise_free" else f'"{variant}"'
    lines = [f"# Shipped learned demosaic (`isettorch.isp.learned.load_pretrained({shown})`)", "",
             f"- command: `{info['command']}`", f"- guard (part of what ships, scored with it): "
             f"`{json.dumps(learned.PRETRAINED_GUARDS[variant])}`",
             f"- correction scale {net.correction_scale:g} and classical blend `{json.dumps(net.blend)}` (part of "
             f"what ships, scored with them)"]
    if variant in learned.PRETRAINED_GATES:
        lines.append(f"- noise gates (part of what ships, `learned.PRETRAINED_GATES`: the low-noise gate to the "
                     f"noise-free network, and the high-noise gate to the classical expert, `classical`): "
                     f"`{json.dumps(learned.PRETRAINED_GATES[variant])}`")
    if cfg.get("init"):
        lines.append(f"- initialised from: `{cfg['init']}` (an earlier run's checkpoint: train that run first)")
    lines += [f"- network: DemosaicNet {net_config}, "
             f"{info['parameters']} parameters", f"- data: {json.dumps(info['data'], default=str)}",
             f"- checkpoint: {args.which} by {selected_by}, "
             + (f"weights interpolated {json.dumps(interpolated)} (the step and wall time are the start's)"
                if interpolated else f"step {ck['step']}")
             + f", training wall time {info['wall_s']} s", f"- hardware: {json.dumps(info['hardware'], default=str)}",
             f"- validation (held out; {info['validation_of']}): {json.dumps(info['validation_synthetic'])}"]
    if heldout:
        lines += ["", f"Held-out camera pairs ({heldout['items']} items {heldout['size']}x{heldout['size']}, dataset "
                  f"seed {heldout['dataset_seed']}, input {heldout['input']} -> camera_rgb, CPSNR dB, crop "
                  f"{heldout['crop']}; halves split at the median noise gain {heldout['noise_gain_median']:.3g}):", "",
                  "| method | mean | low-noise half | high-noise half |", "|---|---|---|---|"]
        for m, v in heldout["cpsnr_db"].items():
            lines.append(f"| {m} | {v['mean']} | {v['low_noise_half']} | {v['high_noise_half']} |")
    if scores:
        lines += ["", "| method | Kodak crop0 | Kodak crop10 | McM crop0 | McM crop10 |", "|---|---|---|---|---|"]
    for m, a in (ANCHORS.items() if scores else ()):
        lines.append(f"| {m} (README anchor) | {a['kodak24'][0]} | {a['kodak24'][1]} | {a['mcmaster18'][0]} | "
                     f"{a['mcmaster18'][1]} |")
    k, mc = scores.get("kodak24", {}), scores.get("mcmaster18", {})
    if scores:
        cell = [d.get(c, "not scored") for d in (k, mc) for c in ("crop0", "crop10")]
        lines.append(f"| **learned (this file)** | {cell[0]} | {cell[1]} | {cell[2]} | {cell[3]} |")
    if args.noise_sigmas and scores:
        lines += ["", "Noisy benchmarks (white Gaussian noise of std sigma on the [0, 1] mosaic, seed 0, crop 10; the "
                  "network is given (a, b) = (0, sigma^2)):", "",
                  "| set | " + " | ".join(f"sigma {s:g}" for s in args.noise_sigmas) + " |",
                  "|---|" + "---|" * len(args.noise_sigmas)]
        for name, sc in scores.items():
            lines.append(f"| {name} | " + " | ".join(str(sc.get(f"sigma{s:g}_crop10")) for s in args.noise_sigmas)
                         + " |")
    (out / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    print(json.dumps(scores))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
