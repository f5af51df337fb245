#!/usr/bin/env bash
# Build the documentation (Sphinx + sphinx-gallery, gallery executed) with warnings as errors.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 dev.py setup
.venv/bin/python -m pip install --disable-pip-version-check -q -c constraints.txt -e ".[docs]"
rm -rf docs/_build docs/auto_examples
# One torch thread: the gallery's tensors are tiny, and on a loaded machine a second thread spins waiting for a
# core (the demosaic-training example took 3 s with one thread, 12-22 s with two, at load 4-5 on 2 cores).
OMP_NUM_THREADS=1 MPLBACKEND=Agg timeout 900 .venv/bin/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
echo "docs.sh: built docs/_build/html"
