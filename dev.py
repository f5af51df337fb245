#!/usr/bin/env python3
"""Set up a virtual environment and run a project task: ``python3 dev.py demo|test|lint|bench``.

Needs only Python >= 3.10 and pip. The environment goes to ``.venv`` and is reused while
``pyproject.toml`` and ``constraints.txt`` are unchanged.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".isettorch-installed"


def _run(*args: str | os.PathLike) -> None:
    print("+", " ".join(str(a) for a in args), flush=True)
    subprocess.run([str(a) for a in args], check=True, cwd=ROOT)


def _fingerprint() -> str:
    h = hashlib.sha256()
    for name in ("pyproject.toml", "constraints.txt"):
        h.update((ROOT / name).read_bytes())
    return h.hexdigest()


def setup() -> None:
    if STAMP.exists() and STAMP.read_text() == _fingerprint() and PY.exists():
        return
    if not PY.exists():
        venv.EnvBuilder(with_pip=True).create(VENV)
    pip = [PY, "-m", "pip", "install", "--disable-pip-version-check", "-q"]
    # torch first and pinned: an unpinned torch would pull a multi-GB CUDA build.
    _run(*pip, "-c", ROOT / "constraints.txt", "torch==2.13.0")
    # The lens extras (glass catalogue, independent reference tracer) and rawpy so their tests run, not skip.
    _run(*pip, "-c", ROOT / "constraints.txt", "-e", f"{ROOT}[test,lens,lens-reference,raw]")
    STAMP.write_text(_fingerprint())


def main(argv: list[str]) -> int:
    task = argv[0] if argv else "test"
    rest = argv[1:]
    setup()
    if task == "setup":
        return 0
    if task == "demo":
        _run(BIN / "isettorch", "demo", "--out", "out", *rest)
    elif task == "test":
        _run(PY, "-m", "pytest", "-q", "-n", "2", *rest)
    elif task == "lint":
        _run(PY, "-m", "ruff", "check", "isettorch", "tests", "training", "benchmarks", *rest)
    elif task == "bench":
        _run(BIN / "isettorch", "bench", *rest)
    else:
        print(f"dev.py: unknown task {task!r}; expected one of setup, demo, test, lint, bench", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except subprocess.CalledProcessError as err:
        sys.exit(err.returncode or 1)
