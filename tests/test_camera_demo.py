"""The main job: ``isettorch demo`` renders the built-in scenes and writes images and a report."""

import json

import numpy as np
import pytest
from PIL import Image

from isettorch.cli import main


def test_demo_writes_images_and_report(tmp_path):
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--size", "64"]) == 0
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
    # Gray patches, white (reflectance 0.9) to black (0.03): shot noise alone would lower the SNR by
    # 10 log10(0.9 / 0.03) = 14.8 dB, read noise by more; measured over >= 12 pixels a patch (a standard error of
    # about 1.7 dB each, 2.4 dB on a difference), so at least 10 dB apart, and falling across the row: the least-
    # squares slope below -1 dB a patch (about -3 measured over noise seeds 0-5; its standard error is about 0.6).
    # A bound on each step (a rise under 3.5 dB: 1.5 standard errors) failed once the blur changed (30.7, 34.4 dB).
    snr = m["gray_patch_snr_db"]
    assert min(m["gray_patch_pixels"]) >= 12
    assert snr[0] - snr[-1] > 10
    assert np.polyfit(np.arange(len(snr)), snr, 1)[0] < -1.0
    md = (out / "report.md").read_text()
    assert "dE" in md or "CIEDE2000" in md


def test_demo_config_typo_is_a_message_and_exit_code_2(tmp_path, capsys):
    # Friction 11 of issue 18: a typo in the user's camera config is reported, not a traceback.
    cfg = tmp_path / "cam.yaml"
    cfg.write_text("optics: {f_numbr: 4.0}\nsensor: {preset: isetcam_default}\n")
    assert main(["demo", "--out", str(tmp_path / "out"), "--size", "32", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "f_numbr" in err and "did you mean 'f_number'" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()  # nothing written for a config that does not load
    assert main(["demo", "--out", str(tmp_path / "out"), "--config", "defualt"]) == 2
    assert "did you mean 'default'" in capsys.readouterr().err


def test_demo_names_a_size_too_small_for_a_wide_sensor(tmp_path, capsys):
    """A fixed 2 x 1000 sensor resized to --size 16 columns has 2 rows: the error named patch_means' 'grid'."""
    cfg = tmp_path / "wide.yaml"
    cfg.write_text("optics: {f_number: 4.0}\nsensor: {preset: isetcam_default, rows: 2, cols: 1000}\n")
    assert main(["demo", "--out", str(tmp_path / "out"), "--size", "16", "--config", str(cfg), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--size: 16 columns give this config's 2 x 1000 sensor 2 rows; the Macbeth chart needs at least 4 " \
           "(--size 2000 or more)" in err and "grid" not in err
    assert not (tmp_path / "out").exists()


def test_demo_runs_from_any_directory_with_the_builtin_config(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "o", "--size", "32", "--quiet"]) == 0
    assert (tmp_path / "o" / "macbeth.png").exists()


def test_demo_monochrome_camera_skips_the_colour_error(tmp_path):
    # a monochrome camera has no XYZ: the report says the colour error was not measured and keeps the rest
    cfg = tmp_path / "mono.yaml"
    cfg.write_text("optics: {f_number: 4.0, focal_length_m: 0.004}\nsensor: {cfa: MONO, auto_exposure: luminance}\n")
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--size", "32", "--config", str(cfg), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    m = report["scenes"]["macbeth"]
    assert m["colour_error"] == "not measured: a monochrome sensor has no colour"
    assert "delta_e2000_mean" not in m
    assert m["gray_patch_snr_channel"] == "W" and len(m["gray_patch_snr_db"]) == 6
    snr = m["gray_patch_snr_db"]
    assert all(np.isfinite(v) for v in snr) and snr[0] > snr[-1]
    assert set(report["scenes"]) == {"macbeth", "slanted_edge", "frequency_sweep", "dead_leaves"}
    md = (out / "report.md").read_text()
    assert "colour error: not measured" in md and "W pixels" in md


def test_demo_snr_names_its_channel_and_never_reports_inf(tmp_path):
    # RGBW on a tiny sensor: the G pixels are measured (the label says which), and a patch with fewer than 2 of them
    # has no SNR (null and a reason), not inf
    cfg = tmp_path / "rgbw.yaml"
    cfg.write_text("optics: {f_number: 4.0, focal_length_m: 0.004}\nsensor: {cfa: RGBW, auto_exposure: luminance}\n")
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--size", "16", "--config", str(cfg), "--quiet"]) == 0
    text = (out / "report.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    m = json.loads(text)["scenes"]["macbeth"]
    assert m["gray_patch_snr_channel"] == "G"
    for v, n, note in zip(m["gray_patch_snr_db"], m["gray_patch_pixels"], m["gray_patch_snr_notes"]):
        assert (v is None) == (n < 2) and (note is None) == (v is not None)
    assert None in m["gray_patch_snr_db"]
    md = (out / "report.md").read_text()
    assert "G pixels" in md and "green pixels" not in md and "n/a" in md


@pytest.mark.parametrize("rows, cols", [(300, 300), (270, 480)])
def test_demo_measures_the_chart_where_a_fixed_sensor_holds_it(tmp_path, rows, cols):
    # A config's fixed sensor keeps its aspect. A square one holds the 6:4 chart, which fills its width, in the middle
    # two thirds of its rows: patch windows over the whole image measured the black border under the top and bottom
    # rows (mean dE2000 22.2, the gray row's 'black' patch at 13 dB). A 16:9 one cropped the chart's top and bottom
    # (its windows straddled patches): the chart is now fitted to the sensor's height. In the chart's footprint the
    # colour error is the sensor-sized camera's (about 4; the 16:9 one was 4.9) and the gray row falls from white
    # to black by shot and read noise (about 28 -> 11 dB, 15 pixels a patch).
    path = tmp_path / "fixed.yaml"
    path.write_text(f"optics: {{f_number: 4.0}}\nsensor: {{preset: isetcam_default, rows: {rows}, cols: {cols}}}\n")
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--size", "64", "--config", str(path), "--quiet"]) == 0
    m = json.loads((out / "report.json").read_text())["scenes"]["macbeth"]
    assert m["sensor_pixels"] == [round(64 * rows / cols / 2) * 2, 64]
    assert m["delta_e2000_mean"] < 6
    snr = m["gray_patch_snr_db"]
    assert snr[0] > 25 and snr[0] - snr[-1] > 8
