"""Train the compact demosaic CNN (:class:`isettorch.isp.learned.DemosaicNet`) on synthetic scenes made on the fly.

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
``(sqrt(a), sqrt(b))`` are given to the network as two extra input planes.

``data.source: camera_pairs`` draws batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` instead
(scene -> diffraction-limited optics -> the isettorch sensor with its own noise model; ``data.scene`` /
``data.camera`` are passed to the dataset). Input: the noisy quantised raw mosaic (``noise.enabled: true``, the
joint variant) or ``noise_free_raw`` (noise-free variant); target: ``camera_rgb``; all in normalised raw units
(0 = black, 1 = white level; camera RGB, not white-balanced). Noise inputs from each item's metadata: the dataset's
Poisson-Gaussian model ``var = a x + b`` in normalised units (Foi et al., IEEE TIP 2008) has
``a = meta['noise_gain']`` (normalised units per electron, so shot noise gives ``a x``) and
``b = meta['noise_floor_var']`` (read noise, DSNU, dark current and quantisation); PRNU (multiplicative,
< 1.5 %) is left out of the model. Items are rendered ``patch + 2`` pixels wide and cropped at the offset that
puts an R pixel top-left, so every Bayer order the dataset draws reaches the network as RGGB.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.isp import learned  # noqa: E402
from isettorch.isp.learned import DemosaicNet, demosaic_malvar_torch  # noqa: E402
from training import common  # noqa: E402
from training.synth import IsetScenePool, SceneSampler, augment_flips, encode, mosaic_rggb  # noqa: E402

VAL_SEED_OFFSET = 1_000_003_000  # validation scenes use seeds far from any training (seed, step, rank)


SOURCES = ("synth", "isettorch", "mix", "camera_pairs")
TEST_SEED_OFFSET = 2_000_006_000  # held-out camera-pair items for evaluation (dataset seed = seed + this)


def rggb_offset(index_map: torch.Tensor) -> tuple[int, int]:
    """(dy, dx) of the R pixel (channel 0) in a 2x2 Bayer cell ``index_map`` (R, G, B = 0, 1, 2)."""
    im = index_map.tolist()
    for dy in (0, 1):
        for dx in (0, 1):
            if im[dy][dx] == 0 and im[1 - dy][1 - dx] == 2:
                return dy, dx
    raise ValueError(f"cfa: expected a 2x2 Bayer cell (R, G, G, B), got {im}")


class CameraPairSource:
    """Training batches from :class:`isettorch.data.camera_pairs.CameraPairDataset` (source ``camera_pairs``).

    ``batch(batch_seed, n)`` renders items ``batch_seed * n + i`` (i < n) of one dataset (seed ``cfg.seed +
    seed_offset``), so a batch depends only on (seed, step, rank) like the other sources, and crops each to
    ``patch x patch`` RGGB. Returns (raw [B,1,P,P], camera_rgb [B,3,P,P], noise features [B,2] or None).
    """

    LENGTH = 2**62

    def __init__(self, cfg: dict, seed_offset: int = 0):
        from isettorch.data.camera_pairs import CameraPairDataset
        from isettorch.data.config import CAMERA_DEFAULTS
        from isettorch.isp.learned import BAYER_PATTERNS

        d = cfg.get("data", {})
        self.patch = int(d.get("patch", 80))
        if self.patch < 4 or self.patch % 2:
            raise ValueError(f"data.patch: expected an even size >= 4, got {self.patch}")
        self.noisy = bool(cfg.get("noise", {}).get("enabled", False))
        scene = dict(d.get("scene") or {}, height=self.patch + 2, width=self.patch + 2)
        camera = dict(d.get("camera") or {})
        pats = camera.get("cfa_patterns", CAMERA_DEFAULTS["cfa_patterns"])
        bad = [p for p in pats if str(p).upper() not in BAYER_PATTERNS]
        if bad:
            raise ValueError(f"data.camera.cfa_patterns: expected Bayer patterns {BAYER_PATTERNS}, got {bad}")
        # only the targets demosaicking uses: no colour targets, so 3 spectral projections instead of 6
        self.ds = CameraPairDataset(self.LENGTH, seed=int(cfg.get("seed", 0)) + int(seed_offset), scene=scene,
                                    camera=camera, targets=("noise_free_raw", "camera_rgb"))

    def indices(self, batch_seed: int, n: int) -> list[int]:
        return [(int(batch_seed) * n + i) % self.LENGTH for i in range(n)]

    def batch(self, batch_seed: int, n: int):
        return pair_batch(self.ds.get_batch(self.indices(batch_seed, n)), self.patch, self.noisy)


def pair_batch(b: dict, patch: int, noisy: bool):
    """(raw, camera_rgb, noise features or None) cropped to ``patch`` RGGB from a camera-pair batch.

    Noise features: ``noise_features((a, b))`` with ``a = meta['noise_gain']``, ``b = meta['noise_floor_var']``
    (``var = a x + b`` in normalised units, the dataset's Poisson-Gaussian model)."""
    src = b["raw"] if noisy else b["noise_free_raw"]
    raws, rgbs = [], []
    for i in range(src.shape[0]):
        dy, dx = rggb_offset(b["meta"]["cfa"][i])
        raws.append(src[i, :, dy:dy + patch, dx:dx + patch])
        rgbs.append(b["camera_rgb"][i, :, dy:dy + patch, dx:dx + patch])
    feats = None
    if noisy:
        ab = torch.stack([b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]], 1).float()
        feats = noise_features(ab)
    return torch.stack(raws).float(), torch.stack(rgbs).float(), feats


def make_sampler(cfg: dict, seed_offset: int = 0) -> SceneSampler | CameraPairSource:
    d = cfg.get("data", {})
    source = d.get("source", "synth")
    if source not in SOURCES:
        raise ValueError(f"data.source: expected one of {SOURCES}, got {source!r}")
    if source == "camera_pairs":
        return CameraPairSource(cfg, seed_offset)
    return SceneSampler(size=int(d.get("patch", 96)), n_shapes=int(d.get("n_shapes", 50)),
                        sensitivities=d.get("sensitivities", "all"))


def make_pool(sampler: SceneSampler, cfg: dict, seed: int) -> IsetScenePool | None:
    """The isettorch.data scene pool for sources 'isettorch' and 'mix' (None for 'synth')."""
    d = cfg.get("data", {})
    if d.get("source", "synth") in ("synth", "camera_pairs"):
        return None
    return IsetScenePool(sampler, seed=seed, scene_size=int(d.get("scene_size", 128)),
                         pool=int(d.get("pool", 64)), refresh=int(d.get("refresh", 2)),
                         config=d.get("scene_config"))


def iset_count(cfg: dict, batch: int) -> int:
    d = cfg.get("data", {})
    src = d.get("source", "synth")
    if src == "synth":
        return 0
    if src == "isettorch":
        return batch
    return int(round(batch * float(d.get("iset_fraction", 0.5))))


def noise_params(batch: int, cfg: dict, g: torch.Generator) -> torch.Tensor:
    """[B, 2] (a, b) of ``var = a x + b`` at log-uniform random gains (x relative to white = 1)."""
    n = cfg["noise"]
    lo, hi = float(n.get("gain_min", 1.0)), float(n.get("gain_max", 32.0))
    gain = lo * (hi / lo) ** torch.rand(batch, generator=g)
    a = gain / float(n.get("full_well_e", 10000.0))
    b = (float(n.get("read_noise_e", 3.0)) * a) ** 2
    return torch.stack([a, b], 1)


def add_noise(raw: torch.Tensor, ab: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """Poisson-Gaussian noise, Gaussian approximation var = a x + b (EMVA 1288 photon transfer)."""
    var = ab[:, 0, None, None, None] * raw.clamp_min(0) + ab[:, 1, None, None, None]
    return raw + var.sqrt() * torch.randn(raw.shape, generator=g)


def noise_features(ab: torch.Tensor) -> torch.Tensor:
    return learned.noise_features(ab[:, 0], ab[:, 1]).to(ab.dtype)


def make_batch(sampler: SceneSampler, cfg: dict, seed: int, batch: int, p_gamma: float,
               pool: IsetScenePool | None = None, step: int = 0):
    """(raw [B,1,H,W], target [B,3,H,W], noise features [B,2] or None) for one (seed, step)."""
    if isinstance(sampler, CameraPairSource):
        return sampler.batch(seed, batch)
    g = torch.Generator().manual_seed(int(seed))
    n_iset = iset_count(cfg, batch) if pool is not None else 0
    parts = [sampler.sample(batch - n_iset, g)] if batch - n_iset else []
    if n_iset:
        parts.append(pool.sample(n_iset, step, g))
    rgb = encode(torch.cat(parts), g, p_gamma=p_gamma)
    rgb = augment_flips(rgb, g)
    raw = mosaic_rggb(rgb)
    feats = None
    if cfg.get("noise", {}).get("enabled", False):
        ab = noise_params(batch, cfg, g)
        raw = add_noise(raw, ab, g)
        feats = noise_features(ab)
    return raw, rgb, feats


def make_validation(sampler_cfg: dict, cfg: dict) -> list:
    v = cfg.get("val", {})
    vcfg = dict(sampler_cfg)
    vcfg["data"] = dict(cfg.get("data", {}), patch=int(v.get("size", 128)))
    vcfg["data"]["scene_size"] = max(int(v.get("size", 128)), int(vcfg["data"].get("scene_size", 128)))
    sampler = make_sampler(vcfg, VAL_SEED_OFFSET)  # camera_pairs: its own dataset seed
    vseed = int(cfg.get("seed", 0)) + VAL_SEED_OFFSET
    pool = make_pool(sampler, vcfg, vseed)  # held-out isettorch scenes: their own seed
    n, bs = int(v.get("images", 32)), 8
    return [make_batch(sampler, vcfg, vseed + i, bs, float(cfg.get("data", {}).get("p_gamma", 0.7)), pool, i)
            for i in range(0, n, bs)]


@torch.no_grad()
def validate(net: torch.nn.Module, val: list, device) -> dict:
    net.eval()
    ps, pm = [], []
    for raw, rgb, feats in val:
        raw, rgb = raw.to(device), rgb.to(device)
        out = net(raw, None if feats is None else feats.to(device))
        ps.append(common.cpsnr(out, rgb, crop=4))
        pm.append(common.cpsnr(demosaic_malvar_torch(raw), rgb, crop=4))
    net.train()
    v, m = float(torch.cat(ps).mean()), float(torch.cat(pm).mean())
    return {"val_cpsnr": v, "val_cpsnr_mhc": m, "val_gain_db": v - m}


@torch.no_grad()
def benchmark(net: torch.nn.Module, folder: str, device, crop: int = 10, limit: int | None = None) -> float:
    """Mean CPSNR on a benchmark folder (RGGB, noise-free, clip, crop); reporting only."""
    net.eval()
    vals = []
    for _, img in common.read_benchmark(folder, limit):
        img = img.float().to(device)
        h, w = img.shape[-2] // 2 * 2, img.shape[-1] // 2 * 2
        img = img[..., :h, :w]
        feats = torch.zeros(1, net.noise_inputs, device=device) if net.noise_inputs else None
        vals.append(float(common.cpsnr(net(mosaic_rggb(img), feats), img, crop=crop)))
    net.train()
    return sum(vals) / len(vals)


def progress(step: int, wall_s: float, cfg: dict) -> float:
    """Fraction of the run done: by steps, or by wall time when ``optim.time_budget_s`` is set (whichever first)."""
    o = cfg["optim"]
    t = step / max(1, int(o["steps"]))
    budget = float(o.get("time_budget_s", 0) or 0)
    return max(t, wall_s / budget) if budget > 0 else t


def lr_at(step: int, frac: float, cfg: dict) -> float:
    o = cfg["optim"]
    warm = int(o.get("warmup", 50))
    lr, lr_min = float(o["lr"]), float(o.get("lr_min", 1e-5))
    if step < warm:
        return lr * (step + 1) / warm
    t = min(1.0, frac)
    return lr_min + 0.5 * (lr - lr_min) * (1 + math.cos(math.pi * t))  # cosine decay (Loshchilov & Hutter 2017)


def save_checkpoint(path: Path, net, opt, step: int, cfg: dict, best: float, history: list, wall_s: float) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "step": step, "net_config": net.config(),
                "train_config": json.dumps(cfg), "best_val_cpsnr": best, "history": json.dumps(history),
                "wall_s": wall_s}, tmp)
    tmp.replace(path)


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
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)

    cfg = common.load_config(args.config, args.set)
    if args.steps is not None:
        cfg.setdefault("optim", {})["steps"] = args.steps
    rank, world, is_dist = common.dist_setup()
    threads = args.threads or int(cfg.get("threads", 0))
    if threads:
        torch.set_num_threads(threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    if device.type == "cuda" and is_dist:
        device = torch.device("cuda", rank % torch.cuda.device_count())
    out = Path(args.out or cfg.get("out", "out/train_demosaic"))
    out.mkdir(parents=True, exist_ok=True)
    seed = int(cfg.get("seed", 0))

    net_cfg = dict(cfg.get("net", {}))
    if cfg.get("noise", {}).get("enabled", False):
        net_cfg["noise_inputs"] = 2
    torch.manual_seed(seed)  # identical initial weights on every rank
    net = DemosaicNet(**net_cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=float(cfg["optim"]["lr"]))
    step, best, history, wall0 = 0, -math.inf, [], 0.0
    resume = Path(args.resume) if args.resume else out / "last.pt"
    init = cfg.get("init")
    if init and not resume.is_file():  # start from another checkpoint's weights (fresh optimizer and schedule)
        ck = torch.load(init, map_location="cpu", weights_only=True)
        if ck["net_config"] != net.config():
            raise ValueError(f"init: {init} has net_config {ck['net_config']}, expected {net.config()}")
        net.load_state_dict({k: v.float() for k, v in ck["model"].items()})
        if rank == 0:
            print(f"initialised from {init}", flush=True)
    if resume.is_file():
        ck = torch.load(resume, map_location="cpu", weights_only=True)
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step, best = int(ck["step"]), float(ck["best_val_cpsnr"])
        history, wall0 = json.loads(ck["history"]), float(ck.get("wall_s", 0.0))
        old = json.loads(ck["train_config"])
        if (old.get("data"), old.get("val"), old.get("noise")) != (cfg.get("data"), cfg.get("val"), cfg.get("noise")):
            best = -math.inf  # the validation set changed: earlier best scores are not comparable
            if rank == 0:
                print("data/val config changed since the checkpoint: best-model selection restarts", flush=True)
        if rank == 0:
            print(f"resumed from {resume} at step {step}", flush=True)
    model = net
    if is_dist:
        model = torch.nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda"
                                                          else None)

    sampler = make_sampler(cfg)
    pool = make_pool(sampler, cfg, seed * 1_000_003 + rank)
    val = make_validation(cfg, cfg) if rank == 0 else None
    total = int(cfg["optim"]["steps"])
    batch = int(cfg["data"].get("batch", 16)) // world
    p_gamma = float(cfg["data"].get("p_gamma", 0.7))
    loss_kind = cfg["optim"].get("loss", "l2")
    val_every = int(cfg.get("val", {}).get("every", 200))
    ckpt_every = int(cfg.get("checkpoint_every", 100))
    bench = cfg.get("eval", {}).get("benchmarks", {}) or {}
    bench_every = int(cfg.get("eval", {}).get("every", 0))
    t_start = time.time()
    pbar = None
    if rank == 0 and not args.no_progress:
        from tqdm import tqdm

        pbar = tqdm(total=total, initial=step, dynamic_ncols=True, file=sys.stdout)
    run_loss, run_n = 0.0, 0
    frac = progress(step, wall0, cfg)
    stop_at = step + args.stop_after if args.stop_after else None
    while frac < 1.0 and (stop_at is None or step < stop_at):
        lr = lr_at(step, frac, cfg)
        for grp in opt.param_groups:
            grp["lr"] = lr
        raw, rgb, feats = make_batch(sampler, cfg, seed * 1_000_003 + step * 1009 + rank, batch, p_gamma, pool, step)
        raw, rgb = raw.to(device), rgb.to(device)
        outp = model(raw, None if feats is None else feats.to(device))
        loss = F.l1_loss(outp, rgb) if loss_kind == "l1" else F.mse_loss(outp, rgb)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        run_loss += loss.item()
        run_n += 1
        if pbar is not None:
            pbar.update(1)
            pbar.set_postfix(loss=f"{float(loss):.4f}", lr=f"{lr:.1e}")
        frac = progress(step, wall0 + time.time() - t_start, cfg)
        if is_dist:  # every rank stops at the same step
            import torch.distributed as dist

            f = torch.tensor([frac], dtype=torch.float64)
            dist.all_reduce(f, op=dist.ReduceOp.MAX)
            frac = float(f)
        last = frac >= 1.0 or step == stop_at
        if rank == 0 and (step % val_every == 0 or last):
            row = {"step": step, "wall_s": round(wall0 + time.time() - t_start, 1), "lr": lr,
                   "train_loss": run_loss / max(run_n, 1)}
            run_loss, run_n = 0.0, 0
            row.update(validate(net, val, device))
            if bench and bench_every and (step % bench_every == 0 or last):
                for name, folder in bench.items():
                    row[f"{name}_crop10"] = benchmark(net, folder, device)
            history.append(row)
            msg = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
            if pbar is not None:
                pbar.write(msg)
            else:
                print(msg, flush=True)
            if row["val_cpsnr"] > best:
                best = row["val_cpsnr"]
                save_checkpoint(out / "best.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start)
            common.write_csv(out / "history.csv", history)
            cols = [("train_loss", f"train {loss_kind} loss"), ("val_cpsnr", "val CPSNR (dB)"),
                    ("val_gain_db", "val CPSNR - MHC (dB)")]
            cols += [(f"{k}_crop10", f"{k} CPSNR crop10 (dB)") for k in bench if any(f"{k}_crop10" in r
                                                                                   for r in history)]
            common.plot_curves(out / "curves.png", history, cols, f"DemosaicNet {net.config()}")
        if rank == 0 and (step % ckpt_every == 0 or last):
            save_checkpoint(out / "last.pt", net, opt, step, cfg, best, history, wall0 + time.time() - t_start)
    if pbar is not None:
        pbar.close()
    if rank == 0:
        record = {"command": " ".join(["python training/train_demosaic.py", *sys.argv[1:]]) if argv is None else argv,
                  "config": cfg, "world_size": world, "steps": step, "best_val_cpsnr": best,
                  "wall_s": round(wall0 + time.time() - t_start, 1), "hardware": common.hardware(),
                  "final": history[-1] if history else {}}
        (out / "record.json").write_text(json.dumps(record, indent=2, default=str))
    common.dist_cleanup(is_dist)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
