"""Checkpoints of the demosaic trainer: saving (:func:`save_checkpoint`), starting a network from another's weights
(:func:`init_state`), the distillation teacher (:func:`load_teacher`, :func:`distill_target`) and the run's record
(:func:`describe_data`, :func:`write_model_card`). Part of ``training/train_demosaic.py``."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from isettorch.isp import learned
from isettorch.isp.learned import DemosaicNet
from training import common
from training.expand import collapsed_state, is_expanded


def load_teacher(cfg: dict, device) -> tuple[DemosaicNet | None, float, bool | str]:
    """(teacher network in eval mode or None, weight, self_ensemble) from the config's ``distill`` block; with
    ``shipped: VARIANT`` the teacher runs as that shipped variant does (:func:`isettorch.isp.learned.
    apply_shipped_settings`: its guard, correction scale and classical blend), else bare."""
    d = cfg.get("distill") or {}
    if not d:
        return None, 0.0, False
    unknown = set(d) - {"teacher", "weight", "self_ensemble", "shipped"}
    if unknown:
        raise ValueError(f"distill: unknown keys {sorted(unknown)}; expected teacher, weight, self_ensemble, shipped")
    weight = float(d.get("weight", 1.0))
    if not 0.0 < weight <= 1.0:
        raise ValueError(f"distill.weight: expected a value in (0, 1], got {weight}")
    ens = learned.check_self_ensemble(d.get("self_ensemble", True), "distill.self_ensemble")
    if "teacher" not in d:
        raise ValueError("distill.teacher: expected the path of a DemosaicNet checkpoint")
    teacher, _ = learned.load_checkpoint(d["teacher"], device=device)
    if d.get("shipped") is not None:  # the teacher as a shipped variant runs: its guard, correction scale and blend
        if d["shipped"] not in learned.PRETRAINED:
            raise ValueError(f"distill.shipped: expected one of {sorted(learned.PRETRAINED)} or null, got "
                             f"{d['shipped']!r}")
        learned.apply_shipped_settings(teacher, d["shipped"])
    want = 2 if cfg.get("noise", {}).get("enabled", False) else 0
    if teacher.noise_inputs != want:
        raise ValueError(f"distill.teacher: {d['teacher']} takes {teacher.noise_inputs} noise inputs, this run's "
                         f"network {want}")
    return teacher, weight, ens


@torch.no_grad()
def distill_target(raw: torch.Tensor, rgb: torch.Tensor, feats: torch.Tensor | None, teacher: DemosaicNet,
                   weight: float, self_ensemble: bool | str) -> torch.Tensor:
    """``(1 - weight) * rgb + weight * teacher(raw)`` (float32); the teacher's output through the library's
    :func:`~isettorch.isp.learned.demosaic_learned` (RGGB), its self-ensemble when ``self_ensemble`` (True or
    ``"transpose"``: two passes; ``"dihedral"``: eight)."""
    out = learned.demosaic_learned(raw, "RGGB", model=teacher, noise=feats, self_ensemble=self_ensemble)
    return torch.lerp(rgb, out.float(), weight)


def save_checkpoint(path: Path, net, opt, step: int, cfg: dict, best: float, history: list, wall_s: float,
                    clip=None, running_loss: tuple[float, int] = (0.0, 0)) -> None:
    """Write the run's state (weights, optimizer, step, configs, best score, history, wall time, ``clip``'s state,
    a :class:`training.train_demosaic.AdaptiveGradClip`, and the training loss summed since the last validation row
    with its step count, so a resumed run's next row is an uninterrupted run's) to ``path`` atomically (a temporary
    file renamed). A network
    trained expanded (:mod:`training.expand`) is written collapsed under ``model`` (the plain network, as the library
    loads it) and as its factors under ``model_expanded``."""
    expanded = is_expanded(net)
    extra = {"model_expanded": net.state_dict()} if expanded else {}  # the factors, for --resume
    common.save_atomic({"model": collapsed_state(net) if expanded else net.state_dict(), **extra,
                        "optimizer": opt.state_dict(), "step": step,
                        "net_config": net.config(), "train_config": json.dumps(cfg), "best_val_cpsnr": best,
                        "history": json.dumps(history), "wall_s": wall_s,
                        "grad_clip": json.dumps(clip.state() if clip else {}),
                        "running_loss": [float(running_loss[0]), int(running_loss[1])]}, path)


def describe_data(cfg: dict) -> str:
    """One line saying what the network was trained on (for the model card)."""
    d, n = cfg.get("data", {}), cfg.get("noise", {})
    src = d.get("source", "natural")
    if src == "camera_pairs":
        what = "isettorch.data.camera_pairs (scene -> optics -> isettorch sensor, its noise model)"
    elif src == "stream":
        what = (f"isettorch.data.PairStream on {d.get('device') or 'the training device'} (scene -> optics -> "
                f"isettorch sensor, its noise model)")
        if d.get("camera_config") is not None:  # camera-specific: every pair through one camera
            what += f" through the one camera {d['camera_config']!r} (data.camera_config)"
    elif src == "natural":
        off = list(d.get("disable") or [])
        what = (f"isettorch.data.natural scenes ({'all components' if not off else 'without ' + ', '.join(off)}; "
                f"overrides {d.get('natural') or {}}), random camera sensitivities, white-balanced")
    else:
        what = "isettorch.data.generate_scene scenes, random camera sensitivities, white-balanced"
    dom = d.get("domain", "mixed")
    dom_txt = f"{dom} domain" + (f" ({d.get('encoded_fraction', 0.8)} encoded)" if dom == "mixed" else "")
    noise = (f"; Poisson-Gaussian noise at gains {n.get('gain_min', 1.0)}-{n.get('gain_max', 32.0)}"
             if n.get("enabled") else "; noise-free")
    if n.get("enabled") and d.get("camera_config") is not None:
        noise = "; the camera's own sensor noise"
    return (f"{what}; {d.get('patch', 80)} px patches, batch {d.get('batch', 16)}, {dom_txt}{noise}; selected on "
            f"held-out synthetic scenes; never Kodak/McMaster")


def write_model_card(path: Path, record: dict, net) -> None:
    """A short markdown model card beside the checkpoints: command, config, data, steps, wall time, hardware."""
    lines = ["# DemosaicNet model card", "", f"- command: `{record['command']}`",
             f"- network: DemosaicNet {net.config()}, {sum(p.numel() for p in net.parameters())} parameters",
             f"- data: {record['data']}", f"- steps: {record['steps']} (world size {record['world_size']})",
             f"- wall time: {record['wall_s']} s", f"- hardware: `{json.dumps(record['hardware'])}`",
             f"- best held-out synthetic validation CPSNR: {record['best_val_cpsnr']}",
             f"- last evaluation: `{json.dumps(record['final'], default=str)}`", "",
             "## Config", "", "```json", json.dumps(record["config"], indent=2, default=str), "```", ""]
    path.write_text("\n".join(lines))


def init_state(ck: dict, net: DemosaicNet, name: str = "init") -> dict:
    """The state dict that starts ``net`` from checkpoint ``ck``, computing the same function as ``ck``'s network:

    - equal configs (the guard, correction scale and blend aside: they hold no weights): its weights as they are;
    - more ``noise_inputs`` (a noise-free checkpoint starting a joint network of the same width and depth): the extra
      input channels of the first convolution zeroed, so the joint network starts as the noise-free one;
    - a deeper residual network of the same width (``depth`` larger, both ``residual``): the checkpoint's blocks,
      then new blocks whose second convolution is zero, each an exact identity at the start (Net2DeeperNet, Chen,
      Goodfellow & Shlens, ICLR 2016, for residual blocks), while their first convolutions keep ``net``'s He
      initialisation so the new blocks train from the first step;
    - another ``base`` (the same width and depth): its weights as they are, now correcting the other classical
      estimate (not the same function: a start close to it where the two bases agree, to be trained on).
    """
    # the guard, correction scale and blend hold no weights: a network trained with them in the loop may start from
    # one trained without (with the shipped ones, from the function it ships as)
    free = ("guard", "correction_scale", "blend")
    old = {k: v for k, v in {"noise_inputs": 0, **ck["net_config"]}.items() if k not in free}
    new = {k: v for k, v in net.config().items() if k not in free}
    state = {k: v.float() for k, v in ck["model"].items()}
    if {**old, "base": None} == {**new, "base": None}:  # the same network, on the same base or another
        return state

    def but(cfg: dict, key: str) -> dict:
        return {k: v for k, v in cfg.items() if k != key}

    if old.get("residual") and new["depth"] > old["depth"] and but(old, "depth") == but(new, "depth"):
        for key, value in net.state_dict().items():
            if key not in state:  # a new block: body.<i>.conv1 as initialised, body.<i>.conv2 zero
                state[key] = torch.zeros_like(value) if ".conv2." in key else value.detach().clone().float()
        return state
    if but(old, "noise_inputs") != but(new, "noise_inputs") or old["noise_inputs"] > new["noise_inputs"]:
        raise ValueError(f"{name}: net_config {old} cannot start a network {new} (expected the same channels and "
                         f"depth, and at most its noise_inputs; or a deeper residual network of the same channels "
                         f"and noise_inputs)")
    w = state["body.0.weight"]
    extra = new["noise_inputs"] - old["noise_inputs"]
    state["body.0.weight"] = torch.cat([w, w.new_zeros(w.shape[0], extra, *w.shape[2:])], 1)
    return state
