"""benchmarks/generator_ablation.py: one tiny ablation (2 steps, one component off) on generated test images."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from benchmarks import generator_ablation  # noqa: E402

SMOKE = ROOT / "configs" / "train" / "demosaic_smoke.yaml"


def _setup(tmp_path, seed):
    """Two random 32 px test images (standing in for both test sets) and the tiny ablation's arguments."""
    ims = tmp_path / "ims"
    ims.mkdir()
    rng = np.random.default_rng(seed)
    for i in range(2):
        Image.fromarray(rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)).save(ims / f"{i}.png")
    table = tmp_path / "table.md"
    args = ["--config", str(SMOKE), "--steps", "2", "--out", str(tmp_path / "runs"), "--components", "fine_detail",
            "--kodak", str(ims), "--mcmaster", str(ims), "--table", str(table)]
    return ims, table, args


def test_ablation_smoke(tmp_path):
    ims, table, args = _setup(tmp_path, 0)
    assert generator_ablation.main(args) == 0
    lines = [ln for ln in table.read_text().splitlines() if ln.startswith("| ")]
    assert lines[0].startswith("| generator | Kodak | d Kodak")
    assert lines[1].startswith("| all components |") and "| +0.00 |" in lines[1]
    assert lines[2].startswith("| without fine_detail |") and len(lines) == 3
    rec = json.loads((tmp_path / "runs" / "without_fine_detail" / "record.json").read_text())
    assert rec["config"]["data"]["disable"] == ["fine_detail"] and rec["steps"] == 2
    assert "without fine_detail" in rec["data"]
    # a second call reuses each finished run and its saved scores (nothing retrained or re-scored)
    scores = tmp_path / "runs" / "without_fine_detail" / "scores.json"
    assert json.loads(scores.read_text())["steps"] == 2
    before = table.read_text()
    (ims / "0.png").unlink()  # re-scoring would now fail
    assert generator_ablation.main(args) == 0 and table.read_text() == before


def test_ablation_seeds(tmp_path):
    """``--seeds 0 1``: each configuration trained once per seed (its own folder and ``seed``); the table's means,
    differences and pooled standard error agree with numpy on the per-run saved scores."""
    _, table, base = _setup(tmp_path, 1)
    assert generator_ablation.main(base + ["--seeds", "0", "1"]) == 0
    scores = {}
    for s in (0, 1):
        for name in ("all_components", "without_fine_detail"):
            run = tmp_path / "runs" / f"seed{s}" / name
            assert json.loads((run / "record.json").read_text())["config"]["seed"] == s
            scores[s, name] = json.loads((run / "scores.json").read_text())
    rows = [ln.split("|")[1:-1] for ln in table.read_text().splitlines() if ln.startswith("| ")][1:]
    assert [r[0].strip() for r in rows] == ["all components", "without fine_detail"]
    names = ("all_components", "without_fine_detail")
    k = {name: np.array([scores[s, name]["kodak"] for s in (0, 1)]) for name in names}
    assert rows[0][1].strip() == " / ".join(f"{v:.2f}" for v in k["all_components"])
    assert float(rows[1][2]) == round(k["without_fine_detail"].mean(), 2)
    assert abs(float(rows[1][3]) - (k["without_fine_detail"].mean() - k["all_components"].mean())) <= 0.0051
    se = np.sqrt(np.mean([np.var(v, ddof=1) for v in k.values()]) * 2 / 2)
    assert f"Kodak {se:.2f} dB" in table.read_text()
    for bad in (["--seeds", "3"], ["--seeds", "1", "1"]):
        with pytest.raises(ValueError, match="--seeds"):
            generator_ablation.main(base + bad)
