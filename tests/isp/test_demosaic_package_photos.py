"""benchmarks/demosaic_package_photos.py: the photographs come from scikit-image's wheel (nothing downloaded), whole
Bayer cells, RGB uint8; its scores are evaluate_demosaic's, checked here against colour-demosaicing's bilinear on the
same mosaic (an independent implementation); a malformed --models argument names itself."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import demosaic_package_photos as dpp  # noqa: E402  (benchmarks/ is not part of the package)


def test_photos_are_shipped_rgb_whole_cells():
    photos = dpp.package_photos()
    assert [n for n, _ in photos] == list(dpp.PHOTOS)
    for name, a in photos:
        assert a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3, name
        assert a.shape[0] % 2 == 0 and a.shape[1] % 2 == 0, name
        assert a.std() > 20, name  # a photograph, not a blank or a placeholder
    assert dict(photos)["chelsea.png"].shape == (300, 450, 3)  # 451 columns, the last one dropped


def test_bilinear_matches_colour_demosaicing():
    cd = pytest.importorskip("colour_demosaicing")
    from isettorch.isp import evaluate_demosaic

    name, a = dpp.package_photos()[1]
    ours = evaluate_demosaic([(name, a)], method="bilinear", crop=10)["mean_cpsnr"]
    truth = a.astype(np.float64) / 255
    est = np.clip(cd.demosaicing_CFA_Bayer_bilinear(cd.mosaicing_CFA_Bayer(truth, "RGGB"), "RGGB"), 0, 1)
    mse = np.mean((est - truth)[10:-10, 10:-10] ** 2)
    assert ours == pytest.approx(10 * np.log10(1 / mse), abs=0.02)


def test_bad_models_argument_names_itself():
    with pytest.raises(ValueError, match="--models"):
        dpp.main(["--models", "no_path_given", "--threads", "1"])


def test_folder_photos_are_read_sorted_and_cut_to_whole_cells(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(0)
    odd = rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)
    even = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    Image.fromarray(odd).save(tmp_path / "b.png")
    Image.fromarray(even).save(tmp_path / "a.png")
    photos = dpp.folder_photos(tmp_path)
    assert [n for n, _ in photos] == ["a.png", "b.png"]
    np.testing.assert_array_equal(photos[0][1], even)
    np.testing.assert_array_equal(photos[1][1], odd[:6, :8])  # the last odd row and column dropped
