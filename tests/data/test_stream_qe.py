"""PairStream with per-item shifted QE curves (``camera.qe_variation > 0``), as CameraPairDataset draws them.

The distribution test compares the location and spread of each channel's QE curve in the items' metadata (its
centroid wavelength, sum l QE(l) / sum QE(l): continuous in the shift, where the argmax moves in 10 nm grid steps)
by two-sample z tests at 4 combined standard errors, as ``tests/data/test_stream.py`` does for the other statistics:
both samples are fixed by their seeds, so the test passes or fails deterministically; were the distributions
equal, an unlucky seed would fail one statistic with probability ~6e-5.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from isettorch.data import PairStream
from isettorch.data.camera_pairs import CameraPairDataset, nikon_d5100_qe

SMALL = {"height": 32, "width": 32}


def _z_close(a, b, n_sigma=4.0):
    a, b = np.asarray(a, float), np.asarray(b, float)
    se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    return abs(a.mean() - b.mean()) <= n_sigma * se, (a.mean(), b.mean(), se)


def test_stream_with_qe_variation_equals_camera(stream_equals_camera):
    """Each group's Camera applied to the drawn scenes with the group's per-item QE (a per-call ``spectral_qe``
    of ``[b, 3, Ln]`` curves) gives the stream's noise-free raw to float rounding, and one group's noisy raw
    bitwise; the items' curves differ and the metadata holds each item's QE x its peak."""
    cam = {"pixel_size_m": [1.4e-6, 2.8e-6], "qe_variation": 1.0}
    stream = PairStream(6, seed=1, scene=SMALL, camera=cam)
    stream_equals_camera(stream, 0,
                         PairStream(5, seed=4, scene=SMALL, camera={"pixel_size_m": [2.0e-6], "qe_variation": 0.5},
                                    targets=("camera_rgb",)), 7)
    batch = stream.batch(0)
    for grp in stream.draw(0):
        qe = grp.kwargs["spectral_qe"]
        assert qe.batch_size == grp.index.numel()
        wl = batch["meta"]["wavelengths_nm"][0].to(torch.float64)
        want = qe(wl) * grp.kwargs["qe_scale"][:, None, None]
        torch.testing.assert_close(batch["meta"]["qe"][grp.index].to(torch.float64), want, rtol=1e-6, atol=1e-7)
    qe = batch["meta"]["qe"].to(torch.float64)
    unit = qe / qe.amax((1, 2), keepdim=True)
    assert float((unit - unit[:1]).abs().amax()) > 0.05  # per-item curves, not one QE scaled


def test_without_qe_variation_the_draws_and_nominal_qe_are_kept():
    """qe_variation 0 draws no shifts (the shifts come last, so every other camera setting of the batch is the one
    drawn with a variation) and renders the nominal D5100 curves x each item's peak (an independent loader:
    ``nikon_d5100_qe`` resamples the NPL set directly)."""
    cam = {"pixel_size_m": [1.4e-6, 2.8e-6], "cfa_patterns": ["RGGB", "GBRG"]}
    plain = PairStream(6, seed=2, scene=SMALL, camera=cam)
    varied = PairStream(6, seed=2, scene=SMALL, camera=dict(cam, qe_variation=0.5))
    gp, gv = plain.draw(3), varied.draw(3)
    assert [g.index.tolist() for g in gp] == [g.index.tolist() for g in gv]
    for a, b in zip(gp, gv):
        assert "spectral_qe" not in a.kwargs and "spectral_qe" in b.kwargs
        assert set(b.kwargs) - {"spectral_qe"} == set(a.kwargs)
        for key, v in a.kwargs.items():
            assert torch.equal(v, b.kwargs[key]), key
    meta = plain.batch(3)["meta"]
    wl = meta["wavelengths_nm"][0].to(torch.float64)
    nominal = nikon_d5100_qe(wl, 1.0)
    peak = meta["qe"].to(torch.float64).amax((1, 2)) / float(nominal.max())
    torch.testing.assert_close(meta["qe"].to(torch.float64), nominal[None] * peak[:, None, None], rtol=1e-6,
                               atol=1e-7)
    with pytest.raises(ValueError, match="qe_variation"):
        PairStream(2, scene=SMALL, camera={"qe_variation": -1.0})


def _centroids(meta) -> np.ndarray:
    """Per item and channel: the QE curve's centroid wavelength (nm) ``[B, 3]``."""
    qe = meta["qe"].to(torch.float64)
    wl = meta["wavelengths_nm"].to(torch.float64)[:, None, :]
    return ((qe * wl).sum(-1) / qe.sum(-1)).numpy()


def test_qe_shift_distribution_matches_camera_pair_dataset():
    """At qe_variation 1 (shifts uniform in [-10, 10] nm per channel) the mean and the spread (mean squared
    deviation from the sample mean) of each channel's centroid agree between stream and dataset items."""
    n = 192
    cam = {"qe_variation": 1.0, "cfa_patterns": ["RGGB", "GRBG"]}
    stream = PairStream(48, seed=11, scene=SMALL, camera=cam, targets=("noise_free_raw",))
    s = np.concatenate([_centroids(stream.batch(k)["meta"]) for k in range(n // 48)])
    d = _centroids(CameraPairDataset(n, seed=11, scene=SMALL, camera=cam, targets=("noise_free_raw",))
                   .get_batch(list(range(n)))["meta"])
    nominal = _centroids({"qe": nikon_d5100_qe(torch.arange(400.0, 701.0, 10.0), 1.0)[None],
                          "wavelengths_nm": torch.arange(400.0, 701.0, 10.0)[None]})[0]
    for c in range(3):
        ok, info = _z_close(s[:, c], d[:, c])
        assert ok, ("mean", c, info)
        ok, info = _z_close((s[:, c] - s[:, c].mean()) ** 2, (d[:, c] - d[:, c].mean()) ** 2)
        assert ok, ("spread", c, info)
        # a shift of s nm moves the centroid by about s (the grid's 10 nm sampling and ends bend it a little): a
        # spread about the uniform law's 10 / sqrt(3) = 5.8 nm (measured 5.9-6.0 here, 5.5-5.6 for the dataset;
        # the bounds catch a wrong scale: no shift, or a range off by a factor), centred on the nominal curve's
        # centroid (a symmetric law)
        assert 4.0 < s[:, c].std() < 7.5 and abs(s[:, c].mean() - nominal[c]) < 4 * s[:, c].std() / math.sqrt(n)
