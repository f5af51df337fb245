"""``isettorch bench``: speed against error of the simulation pipeline (see :mod:`isettorch.bench`).

Prints a Markdown table (or, with ``--json``, one JSON object: ``rows`` of
``{"name", "seconds_median", "error", "error_unit", ...}``, ``pairs_per_s``, ``skipped``, ``machine``).
``--plot PATH`` writes the time-vs-error plot (PNG) with the Pareto front.
"""

from __future__ import annotations

import json
import sys


def _sizes(text: str) -> list[int]:
    try:
        out = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--sizes: expected comma-separated integers such as 128,512, got {text!r}") from None
    if not out or any(n < 16 for n in out):
        raise ValueError(f"--sizes: expected sizes >= 16, got {text!r}")
    return out


def register(sub) -> None:
    p = sub.add_parser("bench", help="time the pipeline and its accuracy-for-speed knobs (with errors) and peers")
    p.add_argument("--json", action="store_true", help="print every row as JSON instead of a table")
    p.add_argument("--quick", action="store_true", help="fewer repeats, no 1024^2, smaller knob scene")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1, ...; default cpu)")
    p.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's choice)")
    p.add_argument("--sizes", default=None, help="pipeline sizes, e.g. 128,512,1024 (default per --quick)")
    p.add_argument("--stable-size", type=int, default=None, help="size of the optics_/sensor_ rows (default 512)")
    p.add_argument("--knob-patch", type=int, default=None, help="Macbeth patch size of the knob scene (16/32)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats per measurement (default 5, quick 2)")
    p.add_argument("--no-peers", action="store_true", help="skip the NumPy, colour-demosaicing and kornia peers")
    p.add_argument("--no-pairs", action="store_true", help="skip the CameraPairDataset throughput")
    p.add_argument("--plot", default=None, help="write the time-vs-error PNG here")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch

    from .. import bench

    try:
        sizes = _sizes(args.sizes) if args.sizes else None
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        print(f"error: --device {args.device}: CUDA is not available on this machine", file=sys.stderr)
        return 2
    if args.threads is not None:
        if args.threads < 1:
            print(f"error: --threads: expected a positive integer, got {args.threads}", file=sys.stderr)
            return 2
        torch.set_num_threads(args.threads)
    log = (lambda s: print(s, file=sys.stderr, flush=True)) if not args.json else (lambda s: None)
    result = bench.run_benchmarks(quick=args.quick, device=device, sizes=sizes, stable_size=args.stable_size,
                                  knob_patch=args.knob_patch, repeats=args.repeats, peers=not args.no_peers,
                                  pairs=not args.no_pairs, log=log)
    if args.plot:
        result["plot"] = str(bench.plot_pareto(result, args.plot))
    if args.json:
        print(json.dumps(result, indent=1, allow_nan=False))
    else:
        print(bench.format_report(result))
        print(f"\ntotal {result['seconds_total']:.1f} s on {result['machine']['processor']} "
              f"({result['machine']['cpu_count']} CPUs, {result['machine']['torch_threads']} torch threads)")
    return 0
