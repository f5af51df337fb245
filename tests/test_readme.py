"""The README's API tour runs as written (from the repository root)."""

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_tour_runs(monkeypatch):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no python block"
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)  # noqa: S102 - our own README
    assert namespace["sfr"].mtf50 is not None
    assert len(namespace["pairs"]) == 1000
    assert os.path.isdir(ROOT / "configs" / "cameras")


def test_readme_quick_start_commands_exist():
    text = (ROOT / "README.md").read_text()
    assert "python3 dev.py demo" in text and "python3 dev.py test" in text
    assert "python3 dev.py test" in (ROOT / ".ci" / "run").read_text()
