"""Smoke test of ``benchmarks/demosaic_noise_speed.py tight`` on two generated images: the table's rows and its
argument errors. Timings are never asserted."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import demosaic_noise_speed as dns  # noqa: E402  (benchmarks/, not part of the package)


@pytest.fixture(autouse=True)
def _keep_threads():  # the script sets torch's thread count (--threads)
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


def test_tight_table(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png"):
        Image.fromarray(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)).save(tmp_path / name)
    out = tmp_path / "tight.md"
    assert dns.main(["tight", "--kodak", str(tmp_path), "--mcmaster", str(tmp_path), "--pair", "bilinear,malvar2004",
                     "--repeats", "2", "--threads", "1", "--out", str(out)]) == 0
    rows = [r for r in out.read_text().splitlines() if r.startswith("| Kodak") or r.startswith("| McMaster")]
    assert len(rows) == 2
    for r in rows:
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert float(cells[1]) > 0 and float(cells[2]) > 0
        for cell in cells[3:5]:  # "median (min-max)" over the images: the median lies in its own range
            med, lo, hi = (float(v) for v in cell.replace("(", " ").replace(")", " ").replace("-", " ").split())
            assert 0 < lo <= med <= hi
    # the footer names the machine, with the vector instructions the CPU kernels used (timings differ ~2x by them)
    footer = json.loads(out.read_text().rstrip().rsplit("; ", 1)[1])
    assert footer["cpu_capability"] == torch.backends.cpu.get_cpu_capability() and footer["torch_threads"] == 1
    for bad in (["--pair", "bilinear"], ["--repeats", "0"]):
        with pytest.raises(SystemExit) as err:
            dns.main(["tight", "--kodak", str(tmp_path), "--mcmaster", str(tmp_path), *bad])
        assert err.value.code == 2
        assert bad[0] in capsys.readouterr().err
