#!/usr/bin/env bash
# Build the documentation (Sphinx + sphinx-gallery, gallery executed) with warnings as errors.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 dev.py setup
.venv/bin/python -m pip install --disable-pip-version-check -q -c constraints.txt -e ".[docs]"
rm -rf docs/_build docs/auto_examples
OMP_NUM_THREADS=2 MPLBACKEND=Agg timeout 900 .venv/bin/python -m sphinx -W --keep-going -q -b html docs docs/_build/html
echo "docs.sh: built docs/_build/html"
