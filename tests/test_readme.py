"""The README's API tour runs as written (from the repository root)."""

import os
import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def test_readme_tour_runs(monkeypatch):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no python block"
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)  # noqa: S102 - our own README
    assert namespace["sfr"].mtf50 is not None
    # the tour's claims about the factored scene: one map per Macbeth patch, and its projection equals the
    # projection of the dense cube (built from the factors, projected by the dense code path)
    s, dense, cmf = namespace["s"], namespace["dense"], namespace["cmf"]
    assert s.is_factored and not dense.is_factored and s.maps.shape[1] == 24
    torch.testing.assert_close(namespace["xyz_planes"], dense.project(cmf), rtol=1e-6, atol=0.0)
    # per-call sensor levels reach the RawImage
    torch.testing.assert_close(namespace["raw_iso"].analog_gain.double().reshape(-1),
                               torch.tensor([4.0], dtype=torch.float64))
    assert len(namespace["pairs"]) == 1000
    assert os.path.isdir(ROOT / "configs" / "cameras")


def test_readme_quick_start_commands_exist():
    text = (ROOT / "README.md").read_text()
    assert "python3 dev.py demo" in text and "python3 dev.py test" in text
    assert "python3 dev.py test" in (ROOT / ".ci" / "run").read_text()
