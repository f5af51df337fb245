"""The main job: ``isettorch demo`` renders the built-in scenes and writes images and a report."""

import json

import numpy as np
from PIL import Image

from isettorch.cli import main


def test_demo_writes_images_and_report(tmp_path):
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--size", "32"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report["scenes"]) == {"macbeth", "slanted_edge", "frequency_sweep", "dead_leaves"}
    for name, entry in report["scenes"].items():
        img = np.asarray(Image.open(out / entry["image"]))
        assert img.shape == (*entry["sensor_pixels"], 3) and img.dtype == np.uint8
        assert img.max() > 100  # auto exposure fills the range
        assert (out / f"{name}_scene.png").exists()
        assert 0 < entry["exposure_s"] < 1
    m = report["scenes"]["macbeth"]
    assert len(m["delta_e2000_per_patch"]) == 24
    assert abs(m["delta_e2000_mean"] - np.mean(m["delta_e2000_per_patch"])) < 2e-3
    assert 0 < m["delta_e2000_mean"] < 10 and m["delta_e2000_max"] >= m["delta_e2000_mean"]
    # Gray patches: SNR falls from white to black (shot noise).
    snr = m["gray_patch_snr_db"]
    assert snr[0] > snr[-1]
    md = (out / "report.md").read_text()
    assert "dE" in md or "CIEDE2000" in md
