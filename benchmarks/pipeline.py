"""Speed against error of the isettorch pipeline (the standard set of ``isettorch bench``), saved for RESULTS.md.

Writes ``<out>/pipeline.json`` (every row, the machine, the settings), ``<out>/pipeline_table.md`` (one table
per section) and ``<out>/pareto.png`` (time vs sensor-volts error of the knob rows, Pareto front), and prints the table.
``--quick`` needs an ``--out`` other than benchmarks/ (the committed files are a full run's).

    python benchmarks/pipeline.py [--quick --out DIR] [--device cpu|cuda] [--threads N] [--out benchmarks]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import bench  # benchmarks/bench.py, beside this script
import torch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent))
    args = ap.parse_args(argv)
    if args.quick and Path(args.out).resolve() == Path(__file__).resolve().parent:
        ap.error("--quick would overwrite the committed full-run results in benchmarks/: give another --out")
    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = bench.run_benchmarks(quick=args.quick, device=args.device, repeats=args.repeats,
                                  log=lambda s: print(s, file=sys.stderr, flush=True))
    result["plot"] = str(bench.plot_pareto(result, out / "pareto.png"))
    (out / "pipeline.json").write_text(json.dumps(result, indent=1, allow_nan=False) + "\n")
    table = bench.format_report(result)
    (out / "pipeline_table.md").write_text(table + "\n")
    print(table)
    m = result["machine"]
    print(f"\ntotal {result['seconds_total']:.1f} s; {m['processor']}, {m['cpu_count']} CPUs, "
          f"{m['torch_threads']} torch threads, load {m.get('load_average_start')} -> {m.get('load_average_end')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
