"""``isettorch process``'s input checks on a tiny 12-bit RGGB camera (written here, so its noise model is known):
the noise model's values and their range, the white level, and output names that would clash."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from isettorch.camera import Camera
from isettorch.cli import main
from isettorch.commands import process
from isettorch.isp.learned import PRETRAINED

# 12-bit ADC over a 1 V swing: 1 DN = 1/4096 V; conversion gain 2^-11 V/e: 2 DN per electron; read noise 3 e
SENSOR = ("sensor: {rows: 8, cols: 8, pixel_size_m: 3.45e-6, cfa: RGGB, adc_bits: 12, voltage_swing_v: 1.0, "
          "conversion_gain_v_per_e: 0.00048828125, black_level_dn: 64, read_noise_v: 0.00146484375, "
          "dark_current_e_per_s: 50.0}")
OPTICS = "optics: {type: diffraction_limited, f_number: 2.8, focal_length_m: 0.004}"
SPAN_DN, DN_PER_E, READ_E, DARK_E_PER_S = 4095 - 64, 2.0, 3.0, 50.0


@pytest.fixture
def camera(tmp_path) -> Path:
    path = tmp_path / "cam.yaml"
    path.write_text(f"{OPTICS}\n{SENSOR}\n")
    return path


def test_noise_params_are_the_cameras_and_stay_in_range(camera):
    sensor = Camera.from_config(camera).sensor
    a = DN_PER_E / SPAN_DN  # normalised units per electron
    quantisation = 1 / 12 / SPAN_DN**2
    assert process.noise_params(sensor) == pytest.approx((a, READ_E**2 * a**2 + quantisation), rel=1e-12)
    assert process.noise_params(sensor, 4.0, 2.0) == pytest.approx(
        (4 * a, (READ_E**2 + DARK_E_PER_S * 2.0) * (4 * a) ** 2 + quantisation), rel=1e-12)
    # settings that take a or b out of the float range (1e308: a = inf; 1e200: a^2 overflows) are named
    for gain in (1e308, 1e200):
        with pytest.raises(ValueError, match=r"^analog_gain: the gain .* makes the noise model's shot gain a"):
            process.noise_params(sensor, gain)
    with pytest.raises(ValueError, match=r"^exposure_s: 1e\+300 s of the sensor's dark current \(50 e/s\)"):
        process.noise_params(sensor, None, 1e300)
    for gain, exposure, name in ((float("inf"), 0.0, "analog_gain"), (None, float("inf"), "exposure_s"),
                                 (None, float("nan"), "exposure_s"), (-1.0, 0.0, "analog_gain")):
        with pytest.raises(ValueError, match=f"^{name}: expected a finite"):
            process.noise_params(sensor, gain, exposure)


def test_output_paths_never_clash(tmp_path):
    out = tmp_path / "out"
    assert process._output_paths(["a/x.npy", "b/y.tif"], out, "png") == [out / "x.png", out / "y.png"]
    with pytest.raises(ValueError, match=r"^RAW: a/frame\.npy and b/frame\.npy would both be written to .*frame\.npy"):
        process._output_paths(["a/frame.npy", "b/frame.npy"], out, "npy")
    with pytest.raises(ValueError, match=r"^RAW: frame\.npy and frame\.tif would both be written"):
        process._output_paths(["frame.npy", "frame.tif"], out, "npy")
    with pytest.raises(ValueError, match=r"^RAW: \./frame\.npy is given twice"):
        process._output_paths(["frame.npy", "./frame.npy"], out, "npy")


def test_values_above_the_largest_adc_code_are_refused(camera, tmp_path, capsys):
    rng = np.random.default_rng(0)
    frame = rng.integers(64, 4096, (8, 8)).astype(np.uint16)
    frame[0, 0] = 4095  # the 12-bit ADC's largest code is a value it gives
    np.save(tmp_path / "white.npy", frame)
    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--out", str(tmp_path / "out"),
            "--quiet"]
    assert main(["process", str(tmp_path / "white.npy"), *args]) == 0
    rgb = np.load(tmp_path / "out" / "white.npy")
    assert rgb.shape == (3, 8, 8) and np.isfinite(rgb).all()
    frame[3, 5] = 4096
    np.save(tmp_path / "over.npy", frame)
    capsys.readouterr()
    assert main(["process", str(tmp_path / "over.npy"), *args]) == 2
    assert capsys.readouterr().err == (f"isettorch process: RAW: {tmp_path / 'over.npy'}: values up to 4096 DN exceed "
                                       f"the camera's largest ADC code 4095 DN (12 bits; data shifted left?)\n")
    assert not (tmp_path / "out" / "over.npy").exists()


def test_a_camera_raws_own_cfa_and_black_level_must_be_the_configs(camera, tmp_path, capsys):
    """A DNG carries its CFA and black level: a GRBG file through the RGGB camera config came out with its colours
    mixed (exit 0), and a black level of 200 was normalised with the config's 64. Both are refused, naming the file;
    a DNG that agrees with the config is processed as its .npy twin is."""
    pytest.importorskip("rawpy")
    from isettorch.io.raw import write_dng

    rng = np.random.default_rng(1)
    mosaic = rng.integers(300, 2000, (24, 24)).astype(np.uint16)
    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--quiet"]
    write_dng(tmp_path / "ok.dng", mosaic, cfa="RGGB", black_level_dn=64, white_level_dn=4095)
    np.save(tmp_path / "ok.npy", mosaic)
    assert main(["process", str(tmp_path / "ok.dng"), *args, "--out", str(tmp_path / "a")]) == 0
    assert main(["process", str(tmp_path / "ok.npy"), *args, "--out", str(tmp_path / "b")]) == 0
    assert np.array_equal(np.load(tmp_path / "a" / "ok.npy"), np.load(tmp_path / "b" / "ok.npy"))
    for name, kw, message in (("grbg.dng", {"cfa": "GRBG", "black_level_dn": 64}, "the file's CFA GRBG differs from "
                                                                                  "the camera config's RGGB"),
                              ("black.dng", {"cfa": "RGGB", "black_level_dn": 200},
                               "the file's black levels [200.0, 200.0, 200.0, 200.0] DN (mean 200) differ from the "
                               "camera config's 64 DN by more than 0.5 DN")):
        write_dng(tmp_path / name, mosaic, white_level_dn=4095, **kw)
        capsys.readouterr()
        assert main(["process", str(tmp_path / name), *args, "--out", str(tmp_path / "c")]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"isettorch process: RAW: {tmp_path / name}: {message}"), err
    assert not (tmp_path / "c").exists()
    # per-column black levels (a DNG's BlackLevelDeltaH, averaging 0 over each channel's columns) are subtracted
    from dng_by_hand import dng_by_hand

    delta = np.array([2, 1, -2, -1] * 6)
    dng_by_hand(tmp_path / "delta.dng", mosaic + delta, extra=[(50715, "h", 24, tuple(int(d) for d in delta), True)])
    assert main(["process", str(tmp_path / "delta.dng"), *args, "--out", str(tmp_path / "d")]) == 0
    assert np.array_equal(np.load(tmp_path / "d" / "delta.npy"), np.load(tmp_path / "b" / "ok.npy"))
    # the file's own per-channel black levels, within 0.5 DN of the config's, are the ones subtracted (the
    # differences were left in the output): R at 64.5, B at 63.5 is the frame with R 0.5 DN down and B 0.5 up
    blacks = [(50713, "H", 2, (2, 2), True), (50714, "2I", 4, (129, 2, 64, 1, 64, 1, 127, 2), True)]
    dng_by_hand(tmp_path / "cells.dng", mosaic, black=None, extra=blacks)
    shifted = mosaic.astype(np.float64)
    shifted[0::2, 0::2] -= 0.5
    shifted[1::2, 1::2] += 0.5
    np.save(tmp_path / "cells_twin.npy", shifted)
    assert main(["process", str(tmp_path / "cells.dng"), *args, "--out", str(tmp_path / "e")]) == 0
    assert main(["process", str(tmp_path / "cells_twin.npy"), *args, "--out", str(tmp_path / "e")]) == 0
    np.testing.assert_allclose(np.load(tmp_path / "e" / "cells.npy"), np.load(tmp_path / "e" / "cells_twin.npy"),
                               rtol=0, atol=1e-6)
    # channels with their own black levels around the config's (62, 66, 63, 65: mean 64, as calibrate measures the
    # one level from all pixels) are the camera's: each channel's own level is subtracted (the raw was refused,
    # R 2 DN from the config's)
    blacks = [(50713, "H", 2, (2, 2), True), (50714, "2I", 4, (62, 1, 66, 1, 63, 1, 65, 1), True)]
    dng_by_hand(tmp_path / "spread.dng", mosaic, black=None, extra=blacks)
    np.save(tmp_path / "spread_twin.npy", mosaic - np.tile([[62.0, 66.0], [63.0, 65.0]], (12, 12)) + 64)
    assert main(["process", str(tmp_path / "spread.dng"), *args, "--out", str(tmp_path / "f")]) == 0
    assert main(["process", str(tmp_path / "spread_twin.npy"), *args, "--out", str(tmp_path / "f")]) == 0
    np.testing.assert_allclose(np.load(tmp_path / "f" / "spread.npy"), np.load(tmp_path / "f" / "spread_twin.npy"),
                               rtol=0, atol=1e-6)
    # a DNG's Orientation (IFD 0 tag 274; 6: rotate 90 degrees clockwise to display) turns the processed image, not
    # the mosaic (its CFA phase would change): a portrait frame came out on its side
    from isettorch.io.raw import read_raw

    for turn, expect in ((6, lambda a: np.rot90(a, -1, axes=(1, 2))), (3, lambda a: a[:, ::-1, ::-1]),
                         (8, lambda a: np.rot90(a, 1, axes=(1, 2)))):
        name = f"turn{turn}.dng"
        dng_by_hand(tmp_path / name, mosaic, extra=[(274, "H", 1, (turn,), False)])
        assert read_raw(tmp_path / name).orientation == turn
        assert main(["process", str(tmp_path / name), *args, "--out", str(tmp_path / "g")]) == 0
        np.testing.assert_array_equal(np.load(tmp_path / "g" / f"turn{turn}.npy"), expect(np.load(tmp_path / "a" /
                                                                                                  "ok.npy")))


def test_the_shipped_joint_checkpoint_runs_as_it_ships(camera, tmp_path):
    """Given the shipped joint checkpoint, process runs it with its guard and gates, as
    demosaic_learned(variant='joint_denoise') does (its bare checkpoint differed by up to 0.08)."""
    import argparse
    import shutil

    import torch

    from isettorch.isp.learned import demosaic_learned, noise_features

    copy = tmp_path / "joint.pt"  # a copy elsewhere is the shipped network too
    shutil.copy(PRETRAINED["joint_denoise"], copy)
    args = argparse.Namespace(camera=str(camera), model=str(copy))
    sensor, pattern, net, _ = process._load(args)
    dn = np.random.default_rng(0).integers(64, 4095, size=(8, 8)).astype(np.float64)
    got = process.process_frame(dn, sensor, pattern, net)
    a, b = process.noise_params(sensor)
    x = torch.as_tensor((dn - 64) / SPAN_DN, dtype=torch.float32)[None, None]
    want = demosaic_learned(x, "RGGB", variant="joint_denoise", noise=noise_features(a, b).float())[0]
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)


def test_left_aligned_frames_are_right_aligned(camera, tmp_path, capsys):
    """12-bit values in 16-bit words are multiples of 16: calibrate writes the config for the right-aligned DN, and
    a dim left-aligned frame (all values under the 12-bit largest code) came out 11x too bright, exit 0. Such a
    frame is divided by 16, said on stderr, and processed as its right-aligned twin is."""
    rng = np.random.default_rng(3)
    right = rng.integers(64, 250, (16, 16)).astype(np.uint16)  # dim: x16 stays under 4095
    np.save(tmp_path / "right.npy", right)
    np.save(tmp_path / "left.npy", (right * 16).astype(np.uint16))
    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--quiet"]
    assert main(["process", str(tmp_path / "right.npy"), *args, "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    assert main(["process", str(tmp_path / "left.npy"), *args, "--out", str(tmp_path / "b")]) == 0
    assert "in 16-bit words is a multiple of 16 DN: 12-bit data left-aligned, divided by 16" in capsys.readouterr().err
    assert np.array_equal(np.load(tmp_path / "a" / "right.npy"), np.load(tmp_path / "b" / "left.npy"))
    # decided over the run, as calibrate decides over its folder: a dark frame alone has too few distinct values
    # (it passed as right-aligned, 0.24 for 0.00), beside the dim one it is right-aligned too
    dark = rng.integers(62, 67, (8, 8)).astype(np.uint16)
    np.save(tmp_path / "dark_right.npy", dark)
    np.save(tmp_path / "dark.npy", (dark * 16).astype(np.uint16))
    assert main(["process", str(tmp_path / "dark_right.npy"), *args, "--out", str(tmp_path / "c")]) == 0
    assert main(["process", str(tmp_path / "left.npy"), str(tmp_path / "dark.npy"), *args, "--out",
                 str(tmp_path / "d")]) == 0
    assert np.array_equal(np.load(tmp_path / "c" / "dark_right.npy"), np.load(tmp_path / "d" / "dark.npy"))
    # a float frame beside them does not change the integer frames' decision (it stopped it: 0.62 for 0.02)
    np.save(tmp_path / "float.npy", right.astype(np.float64))
    assert main(["process", str(tmp_path / "left.npy"), str(tmp_path / "dark.npy"), str(tmp_path / "float.npy"),
                 *args, "--out", str(tmp_path / "e")]) == 0
    assert np.array_equal(np.load(tmp_path / "b" / "left.npy"), np.load(tmp_path / "e" / "left.npy"))
    # the dark frame alone cannot be told: processed as right-aligned, with a warning
    capsys.readouterr()
    assert main(["process", str(tmp_path / "dark.npy"), *args, "--out", str(tmp_path / "f")]) == 0
    assert "too few distinct values to tell left-aligned 12-bit data" in capsys.readouterr().err
    # a left-aligned and a right-aligned frame in one run: refused (the right one took the division from the left
    # one, whose output came out 16x too bright, exit 0)
    right16 = (right | 1).astype(np.uint16)  # odd values: right-aligned in the 16-bit words
    np.save(tmp_path / "right16.npy", right16)
    capsys.readouterr()
    assert main(["process", str(tmp_path / "left.npy"), str(tmp_path / "right16.npy"), *args, "--out",
                 str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"isettorch process: RAW: {tmp_path / 'left.npy'} holds 12-bit data left-aligned in 16-bit "
                          f"words"), err
    assert not (tmp_path / "g").exists()
    # an all-zero frame (a black dark) tells nothing: it follows the left-aligned frame (it was refused as mixed)
    np.save(tmp_path / "black.npy", np.zeros((16, 16), np.uint16))
    assert main(["process", str(tmp_path / "left.npy"), str(tmp_path / "black.npy"), *args, "--out",
                 str(tmp_path / "h")]) == 0
    assert np.array_equal(np.load(tmp_path / "b" / "left.npy"), np.load(tmp_path / "h" / "left.npy"))


def test_a_left_aligned_camera_raw_is_right_aligned_with_its_black_level(camera, tmp_path, capsys):
    """A DNG of 12-bit codes in 16-bit words (its BlackLevel tag 64 x 16): calibrate writes the right-aligned
    config, and process refused the camera's own raw ("black levels [1024.0, ...] differ from 64"). It is divided by
    16, codes and black level, and processed as its right-aligned twin is."""
    pytest.importorskip("rawpy")
    from isettorch.io.raw import write_dng

    mosaic = np.random.default_rng(4).integers(300, 2000, (24, 24)).astype(np.uint16)
    write_dng(tmp_path / "right.dng", mosaic, cfa="RGGB", black_level_dn=64, white_level_dn=4095)
    write_dng(tmp_path / "left.dng", mosaic * 16, cfa="RGGB", black_level_dn=64 * 16, white_level_dn=65535)
    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--quiet"]
    assert main(["process", str(tmp_path / "right.dng"), *args, "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    assert main(["process", str(tmp_path / "left.dng"), *args, "--out", str(tmp_path / "b")]) == 0
    assert "in 16-bit words is a multiple of 16 DN: 12-bit data left-aligned, divided by 16" in capsys.readouterr().err
    assert np.array_equal(np.load(tmp_path / "a" / "right.npy"), np.load(tmp_path / "b" / "left.npy"))


def test_each_frame_is_read_twice_at_most(camera, tmp_path, monkeypatch):
    """The left-alignment check reads each frame once, the processing once more (a left-aligned run read every frame
    up to five times: its word width, its step, the step again over fewer values, its maximum, then the frame)."""
    from isettorch.commands import process

    rng = np.random.default_rng(4)
    names = []
    for k in range(3):
        np.save(tmp_path / f"f{k}.npy", (rng.integers(64, 250, (16, 16)) * 16).astype(np.uint16))
        names.append(str(tmp_path / f"f{k}.npy"))
    reads = []
    real = process._read
    monkeypatch.setattr(process, "_read", lambda f: reads.append(f) or real(f))
    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--quiet"]
    assert main(["process", *names, *args, "--out", str(tmp_path / "out")]) == 0
    assert sorted(reads) == sorted(names * 2)


def test_settings_beyond_any_camera_and_folders_are_refused(camera, tmp_path, capsys):
    """A gain making one electron the whole span, or an exposure whose dark noise exceeds it, wrote a constant image
    (gain 1e30: -6e13) with exit 0; a folder was 'no such raw frame'; a reader error did not name RAW."""
    sensor = Camera.from_config(camera).sensor
    with pytest.raises(ValueError, match=r"^analog_gain: the gain 3000 makes one electron 1\.49 of the signal's span"):
        process.noise_params(sensor, 3000.0)
    with pytest.raises(ValueError, match=r"^exposure_s: 1e\+09 s of the sensor's dark current \(50 e/s\) makes the "
                                         r"noise floor's standard deviation"):
        process.noise_params(sensor, None, 1e9)
    np.save(tmp_path / "f.npy", np.random.default_rng(0).integers(64, 4095, (8, 8)).astype(np.uint16))
    np.save(tmp_path / "rgb.npy", np.zeros((8, 8, 3), np.uint16))
    (tmp_path / "dir").mkdir()
    base = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--out", str(tmp_path / "o")]
    for argv, message in (([str(tmp_path / "dir"), *base], f"RAW: {tmp_path / 'dir'} is a folder"),
                          ([str(tmp_path / "f.npy"), "--camera", str(camera), "--model", str(tmp_path / "dir")],
                           f"--model: {tmp_path / 'dir'} is a folder"),
                          ([str(tmp_path / "rgb.npy"), *base], f"RAW: {tmp_path / 'rgb.npy'}: expected a 2-D")):
        capsys.readouterr()
        assert main(["process", *argv, "--quiet"]) == 2
        assert capsys.readouterr().err.startswith(f"isettorch process: {message}")


def test_a_camera_specific_network_at_another_gain_is_warned_about(camera, tmp_path, capsys):
    """A camera-specific network learned the config's gain alone: another --analog-gain is warned about (at gain 64
    for a gain-1 camera one came out with an RMS error of 0.14, exit 0); the shipped joint network, trained over
    noise levels, is not."""
    import torch

    from isettorch.isp.learned import DemosaicNet

    ckpt = tmp_path / "own.pt"
    net = DemosaicNet(channels=4, depth=1, noise_inputs=2)
    torch.save({"model": net.state_dict(), "net_config": {"channels": 4, "depth": 1, "noise_inputs": 2}}, ckpt)
    np.save(tmp_path / "f.npy", np.random.default_rng(0).integers(64, 4095, (8, 8)).astype(np.uint16))
    for model, warned in ((ckpt, True), (PRETRAINED["joint_denoise"], False)):
        capsys.readouterr()
        code = main(["process", str(tmp_path / "f.npy"), "--camera", str(camera), "--model", str(model),
                     "--analog-gain", "4", "--out", str(tmp_path / f"o{warned}"), "--quiet"])
        err = capsys.readouterr().err
        assert code == 0, err
        assert ("warning: analog_gain 4 differs from the camera config's 1" in err) == warned, err


def test_a_camera_without_an_adc_is_one_line(tmp_path, capsys):
    """A camera config with an analog readout (adc_bits null): the noise model's refusal, one line, exit 2 (the
    left-alignment step read int(adc_bits) before it, a TypeError traceback)."""
    sensor = SENSOR.replace("adc_bits: 12", "adc_bits: null").replace("black_level_dn: 64", "black_level_dn: 0")
    (tmp_path / "analog.yaml").write_text(f"{OPTICS}\n{sensor}\n")
    np.save(tmp_path / "f.npy", np.random.default_rng(0).integers(64, 4095, (8, 8)).astype(np.uint16))
    assert main(["process", str(tmp_path / "f.npy"), "--camera", str(tmp_path / "analog.yaml"), "--model",
                 str(PRETRAINED["joint_denoise"]), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert capsys.readouterr().err == ("isettorch process: --camera: the sensor has no ADC (adc_bits null); expected a "
                                       "sensor that outputs DN\n")


def test_a_camera_raws_white_level_and_a_monochrome_raw_must_be_the_configs(camera, tmp_path, capsys):
    """A 10-bit DNG (WhiteLevel 1023) through the 12-bit config: its clipped pixels came out at 0.238 of white, exit 0
    (the white level was read but never compared); a monochrome DNG was demosaiced as the config's Bayer (grey stripes
    came out orange)."""
    pytest.importorskip("rawpy")
    from isettorch.io.raw import write_dng

    args = ["--camera", str(camera), "--model", str(PRETRAINED["joint_denoise"]), "--quiet"]
    write_dng(tmp_path / "ten.dng", np.full((24, 24), 1023, np.uint16), cfa="RGGB", black_level_dn=64,
              white_level_dn=1023)
    assert main(["process", str(tmp_path / "ten.dng"), *args, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "RAW: " in err and "the file's white level 1023 DN is below the camera config's 4095 DN" in err
    assert "would come out at 0.238 of white" in err and not (tmp_path / "a").exists()
    write_dng(tmp_path / "sixteen.dng", np.full((24, 24), 1000, np.uint16), cfa="RGGB", black_level_dn=64,
              white_level_dn=65535)  # (values in range: the codes alone did not tell)
    assert main(["process", str(tmp_path / "sixteen.dng"), *args, "--out", str(tmp_path / "b")]) == 2
    assert "white level 65535 DN is above the camera config's largest ADC code 4095 DN (12 bits" in \
        capsys.readouterr().err
    write_dng(tmp_path / "clip.dng", np.full((24, 24), 4000, np.uint16), cfa="RGGB", black_level_dn=64,
              white_level_dn=4050)  # within 2 % of the span: the camera's own clip
    assert main(["process", str(tmp_path / "clip.dng"), *args, "--out", str(tmp_path / "c")]) == 0
    capsys.readouterr()
    _write_monochrome_dng(tmp_path / "mono.dng", np.tile(np.array([500, 1500], np.uint16), (24, 12)))
    assert main(["process", str(tmp_path / "mono.dng"), *args, "--out", str(tmp_path / "d")]) == 2
    assert "the file is a monochrome raw (no colour filter array); the camera config's CFA is RGGB" in \
        capsys.readouterr().err


def _write_monochrome_dng(path, mosaic):
    """A LinearRaw DNG of one sample per pixel (a monochrome camera's raw): BlackLevel 64, WhiteLevel 4095 (tifffile
    writes it as grey; the PhotometricInterpretation entry is then set to LinearRaw, 34892; DNG 1.4 p. 19)."""
    import tifffile

    tags = [(50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True), (50708, "s", 0, "mono", True),
            (50714, "H", 1, (64,), True), (50717, "H", 1, (4095,), True)]
    tifffile.imwrite(path, mosaic, photometric="minisblack", subfiletype=0, extratags=tags, metadata=None)
    data = bytearray(path.read_bytes())
    entry = bytes.fromhex("0601030001000000") + (1).to_bytes(2, "little")  # tag 262, SHORT, count 1, value 1
    i = data.find(entry)
    assert i > 0
    data[i + 8:i + 10] = (34892).to_bytes(2, "little")
    path.write_bytes(bytes(data))
