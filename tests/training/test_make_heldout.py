"""training/make_heldout.py: held-out synthetic PNGs, deterministic, with generator components switched off."""

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from training import make_heldout  # noqa: E402


def _write(folder, *extra):
    assert make_heldout.main(["--out", str(folder), "--n", "2", "--size", "48", "--quiet", *extra]) == 0
    files = sorted(folder.glob("*.png"))
    assert [f.name for f in files] == ["natural_000.png", "natural_001.png"]
    return np.stack([np.asarray(Image.open(f)) for f in files])


def test_deterministic_and_disable_changes_the_scenes(tmp_path):
    a = _write(tmp_path / "a", "--colour-space", "linear_srgb")
    b = _write(tmp_path / "b", "--colour-space", "linear_srgb")
    np.testing.assert_array_equal(a, b)  # same seeds, same bytes
    assert a.shape == (2, 48, 48, 3) and a.dtype == np.uint8
    c = _write(tmp_path / "c", "--colour-space", "linear_srgb", "--disable", "colour_correlation")
    assert np.abs(a.astype(int) - c.astype(int)).mean() > 1.0  # another generator, other scenes


def test_bad_component_is_named(tmp_path):
    with pytest.raises(ValueError, match="disable"):
        make_heldout.main(["--out", str(tmp_path), "--n", "1", "--size", "32", "--quiet", "--disable", "sky"])


def test_stress_set_gains_and_grain(tmp_path):
    base = _write(tmp_path / "base").astype(float)
    dark = _write(tmp_path / "dark", "--channel-gains", "1", "0.25", "0.25").astype(float)
    np.testing.assert_array_equal(dark[..., 0], base[..., 0])
    np.testing.assert_allclose(dark[..., 1:], np.round(base[..., 1:] / 255 * 0.25 * 255), atol=1)  # 8-bit rounding
    grainy = _write(tmp_path / "grain", "--grain-std", "0.02").astype(float)
    d = (grainy - base) / 255
    inner = (base > 20) & (base < 235)  # away from the clip at 0 and 1
    assert abs(d[inner].std() - 0.02) < 0.003  # the grain's std, to the 8-bit rounding's
    with pytest.raises(ValueError, match="--channel-gains"):
        make_heldout.main(["--out", str(tmp_path / "x"), "--channel-gains", "1", "2", "1"])


def test_generator_options_draw_another_set(tmp_path):
    """--natural: a held-out set drawn with a candidate generator's options (here the multiplicative grain); '{}' is
    the default set, byte for byte; bad JSON or an unknown option raises naming it."""
    a = _write(tmp_path / "a")
    np.testing.assert_array_equal(_write(tmp_path / "b", "--natural", "{}"), a)
    rel = _write(tmp_path / "rel", "--natural", '{"components": {"grain": {"relative": {"probability": 1.0}}}}')
    assert np.abs(rel.astype(int) - a.astype(int)).mean() > 0.5
    for bad, match in (("{oops", "--natural"), ("[1]", "--natural"), ('{"components": {"sky": {}}}', "sky")):
        with pytest.raises(ValueError, match=match):
            make_heldout.main(["--out", str(tmp_path / "x"), "--n", "1", "--size", "32", "--quiet", "--natural", bad])
