"""Installation: the camera configs are package data, found by name from any directory (issue 18, item 1)."""

from fnmatch import fnmatch
from pathlib import Path

import pytest
import torch
import yaml

import isettorch
from isettorch.camera import Camera, camera_config_names, load_config

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(isettorch.__file__).resolve().parent


def test_builtin_configs_are_package_data():
    # Every camera config lives inside the package and matches a package-data glob of pyproject.toml, so the
    # wheel carries it (.ci/run checks the installed wheel itself from an empty folder).
    files = sorted(p.relative_to(PACKAGE).as_posix() for p in (PACKAGE / "configs" / "cameras").glob("*.yaml"))
    assert files == [f"configs/cameras/{n}.yaml" for n in ("cooke_lens", "default", "imx363", "isetcam_microlens",
                                                           "paper2004_cds", "phone_microlens")]
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["isettorch"]
    for f in files:
        assert any(fnmatch(f, g) for g in globs), (f, globs)
    # The source tree's configs/cameras is the same folder (one copy of each file).
    assert (ROOT / "configs" / "cameras").resolve() == (PACKAGE / "configs" / "cameras").resolve()


def test_from_config_by_name_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing relative to the checkout
    assert camera_config_names() == ["cooke_lens", "default", "imx363", "isetcam_microlens", "paper2004_cds",
                                     "phone_microlens"]
    cam = Camera.from_config("default")
    assert cam.name == "default" and float(cam.optics.f_number) == 4.0
    assert abs(float(cam.optics.focal_length_m) - 3.862755099e-3) < 1e-15


def test_unknown_name_suggests_the_closest():
    with pytest.raises(ValueError, match=r"'defualt'.*did you mean 'default'"):
        Camera.from_config("defualt")
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        Camera.from_config("nope.yaml")


@pytest.mark.parametrize("name", ["default", "imx363", "paper2004_cds"])
def test_dict_config_equals_yaml_config(name):
    # One schema: the dict a user writes in Python has exactly the YAML's keys and builds the same camera.
    path = PACKAGE / "configs" / "cameras" / f"{name}.yaml"
    as_dict = yaml.safe_load(path.read_text())
    assert load_config(name) == load_config(path) == as_dict
    a, b = Camera.from_config(path).state_dict(), Camera.from_config(as_dict).state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_config_keys_with_units_carry_them_in_their_names():
    # Physical quantities in the shipped configs are named with their unit (SI unless the name says otherwise).
    quantities = {"focal_length": "_m", "exposure": "_s", "pixel_size": "_m"}
    for name in camera_config_names():
        cfg = load_config(name)
        for section in ("optics", "sensor"):
            for key in cfg.get(section) or {}:
                for stem, unit in quantities.items():
                    if key.startswith(stem) and key != "auto_exposure":
                        assert key.endswith(unit), (name, section, key)
