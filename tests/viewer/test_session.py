"""The viewer's session (no browser): region geometry, config overrides and errors."""

from __future__ import annotations

import numpy as np
import pytest

from isettorch.viewer.session import ROI, Settings, ViewerSession, resolve_config


def test_roi_from_box_maps_bokeh_y_up_to_rows_and_limits_to_the_image():
    # A 10 x 20 image shown with y = height - row: the box x 2.4..7.6, y 6.5..9.2 covers rows 0.8..3.5.
    assert ROI.from_box(2.4, 7.6, 6.5, 9.2, 10, 20) == ROI(0, 4, 2, 8)
    # Reversed corners give the same region; a box past the edges is limited to the image.
    assert ROI.from_box(7.6, 2.4, 9.2, 6.5, 10, 20) == ROI(0, 4, 2, 8)
    assert ROI.from_box(-5, 30, -3, 15, 10, 20) == ROI(0, 10, 0, 20)
    # A click (zero-area box) still selects one pixel.
    assert ROI.from_box(3.2, 3.2, 4.7, 4.7, 10, 20) == ROI(5, 6, 3, 4)
    assert ROI(8, 12, 18, 25).fit(10, 20) == ROI(8, 10, 18, 20)
    assert ROI.centre(8, 12, 0.5) == ROI(2, 6, 3, 9)


def test_camera_config_overrides_use_the_configs_own_keys():
    s = ViewerSession.__new__(ViewerSession)  # only the config logic, no render
    s.base_config = {"optics": {"f_number": 4.0}, "sensor": {"auto_exposure": "luminance"}, "isp": {}}
    s.settings = Settings()
    cfg = s.camera_config(Settings(f_number=8.0, exposure_ms=2.0, pixel_size_um=1.4, cfa="RGGB", noise=False,
                                   demosaic="malvar2004"))
    assert cfg["optics"]["f_number"] == 8.0
    assert cfg["sensor"] == {"auto_exposure": None, "exposure_s": 0.002, "pixel_size_m": pytest.approx(1.4e-6),
                             "cfa": "RGGB"}
    assert cfg["camera"] == {"noise": False} and cfg["isp"] == {"demosaic": "malvar2004"}
    assert s.base_config["optics"]["f_number"] == 4.0  # the base config is not modified


def test_bad_inputs_name_the_argument(tmp_path):
    with pytest.raises(FileNotFoundError, match="config"):
        resolve_config("no_such_camera")
    with pytest.raises(ValueError, match="size"):
        ViewerSession("default", size=4)
    bad = tmp_path / "scene.xyz"
    bad.write_text("x")
    with pytest.raises(ValueError, match="scene"):
        ViewerSession("default", scene=str(bad), size=32)


def test_view_command_reports_a_bad_config_without_a_traceback(capsys):
    pytest.importorskip("bokeh", reason="the viewer extra (bokeh) is not installed")
    from isettorch.cli import main

    assert main(["view", "--config", "no_such_camera", "--no-browser", "--port", "0"]) == 2
    assert "no_such_camera" in capsys.readouterr().err


def test_sensor_window_etendue_map_of_pixel_optics():
    import math

    import torch

    from isettorch.camera import load_config
    from isettorch.sensor.microlens import microlens_etendue

    cfg = load_config("isetcam_microlens")
    cfg["sensor"]["pixel_optics"]["exit_pupil_distance_m"] = 0.15e-3  # a short pupil: CRAs to ~17 deg
    s = ViewerSession(cfg, scene="uniform_d65", size=32)
    s.render()
    em = s.etendue_map()
    rows, cols = s.output.raw.data.shape[-2:]
    assert em["map"].shape == (rows, cols) and em["method"] == "centred"
    r = math.hypot((rows - 1) / 2, (cols - 1) / 2) * 2.8e-6
    cra = math.degrees(math.atan(r / 0.15e-3))
    assert em["corner_cra_deg"] == pytest.approx(cra, rel=1e-9)
    assert em["corner"] == pytest.approx(float(microlens_etendue(torch.tensor(cra), "centred")), abs=0.01)
    assert em["centre"] == pytest.approx(1.0, abs=1e-6) and em["corner"] < 0.95
    plain = ViewerSession("default", scene="uniform_d65", size=32)
    plain.render()
    assert plain.etendue_map() is None


def test_a_photograph_scene_is_read_as_the_library_reads_photographs(tmp_path):
    """A photograph opens through io.images.read_rgb8 (as design-eval and demosaic-eval open them): the scene is
    scene.from_rgb of its code values / 255, shown in its EXIF orientation, and a 16-bit PNG is refused by name
    (Pillow's convert('RGB') kept 8 of its 16 bits)."""
    import numpy as np
    import torch
    from PIL import Image

    from isettorch.scene import from_rgb
    from isettorch.viewer.session import _read_scene_file

    codes = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    img = Image.fromarray(codes)
    exif = img.getexif()
    exif[0x0112] = 6  # orientation: rotate 90 degrees clockwise to display
    img.save(tmp_path / "p.jpg", exif=exif, quality=100)
    shown = np.asarray(Image.open(tmp_path / "p.jpg").transpose(Image.Transpose.ROTATE_270))
    scene = _read_scene_file(tmp_path / "p.jpg", 10.0)
    expected = from_rgb(torch.from_numpy(shown.astype(np.float64) / 255).permute(2, 0, 1)[None].float())
    torch.testing.assert_close(scene.to_dense().photons, expected.to_dense().photons)
    Image.fromarray(np.full((4, 4), 60000, dtype=np.uint16)).save(tmp_path / "deep.png")
    with pytest.raises(ValueError, match="expected 8-bit samples"):
        _read_scene_file(tmp_path / "deep.png", 10.0)
    # the photo folders' formats (a .webp or .jfif was "not a readable file" here)
    Image.fromarray(codes).save(tmp_path / "p.webp", lossless=True)
    webp = _read_scene_file(tmp_path / "p.webp", 10.0)
    flat = from_rgb(torch.from_numpy(codes.astype(np.float64) / 255).permute(2, 0, 1)[None].float())
    torch.testing.assert_close(webp.to_dense().photons, flat.to_dense().photons)


def test_a_rejected_change_leaves_the_session_and_its_caches_consistent():
    s = ViewerSession("default", "macbeth", size=32)  # (cache_size 4: the sequence below evicts an OI, not its raw)
    before = s.settings
    with pytest.raises(ValueError, match="exposure_s"):
        s.update(exposure_ms=-1.0)
    assert s.settings == before  # (it stayed, and every later change failed with the exposure's message)
    for bad in ("yes", "no", 1):  # noise 'no' was bool('no'): noise on, and a second raw cache entry
        with pytest.raises(TypeError, match=r"config: camera\.noise must be bool"):
            s.update(noise=bad)
        assert s.settings == before
    # one raw outliving its optical image in the caches (trimmed apart) was a KeyError on its reuse
    for f in (2.0, 2.8, 5.6):
        s.update(f_number=f)
    s.update(cfa="RGGB")
    for f in (2.0, 8.0, 11.0, 2.0):
        s.update(f_number=f)
        assert float(s.output.optical_image.f_number.reshape(-1)[0]) == f
    s.update(cfa=None)
    fresh = ViewerSession("default", "macbeth", size=32)
    fresh.update(f_number=2.0)
    assert s.output.raw.data.equal(fresh.output.raw.data)


def test_a_lens_config_has_no_f_number_setting_and_no_single_otf():
    s = ViewerSession.__new__(ViewerSession)  # only the config logic, no render
    s.base_config = {"optics": {"type": "lens", "lens": "cooke_triplet"}, "sensor": {}, "isp": {}}
    assert not s.f_number_settable
    with pytest.raises(ValueError, match="f_number: the camera's optics are a lens prescription"):
        s.camera_config(Settings(f_number=8.0))

    class _Lens:  # a shift-variant optics (LensOptics): no otf
        pass

    s.camera = type("Cam", (), {"optics": _Lens()})()
    assert s.optics_curves() is None


def test_sensor_stats_measure_the_signal_above_black_and_count_every_pixel():
    """A DN raw's black level (imx363: 64 DN) was counted as signal (SNR 39.6 dB for 6.6 at 0.1 ms), and values below
    it fell outside the histogram, uncounted (an audit of the viewer's numbers)."""
    s = ViewerSession("imx363", scene="uniform_d65", size=64)
    s.update(exposure_ms=0.1)
    raw = s.output.raw
    h, w = raw.data.shape[-2:]
    stats = s.sensor_stats(ROI(0, h, 0, w))
    data = raw.data[0, 0].double().numpy()
    masks = raw.channel_masks().bool().numpy()
    black = float(raw.black_level)
    assert black == 64.0 and (data < black).any()
    for c, ch in enumerate(stats["channels"]):
        v = data[masks[c]]
        assert int(ch["counts"].sum()) == ch["n"] == v.size
        expected = 20 * np.log10((v.mean() - black) / v.std(ddof=1))
        assert ch["snr_db"] == pytest.approx(expected, abs=1e-9)


def test_colour_stats_find_the_chart_in_a_sensor_larger_than_its_image(tmp_path):
    """A config with fixed rows and cols holds the Macbeth chart in the middle of a larger image; the patch means and
    the patch under the ROI took the chart to fill the image (mean dE2000 73 instead of 3.7; the dark-skin patch was
    named purplish blue). A sensor that crops the chart reports no dE (its cells were other patches)."""
    import warnings

    body = ("optics: {type: diffraction_limited, f_number: 4.0, focal_length_m: 0.003862755099}\n"
            "sensor: {preset: isetcam_default, rows: %d, cols: %d, auto_exposure: luminance}\ncamera: {noise: false}\n"
            "isp: {demosaic: bilinear, illuminant_correction: none, correction_space: xyz, sensor_conversion: "
            "{method: mcc_optimized, illuminant: D65, surfaces: macbeth}, display: srgb, encoding: srgb, "
            "scaling: adaptive}\n")
    stats, sessions = {}, {}
    for rows, cols in ((86, 128), (240, 320), (72, 88)):  # the chart's own size at size=128, larger, smaller
        (tmp_path / "cam.yaml").write_text(body % (rows, cols))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            session = ViewerSession(str(tmp_path / "cam.yaml"), "macbeth", size=128)
        window = session.chart_window()
        roi = ROI(0, 4, 0, 4)
        if window is not None:  # the top-left patch's centre: an eighth of the chart down, a twelfth across
            r0, r1, c0, c1 = window
            cy, cx = r0 + (r1 - r0) // 8, c0 + (c1 - c0) // 12
            roi = ROI(cy - 2, cy + 2, cx - 2, cx + 2)
        stats[cols], sessions[cols] = (session.colour_stats(roi), window), session
    (fits, win_fits), (large, win_large), (small, win_small) = stats[128], stats[320], stats[88]
    assert win_fits == pytest.approx((0, 86, 0, 128), abs=1) and win_small is None
    assert (win_large[1] - win_large[0], win_large[3] - win_large[2]) == pytest.approx((86, 128), abs=1)
    assert win_large[0] == pytest.approx(240 / 2 - 43, abs=1) and win_large[2] == pytest.approx(320 / 2 - 64, abs=1)
    for s in (fits, large):
        assert s["patch_names"][s["roi_patch"]] == "dark skin"
    # a ROI centred off the chart (the large sensor's top-left corner, outside rows 77..163) has no patch: it was
    # clamped to the nearest edge patch, the surround shown as 'dark skin' with that patch's delta E
    assert sessions[320].colour_stats(ROI(0, 4, 0, 4))["roi_patch"] is None
    assert sessions[320].colour_stats(ROI(0, 4, 300, 304))["roi_patch"] is None
    assert sessions[128].colour_stats(ROI(82, 86, 124, 128))["roi_patch"] == 23  # inside: the last patch
    assert large["delta_e_mean"] == pytest.approx(fits["delta_e_mean"], abs=0.3) and fits["delta_e_mean"] < 6
    assert "delta_e" not in small and "roi_xy" in small
