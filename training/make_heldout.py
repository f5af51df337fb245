"""Write held-out synthetic scenes as 8-bit PNGs for ``isettorch demosaic-eval`` (seeds never drawn in training).

Usage::

    python training/make_heldout.py --out out/heldout_natural --n 24 --size 256 [--source natural|isettorch]
        [--domain mixed] [--colour-space linear_srgb] [--disable colour_correlation ...]
        [--channel-gains 1 0.15 0.15 --grain-std 0.005]

``--channel-gains`` and ``--grain-std`` make a stress set for the failure that a colour-ratio prior has on saturated
colours: green and blue scaled down (the scene's structure stays in all channels) plus seeded Gaussian grain drawn
independently per channel, before the 8-bit rounding (docs/training_log.md#natural_v4_64x13_2026-11-26).
    isettorch demosaic-eval out/heldout_natural --method learned --crop 10
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._progress import add_quiet_argument, progress  # noqa: E402
from isettorch.data import natural as nat  # noqa: E402
from isettorch.sensor.noise import poisson_gaussian  # noqa: E402
from training.train_demosaic import COLOUR_SPACES, ScenePool  # noqa: E402

HELDOUT_SEED = 3_000_029_000  # far from the training (seed, step, rank) and validation seeds


def main(argv: list[str] | None = None) -> int:
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--source", choices=("natural", "isettorch"), default="natural")
    ap.add_argument("--domain", choices=nat.DOMAINS, default="mixed")
    ap.add_argument("--colour-space", choices=COLOUR_SPACES, default="camera_rgb",
                    help="the scenes' RGB (data.colour_space of the training configs; natural source only)")
    ap.add_argument("--disable", nargs="*", default=[], metavar="COMPONENT",
                    help=f"natural-generator components to switch off (from {nat.COMPONENTS}), e.g. colour_correlation "
                         "for a held-out set with chromatic fine detail")
    ap.add_argument("--natural", default=None, metavar="JSON",
                    help='generator options (data.natural of the training configs), e.g. '
                         '\'{"components": {"grain": {"relative": {"probability": 0.5}}}}\': a held-out set drawn '
                         'with a candidate generator\'s options')
    ap.add_argument("--channel-gains", type=float, nargs=3, default=None, metavar=("R", "G", "B"),
                    help="scale the encoded image's channels (a stress set: e.g. 1 0.15 0.15 for saturated reds)")
    ap.add_argument("--grain-std", type=float, default=0.0,
                    help="std of seeded Gaussian grain added independently to each channel (values in [0, 1])")
    add_quiet_argument(ap)
    args = ap.parse_args(argv)
    if args.channel_gains is not None and any(not 0 <= c <= 1 for c in args.channel_gains):
        raise ValueError(f"--channel-gains: expected three values in [0, 1], got {args.channel_gains}")
    if not args.grain_std >= 0:
        raise ValueError(f"--grain-std: expected a std >= 0, got {args.grain_std}")
    try:
        natural = json.loads(args.natural) if args.natural is not None else {}
    except json.JSONDecodeError as e:
        raise ValueError(f"--natural: expected a JSON mapping of generator options, got {args.natural!r} ({e})") from e
    if not isinstance(natural, dict):
        raise ValueError(f"--natural: expected a JSON mapping of generator options, got {args.natural!r}")
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = {"source": args.source, "patch": args.size, "scene_size": args.size, "disable": list(args.disable),
            "colour_space": args.colour_space, "natural": natural}
    pool = ScenePool({"data": data}, HELDOUT_SEED)
    for i in progress(range(args.n), desc="held-out", unit="image", quiet=args.quiet):
        g = torch.Generator().manual_seed(HELDOUT_SEED + i)
        x = nat.expose_and_encode(pool.render(i)[None], g, args.domain)[0].permute(1, 2, 0).numpy()
        if args.channel_gains is not None:
            x = x * np.asarray(args.channel_gains, dtype=x.dtype)
        if args.grain_std > 0:  # the sensor's white Gaussian noise (a = 0); clipped to [0, 1], as 8-bit storage must
            grainy = poisson_gaussian(torch.from_numpy(x).to(torch.float64), 0.0, args.grain_std, g)
            x = np.clip(grainy.numpy(), 0, 1)
        Image.fromarray(np.round(x * 255).astype(np.uint8)).save(out / f"{args.source}_{i:03d}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
