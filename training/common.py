"""Shared helpers for the training scripts: config loading, distributed setup, CPSNR (the library's), CSV, curves,
atomic saves."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np
import torch

from isettorch._files import torch_save_atomic
from isettorch._yaml import load_yaml


def config_changes(old: dict, new: dict, allowed: tuple[str, ...] = ()) -> list[str]:
    """The dotted keys of a run's config that differ between a checkpoint's run (``old``) and this one (``new``),
    except those in ``allowed`` (a key or a whole section a resumed run may change)."""
    import json

    def flat(d, prefix=""):
        out = {}
        for k, v in (d or {}).items():
            key = f"{prefix}{k}"
            if isinstance(v, dict) and key not in allowed:
                out.update(flat(v, key + "."))
            else:
                out[key] = v
        return out

    a, b = flat(old), flat(json.loads(json.dumps(new)))  # (as the checkpoint stores it: tuples are lists)
    return sorted(k for k in a.keys() | b.keys() if k not in allowed and a.get(k) != b.get(k))


def check_keys(cfg: dict, top_keys, section_keys: dict, nullable: tuple[str, ...] = ()) -> None:
    """A ValueError naming the first key a training script does not read (``config.optim.lrr: unknown key; expected
    one of [...]``: a misspelt key ran silently with its default). ``section_keys``: each section's keys (None: not
    checked here); a section in ``nullable`` may be null."""
    for key, value in cfg.items():
        if key not in top_keys:
            raise ValueError(f"config.{key}: unknown key; expected one of {sorted(top_keys)}")
        keys = section_keys.get(key)
        if key in section_keys and (value is not None or key not in nullable):
            if not isinstance(value, dict):
                raise ValueError(f"config.{key}: expected a mapping, got {value!r}")
            unknown = [k for k in value if keys is not None and k not in keys]
            if unknown:
                raise ValueError(f"config.{key}.{unknown[0]}: unknown key; expected one of {sorted(keys)}")


def check_number(value, name: str, *, integer: bool = False, minimum: float | None = None,
                 above: float | None = None, below: float | None = None) -> None:
    """A ValueError naming ``config.<name>`` unless ``value`` is a finite number (an integer with ``integer``), at
    least ``minimum``, above ``above`` and below ``below`` (a string, a negative learning rate or a crop wider than
    the image failed deep in a run, or ran silently)."""
    ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
          and (not integer or float(value).is_integer()) and (minimum is None or value >= minimum)
          and (above is None or value > above) and (below is None or value < below))
    if not ok:
        bounds = [f">= {minimum:g}" if minimum is not None else "", f"> {above:g}" if above is not None else "",
                  f"< {below:g}" if below is not None else ""]
        if above == 0 and minimum is None and below is None:
            what = "a positive integer" if integer else "a positive number"
        else:
            what = ("an integer" if integer else "a number") + (" " if any(bounds) else "") + " and ".join(
                b for b in bounds if b)
        raise ValueError(f"config.{name}: expected {what}, got {value!r}")


def load_config(path: str | Path, overrides: list[str] | None = None) -> dict:
    """Read a YAML config and apply ``key.sub=value`` overrides (values parsed as YAML), both with the library's
    reader (:func:`isettorch._yaml.load_yaml`: YAML 1.2 floats, so ``optim.lr=1e-3`` is a number, not the string
    ``'1e-3'`` of ``yaml.safe_load``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config: no file at {path}")
    cfg = load_yaml(path.read_text())
    if not isinstance(cfg, dict):
        raise ValueError(f"config: expected a YAML mapping in {path}, got {type(cfg).__name__}")
    for item in overrides or []:
        if "=" not in item:
            raise ValueError(f"override: expected key.sub=value, got {item!r}")
        key, value = item.split("=", 1)
        node = cfg
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ValueError(f"override: {key!r} goes through a non-mapping value")
        node[parts[-1]] = load_yaml(value)
    return cfg


def dist_setup(device: torch.device) -> tuple[int, int, bool]:
    """Initialise torch.distributed when run under torchrun (WORLD_SIZE > 1); returns (rank, world, is_dist).

    The backend follows the device the run trains on: NCCL for CUDA, gloo for the CPU (also on a machine with a GPU,
    where ``--device cpu`` tensors cannot go through NCCL)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1, False
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group("nccl" if torch.device(device).type == "cuda" else "gloo")
    return dist.get_rank(), dist.get_world_size(), True


def dist_cleanup(is_dist: bool) -> None:
    if is_dist:
        import torch.distributed as dist

        dist.barrier()
        dist.destroy_process_group()


def cpsnr(pred: torch.Tensor, target: torch.Tensor, crop: int = 0) -> torch.Tensor:
    """Colour PSNR (dB) per image after clipping ``pred`` to [0, 1]: the library's
    :func:`isettorch.isp.evaluation.cpsnr` (the convention of /work/shared/data/README.md)."""
    from isettorch.isp.evaluation import cpsnr as _cpsnr

    return _cpsnr(pred.clamp(0, 1).double(), target.double(), crop)


def save_atomic(obj, path: Path) -> None:
    """``torch.save(obj)`` to ``path`` through a temporary file renamed over it: an interrupted write never leaves a
    truncated checkpoint or chunk where a resumed run would read it."""
    torch_save_atomic(obj, path)


def write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def plot_curves(path: Path, rows: list[dict], keys: list[tuple[str, str]], title: str, log_y: bool = False) -> None:
    """Plot columns ``keys`` ([(column, label)]) of ``rows`` against 'step' into a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.6))
    axes = np.atleast_1d(axes)
    for ax, (col, label) in zip(axes, keys):
        pts = [(r["step"], r[col]) for r in rows if r.get(col) not in (None, "") and math.isfinite(float(r[col]))]
        if pts:
            ax.plot(*zip(*pts), marker="." if len(pts) < 50 else None)
        ax.set_xlabel("step")
        ax.set_ylabel(label)
        if log_y:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def hardware() -> dict:
    """The machine a run trained on (:func:`isettorch._machine.machine_info`; with CUDA, the first GPU)."""
    from isettorch._machine import machine_info

    return machine_info("cuda" if torch.cuda.is_available() else "cpu")


# The test sets' pixels (Kodak 24, McMaster 18: sha256 of each decoded 8-bit image with its shape), written by
# ``python -c "from training.common import write_test_set_fingerprints as w; w(['../shared/data/kodak24',
# '../shared/data/mcmaster18'])"``: never train, tune or select on them; the scripts that take photographs for those
# purposes refuse any image among them (in any file format, under any name).
TEST_SET_FINGERPRINTS = Path(__file__).with_name("test_set_fingerprints.json")


def pixel_fingerprint(image: np.ndarray) -> str:
    """sha256 of an 8-bit image's shape and pixels (the same for a PNG and a TIFF of it)."""
    import hashlib

    a = np.ascontiguousarray(np.asarray(image, dtype=np.uint8))
    return hashlib.sha256(repr(a.shape).encode() + a.tobytes()).hexdigest()


def write_test_set_fingerprints(folders: list[str | Path]) -> Path:
    """Record the fingerprints of every image of ``folders`` (the test sets) in :data:`TEST_SET_FINGERPRINTS`."""
    import json

    from isettorch.isp.evaluation import load_images

    prints = {Path(f).name: sorted(pixel_fingerprint(a) for _, a in load_images(f)) for f in folders}
    TEST_SET_FINGERPRINTS.write_text(json.dumps(prints, indent=1) + "\n")
    return TEST_SET_FINGERPRINTS


def refuse_test_images(source, what: str) -> None:
    """A ValueError naming ``what`` when ``source`` (a folder, or ``(name, uint8 array)`` pairs as
    :func:`isettorch.isp.evaluation.load_images` gives) holds an image of the test sets."""
    import json

    from isettorch.isp.evaluation import load_images

    known = {p: name for name, prints in json.loads(TEST_SET_FINGERPRINTS.read_text()).items() for p in prints}
    for name, image in load_images(source):
        hit = known.get(pixel_fingerprint(image))
        if hit is not None:
            raise ValueError(f"{what}: {name} is an image of the test set {hit} (never train, tune or select on it: "
                             f"../shared/data/README.md)")
