"""``isettorch bench``: speed against error of the simulation pipeline, run from a source checkout.

The benchmark lives in ``benchmarks/bench.py`` (next to its peers: the NumPy reference, colour-demosaicing,
kornia), outside the package, and the package never imports ``benchmarks/``. This command finds that file
beside the package (or under the current directory) and runs it as a script in a child Python with the same
arguments, so the peers' imports and helpers never enter the library. ``--json`` prints one JSON object:
``rows`` of ``{"name", "seconds_median", "seconds_min", "error", "error_unit", ...}``, ``pairs_per_s``,
``skipped``, ``machine``; ``--plot PATH`` writes the time-vs-error plot (PNG).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SCRIPT = Path("benchmarks") / "bench.py"


def find_script() -> Path | None:
    """``benchmarks/bench.py`` of the checkout holding this package, else of the current directory."""
    here = Path(__file__).resolve().parents[2]  # <checkout>/isettorch/commands/bench.py -> <checkout>
    for root in (here, Path.cwd()):
        if (root / SCRIPT).is_file():
            return root / SCRIPT
    return None


def register(sub) -> None:
    # Every argument (``--json``, ``-h``, ...) goes to the script, whose parser defines and checks the options:
    # this parser takes no options of its own ("+" is never used as a prefix), so it treats them as positionals.
    p = sub.add_parser("bench", add_help=False, prefix_chars="+",
                       help="time the pipeline and its accuracy-for-speed knobs (with errors) and peers; "
                            "needs a source checkout (runs benchmarks/bench.py; `isettorch bench -h` for options)")
    p.add_argument("args", nargs="*")
    p.set_defaults(func=run)


def run(args) -> int:
    script = find_script()
    if script is None:
        print(f"isettorch bench: needs a source checkout: {SCRIPT} was found neither beside the package "
              f"({Path(__file__).resolve().parents[2]}) nor under the current directory ({Path.cwd()})",
              file=sys.stderr)
        return 2
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])  # the child imports this same isettorch
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    proc = subprocess.run([sys.executable, str(script), *args.args], env=env, stdout=subprocess.PIPE, text=True)
    sys.stdout.write(proc.stdout)  # through sys.stdout, so callers that redirect it see the rows
    sys.stdout.flush()
    return proc.returncode
