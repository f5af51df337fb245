"""training/photo_select.py: a checkpoint's correction scales scored on a folder of photographs, each row checked
against the shipped method and scikit-image's PSNR on the same pixels."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image
from skimage.metrics import peak_signal_noise_ratio

from isettorch.isp.demosaicing import demosaic, mosaic
from isettorch.isp.learned import PRETRAINED
from training import photo_select


def _photos(folder, n=2, size=64):
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:size, 0:size]
    out = []
    for i in range(n):  # smooth colour ramps with an edge and some texture: the network and MHC disagree
        img = np.stack([0.5 + 0.4 * np.sin(xx / (5 + i) + c) * (yy > size // 2) for c in range(3)], -1)
        img = np.clip(img + rng.normal(0, 0.03, img.shape), 0, 1)
        a = (img * 255).round().astype(np.uint8)
        Image.fromarray(a).save(folder / f"p{i}.png")
        out.append(a)
    return out


def _skimage_cpsnr(a: np.ndarray, method: str) -> float:
    truth = torch.from_numpy(a).permute(2, 0, 1)[None].double() / 255
    out = demosaic(mosaic(truth, "RGGB").float(), "RGGB", method=method).double().clamp(0, 1)
    t, o = (x[0, :, 10:-10, 10:-10].numpy() for x in (truth, out))
    return peak_signal_noise_ratio(t, o, data_range=1.0)


def test_rows_are_the_shipped_method_scored_independently(tmp_path):
    photos = _photos(tmp_path)
    nets = photo_select._candidates(str(PRETRAINED["tiny"]), "tiny", [0.5, 1.0])
    rows = photo_select.score(nets, str(tmp_path), stress=False)
    want = [_skimage_cpsnr(a, "learned_tiny") for a in photos]
    mhc = [_skimage_cpsnr(a, "malvar2004") for a in photos]
    assert abs(rows["shipped"]["photos_mean"] - np.mean(want)) < 1e-3
    assert abs(rows["malvar2004"]["photos_mean"] - np.mean(mhc)) < 1e-3
    assert rows["shipped"]["photos_below_mhc"] == sum(w < m - 0.1 for w, m in zip(want, mhc))
    # the shipped scale is 0.5: that candidate is the shipped network; scale 1 is another function
    assert rows["scale 0.5"]["per_photo"] == rows["shipped"]["per_photo"]
    assert abs(rows["scale 1"]["photos_mean"] - rows["shipped"]["photos_mean"]) > 1e-3


def test_guard_options_change_the_candidates_only(tmp_path):
    _photos(tmp_path, n=1)
    nets = photo_select._candidates(str(PRETRAINED["tiny"]), "tiny", [0.5], {"reference": "base"})
    assert nets["scale 0.5"].guard["reference"] == "base" and "reference" not in nets["shipped"].guard
    rows = photo_select.score(nets, str(tmp_path), stress=False)
    assert rows["scale 0.5"]["photos_mean"] != rows["shipped"]["photos_mean"]


def test_weight_interpolation_candidates(tmp_path):
    # alpha 0 is the start's weights, alpha 1 the checkpoint's; both ends are the shipped tiny network here
    nets = photo_select._candidates(str(PRETRAINED["tiny"]), "tiny", [0.5], start=str(PRETRAINED["tiny"]),
                                    alphas=[0.0, 1.0])
    raw = torch.rand(1, 1, 32, 32, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        ref = nets["shipped"](raw)
        for name in ("alpha 0 scale 0.5", "alpha 1 scale 0.5"):
            torch.testing.assert_close(nets[name](raw), ref, rtol=0, atol=1e-6)
