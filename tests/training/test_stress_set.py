"""training/stress_set.py's folder mode: another folder's photographs as centre crops in the stress set's variants."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from training import stress_set as ss  # noqa: E402


def _photos(folder: Path) -> dict:
    g = np.random.default_rng(0)
    arrays = {"big": g.integers(0, 256, (41, 57, 3), dtype=np.uint8),  # cropped to 32 x 32 at its centre
              "small": g.integers(0, 256, (21, 27, 3), dtype=np.uint8)}  # smaller than the crop: cut to even sides
    for name, a in arrays.items():
        Image.fromarray(a).save(folder / f"{name}.png")
    return arrays


def test_folder_set_crops_and_variants(tmp_path):
    arrays = _photos(tmp_path)
    images = dict(ss.folder_set(tmp_path, 32, bits=None))
    assert set(images) == {f"{n}/{v}" for n in arrays for v in ss.VARIANTS}
    big = torch.from_numpy(arrays["big"][4:36, 12:44].astype("float64") / 255).permute(2, 0, 1)
    assert torch.equal(images["big/plain"], big)
    assert images["small/plain"].shape == (3, 20, 26)
    assert torch.equal(images["small/plain"], torch.from_numpy(arrays["small"][:20, :26] / 255).permute(2, 0, 1))
    # each variant is the stress set's own (the same function on the same crop)
    for v in ss.VARIANTS:
        assert torch.equal(images[f"big/{v}"], ss.apply_variant(big, v))
    assert torch.allclose(images["big/dark0.1"], 0.1 * big, atol=0, rtol=1e-15)
    q = dict(ss.folder_set(tmp_path, 32))  # 8 bits, as the benchmark's images are
    assert torch.equal(q["big/red"], torch.round(images["big/red"] * 255) / 255)


def test_folder_mode_scores_against_mhc(tmp_path, capsys):
    (tmp_path / "in").mkdir()
    g = np.random.default_rng(1)
    for name, shape in (("a", (40, 44, 3)), ("b", (36, 50, 3))):
        Image.fromarray(g.integers(0, 256, shape, dtype=np.uint8)).save(tmp_path / "in" / f"{name}.png")
    out = tmp_path / "res.json"
    assert ss.main(["--folder", str(tmp_path / "in"), "--size", "32", "--methods", "learned_tiny", "--threads", "1",
                    "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert set(res) == {"malvar2004", "menon2007", "learned_tiny"}
    assert len(res["learned_tiny"]) == 2 * len(ss.VARIANTS)
    # a score, written independently: colour-demosaicing's Malvar-He-Cutler on the centre 32 x 32 crop of "b" (RGGB),
    # CPSNR over the pixels 10 from the border (the benchmark convention)
    cd = pytest.importorskip("colour_demosaicing")
    a = np.asarray(Image.open(tmp_path / "in" / "b.png"), np.float64)[2:34, 9:41] / 255
    rgb = np.clip(cd.demosaicing_CFA_Bayer_Malvar2004(cd.mosaicing_CFA_Bayer(a, "RGGB"), "RGGB"), 0, 1)
    mse = ((rgb - a)[10:-10, 10:-10] ** 2).mean()
    assert res["malvar2004"]["b/plain"] == pytest.approx(10 * np.log10(1 / mse), abs=1e-4)
    assert "learned_tiny: " in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        ss.main(["--folder", str(tmp_path / "in"), "--methods", "menon2007"])
    assert e.value.code == 2 and "--methods" in capsys.readouterr().err
