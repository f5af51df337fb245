"""Single-raw Poisson-Gaussian estimate (Foi et al. 2008) and camera raws through rawpy."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import numpy_capture as nc  # noqa: E402
from dng_by_hand import dng_by_hand  # noqa: E402

from isettorch.sensor.noise_estimation import estimate_poisson_gaussian  # noqa: E402


def _scene(h=768, w=768, seed=0):
    """A clean image in DN, 2 to 3000 DN (half of it below 750 DN, where b shows), smooth gradients and sharp-edged
    discs (edges must not bias the fit)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = 2 + 3000 * (xx / w) ** 2 * (0.6 + 0.4 * yy / h)
    for _ in range(25):
        cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(10, 60)
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.uniform(2, 3000)
    return img


@pytest.mark.parametrize("a, b", [(0.6, 4.0), (2.0, 30.0), (0.25, 1.0)])
def test_foi_fit_recovers_known_a_b(a, b):
    """z = a Poisson(y / a) + N(0, b): the fit returns a within 3 % and b within 10 %."""
    rng = np.random.default_rng(1)
    y = _scene()
    z = a * rng.poisson(y / a) + np.sqrt(b) * rng.standard_normal(y.shape)
    res = estimate_poisson_gaussian(z)
    assert res["a"] == pytest.approx(a, rel=0.03)
    assert res["b"] == pytest.approx(b, rel=0.10)


def test_foi_fit_on_a_bayer_mosaic_with_black_level_and_clipping():
    rng = np.random.default_rng(2)
    y = _scene(seed=3) * np.tile([[1.0, 0.6], [0.6, 0.4]], (384, 384))  # channel gains of a Bayer mosaic
    a, b, black, white = 0.8, 9.0, 256.0, 2800.0
    z = np.clip(np.round(a * rng.poisson(y / a) + np.sqrt(b) * rng.standard_normal(y.shape) + black), 0, white)
    res = estimate_poisson_gaussian(z, cfa="RGGB", black_level_dn=black, white_level_dn=white)
    assert res["a"] == pytest.approx(a, rel=0.03)
    assert res["b"] == pytest.approx(b + 1 / 12, rel=0.10)  # + the quantisation variance of the rounding


def test_foi_fit_saturation_zero_clipping_and_its_reliability_warnings():
    """An audit against a NumPy truth (a = 0.5 DN/e-, read noise 2 DN): a frame saturated on 23-46 % of its pixels
    with no white level given (the CLI has none for PNG / .npy) read a = 0.25 or negative; one clipped at 0 DN with
    no pedestal a +27..42 % high. Now a saturated plateau at the frame's largest value is the white level, blocks
    within 3 noise sigmas of 0 DN are left out, and the fit says when it cannot be trusted: a narrow signal range
    (a flat frame: a 6-20 % off) and variance the line does not hold (texture: +78 % on a fine Bayer pattern)."""
    rng = np.random.default_rng(7)
    h = w = 512
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    a, read = 0.5, 2.0

    def capture(electrons, black):
        z = a * rng.poisson(electrons) + read * rng.standard_normal(electrons.shape) + black
        return np.clip(np.round(z), 0, 4095)

    saturated = capture(20 + 14000 * xx / w, 256.0)  # 46 % of the pixels at 4095
    res = estimate_poisson_gaussian(saturated, black_level_dn=256.0)
    assert res["a"] == pytest.approx(a, rel=0.02)
    assert any("taken as its white level" in m for m in res["warnings"])
    # and below a given white level above it (a DNG's WhiteLevel 65535 on a sensor that clips at 4095: a = 0.49 for 2)
    res = estimate_poisson_gaussian(saturated, black_level_dn=256.0, white_level_dn=65535.0)
    assert res["a"] == pytest.approx(a, rel=0.02)
    assert any("below the given white level 65535 DN" in m for m in res["warnings"])
    dark = capture(200 * (xx / w) * (0.5 + 0.5 * yy / h), 0.0)  # no pedestal: 1 % of the pixels at 0 DN
    res = estimate_poisson_gaussian(dark)
    assert res["a"] == pytest.approx(a, rel=0.05) and res["read_noise_dn"] == pytest.approx(read, rel=0.1)
    assert any("clipped at 0 DN" in m for m in res["warnings"])
    smooth_frame = capture(20 + 3000 * xx / w, 256.0)
    smooth_frame[5, 7] = 0.0  # a dead pixel at 0 DN is no clipped frame
    smooth = estimate_poisson_gaussian(smooth_frame, black_level_dn=256.0)
    assert smooth["a"] == pytest.approx(a, rel=0.02)
    assert smooth["warnings"] == ["1 pixels at 0 DN under a black level of 256 DN (dead pixels?): their blocks are "
                                  "left out"]
    assert smooth["a_standard_error"] < 0.01 * a and smooth["fit_chi2_per_dof"] < 3
    # saturation spread over a few codes (an analog clip, then ADC noise): the pile-up's lowest code is the white
    # level (it took none: a = 0.004 for 0.5)
    spread = np.clip(np.round(np.minimum(a * rng.poisson((20 + 6000 * xx / w) / a) + read * rng.standard_normal((h, w))
                                         + 256, 4094.6) + 0.6 * rng.standard_normal((h, w))), 0, 4095)
    assert (spread == 4094).mean() > 0.05 and (spread == 4095).mean() > 0.05
    res = estimate_poisson_gaussian(spread, black_level_dn=256.0)
    assert res["a"] == pytest.approx(a, rel=0.03) and any("taken as its white level" in m for m in res["warnings"])
    # a low-noise frame far from saturation has few pixels on its largest value, fewer than on the next one down: no
    # white level is taken from it
    level = 2 + 38 * np.minimum(xx / 0.67, w - 1) / (w - 1)  # 2-40 DN, its brightest third uniform (a white patch)
    quiet = np.round(0.002 * rng.poisson(level / 0.002) + 0.1 * rng.standard_normal((h, w)) + 16)
    top = quiet.max()
    assert (quiet == top).sum() >= 1e-3 * quiet.size  # (enough pixels on it to have been taken for saturation)
    assert not any("white level" in m for m in estimate_poisson_gaussian(quiet, black_level_dn=16.0)["warnings"])
    flat = estimate_poisson_gaussian(capture(np.full((h, w), 1000.0), 256.0), black_level_dn=256.0)
    assert any("too narrow a range" in m for m in flat["warnings"])
    fine = 200 + 1500 * (0.5 + 0.5 * np.sin(xx / 8) * np.cos(yy / 6))
    fine = fine * np.tile([[0.55, 1.0], [1.0, 0.4]], (h // 2, w // 2))  # a Bayer mosaic of it
    textured = estimate_poisson_gaussian(capture(fine, 256.0), cfa="RGGB", black_level_dn=256.0)
    assert textured["a"] > 1.3 * a  # the inherent limit: texture leaks into the details
    assert any("depart from a line" in m for m in textured["warnings"])


def test_foi_fit_needs_a_range_of_signal():
    with pytest.raises(ValueError, match="range of signal"):
        estimate_poisson_gaussian(np.full((64, 64), 100.0) + np.random.default_rng(0).standard_normal((64, 64)),
                                  min_blocks=200, levels=24)


def test_single_raw_cli(tmp_path, capsys):
    from isettorch.cli import main
    from isettorch.io.frames import write_frame

    rng = np.random.default_rng(4)
    z = np.round(0.5 * rng.poisson(_scene(seed=5) / 0.5) + 2 * rng.standard_normal((768, 768)) + 100)
    write_frame(tmp_path / "one.png", z)
    assert main(["calibrate", str(tmp_path / "one.png"), "--json", "--quiet", "--black-level", "100"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["conversion_gain_dn_per_e"] == pytest.approx(0.5, rel=0.03)
    assert res["read_noise_dn"] == pytest.approx(np.sqrt(4 + 1 / 12), rel=0.05)


# --- camera raws (optional extra 'raw') -------------------------------------------------------------------------

def test_dng_round_trip_through_rawpy(tmp_path):
    rawpy = pytest.importorskip("rawpy")  # noqa: F841
    from isettorch.io.raw import read_raw, write_dng

    m = (np.arange(64 * 96).reshape(64, 96) % 4000 + 64).astype(np.uint16)
    write_dng(tmp_path / "x.dng", m, cfa="GRBG", black_level_dn=64, white_level_dn=4095)
    r = read_raw(tmp_path / "x.dng")
    assert np.array_equal(r.data, m) and r.cfa == "GRBG"
    assert r.black_level_dn == [64.0] * 4 and r.white_level_dn == 4095
    # the public frame reader keeps the raw's CFA and black levels; a .npy frame has none
    from isettorch.io.frames import read_frame_data
    f = read_frame_data(tmp_path / "x.dng")
    assert np.array_equal(f.dn, m) and f.cfa == "GRBG" and f.black_level_dn == [64.0] * 4
    np.save(tmp_path / "x.npy", m)
    f = read_frame_data(tmp_path / "x.npy")
    assert np.array_equal(f.dn, m) and f.cfa is None and f.black_level_dn is None
    # the name asked for, whatever its suffix's case (np.save wrote UP.NPY.npy)
    from isettorch.io.frames import write_frame
    write_frame(tmp_path / "UP.NPY", m)
    assert not (tmp_path / "UP.NPY.npy").exists() and np.array_equal(read_frame_data(tmp_path / "UP.NPY").dn, m)
    # what LibRaw could not read back, or the tags would not hold, is refused before a file is written
    small = np.full((21, 64), 100, dtype=np.uint16)
    for kwargs, message in (({"mosaic": small}, "LibRaw reads no raw smaller than 22 pixels a side"),
                            ({"black_level_dn": 63.7}, "black_level_dn, white_level_dn: expected integers"),
                            ({"black_level_dn": 4095}, "black_level_dn, white_level_dn: expected integers"),
                            ({"white_level_dn": 70000}, "black_level_dn, white_level_dn: expected integers"),
                            ({"cfa": "RRGG"}, "cfa: expected a 2 x 2 Bayer pattern with R, G and B"),
                            ({"cfa": ["R", "G", "G", "B"]}, "cfa: expected"),
                            ({"mosaic": np.zeros((0, 0))}, "mosaic: expected a non-empty 2-D array")):
        args = {"mosaic": m, "cfa": "GRBG", "black_level_dn": 64, "white_level_dn": 4095, **kwargs}
        with pytest.raises(ValueError, match=message):
            write_dng(tmp_path / "bad.dng", args.pop("mosaic"), **args)
        assert not (tmp_path / "bad.dng").exists()
    with pytest.raises(ValueError, match="mosaic: values up to 5000 DN exceed white_level_dn 4095"):
        write_dng(tmp_path / "bright.dng", np.full((22, 22), 5000, dtype=np.uint16), white_level_dn=4095)
    write_dng(tmp_path / "small.dng", np.full((22, 22), 100, dtype=np.uint16))
    assert read_raw(tmp_path / "small.dng").data.shape == (22, 22)


def _write_dng_stacks(root, dark, flat):
    """Each exposure's frames as RGGB DNGs (black 100, white 4095 DN) in dark_<ms>ms / flat_<ms>ms folders."""
    from isettorch.io.raw import write_dng

    for kind, stacks in (("dark", dark), ("flat", flat)):
        for ms, stack in stacks.items():
            d = root / f"{kind}_{ms:g}ms"
            d.mkdir()
            for i, f in enumerate(stack):
                write_dng(d / f"f{i}.dng", f, cfa="RGGB", black_level_dn=100, white_level_dn=4095)


def test_calibration_from_dng_folders(tmp_path, capsys):
    """DNG frames (written with write_dng, read by LibRaw) feed the same calibration as PNGs."""
    pytest.importorskip("rawpy")
    from isettorch.cli import main

    truth = dict(nc.TRUTH, qe=nc.BAYER_QE)
    dark, flat, _ = nc.simulate(truth, cfa="RGGB", shape=(128, 128), frames=2, seed=8)
    root = nc.write_capture(tmp_path / "cap", {}, {}, bits=12, cfa="RGGB")
    _write_dng_stacks(root, dark, flat)
    assert main(["calibrate", str(root), "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["sensor"]["conversion_gain_dn_per_e"] == pytest.approx(truth["gain_dn_per_e"], rel=0.02)
    assert res["sensor"]["black_level_dn"] == pytest.approx(100, abs=0.5)


def test_unreadable_raw_names_file(tmp_path):
    pytest.importorskip("rawpy")
    from isettorch.io.raw import read_raw

    (tmp_path / "bad.dng").write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match="bad.dng: cannot read the raw file"):
        read_raw(tmp_path / "bad.dng")


def test_folder_of_dngs_without_cfa_in_capture_yaml_uses_their_cfa(tmp_path, capsys):
    """capture.yaml without cfa, DNG frames with RGGB in their metadata: calibrated as RGGB (with a warning), so the
    PRNU is the truth's 1 % (as mono, the channels' QE differences read as ~20 % PRNU); frames that disagree on the
    CFA are an error naming a file."""
    pytest.importorskip("rawpy")
    from isettorch.cli import main
    from isettorch.io.raw import write_dng

    truth = dict(nc.TRUTH, qe=nc.BAYER_QE)
    dark, flat, _ = nc.simulate(truth, cfa="RGGB", shape=(128, 128), frames=2, seed=8,
                                exposures_ms=[1.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 60.0])
    root = nc.write_capture(tmp_path / "cap", {}, {}, bits=12)  # no cfa key
    _write_dng_stacks(root, dark, flat)
    assert main(["calibrate", str(root), "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["cfa"] == "RGGB"
    assert any("capture.yaml has no cfa: using RGGB" in w for w in res["warnings"])
    assert res["sensor"]["prnu_percent"] == pytest.approx(truth["prnu_percent"], rel=0.15)
    assert res["sensor"]["conversion_gain_dn_per_e"] == pytest.approx(truth["gain_dn_per_e"], rel=0.02)
    write_dng(root / "flat_10ms" / "f1.dng", flat[10.0][1], cfa="GRBG", black_level_dn=100, white_level_dn=4095)
    assert main(["calibrate", str(root), "--json", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "flat_10ms/f1.dng: its CFA GRBG (raw metadata) differs from RGGB" in err


@pytest.fixture
def one_frame(tmp_path):
    """One raw PNG of a gradient scene: a = 0.5 DN/e-, b = 4 DN^2, black level 100 DN."""
    from isettorch.io.frames import write_frame

    rng = np.random.default_rng(4)
    z = np.round(0.5 * rng.poisson(_scene(256, 256, seed=5) / 0.5) + 2 * rng.standard_normal((256, 256)) + 100)
    write_frame(tmp_path / "one.png", z)
    return tmp_path / "one.png", z


@pytest.mark.parametrize("value", ["-5", "nan", "inf", "1e9", "max"])
def test_single_raw_black_level_is_validated(one_frame, capsys, value):
    from isettorch.cli import main

    path, z = one_frame
    value = f"{z.max():g}" if value == "max" else value
    assert main(["calibrate", str(path), "--black-level", value, "--quiet"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("isettorch calibrate: --black-level: expected a finite level in [0, ")


def test_single_raw_without_black_level_warns(one_frame, capsys):
    """No --black-level and none in a PNG: 0 is assumed, with a warning naming the darkest values (~ the truth's
    black level of 100 DN, whose 0.1 % quantile is at least 100 - 4 sigma); the fit's b is then negative
    (b - a x 100 = 4 - 50 DN^2), which is reported instead of silently floored."""
    from isettorch.cli import main

    path, _ = one_frame
    assert main(["calibrate", str(path), "--json", "--quiet"]) == 0
    shown = capsys.readouterr()
    res = json.loads(shown.out)
    assert res["black_level_dn"] == 0
    zero = [w for w in res["warnings"] if w.startswith("black level 0 assumed")]
    assert zero and "pass --black-level" in zero[0]
    assert float(zero[0].split("darkest values are ")[1].split(" DN")[0]) >= 100 - 4 * 2.5
    assert res["b"] == pytest.approx(4 - 0.5 * 100, rel=0.15)
    assert any("is negative" in w for w in res["warnings"])
    assert "isettorch calibrate: warning: black level 0 assumed" in shown.err
    assert main(["calibrate", str(path), "--json", "--quiet", "--black-level", "100"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []


def test_poisson_gaussian_estimate_checks_its_levels():
    """A NaN white level silently turned off the exclusion of clipped blocks, a NaN black level gave 'fewer than 2
    signal levels', min_blocks 0 or 2.5 were taken."""
    from isettorch.sensor.noise_estimation import estimate_poisson_gaussian

    z = np.random.default_rng(0).normal(100.0, 2.0, (64, 64))
    for kw, name in (({"white_level_dn": float("nan")}, "white_level_dn"),
                     ({"black_level_dn": float("nan")}, "black_level_dn"),
                     ({"min_blocks": 0}, "min_blocks"), ({"min_blocks": 2.5}, "min_blocks"), ({"levels": 1}, "levels")):
        with pytest.raises(ValueError, match=f"^{name}: expected"):
            estimate_poisson_gaussian(z, **kw)


def test_a_black_level_above_the_frame_is_warned_and_tiny_frames_refused():
    """A black level d DN too high moves b by +a d: 500 DN for a frame at 64 gave b = 436 for 4, with no warning
    (a too-low one already warns, through a negative b). The correct black level, and a frame that is 90 % pure read
    noise, raise no such warning. An empty or 1 x 1 frame crashed in NumPy without naming ``raw``."""
    rng = np.random.default_rng(0)
    y = np.linspace(10, 1000, 256)[None].repeat(256, 0)
    z = np.round(rng.poisson(y) + rng.normal(0, 2, y.shape)) + 64
    ok = estimate_poisson_gaussian(z, black_level_dn=64)
    assert ok["b"] == pytest.approx(4 + 1 / 12, abs=3) and not ok["warnings"]
    high = estimate_poisson_gaussian(z, black_level_dn=500)
    assert high["b"] == pytest.approx(4 + 436 * high["a"], rel=0.05)  # the +a d of the docstring
    assert any(w.startswith("black_level_dn = 500 DN is above the frame's black") for w in high["warnings"])
    dark = np.linspace(0, 300, 256)[None].repeat(256, 0)
    dark[:, :230] = 0
    for seed in range(3):
        g = np.random.default_rng(seed)
        zd = np.round(g.poisson(dark) + g.normal(0, 3, dark.shape)) + 200
        res = estimate_poisson_gaussian(zd, black_level_dn=200, levels=48, min_blocks=50)
        assert not any("above the frame" in w for w in res["warnings"])
    for shape in ((0, 0), (1, 1), (3, 1)):
        with pytest.raises(ValueError, match="^raw: expected a mosaic with at least one 2 x 2 block"):
            estimate_poisson_gaussian(np.full(shape, 5.0))
    with pytest.raises(ValueError, match="^raw: expected a mosaic with at least one 2 x 2 block"):
        estimate_poisson_gaussian(np.full((3, 3), 5.0), cfa="RGGB")


def test_raws_that_read_back_wrong_are_refused(tmp_path):
    """What LibRaw reads back silently wrong is refused naming the file (an audit with hand-written DNGs): a plain
    TIFF named .dng (read as an RGGB raw of black 0), a 4-colour CFA (LibRaw names every one GMCY: a CYGM file read
    as 'GMCY'), a black level not below the white level (the DNG specification asks black < white)."""
    pytest.importorskip("rawpy")
    import tifffile

    from isettorch.io.raw import read_raw

    m = (np.arange(32 * 48).reshape(32, 48) % 3000 + 100).astype(np.uint16)
    dng_by_hand(tmp_path / "ok.dng", m)
    assert read_raw(tmp_path / "ok.dng").cfa == "RGGB"  # the hand-written form reads (the tests below can fail)
    tifffile.imwrite(str(tmp_path / "plain.dng"), m)
    with pytest.raises(ValueError, match="plain.dng: not a DNG .no DNGVersion tag"):
        read_raw(tmp_path / "plain.dng")
    # CFAPattern holds colour codes among CFAPlaneColor's (TIFF/EP; LibRaw names every 4-colour CFA GMCY)
    dng_by_hand(tmp_path / "cygm.dng", m, cfa_codes=(3, 5, 1, 4), plane_colors=(3, 5, 1, 4))
    assert read_raw(tmp_path / "cygm.dng").cfa == "CYGM"
    dng_by_hand(tmp_path / "planes.dng", m, cfa_codes=(0, 1, 2, 3), plane_colors=(3, 4, 1, 5))
    with pytest.raises(ValueError, match=r"planes.dng: CFAPattern \(0, 1, 2, 3\) with CFAPlaneColor \(3, 4, 1, 5\)"):
        read_raw(tmp_path / "planes.dng")
    dng_by_hand(tmp_path / "black.dng", np.minimum(m, 4095), black=5000, white=4095)
    with pytest.raises(ValueError, match="black.dng: black level 5000 DN is not below the white level 4095 DN"):
        read_raw(tmp_path / "black.dng")


def test_dng_window_cfa_and_black_levels_come_from_its_tags(tmp_path):
    """A DNG's ActiveArea, CFA and black levels are its tags' (DNG 1.4 chapter 4: CFAPattern, BlackLevel and the
    deltas count from the ActiveArea's top-left corner), where LibRaw 0.22 silently differs (an audit with
    hand-written DNGs): an odd ActiveArea margin lost a row, an X-Trans pattern took the wrong phase, a Quad-Bayer
    cell read as its 2 x 2 corner, a RATIONAL black level was floored, per-column deltas were averaged."""
    pytest.importorskip("rawpy")
    from isettorch.io.frames import read_frame_data
    from isettorch.io.raw import read_raw

    m = (np.arange(48 * 60).reshape(48, 60) * 7 % 3000 + 300).astype(np.uint16)
    area = (50829, "I", 4, (3, 5, 45, 56), True)  # ActiveArea top, left, bottom, right
    dng_by_hand(tmp_path / "odd.dng", m, extra=[area])  # RGGB from the ActiveArea's corner
    r = read_raw(tmp_path / "odd.dng")
    assert np.array_equal(r.data, m[3:45, 5:56]) and r.cfa == "RGGB" and r.black_level_delta_dn is None
    xtrans = "GGRGGB" "GGBGGR" "BRGRBG" "GGBGGR" "GGRGGB" "RBGBRG"
    codes = tuple("RGB".index(c) for c in xtrans)
    for top, left in ((1, 0), (0, 1), (5, 3), (3, 3)):
        dng_by_hand(tmp_path / "x.dng", m, cfa_codes=codes, dim=(6, 6),
                     extra=[(50829, "I", 4, (top, left, 44, 56), True)])
        r = read_raw(tmp_path / "x.dng")
        assert r.cfa == xtrans and np.array_equal(r.data, m[top:44, left:56]), (top, left)
    quad = "RRGG" "RRGG" "GGBB" "GGBB"
    dng_by_hand(tmp_path / "quad.dng", m, cfa_codes=tuple("RGB".index(c) for c in quad), dim=(4, 4))
    assert read_raw(tmp_path / "quad.dng").cfa == quad
    # RATIONAL black levels, one per position of a 2 x 2 repeat: 60.5, 61.25, 62.75, 63.5 DN
    blacks = [(50713, "H", 2, (2, 2), True), (50714, "2I", 4, (121, 2, 245, 4, 251, 4, 127, 2), True)]
    dng_by_hand(tmp_path / "frac.dng", m, black=None, cfa_codes=(1, 0, 2, 1), extra=blacks)
    r = read_raw(tmp_path / "frac.dng")
    assert r.cfa == "GRBG" and r.black_level_dn == [60.5, 61.25, 62.75, 63.5] and r.black_level_delta_dn is None
    # per-column (SRATIONAL) and per-row deltas over the ActiveArea: pixel (y, x)'s black is 64 + x % 7 - y % 3 / 4
    h, w = 42, 51
    deltas = [(50715, "2i", w, sum(((x % 7, 1) for x in range(w)), ()), True),
              (50716, "2i", h, sum(((-(y % 3), 4) for y in range(h)), ()), True)]
    dng_by_hand(tmp_path / "delta.dng", m, extra=[area, *deltas])
    r = read_raw(tmp_path / "delta.dng")
    y, x = np.mgrid[:h, :w]
    level = 64 + x % 7 - (y % 3) / 4
    per_channel = np.array(r.black_level_dn).reshape(2, 2)
    assert np.allclose(np.tile(per_channel, (21, 26))[:h, :w] + r.black_level_delta_dn, level, atol=1e-12)
    assert np.allclose(per_channel, [[level[i::2, j::2].mean() for j in range(2)] for i in range(2)])
    assert read_frame_data(tmp_path / "delta.dng").black_level_delta_dn is not None
    # a black level that does not fit its repeat, deltas of the wrong length: refused naming the file
    dng_by_hand(tmp_path / "bad.dng", m, black=None, extra=[(50713, "H", 2, (2, 2), True),
                                                            (50714, "H", 3, (1, 2, 3), True)])
    with pytest.raises(ValueError, match="bad.dng: BlackLevel has 3 values for a BlackLevelRepeatDim of"):
        read_raw(tmp_path / "bad.dng")
    dng_by_hand(tmp_path / "bad.dng", m, black=None, extra=[(50714, "s", 0, "n/a", True)])  # an ASCII BlackLevel
    with pytest.raises(ValueError, match="bad.dng: DNG tag 50714 holds"):  # (read by LibRaw alone, black 0)
        read_raw(tmp_path / "bad.dng")
    dng_by_hand(tmp_path / "bad.dng", m, black=None, extra=[(50714, "2I", 1, (64, 0), True)])  # a zero denominator
    with pytest.raises(ValueError, match="bad.dng: DNG tag 50714 holds non-finite values"):
        read_raw(tmp_path / "bad.dng")
    dng_by_hand(tmp_path / "bad.dng", m, extra=[area, (50715, "2i", 3, (1, 1) * 3, True)])
    with pytest.raises(ValueError, match="bad.dng: BlackLevelDeltaV / DeltaH have 42 / 3 values"):
        read_raw(tmp_path / "bad.dng")


def test_a_clip_at_the_full_well_spread_by_read_noise_is_left_out():
    """The library's own sensor clips at the full well and adds read noise after (EMVA 4.1): the saturated pixels
    spread over about 9 codes below the frame's largest value, whose top code holds the fewest, so no pile-up was
    found and the clipped bump was fitted as a bright noise-free level: a = 0.155 for 0.4 with 25 % saturated. A
    uniform bright patch (not clipped) makes the same bump but keeps its shot noise: it is fitted, not left out."""
    import torch

    from isettorch.sensor import Sensor

    k, read_e, well = 0.4, 3.0, 9000.0
    cg = k / 2 ** 12
    sensor = Sensor(rows=512, cols=512, cfa="mono", adc_bits=12, voltage_swing_v=1.0, conversion_gain_v_per_e=cg,
                    read_noise_v=read_e * cg, black_level_dn=100, full_well_e=well, fill_factor=1.0)
    for saturated in (0.05, 0.25):
        rate = torch.linspace(5, well / (1 - saturated), 512, dtype=torch.float64).expand(1, 1, 512, 512) / 0.01
        z = sensor.capture(rate, exposure_s=0.01, generator=torch.Generator().manual_seed(0)).data[0, 0].numpy()
        top = z.max()
        assert (z == top).sum() < (z == top - 3).sum()  # (the top code is the bump's thin upper tail)
        res = estimate_poisson_gaussian(z, black_level_dn=100, white_level_dn=4095)
        assert res["a"] == pytest.approx(k, rel=0.02)
        assert any("form a pile-up below the frame's largest value" in w for w in res["warnings"])
    rng = np.random.default_rng(3)
    xx = np.mgrid[0:512, 0:512][1].astype(np.float64)
    electrons = np.where(xx < 384, 20 + 6000 * xx / 384, 6000.0)  # a ramp, then a uniform bright quarter
    patch = np.round(k * rng.poisson(electrons) + 1.2 * rng.standard_normal(electrons.shape) + 100)
    res = estimate_poisson_gaussian(patch, black_level_dn=100)
    assert res["a"] == pytest.approx(k, rel=0.02) and not any("pile-up" in w for w in res["warnings"])
    assert max(level[0] for level in res["levels"]) > 0.9 * k * 6000  # the patch's level was fitted
    # a uniform low-noise frame is one bump: left out, nothing would be left to fit; it is fitted, with the warning
    # that one level cannot separate a from b
    uniform = np.round(0.05 * rng.poisson(np.full((256, 256), 2000.0)) + 0.5 * rng.standard_normal((256, 256)) + 64)
    res = estimate_poisson_gaussian(uniform, black_level_dn=64)
    assert any("too narrow a range" in w for w in res["warnings"]) and not any("pile-up" in w for w in res["warnings"])


def test_a_floating_point_dng_is_refused_naming_the_file(tmp_path):
    # DNG 1.4 allows float samples (SampleFormat 3: HDR merges). LibRaw scales them to 14-bit codes (1.0 -> 16383)
    # while the black level came from the tag in float units (0.05): normalised, black was ignored, unsaid.
    pytest.importorskip("rawpy")
    import tifffile

    from isettorch.io.raw import read_raw

    dng = [(50706, "B", 4, (1, 4, 0, 0), False), (33421, "H", 2, (2, 2), False), (33422, "B", 4, (0, 1, 1, 2), False),
           (50714, "d", 1, 0.05, False)]
    tifffile.imwrite(tmp_path / "hdr.dng", np.full((8, 8), 0.5, np.float32), photometric=32803, extratags=dng)
    with pytest.raises(ValueError, match=r"hdr.dng: a floating-point DNG \(SampleFormat 3"):
        read_raw(tmp_path / "hdr.dng")
