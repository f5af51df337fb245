"""Design a camera through its gradients: the colour filters, the mosaic and a reconstruction network learned
together (issue 36), or a fixed design's network alone with the same data and budget.

Usage::

    python training/codesign.py --config configs/train/codesign_learned.yaml [--set key.sub=value ...]

Each step draws a batch of spectral scenes (a pluggable source, :data:`SOURCES`: ``layouts`` are PairStream's
device-batched scenes, :func:`isettorch.data.batched.draw_layout_scenes`; ``photos`` random crops of a folder of
photographs lifted to spectra, :func:`isettorch.data.photos.lift_srgb`; ``natural``
:func:`isettorch.data.natural.generate_natural`), takes each scene's reflectance (its spectra divided by its
light's white), lights it with D65 at one of the configured light levels (lux, in turn), renders it through the
design's camera (:class:`isettorch.design.DesignCamera`: fixed optics, the design sensor with its photon and read
noise, the incident-light exposure rule and the ADC, all differentiable) and reconstructs linear sRGB with that
level's network. The loss is the L1 distance to the scene's linear sRGB under D65 (white = 1) plus the L1 distance
in encoded sRGB (the metric's space). The filters and mosaic logits (a learned design) share one optimiser group,
the networks another; the design may wait while the networks learn (``optim.design_warmup``, a fraction of the
steps); the mosaic's softmax temperature then falls geometrically (``mosaic.temperature_*``), and the mosaic is
read hard with straight-through gradients (``mosaic.straight_through_after``); after ``optim.design_until`` (a
fraction of the steps) the design is frozen, hard, and the networks alone learn the sensor that would be built.

Outputs in ``out``: ``design.pt`` (the design file: filters, hard mosaic, network weights per level, config, card),
``card.md``, ``history.csv``, ``curves.png``, ``filters.png`` (filters and mosaic) and ``record.json``. Every
``checkpoint_every`` steps the run's state goes to ``out/checkpoint.pt``; running the same command again resumes
from it (on the same device, the same steps as an uninterrupted run: each step's scenes and noise depend only on
the seed and the step)
and a finished run removes it.

``device`` (``cpu``, ``cuda``, ``cuda:N``) is where the camera renders and the networks train. The scenes are drawn
on the CPU (each batch a function of the seed and the step on any device), the predesign runs on the CPU, and the
noise comes from a generator on the device: a run on CUDA draws other noise than the same run on the CPU. A run
resumes on any device.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.data.config import seed_for  # noqa: E402
from isettorch.design import (  # noqa: E402
    DesignCamera,
    design_card,
    make_design,
    predesign_filters,
    save_design,
)
from isettorch.image import srgb_encode  # noqa: E402
from isettorch.sensor.mosaic import temperature_schedule  # noqa: E402
from training import common  # noqa: E402
from training.codesign_sources import (  # noqa: E402, F401  (the scene sources; re-exported)
    SOURCES,
    common_path,
    source_layouts,
    source_natural,
    source_photos,
    targets,
)

DEFAULTS: dict = {
    "seed": 0,
    "threads": None,
    "device": "cpu",
    "out": "out/codesign",
    "name": None,
    "design": "bayer_rgb",
    "camera": {},
    "lux": [1.0, 10.0, 100.0],
    "data": {"source": "layouts", "size": 64, "batch": 8, "scene": {}, "folder": None, "natural": {}},
    "optim": {"steps": 2000, "lr": 1.0e-3, "design_lr": 2.0e-2, "lr_min": 1.0e-5, "srgb_weight": 1.0, "loss": "l1",
              "design_warmup": 0.0, "design_until": 1.0, "design_lux": None},
    "mosaic": {"temperature_start": 1.0, "temperature_end": 0.03, "anneal_fraction": 0.7,
               "straight_through_after": 0.8},
    "val": {"batches": 2, "every": 200, "seed_offset": 1_000_003, "crop": 4},
    "loss_crop": 4,
    "checkpoint_every": 250,
    # the learned filters designed on the noise-limited colour estimate before any network training (predesign)
    "predesign": {"steps": 0, "lr": 0.05, "window": 16, "lux": None, "fit_patches": 256, "test_colours": 64,
                  "seed": 5},
}


def merged_config(cfg: dict) -> dict:
    """``cfg`` over :data:`DEFAULTS` (one level deep for the sections); unknown top-level keys raise."""
    out = json.loads(json.dumps(DEFAULTS))
    sections = {k: (None if k == "camera" else set(v)) for k, v in out.items() if isinstance(v, dict)}
    # (a section given as a number, optim=5, was skipped here and failed later: 'int' object is not subscriptable)
    common.check_keys(cfg, set(out), sections)
    for key, value in cfg.items():
        if isinstance(out[key], dict) and key not in ("camera",) and isinstance(value, dict):
            out[key].update(value)
        else:
            out[key] = value
    lux = out["lux"]
    if (not isinstance(lux, (list, tuple)) or not lux
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not (v > 0) for v in lux)):
        raise ValueError(f"config.lux: expected a list of positive light levels, got {lux!r}")
    _check_values(out)
    return out


def _check_values(cfg: dict) -> None:
    """The numbers a run divides, crops or counts by, named when out of range (a negative learning rate trained by
    gradient ascent, a loss crop of half the image gave a NaN loss at every step and still wrote a design,
    val.batches 0 failed after the last step leaving nothing)."""
    num = common.check_number
    num(cfg["seed"], "seed", integer=True, minimum=0)
    o, v, d = cfg["optim"], cfg["val"], cfg["data"]
    for key in ("steps",):
        num(o[key], f"optim.{key}", integer=True, minimum=1)
    num(d["size"], "data.size", integer=True, minimum=2)
    num(d["batch"], "data.batch", integer=True, minimum=1)
    for key in ("lr", "design_lr"):
        num(o[key], f"optim.{key}", above=0)
    num(o["lr_min"], "optim.lr_min", minimum=0)
    num(o["srgb_weight"], "optim.srgb_weight", minimum=0)
    half = d["size"] / 2
    num(cfg["loss_crop"], "loss_crop", integer=True, minimum=0, below=half)
    num(v["crop"], "val.crop", integer=True, minimum=0, below=half)
    num(v["batches"], "val.batches", integer=True, minimum=1)
    num(v["every"], "val.every", integer=True, minimum=0)
    num(cfg["checkpoint_every"], "checkpoint_every", integer=True, minimum=0)
    num(cfg["mosaic"]["anneal_fraction"], "mosaic.anneal_fraction", minimum=0)
    num(cfg["predesign"]["steps"], "predesign.steps", integer=True, minimum=0)


# ------------------------------------------------------------------------------------------------ predesign

def predesign(camera: DesignCamera, cfg: dict, *, quiet: bool = False) -> dict:
    """Design the learned filters on the noise-limited colour estimate before the networks train
    (:func:`isettorch.design.predesign_filters` with the config's ``predesign`` section; its levels default to the
    run's). Returns its record."""
    p = cfg["predesign"]
    steps = int(p["steps"])

    def progress(step, loss):
        if not quiet and (step % 50 == 0 or step + 1 == steps):
            print(json.dumps({"predesign_step": step, "bound_loss": round(loss, 4)}), flush=True)

    return predesign_filters(camera, p["lux"] or cfg["lux"], steps=steps, lr=float(p["lr"]), window=int(p["window"]),
                             fit_patches=int(p["fit_patches"]), test_colours=int(p["test_colours"]),
                             seed=int(p["seed"]), progress=progress)


# ------------------------------------------------------------------------------------------------ training

LOSSES = ("l1", "mse_srgb")


def _loss(out: torch.Tensor, target: torch.Tensor, crop: int, srgb_weight: float, kind: str = "l1") -> torch.Tensor:
    """``l1``: L1 in linear sRGB plus ``srgb_weight`` x L1 in encoded sRGB; ``mse_srgb``: the squared error in
    encoded sRGB alone (what CPSNR scores, -10 log10 of it)."""
    if crop:
        out, target = out[..., crop:-crop, crop:-crop], target[..., crop:-crop, crop:-crop]
    diff = srgb_encode(out.clamp(0, 1)) - srgb_encode(target.clamp(0, 1))
    if kind == "mse_srgb":
        return (diff**2).mean()
    return (out - target).abs().mean() + srgb_weight * diff.abs().mean()


def validate(camera: DesignCamera, cfg: dict, source) -> dict:
    """Mean CPSNR (dB, sRGB) per light level on the held-out batches (hard mosaic, fixed noise)."""
    was = camera.training
    camera.eval()
    v = cfg["val"]
    device = next(camera.parameters()).device
    out = {}
    with torch.no_grad():
        for lux in cfg["lux"]:
            scores = []
            for b in range(int(v["batches"])):
                seed = int(cfg["seed"]) + int(v["seed_offset"])
                maps, refl = (t.to(device) for t in source(b, int(cfg["data"]["batch"]), int(cfg["data"]["size"]),
                                                          camera, cfg, seed, split="val"))
                scene = camera.scene(maps, refl, float(lux))
                g = torch.Generator(device=device).manual_seed(seed_for(seed, b, stream=round(1000 * float(lux))))
                pred = camera(scene, float(lux), generator=g)
                target = targets(maps, refl, camera)
                scores.append(common.cpsnr(srgb_encode(pred.clamp(0, 1)), srgb_encode(target.clamp(0, 1)),
                                           int(v["crop"])))
            out[f"{float(lux):g}"] = float(torch.cat(scores).mean())
    camera.train(was)
    return out


def draw_design(filters_ax, mosaic_ax, camera: DesignCamera, title: str | None = None) -> None:
    """Draw a design's filters (transmittance against wavelength) on ``filters_ax`` and its hard mosaic cell, in the
    same colours, on ``mosaic_ax`` (matplotlib axes)."""
    import numpy as np
    from matplotlib.colors import ListedColormap

    bank = camera.bank
    wl = bank.wavelengths_nm.numpy()
    f = bank.filters.detach().numpy()
    colours = []
    for i, name in enumerate(bank.channel_names):
        line, = filters_ax.plot(wl, f[i], label=name)
        colours.append(line.get_color())
    filters_ax.set_xlabel("wavelength (nm)")
    filters_ax.set_ylabel("transmittance")
    filters_ax.set_ylim(0, 1.02)
    filters_ax.legend(fontsize=7)
    filters_ax.grid(alpha=0.3)
    if title:
        filters_ax.set_title(title, fontsize=9)
    idx = camera.mosaic.index_map.numpy()
    mosaic_ax.imshow(idx, cmap=ListedColormap(colours), vmin=-0.5, vmax=len(colours) - 0.5)
    for (r, c), v in np.ndenumerate(idx):
        mosaic_ax.text(c, r, bank.channel_names[v], ha="center", va="center", fontsize=8, color="white")
    mosaic_ax.set_xticks([])
    mosaic_ax.set_yticks([])
    mosaic_ax.set_title("mosaic (one cell)", fontsize=9)


def plot_design(path: Path, camera: DesignCamera) -> None:
    """The filters and the hard mosaic cell (:func:`draw_design`) as a figure file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6), gridspec_kw={"width_ratios": [2, 1]})
    draw_design(a, b, camera)
    fig.suptitle(f"design {camera.name}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def train(cfg: dict, *, quiet: bool = False) -> dict:
    cfg = merged_config(cfg)
    if cfg["threads"]:
        torch.set_num_threads(int(cfg["threads"]))
    seed = int(cfg["seed"])
    torch.manual_seed(seed)
    if cfg["optim"]["loss"] not in LOSSES:
        raise ValueError(f"optim.loss: expected one of {LOSSES}, got {cfg['optim']['loss']!r}")
    source = SOURCES.get(cfg["data"]["source"])
    if source is None:
        raise ValueError(f"data.source: expected one of {sorted(SOURCES)}, got {cfg['data']['source']!r}")
    name = cfg["name"] or (cfg["design"] if isinstance(cfg["design"], str) else "learned")
    levels = [float(v) for v in cfg["lux"]]
    from isettorch.isp.evaluation import check_device

    device = check_device(cfg["device"])
    cfg["device"] = str(device)  # a torch.device given from Python: the config is written as JSON
    camera = make_design(cfg["design"], dict(cfg["camera"]), levels, seed=seed, name=name).train()
    out_dir = Path(cfg["out"])
    ck_path = out_dir / "checkpoint.pt"
    predesigned = None
    if int(cfg["predesign"]["steps"]) > 0:
        if not camera.bank.num_learned:
            raise ValueError("predesign.steps: only a design with learned filters can be predesigned")
        if not ck_path.exists():  # a resumed run's filters come from its checkpoint
            predesigned = predesign(camera, cfg, quiet=quiet)
    camera.to(device)
    o = cfg["optim"]
    # (optim.steps, data.batch, data.size: checked by merged_config; steps <= 0 were blamed on
    # design_warmup/design_until or failed with an IndexError, batch 0 in a reshape)
    steps = int(o["steps"])
    design_params = [p for n, p in camera.named_parameters() if p.requires_grad and not n.startswith("networks.")]
    groups = [{"params": list(camera.networks.parameters()), "lr": float(o["lr"])}]
    if design_params:
        groups.append({"params": design_params, "lr": float(o["design_lr"])})
    opt = torch.optim.Adam(groups)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=float(o["lr_min"]))
    m = cfg["mosaic"]
    anneal = max(1, round(float(m["anneal_fraction"]) * steps))
    # the networks alone first (a fraction of the steps): a design that adapts to an untrained network drifts to
    # what it can use early, the luminance (pilots at 1 lux: the mosaic collapsed to one broad filter)
    warmup = round(float(o["design_warmup"]) * steps)
    # ... and alone again at the end, on the frozen hard design (the sensor that would be built)
    until = round(float(o["design_until"]) * steps)
    if not 0 <= warmup <= until <= steps:
        raise ValueError(f"optim.design_warmup, optim.design_until: expected 0 <= warmup <= until <= 1, got "
                         f"{o['design_warmup']!r}, {o['design_until']!r}")
    # the levels whose steps move the design (None: every level); the networks learn at every level regardless
    design_lux = levels if o["design_lux"] is None else [float(v) for v in o["design_lux"]]
    if not design_lux or any(v not in levels for v in design_lux):
        raise ValueError(f"optim.design_lux: expected None or some of the levels {levels}, got {o['design_lux']!r}")
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, start, wall0 = [], 0, 0.0
    if ck_path.exists():  # resume: every step's data and noise depend only on (seed, step), so the run continues
        start, rows, wall0, predesigned = _resume(ck_path, cfg, camera, opt, sched, device)
        if not quiet:
            print(json.dumps({"resumed_at_step": start}), flush=True)
    t0 = time.time() - wall0
    b, size = int(cfg["data"]["batch"]), int(cfg["data"]["size"])
    ck_every = int(cfg["checkpoint_every"])
    for step in range(start, steps):
        lux = levels[step % len(levels)]
        if design_params:
            for p in design_params:
                p.requires_grad_(warmup <= step < until and lux in design_lux)
        if camera.mosaic.learnable:
            camera.mosaic.temperature = temperature_schedule(max(0, step - warmup), anneal,
                                                             float(m["temperature_start"]),
                                                             float(m["temperature_end"]))
            if step >= float(m["straight_through_after"]) * steps or step >= until:
                camera.mosaic.relax = "straight_through"  # the hard mosaic in the forward pass
        maps, refl = (t.to(device) for t in source(step, b, size, camera, cfg, seed))
        scene = camera.scene(maps, refl, lux)
        g = torch.Generator(device=device).manual_seed(seed_for(seed, step, stream=1))
        pred = camera(scene, lux, generator=g)
        loss = _loss(pred, targets(maps, refl, camera), int(cfg["loss_crop"]), float(o["srgb_weight"]), o["loss"])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        row = {"step": step + 1, "lux": lux, "loss": float(loss.detach()), "temperature": camera.mosaic.temperature,
               "seconds": round(time.time() - t0, 2)}
        every = int(cfg["val"]["every"])
        if (every and (step + 1) % every == 0) or step + 1 == steps:
            for key, v in validate(camera, cfg, source).items():
                row[f"val_cpsnr_{key}"] = v
            if not quiet:
                print(json.dumps(row), flush=True)
        rows.append(row)
        if ck_every and (step + 1) % ck_every == 0 and step + 1 < steps:
            _save_checkpoint(ck_path, cfg, camera, opt, sched, step + 1, rows, time.time() - t0, predesigned)
    camera.cpu().eval()  # the design file and figures are written from the CPU
    if camera.bank.learnable:
        camera.bank.freeze()
    final = {k[len("val_cpsnr_"):]: v for k, v in rows[-1].items() if k.startswith("val_cpsnr_")}
    camera.config["training"] = {"steps": steps, "batch": b, "size": size, "source": cfg["data"]["source"],
                                 "seed": seed, "lux": levels, "lr": float(o["lr"]), "design_lr": float(o["design_lr"]),
                                 "design_steps": [warmup, until] if design_params else None,
                                 "predesign": predesigned,
                                 "minutes": round((time.time() - t0) / 60, 2)}
    card = design_card(camera) + "\nHeld-out training-distribution scenes (sRGB CPSNR, dB): " + ", ".join(
        f"{k} lux {v:.2f}" for k, v in final.items()) + "\n"
    path = save_design(camera, out_dir / "design.pt", card=card)
    (out_dir / "card.md").write_text(card)
    common.write_csv(out_dir / "history.csv", rows)
    val_keys = [(f"val_cpsnr_{float(v):g}", f"CPSNR {float(v):g} lux (dB)") for v in levels]
    common.plot_curves(out_dir / "curves.png", rows, [("loss", "loss"), *val_keys], f"codesign {name}")
    plot_design(out_dir / "filters.png", camera)
    record = {"design": name, "path": str(path), "val_cpsnr": final, "steps": steps,
              "seconds": round(time.time() - t0, 1), "mosaic": camera.mosaic.cell,
              "hardware": common.hardware(), "config": cfg}
    (out_dir / "record.json").write_text(json.dumps(record, indent=2))
    if ck_path.exists():
        ck_path.unlink()  # the design file is the run's result; a finished run starts afresh if run again
    return record


def _save_checkpoint(path: Path, cfg: dict, camera: DesignCamera, opt, sched, step: int, rows: list,
                     wall_s: float, predesigned: dict | None = None) -> None:
    """The run's state after ``step`` steps (camera with filters, mosaic logits and networks, optimiser, schedule,
    history, the predesign's record), written atomically (a temporary file renamed)."""
    common.save_atomic({"config": json.dumps(cfg, sort_keys=True), "step": step, "camera": camera.state_dict(),
                        "optimizer": opt.state_dict(), "scheduler": sched.state_dict(), "history": json.dumps(rows),
                        "wall_s": wall_s, "predesign": json.dumps(predesigned)}, path)


def _resume(path: Path, cfg: dict, camera: DesignCamera, opt, sched, device) -> tuple[int, list, float, dict | None]:
    """Load a checkpoint of the same config (on any device) into ``camera``, ``opt`` and ``sched`` on ``device``:
    (next step, history, wall s, the predesign's record)."""
    ck = torch.load(path, weights_only=True, map_location=device)
    changed = common.config_changes(json.loads(ck["config"]), cfg, ("device",))  # the same run on any device
    if changed:
        raise ValueError(f"out: {path} is a checkpoint of another config ({', '.join(changed)} changed); remove it "
                         f"or choose another out folder")
    camera.load_state_dict(ck["camera"])
    opt.load_state_dict(ck["optimizer"])
    sched.load_state_dict(ck["scheduler"])
    return int(ck["step"]), json.loads(ck["history"]), float(ck["wall_s"]), json.loads(ck.get("predesign", "null"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True, help="YAML config (configs/train/codesign_*.yaml)")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="overrides, e.g. optim.steps=10")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    record = train(common.load_config(args.config, args.set), quiet=args.quiet)
    print(json.dumps({k: record[k] for k in ("design", "path", "val_cpsnr", "steps", "seconds")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
