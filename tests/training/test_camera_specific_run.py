"""training/camera_specific_run.py (issue 35 item 5's full-size run), shrunk: the simulated capture calibrates to the
camera's truth, the camera config carries it, and the simulated raw frames of a photograph are exposed as stated."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from training import camera_specific_run as run


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_prepare_calibrates_to_the_truth_and_frames_are_exposed_as_stated(tmp_path, monkeypatch):
    monkeypatch.setattr(run, "SHAPE", (96, 96))
    calib = run.prepare(tmp_path)
    # 96^2 px, 2 frames per exposure: the variance estimates' standard error is about sqrt(2 / 9216) = 1.5 %
    assert calib["gain_dn_per_e"]["measured"] == pytest.approx(run.TRUTH["gain_dn_per_e"], rel=0.05)
    assert calib["read_noise_e"]["measured"] == pytest.approx(run.TRUTH["read_noise_e"], rel=0.08)
    assert calib["black_level_dn"]["measured"] == pytest.approx(run.TRUTH["black_level_dn"], abs=0.5)
    assert json.loads((tmp_path / "calibration.json").read_text()) == calib
    cam = yaml.safe_load((tmp_path / "camera.yaml").read_text())
    assert cam["sensor"]["cfa"] == "RGGB" and cam["sensor"]["auto_exposure"] == "percentile"
    # a grey photograph: every mosaic pixel at the AE target, so the frame's mean is black + target x span (DN),
    # up to PRNU (0.8 %, zero mean) and the Poisson noise of ~9000 pixels
    grey = np.full((64, 80, 3), 128, np.uint8)
    (name, path, truth, scale), = run._frames([("grey.png", grey)], tmp_path / "frames", 0.5)
    dn = np.load(path)
    span = 2 ** run.TRUTH["bits"] - 1 - run.TRUTH["black_level_dn"]
    assert dn.shape == (64, 80) and dn.dtype == np.uint16 and scale == pytest.approx(0.5 / (128 / 255))
    assert dn.mean() == pytest.approx(run.TRUTH["black_level_dn"] + 0.5 * span, rel=2e-3)
    # shot noise: var(DN) = K^2 mean electrons (+ read noise), K = 4 DN/e-
    electrons = 0.5 * span / run.TRUTH["gain_dn_per_e"]
    expected_var = run.TRUTH["gain_dn_per_e"] ** 2 * (electrons + run.TRUTH["read_noise_e"] ** 2)
    assert dn.astype(float).var() == pytest.approx(expected_var, rel=0.1)
