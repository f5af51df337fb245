"""Reproduce a shipped demosaic model with one command: every training step of its model card in order, then the
selection and the export.

    python training/reproduce_demosaic.py noise_free [--assets out/reproduced] [--dry-run]
    python training/reproduce_demosaic.py joint_denoise [--assets out/reproduced] [--dry-run]
    python training/reproduce_demosaic.py tiny|small [--assets out/reproduced] [--dry-run]

Each step is ``training/train_demosaic.py --config configs/train/NAME.yaml`` and starts from the previous step's
``best.pt`` (the configs' ``init``); a finished step returns at once and an interrupted one resumes from its
``last.pt`` (the time budget counts across resumes), so the command can be re-run after any interruption. On 2 CPU
cores the noise-free chain takes about 12 hours, the joint one (from the shipped noise-free network) about 105
minutes.

``noise_free`` ends with the weight-interpolation screen ``wise_specular_2026-11-27`` of
``training/heldout_screen.py`` (its rule, fixed before it was first run; the record in docs/training_log.md): the five
held-out synthetic sets are written if missing (``training/make_heldout.py``), W(alpha) = (1 - alpha) distill-4 +
alpha specular is scored for alpha = 0.1 ... 0.9, and the passing alpha with the highest score is exported; if none
passes, distill-4 is. ``joint_denoise`` exports its last step's best checkpoint,
with the noisy benchmark scores; ``tiny`` and ``small`` (the fast members of the speed-error family, 1 hour each)
export theirs. The weights are written to ``--assets`` (not over the shipped files unless asked).
Training steps run on budgets of wall time, so a reproduction on another machine takes other step counts and its
weights differ from the shipped ones; the procedure, data and selection are the same.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._yaml import load_yaml  # noqa: E402
from training import heldout_screen  # noqa: E402

CONFIGS = ROOT / "configs" / "train"
CHAINS = {
    "noise_free": ["demosaic_noise_free", "demosaic_noise_free_finetune", "demosaic_noise_free_stage3",
                   "demosaic_noise_free_distill", "demosaic_noise_free_distill2", "demosaic_noise_free_distill3",
                   "demosaic_noise_free_distill4", "demosaic_noise_free_specular"],
    # starts from the shipped noise-free network (isettorch/assets/demosaic_learned.pt, the config's init), which
    # ``noise_free`` reproduces
    "joint_denoise": ["demosaic_joint_all_levels", "demosaic_joint_guarded"],
    # the speed-error family (issue #35): from scratch; the tiny network then distilled from the shipped noise-free
    # one (which its photographs rule chose over the first step: docs/training_log.md#family_2026-11-27), then
    # moved to Menon without its refining step and distilled again (#tiny_norefine_2026-11-29)
    "tiny": ["demosaic_tiny", "demosaic_tiny_distill", "demosaic_tiny_norefine"],
    "small": ["demosaic_small"],
}
#: what the export of a chain's last best.pt adds (the noise-free chain ends with its interpolation screen instead)
EXPORT_EXTRA = {"joint_denoise": ["--noise-sigmas", "0.01", "0.02", "0.05"], "tiny": [], "small": []}
#: the interpolation screen's five held-out sets (training.heldout_screen.HELDOUT: their make_heldout.py options)
_HELDOUT_BASE, HELDOUT = heldout_screen.HELDOUT_BASE, heldout_screen.HELDOUT
WISE = {"start": "out/train_demosaic_noise_free_distill4/best.pt",
        "finetuned": "out/train_demosaic_noise_free_specular/best.pt",
        "alphas": [k / 10 for k in range(1, 10)], "out": "out/wise_specular"}


def load_config(name: str, configs: Path = CONFIGS) -> dict:
    path = Path(configs) / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"chain: expected a config {path}, it does not exist")
    return load_yaml(path.read_text())


#: shipped models a chain may start from (the joint model starts from the noise-free one: ``noise_free`` makes it)
SHIPPED_INITS = ("isettorch/assets/demosaic_learned.pt",)


def check_chain(names: list[str], configs: Path = CONFIGS) -> list[dict]:
    """The chain's configs, after checking that each step starts from an earlier step's ``best.pt`` (its ``init``)
    or from a shipped model (:data:`SHIPPED_INITS`: a file in the repository, which another chain reproduces) and
    that every distillation teacher is an earlier step's ``best.pt``: a chain that would read a checkpoint no step
    writes raises, naming the step."""
    cfgs, made = [], set(SHIPPED_INITS)
    for name in names:
        cfg = load_config(name, configs)
        for key, path in (("init", cfg.get("init")), ("distill.teacher", (cfg.get("distill") or {}).get("teacher"))):
            if path and path not in made:
                raise ValueError(f"chain: step {name!r} reads {key} {path!r}, which no earlier step writes "
                                 f"(earlier steps write {sorted(made - set(SHIPPED_INITS)) or 'nothing'})")
        made.add(f"{cfg['out']}/best.pt")
        cfgs.append(cfg)
    return cfgs


def plan(model: str, assets: str) -> list[str]:
    """The commands the reproduction runs, in order (what ``--dry-run`` prints)."""
    if model not in CHAINS:
        raise ValueError(f"model: expected one of {sorted(CHAINS)}, got {model!r}")
    check_chain(CHAINS[model])
    cmds = [f"python training/train_demosaic.py --config configs/train/{n}.yaml --no-progress" for n in CHAINS[model]]
    if model == "noise_free":
        cmds += [shlex.join(["python", "training/make_heldout.py", "--out", d, *_HELDOUT_BASE, *a])
                 for d, a in HELDOUT.items()]
        cmds.append(f"interpolation screen: (1 - alpha) {WISE['start']} + alpha {WISE['finetuned']}, alpha in "
                    f"{WISE['alphas']} -> {WISE['out']}/best.pt")
        cmds.append(f"python training/export_demosaic.py --run {WISE['out']} --crops 10 --out {assets}")
    else:
        cmds.append(shlex.join(["python", "training/export_demosaic.py", *_export_args(model, assets)]))
    return cmds


def _export_args(model: str, assets: str) -> list[str]:
    """export_demosaic.py's arguments for a chain that exports its last step's best checkpoint as ``model``."""
    last = load_config(CHAINS[model][-1])
    return ["--run", str(last["out"]), "--crops", "10", "--variant", model, *EXPORT_EXTRA[model], "--out", assets]


def wise_select(sets: list[str], start_path: str = WISE["start"], finetuned_path: str = WISE["finetuned"],
                out: str = WISE["out"]) -> tuple[str, dict]:
    """The interpolation screen (training.heldout_screen's rule, the incumbent being ``start_path``): scores
    W(alpha) = (1 - alpha) start + alpha finetuned for ``WISE["alphas"]``, writes the chosen network to
    ``out/best.pt`` (the start itself if no alpha passes) and returns how it was chosen and the scores (with
    ``decision``: ``"a0.6"``-style or ``"incumbent"``). Relative paths are from the repository root."""
    import torch

    from isettorch.isp.learned import DemosaicNet
    interpolate_checkpoints, mhc_scores = heldout_screen.interpolate_checkpoints, heldout_screen.mhc_scores
    passes, score_network = heldout_screen.passes, heldout_screen.score_network

    start, tuned = (torch.load(ROOT / p, map_location="cpu", weights_only=True) for p in (start_path, finetuned_path))
    mhc = mhc_scores(sets)
    incumbent = DemosaicNet(**start["net_config"])
    incumbent.load_state_dict(start["model"])
    res = {"incumbent": {"path": str(start_path), **score_network(incumbent.eval(), sets, mhc)}}
    print("incumbent", " ".join(f"{res['incumbent'][s]['mean']:.3f}" for s in sets),
          f"score {res['incumbent']['score']:.3f}", flush=True)
    for a in WISE["alphas"]:
        net = DemosaicNet(**start["net_config"])
        net.load_state_dict(interpolate_checkpoints(a, start, tuned)["model"])
        res[f"a{a:.1f}"] = row = score_network(net.eval(), sets, mhc)
        row["passes"] = passes(row, res["incumbent"], sets)
        print(f"a{a:.1f}", " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in sets),
              f"score {row['score']:.3f}", "passes" if row["passes"] else "", flush=True)
    ok = [k for k in res if k != "incumbent" and res[k]["passes"]]
    res["decision"] = max(ok, key=lambda k: res[k]["score"]) if ok else "incumbent"
    print("ship:", res["decision"])
    best = None if res["decision"] == "incumbent" else float(res["decision"][1:])
    (ROOT / out).mkdir(parents=True, exist_ok=True)
    torch.save(interpolate_checkpoints(best, start, tuned) if best is not None else start, ROOT / out / "best.pt")
    how = (f"the interpolation screen (training/reproduce_demosaic.py): W({best}) = (1 - alpha) distill-4 + "
           f"alpha specular" if best is not None else "the interpolation screen passed no alpha: distill-4")
    return how, res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "),
                                 epilog="On 2 CPU cores: noise_free about 12 hours, joint_denoise about 105 minutes, "
                                        "tiny and small about 1 hour each; interrupted runs resume when re-run.")
    ap.add_argument("model", choices=sorted(CHAINS), help="the shipped model to reproduce")
    ap.add_argument("--assets", default="out/reproduced", help="where the exported weights and card go")
    ap.add_argument("--dry-run", action="store_true", help="print the commands and check the chain; run nothing")
    args = ap.parse_args(argv)
    if Path.cwd().resolve() != ROOT:
        # the chain's training runs write out/... under the working directory, its selection screen and held-out
        # sets are read under the repository: run from anywhere else, it trained for hours, then failed (or screened
        # a stale out/ of the repository)
        ap.error(f"run it from the repository root (cd {ROOT}); the chain's paths (out/..., configs/...) are "
                 f"relative to it, and the working directory is {Path.cwd()}")
    cmds = plan(args.model, args.assets)
    if args.dry_run:
        print("\n".join(cmds))
        return 0
    from training import export_demosaic, make_heldout, train_demosaic

    for name in CHAINS[args.model]:
        print(f"== {name}", flush=True)
        train_demosaic.main(["--config", str(CONFIGS / f"{name}.yaml"), "--no-progress"])
    command = f"python training/reproduce_demosaic.py {args.model}"
    if args.model != "noise_free":
        return export_demosaic.main([*_export_args(args.model, args.assets), "--threads", "2", "--command", command])
    for folder, extra in HELDOUT.items():
        if not (ROOT / folder).is_dir():
            make_heldout.main(["--out", str(ROOT / folder), *_HELDOUT_BASE, *extra])
    how, res = wise_select([str(ROOT / d) for d in HELDOUT])
    (ROOT / WISE["out"] / "wise_screen.json").write_text(json.dumps(res, indent=1))
    return export_demosaic.main(["--run", str(ROOT / WISE["out"]), "--crops", "10", "--threads", "2",
                                 "--out", args.assets, "--command", command, "--selected-by", how])


if __name__ == "__main__":
    raise SystemExit(main())
