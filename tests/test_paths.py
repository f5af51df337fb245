"""ISETTORCH_DATA and data paths in configs (issue 18, friction 5)."""

import re
from pathlib import Path

import pytest

from isettorch.paths import data_path, data_root

ROOT = Path(__file__).resolve().parents[1]


def test_configs_hold_no_machine_specific_paths():
    # Configs name data relative to $ISETTORCH_DATA: no absolute or home paths that only exist on one machine.
    absolute = re.compile(r"(?<![\w.])(/(?:work|home|Users|mnt|data|tmp|scratch)/|~/|[A-Za-z]:\\\\)")
    for cfg in sorted((ROOT / "configs").rglob("*.yaml")):
        for n, line in enumerate(cfg.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            assert not absolute.search(code), f"{cfg.relative_to(ROOT)}:{n}: machine-specific path in {line!r}"


def test_data_path_resolves_under_isettorch_data(tmp_path, monkeypatch):
    (tmp_path / "kodak24").mkdir()
    monkeypatch.setenv("ISETTORCH_DATA", str(tmp_path))
    assert data_root() == tmp_path
    assert data_path("kodak24") == tmp_path / "kodak24"
    assert data_path(str(tmp_path / "kodak24")) == tmp_path / "kodak24"  # absolute: as given
    monkeypatch.setenv("OTHER_ROOT", str(tmp_path))
    assert data_path("$OTHER_ROOT/kodak24") == tmp_path / "kodak24"
    with pytest.raises(FileNotFoundError, match=r"'mcmaster18' .* does not exist .*ISETTORCH_DATA.*set to"):
        data_path("mcmaster18")
    monkeypatch.delenv("ISETTORCH_DATA")
    monkeypatch.chdir(tmp_path)
    assert data_root() == Path("data")
    with pytest.raises(FileNotFoundError, match="unset, so ./data"):
        data_path("kodak24")
    with pytest.raises(ValueError, match="path"):
        data_path("")


def test_readme_documents_isettorch_data():
    text = (ROOT / "README.md").read_text()
    assert "ISETTORCH_DATA" in text and "isettorch.paths" in text
