"""Train the compact demosaic CNN (:class:`isettorch.isp.learned.DemosaicNet`) on synthetic scenes made on the fly.

Data come only from the library: ``data.source: natural`` (default; :mod:`isettorch.data.natural`, the
natural-statistics generator, components switched off with ``data.disable: [name, ...]``, its scenes rendered by
:class:`isettorch.data.camera_pairs.CameraPairDataset` through the library's Camera: :class:`ScenePool`),
``isettorch``
(:func:`isettorch.data.generate_scene`) or ``camera_pairs`` (below). ``data.domain`` (``linear``, ``encoded`` or
``mixed`` with ``data.encoded_fraction``) is the training domain: Kodak/McMaster are 8-bit encoded sRGB mosaics
scored as linear, so a linear-domain model and an encoded-domain model are different models.

Usage::

    python training/train_demosaic.py --config configs/train/demosaic_noise_free.yaml [--out DIR] [--steps N]
    torchrun --nproc_per_node 2 training/train_demosaic.py --config ...   # DistributedDataParallel (gloo on CPU)

Every batch depends only on (seed, step, rank), so a run resumes exactly from its last checkpoint
(``--resume``, or automatically when ``out/last.pt`` exists). Validation uses held-out synthetic scenes (their
own seeds, never drawn for training); the model with the best validation CPSNR is kept as ``best.pt``. Kodak and
McMaster are scored only for reporting (``eval.benchmarks``), never for selection. Checkpoints are read with
``torch.load(weights_only=True)``. Outputs: ``last.pt``, ``best.pt``, ``history.csv``, ``curves.png``,
``record.json``.

The joint denoise+demosaic variant (``noise.enabled: true``) adds heteroscedastic sensor noise at a random gain
per image: ``var = a * x + b`` (Poisson shot noise of ``x / a`` electrons plus Gaussian read noise, the
photon-transfer model of EMVA 1288), with ``a = gain / full_well_e`` and ``b = (read_noise_e * a)^2``;
``(sqrt(a), sqrt(b))`` are given to the network as two extra input planes. With dark current, DSNU, PRNU or
``bits`` set, the noise is drawn by one :class:`isettorch.sensor.Sensor` with per-image levels (:func:`add_noise`).

``data.source: stream`` (with ``data.device``, default the training device) draws the same kind of batches from
:class:`isettorch.data.PairStream`, generated and rendered on that device (:class:`StreamSource`); with
``data.camera_config`` (a camera YAML, e.g. with a sensor calibrated by ``isettorch calibrate``) every pair is
rendered through that one camera instead of drawn cameras: camera-specific denoising
(``configs/train/demosaic_camera_specific.yaml``, docs/camera_specific_denoising.md). ``data.stream_chunk``
training batches are rendered at once (default 4 on a CPU, 64 on an accelerator; :class:`StreamSource`).

``data.source: camera_pairs`` draws batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` instead
(scene -> diffraction-limited optics -> the isettorch sensor with its own noise model; ``data.scene`` /
``data.camera`` are passed to the dataset). Input: the noisy quantised raw mosaic (``noise.enabled: true``, the
joint variant) or ``noise_free_raw`` (noise-free variant); target: ``camera_rgb``; all in normalised raw units
(0 = black, 1 = white level; camera RGB, not white-balanced). Noise inputs from each item's metadata: the dataset's
Poisson-Gaussian model ``var = a x + b`` in normalised units (Foi et al., IEEE TIP 2008) has
``a = meta['noise_gain']`` (normalised units per electron, so shot noise gives ``a x``) and
``b = meta['noise_floor_var']`` (the capturing sensor's ``Sensor.poisson_gaussian``: read noise, DSNU, dark
current, row/column noise and, for a DN readout, quantisation); PRNU (multiplicative,
< 1.5 %) is left out of the model. Items are rendered ``patch + 2`` pixels wide and cropped at the offset that
puts an R pixel top-left, so every Bayer order the dataset draws reaches the network as RGGB.

``distill: {teacher: CKPT, weight: w, self_ensemble: true}`` trains towards ``(1 - w) * target + w * teacher``,
where ``teacher`` is a trained checkpoint's output on the same mosaic (:func:`distill_target`; knowledge
distillation, Hinton, Vinyals & Dean 2015). With ``self_ensemble`` the teacher's output is its geometric
self-ensemble (:func:`isettorch.isp.learned.demosaic_learned`, the mean over the mosaic and its transpose), so a
one-pass student is taught the two-pass network's exactly transpose-equivariant output; ``self_ensemble: dihedral``
teaches the eight-pass ensemble over flips and transposes.

``expand: M`` trains every convolution as a collapsible pair (a convolution into ``M`` channels and a 1 x 1 back,
:mod:`training.expand`): the same network at inference and in the checkpoint's ``model`` (the collapsed weights),
another optimisation; the factors are kept in the checkpoint's ``model_expanded`` for ``--resume``.

The trainer's parts: :mod:`training.demosaic_data` (scene pool and bank, batches), :mod:`training.demosaic_pairs`
(camera-pair and stream sources), :mod:`training.demosaic_noise` (sensor noise) and
:mod:`training.demosaic_checkpoints` (checkpoints, distillation teacher, model card); their names are importable
from this module too.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._progress import add_quiet_argument  # noqa: E402
from isettorch._progress import progress as progress_bar  # noqa: E402
from isettorch.isp.demosaicing import demosaic_malvar2004  # noqa: E402
from isettorch.isp.learned import DemosaicNet  # noqa: E402
from isettorch.paths import data_path  # noqa: E402
from training import common  # noqa: E402
from training.demosaic_checkpoints import (  # noqa: E402, F401  (re-exported: the trainer's public names)
    describe_data,
    distill_target,
    init_state,
    load_teacher,
    save_checkpoint,
    write_model_card,
)
from training.demosaic_config import check_config  # noqa: E402
from training.demosaic_data import (  # noqa: E402, F401
    BANK_CHUNK,
    COLOUR_SPACES,
    POOL_CAMERA,
    SOURCES,
    SceneBank,
    ScenePool,
    augment_flips,
    make_batch,
    make_sampler,
    mosaic_rggb,
)
from training.demosaic_noise import add_noise, gaussian_params, noise_features, noise_params  # noqa: E402, F401
from training.demosaic_pairs import TEST_SEED_OFFSET, CameraPairSource, StreamSource, pair_batch, rggb_offset  # noqa: E402, F401
from training.expand import expand_convolutions  # noqa: E402

VAL_SEED_OFFSET = 1_000_003_000  # validation scenes use seeds far from any training (seed, step, rank)
LOG_EVERY = 10  # steps between reads of the loss for the progress bar (a host read synchronises the device)
#: training arithmetic: float32, or bfloat16 autocast for the network's body (``optim.precision``; the MHC base,
#: the loss and the weights stay float32, validation and benchmarks run in float32). On a CPU with AVX-512 BF16
#: a 64 x 8 step of 12 x 80^2 took 98 ms against 188 ms float32 (2 threads, 2026-11-26).
PRECISIONS = ("fp32", "bf16")


def make_validation(cfg: dict) -> list:
    """Held-out synthetic validation batches: scenes of their own seed (never drawn in training), whole scenes of
    ``val.size`` pixels, the training domain and noise; never Kodak/McMaster."""
    v = cfg.get("val", {})
    size = int(v.get("size", 128))
    vcfg = json.loads(json.dumps(cfg))
    vcfg["data"] = dict(cfg.get("data", {}), patch=size, hard_mining=0)
    vcfg["data"]["scene_size"] = size
    vseed = int(cfg.get("seed", 0)) + VAL_SEED_OFFSET
    n, bs = int(v.get("images", 32)), 8
    sampler = make_sampler(vcfg, VAL_SEED_OFFSET, seed=vseed, scene_size=size, batch=bs)
    if isinstance(sampler, StreamSource):  # whole batches of bs on the stream (the last one cut to n)
        return [tuple(None if x is None else x[:min(bs, n - i)] for x in make_batch(sampler, vcfg, vseed, bs, i // bs))
                for i in range(0, n, bs)]
    if isinstance(sampler, ScenePool):
        # each batch of bs images from a pool of bs scenes of its own, drawn with replacement: repeats within a
        # batch (19 distinct scenes of 32 images at the shipped config; "every image a different scene" was claimed),
        # kept as it is so that the recorded runs' validation stays reproducible
        sampler.pool_size, sampler.refresh = bs, bs // 1
    return [make_batch(sampler, vcfg, vseed + i, min(bs, n - i), i // bs) for i in range(0, n, bs)]


@torch.no_grad()
def validate(net: torch.nn.Module, val: list, device) -> dict:
    net.eval()
    ps, pm = [], []
    for raw, rgb, feats in val:
        raw, rgb = raw.to(device), rgb.to(device)
        out = net(raw, None if feats is None else feats.to(device))
        ps.append(common.cpsnr(out, rgb, crop=4))
        pm.append(common.cpsnr(demosaic_malvar2004(raw), rgb, crop=4))
    net.train()
    v, m = float(torch.cat(ps).mean()), float(torch.cat(pm).mean())
    return {"val_cpsnr": v, "val_cpsnr_mhc": m, "val_gain_db": v - m}


@torch.no_grad()
def benchmark(net: torch.nn.Module, folder: str, device, crop: int = 10, limit: int | None = None) -> float:
    """Mean CPSNR on a benchmark folder with ``isettorch demosaic-eval``'s code (RGGB, noise-free, clip, crop;
    a noise-input network gets zero noise); reporting only."""
    from isettorch.isp.evaluation import evaluate_demosaic, load_images

    net.eval()
    items = load_images(folder)[:limit]
    res = evaluate_demosaic(items, "learned", "RGGB", crop, model=net, device=device)
    net.train()
    return res["mean_cpsnr"]


def progress(step: int, wall_s: float, cfg: dict) -> float:
    """Fraction of the run done: by steps, or by wall time when ``optim.time_budget_s`` is set (whichever first)."""
    o = cfg["optim"]
    t = step / max(1, int(o["steps"]))
    budget = float(o.get("time_budget_s", 0) or 0)
    return max(t, wall_s / budget) if budget > 0 else t


# what a resumed run may change: how long it runs, where and how it reports, its threads (the rest is the run)
RESUMABLE_KEYS = ("out", "threads", "checkpoint_every", "eval", "optim.steps", "optim.time_budget_s")


def resume_changes(old: dict, new: dict) -> list[str]:
    """The dotted keys of the config that differ between a checkpoint's run (``old``) and this one, except
    :data:`RESUMABLE_KEYS`."""
    return common.config_changes(old, new, RESUMABLE_KEYS)


def lr_at(step: int, frac: float, cfg: dict) -> float:
    o = cfg["optim"]
    warm = int(o.get("warmup", 50))
    lr, lr_min = float(o["lr"]), float(o.get("lr_min", 1e-5))
    if step < warm:
        return lr * (step + 1) / warm
    t = min(1.0, frac)
    return lr_min + 0.5 * (lr - lr_min) * (1 + math.cos(math.pi * t))  # cosine decay (Loshchilov & Hutter 2017)


class AdaptiveGradClip:
    """``optim.clip_grad_factor: k`` (> 0): scale the gradient down to ``k`` times the running mean (EMA, 0.99) of
    the earlier steps' clipped gradient norms when its norm exceeds that, so one outlier batch cannot throw Adam off
    (a residual 64 x 13 at lr 1e-3 lost 4 dB of validation CPSNR in one such step). Scale-free: no absolute norm to
    tune. ``state`` goes into the checkpoint, so a resumed run clips exactly as the uninterrupted one."""

    def __init__(self, factor: float, state: dict | None = None):
        if factor < 0:
            raise ValueError(f"optim.clip_grad_factor: expected >= 0 (0 = off), got {factor}")
        self.factor, self.ema = float(factor), (state or {}).get("ema")

    def state(self) -> dict:
        return {"ema": self.ema}

    def __call__(self, params) -> float:
        """Clip the gradients of ``params`` in place; returns the norm before clipping."""
        params = [p for p in params if p.grad is not None]
        norm = float(torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(p.grad) for p in params])))
        if not math.isfinite(norm):  # (a NaN made the EMA NaN, clipping off for good, and Adam's weights NaN)
            raise FloatingPointError(f"the gradient's norm is {norm}: the step would corrupt the weights (the last "
                                     f"checkpoint holds the run before it)")
        if not self.factor:
            return norm
        limit = math.inf if self.ema is None else self.factor * self.ema
        if norm > limit:
            for p in params:
                p.grad.mul_(limit / norm)
        kept = min(norm, limit)
        self.ema = kept if self.ema is None else 0.99 * self.ema + 0.01 * kept
        return norm


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--out", default=None, help="output folder (default: config 'out')")
    ap.add_argument("--steps", type=int, default=None, help="override optim.steps")
    ap.add_argument("--resume", default=None, help="checkpoint to resume from (default: OUT/last.pt if present)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads per process")
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    ap.add_argument("--set", nargs="*", default=[], help="config overrides key.sub=value")
    ap.add_argument("--stop-after", type=int, default=None,
                    help="stop (with a checkpoint) after this many steps in this invocation; resume later")
    add_quiet_argument(ap, "--no-progress")
    args = ap.parse_args(argv)
    if args.stop_after is not None and args.stop_after < 1:  # (0 ran the whole run, -2 did nothing with exit 0)
        raise SystemExit(f"--stop-after: expected a number of steps >= 1, got {args.stop_after}")
    cfg = common.load_config(args.config, args.set)
    if args.steps is not None:
        cfg.setdefault("optim", {})["steps"] = args.steps
    check_config(cfg)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    rank, world, is_dist = common.dist_setup(device)
    # the reporting folders, which rank 0 scores, found before anything runs, not when the first row falls due (step
    # 10000, or the end of a 6000 s run, died on an unset $ISETTORCH_DATA)
    bench_every = int(cfg.get("eval", {}).get("every", 0))
    bench = {name: data_path(folder) for name, folder in (cfg.get("eval", {}).get("benchmarks") or {}).items()
             } if bench_every and rank == 0 else {}
    threads = args.threads or int(cfg.get("threads", 0))
    if threads:
        torch.set_num_threads(threads)
    if device.type == "cuda" and is_dist:
        local, n_gpu = int(os.environ.get("LOCAL_RANK", rank)), torch.cuda.device_count()
        if local >= n_gpu:  # NCCL cannot share one GPU between processes
            raise ValueError(f"--device cuda: torchrun started {world} processes, each needs a GPU of its own and "
                             f"this node has {n_gpu}; use --device cpu or --nproc_per_node {n_gpu}")
        device = torch.device("cuda", local)
    out = Path(args.out or cfg.get("out", "out/train_demosaic"))
    out.mkdir(parents=True, exist_ok=True)
    seed = int(cfg.get("seed", 0))

    net_cfg = dict(cfg.get("net", {}))
    if cfg.get("noise", {}).get("enabled", False):
        net_cfg["noise_inputs"] = 2
    torch.manual_seed(seed)  # identical initial weights on every rank
    net = DemosaicNet(**net_cfg).to(device)
    precision = str(cfg["optim"].get("precision", "fp32"))
    if precision not in PRECISIONS:
        raise ValueError(f"optim.precision: expected one of {PRECISIONS}, got {precision!r}")
    if precision == "bf16":  # oneDNN's bfloat16 convolutions are fastest on channels-last weights
        net = net.to(memory_format=torch.channels_last)
        if device.type == "cpu" and rank == 0 and "AVX512" not in torch.backends.cpu.get_cpu_capability():
            # measured on a 2-core AVX2 machine (64 x 13 residual network, batch 16, 80 px): 7.5 s per step in
            # bfloat16 against 0.55 s in float32 (no native bfloat16 arithmetic: oneDNN emulates it)
            print(f"warning: optim.precision bf16 on a CPU without AVX-512 ({torch.backends.cpu.get_cpu_capability()})"
                  f" runs about 14x slower than fp32 here; set optim.precision: fp32", file=sys.stderr, flush=True)
    step, best, history, wall0 = 0, -math.inf, [], 0.0
    clip_state, run_loss0, run_n0 = None, 0.0, 0
    resume = Path(args.resume) if args.resume else out / "last.pt"
    init = cfg.get("init")
    if init and not resume.is_file():  # start from another checkpoint's weights (fresh optimizer and schedule)
        if not Path(init).is_file():
            raise SystemExit(f"init: no such checkpoint {str(init)!r} (from {Path.cwd()}; the paths in "
                             f"configs/train are relative to the repository root: run from there)")
        ck = torch.load(init, map_location="cpu", weights_only=True)
        net.load_state_dict(init_state(ck, net, str(init)))
        if rank == 0:
            print(f"initialised from {init}", flush=True)
    if cfg.get("expand"):  # train the convolutions as collapsible pairs (training/expand.py), from the weights above
        expand_convolutions(net, cfg["expand"])
    opt = torch.optim.Adam(net.parameters(), lr=float(cfg["optim"]["lr"]))
    if resume.is_file():
        ck = torch.load(resume, map_location="cpu", weights_only=True)
        changed = resume_changes(json.loads(ck["train_config"]), cfg)
        if changed:  # (a new seed, lr, loss or data ran on, the two runs' histories and best scores mixed; a new
            # network's shape was a raw load_state_dict size mismatch, before this check)
            raise SystemExit(f"--resume: {resume} is a checkpoint of another config ({', '.join(changed)} changed); "
                             f"start a new out folder, or begin from its weights with init: {resume}")
        if cfg.get("expand") and "model_expanded" not in ck:
            raise ValueError(f"--resume: {resume} holds no expanded weights (model_expanded) for this run's "
                             f"expand: {cfg['expand']}")
        net.load_state_dict(ck["model_expanded"] if cfg.get("expand") else ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step, best = int(ck["step"]), float(ck["best_val_cpsnr"])
        history, wall0 = json.loads(ck["history"]), float(ck.get("wall_s", 0.0))
        clip_state = json.loads(ck.get("grad_clip", "{}"))
        run_loss0, run_n0 = ck.get("running_loss", (0.0, 0))
        if rank == 0:
            print(f"resumed from {resume} at step {step}", flush=True)
    clip = AdaptiveGradClip(float(cfg["optim"].get("clip_grad_factor", 0.0) or 0.0), clip_state)
    model = net
    if is_dist:
        model = torch.nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda"
                                                          else None)

    # each rank renders its own scenes; data.scene_seed (default: the run's seed) lets runs share scenes (a bank)
    scene_seed = int(cfg.get("data", {}).get("scene_seed", seed))
    # make_validation's scene pool (its seed plus the sampler's offset) must not be a rank's training pool
    if 0 <= int(cfg.get("seed", 0)) + 2 * VAL_SEED_OFFSET - scene_seed * 1_000_003 < world:
        raise SystemExit(f"data.scene_seed: {scene_seed} draws the validation scenes of seed {cfg.get('seed', 0)} "
                         f"for training; choose another")
    images = int(cfg["data"].get("batch", 16))
    batch = images // world  # each process's share
    if images % world:  # (each process's batch // world was 0: an empty torch.stack; 10 over 4 trained 8 a step)
        raise SystemExit(f"data.batch: {images} images do not split evenly over {world} processes (each would train "
                         f"{batch}, {batch * world} a step); expected a multiple of {world}")
    sampler = make_sampler(cfg, seed=scene_seed * 1_000_003 + rank, progress=rank == 0 and not args.quiet,
                           device=device, batch=batch)
    val = make_validation(cfg) if rank == 0 else None
    teacher, distill_w, distill_ens = load_teacher(cfg, device)
    total = int(cfg["optim"]["steps"])
    loss_kind = cfg["optim"].get("loss", "l2")
    val_every = int(cfg.get("val", {}).get("every", 200))
    ckpt_every = int(cfg.get("checkpoint_every", 100))
    t_start = time.time()
    # the bar on stderr (rank 0 only); the validation rows go to stdout through pbar.write (kept under --quiet)
    pbar = progress_bar(total=total, initial=step, desc="train", unit="step", quiet=rank != 0 or args.quiet)
    run_loss, run_n = float(run_loss0), int(run_n0)  # (a resumed run's first row averages the steps before the stop)
    frac = progress(step, wall0, cfg)
    stop_at = step + args.stop_after if args.stop_after else None
    while frac < 1.0 and (stop_at is None or step < stop_at):
        lr = lr_at(step, frac, cfg)
        for grp in opt.param_groups:
            grp["lr"] = lr
        raw, rgb, feats = make_batch(sampler, cfg, seed * 1_000_003 + step * 1009 + rank, batch, step)
        raw, rgb = raw.to(device), rgb.to(device)
        if teacher is not None:  # the teacher in the run's precision: its bf16 outputs differ from float32 by an
            # MSE of 1.3e-7 on held-out v5 scenes, 1/55 of the one-pass - ensemble MSE the student is taught (7.2e-6)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
                rgb = distill_target(raw, rgb, None if feats is None else feats.to(device), teacher, distill_w,
                                     distill_ens)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
            outp = model(raw, None if feats is None else feats.to(device))
        outp = outp.float()
        loss = F.l1_loss(outp, rgb) if loss_kind == "l1" else F.mse_loss(outp, rgb)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        clip(net.parameters())
        opt.step()
        step += 1
        run_loss = run_loss + loss.detach()  # on the device: read back only when logging (no sync per step)
        run_n += 1
        pbar.update(1)
        if step % LOG_EVERY == 0:
            pbar.set_postfix(loss=f"{loss.item():.4f}", lr=f"{lr:.1e}")
        frac = progress(step, wall0 + time.time() - t_start, cfg)
        if is_dist:  # every rank stops at the same step
            import torch.distributed as dist

            f = torch.tensor([frac], dtype=torch.float64)
            dist.all_reduce(f, op=dist.ReduceOp.MAX)
            frac = float(f)
        last = frac >= 1.0
        # a --stop-after stop checkpoints without a validation row of its own: a row there made best.pt's choice
        # (and the history) differ from an uninterrupted run's
        stopping = step == stop_at
        if rank == 0 and (step % val_every == 0 or last):
            row = {"step": step, "wall_s": round(wall0 + time.time() - t_start, 1), "lr": lr,
                   "train_loss": float(run_loss) / max(run_n, 1)}
            run_loss, run_n = 0.0, 0
            row.update(validate(net, val, device))
            if bench and bench_every and (step % bench_every == 0 or last):
                for name, folder in bench.items():
                    row[f"{name}_crop10"] = benchmark(net, folder, device)
            history.append(row)
            msg = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
            pbar.write(msg, file=sys.stdout)
            if row["val_cpsnr"] > best:
                best = row["val_cpsnr"]
                save_checkpoint(out / "best.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start,
                                clip)
            common.write_csv(out / "history.csv", history)
            cols = [("train_loss", f"train {loss_kind} loss"), ("val_cpsnr", "val CPSNR (dB)"),
                    ("val_gain_db", "val CPSNR - MHC (dB)")]
            cols += [(f"{k}_crop10", f"{k} CPSNR crop10 (dB)") for k in bench if any(f"{k}_crop10" in r
                                                                                   for r in history)]
            common.plot_curves(out / "curves.png", history, cols, f"DemosaicNet {net.config()}")
        if rank == 0 and (step % ckpt_every == 0 or last or stopping):
            save_checkpoint(out / "last.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start,
                            clip, (float(run_loss), run_n))
    pbar.close()
    if rank == 0 and frac >= 1.0:  # a --stop-after stop is no finished run: its record's final row was an earlier step
        record = {"command": " ".join(["python training/train_demosaic.py", *sys.argv[1:]]) if argv is None else argv,
                  "config": cfg, "world_size": world, "steps": step, "best_val_cpsnr": best,
                  "wall_s": round(wall0 + time.time() - t_start, 1), "hardware": common.hardware(),
                  "final": history[-1] if history else {}}
        record["data"] = describe_data(cfg)
        (out / "record.json").write_text(json.dumps(record, indent=2, default=str))
        write_model_card(out / "MODEL_CARD.md", record, net)
    common.dist_cleanup(is_dist)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
