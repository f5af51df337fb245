"""`isettorch parity`: the shared ISETCam cases pass, and synthetic cases in the parity format computed by an
independent numpy implementation of FORMAT.md 4.6 (YCMY, monochrome, N-bit, analog gain, even-k pre-blur,
odd sizes, coarse wavelength bins) match the sensor stage."""

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from isettorch.cli import main
from isettorch.commands import parity

SHARED = sorted(Path("/work/shared/isetcam-parity").glob("*.npz"))
Q = 1.602177e-19  # ISETCam vcConstants


def reference_sensor(oi, wave, qe, pattern, dx, pitch, ff, rows, cols, t, cg, swing, gain, offset, bits):
    """FORMAT.md 4.6, written out with loops (float64): returns current (A), volts and dv (or None)."""
    oi = oi.astype(np.float64)
    n_l, h2, w2 = oi.shape
    bw = wave[1] - wave[0]
    scd = Q * bw * np.einsum("lhw,cl->chw", oi, qe)  # step 1: A/m^2 per filter
    k = math.ceil(pitch / dx)
    if k > 1:  # step 2: fspecial('gaussian', [k k], k/4), conv2 'same', zero boundary
        g = fspecial_gaussian(k)
        blurred = np.empty_like(scd)
        for c in range(scd.shape[0]):
            full = np.zeros((h2 + k - 1, w2 + k - 1))
            for i in range(k):
                for j in range(k):
                    full[i:i + h2, j:j + w2] += g[i, j] * scd[c]
            blurred[c] = full[k // 2:k // 2 + h2, k // 2:k // 2 + w2]
        scd = blurred
    # step 3: both grids centred on the optical axis, bilinear, outside -> 0
    u = (w2 - 1) / 2 + (np.arange(cols) - (cols - 1) / 2) * pitch / dx
    v = (h2 - 1) / 2 + (np.arange(rows) - (rows - 1) / 2) * pitch / dx
    pr, pc = pattern.shape
    current = np.zeros((rows, cols))
    for r in range(rows):
        for c in range(cols):
            ch = pattern[r % pr, c % pc] - 1
            y, x = v[r], u[c]
            if not (0 <= y <= h2 - 1 and 0 <= x <= w2 - 1):
                continue
            y0 = min(int(np.floor(y)), h2 - 2)
            x0 = min(int(np.floor(x)), w2 - 2)
            ty, tx = y - y0, x - x0
            a = scd[ch]
            val = ((1 - ty) * (1 - tx) * a[y0, x0] + (1 - ty) * tx * a[y0, x0 + 1]
                   + ty * (1 - tx) * a[y0 + 1, x0] + ty * tx * a[y0 + 1, x0 + 1])
            current[r, c] = val * ff * pitch**2  # step 4
    volts = current * t * cg / Q  # step 5
    if gain != 1 or offset != 0:
        volts = (volts + offset) / gain  # step 7: ISETCam divides
    volts = np.clip(volts, 0, swing).astype(np.float32)  # step 8 (ISETCam holds single)
    dv = None
    if bits:
        dv = np.floor(volts.astype(np.float64) / (swing / 2**bits) + 0.5).astype(np.float32)  # step 9, no clamp
    return current.astype(np.float32), volts, dv


def fspecial_gaussian(k):
    o = np.arange(k) - (k - 1) / 2
    g = np.exp(-(o[:, None] ** 2 + o[None, :] ** 2) / (2 * (k / 4) ** 2))
    return g / g.sum()


def make_case(path, *, cfa, pattern, names, letters, bits, gain, offset, pitch, dx, rows, cols, oi_size, wave,
              peak_volts, seed):
    rng = np.random.default_rng(seed)
    n_l = len(wave)
    h2, w2 = oi_size
    yy, xx = np.mgrid[0:h2, 0:w2]
    smooth = 1 + 0.5 * np.sin(xx / 3.0)[None] * np.cos(yy / 4.0)[None]
    oi = (1e16 * smooth * rng.uniform(0.2, 1.0, (n_l, h2, w2))).astype(np.float32)
    qe = rng.uniform(0.0, 0.4, (len(names), n_l))
    ff, cg, swing = 0.75, 1e-4, 1.0
    # exposure chosen so the brightest pre-gain volts are about peak_volts (clipping after the gain)
    bw = wave[1] - wave[0]
    t = peak_volts / (cg * ff * pitch**2 * bw * np.einsum("lhw,cl->chw", oi.astype(float), qe).max())
    pattern = np.asarray(pattern, np.int64)
    current, volts, dv = reference_sensor(oi, wave, qe, pattern, dx, pitch, ff, rows, cols, t, cg, swing, gain,
                                          offset, bits)
    k = math.ceil(pitch / dx)
    data = dict(
        oi_photons=oi, wavelengths_nm=np.asarray(wave, np.float64), oi_sample_spacing_m=np.float64(dx),
        oi_pad_rows=np.int64(0), oi_pad_cols=np.int64(0), sensor_rows=np.int64(rows), sensor_cols=np.int64(cols),
        sensor_pixel_size_m=np.float64(pitch), sensor_fill_factor=np.float64(ff),
        sensor_conversion_gain_v_per_e=np.float64(cg), sensor_voltage_swing_v=np.float64(swing),
        sensor_exposure_s=np.float64(t), sensor_cfa=np.str_(cfa), sensor_filter_names=np.array(names),
        sensor_filter_letters=np.str_(letters), sensor_cfa_pattern=pattern, sensor_spectral_qe=qe,
        sensor_analog_gain=np.float64(gain), sensor_analog_offset=np.float64(offset),
        sensor_quantization=np.str_(str(bits) if bits else "analog"), sensor_volts=volts,
        sensor_signal_current_a=current, sensor_regrid_kernel=fspecial_gaussian(k),
        case_name=np.str_(Path(path).stem), meta=np.str_("synthetic: numpy implementation of FORMAT.md 4.6"),
    )
    if dv is not None:
        data["sensor_dv"] = dv
    np.savez(path, **data)
    return data


SYNTHETIC = {
    # YCMY, 10-bit, analog gain 2 (divides), even-k pre-blur (k = 4), odd sizes, 45 nm bins
    "ycmy_10bit_gain2_k4": dict(cfa="YCMY", pattern=[[2, 1], [3, 2]], names=["cDefault", "yDefault", "mDefault"],
                                letters="cym", bits=10, gain=2.0, offset=0.0, pitch=3.5e-6, dx=1e-6, rows=9,
                                cols=11, oi_size=(37, 45), wave=np.arange(400.0, 700.0, 45.0), peak_volts=3.5),
    # monochrome, 8-bit, gain 1.5 and offset, k = 2 (the half-sample shift), sensor larger than the OI
    "mono_8bit_k2": dict(cfa="W", pattern=[[1]], names=["w"], letters="w", bits=8, gain=1.5, offset=0.01,
                         pitch=1.5e-6, dx=1e-6, rows=15, cols=21, oi_size=(21, 29), wave=np.arange(400.0, 701.0, 50.0),
                         peak_volts=3.0),
    # GRBG analog, pixels much smaller than the OI samples (no pre-blur)
    "grbg_analog_small_pixels": dict(cfa="GRBG", pattern=[[2, 1], [3, 2]], names=["rDefault", "gDefault", "bDefault"],
                                     letters="rgb", bits=0, gain=1.0, offset=0.0, pitch=1.1e-6, dx=4.3e-6, rows=31,
                                     cols=41, oi_size=(13, 15), wave=np.arange(400.0, 701.0, 10.0), peak_volts=0.9),
}


@pytest.mark.parametrize("name", sorted(SYNTHETIC))
def test_synthetic_cases_sensor_stage(tmp_path, name):
    path = tmp_path / f"{name}.npz"
    data = make_case(path, seed=len(name), **SYNTHETIC[name])
    res = parity.run_case(path)
    st = res["stages"]
    assert st["oi_photons"]["ok"] is None  # no scene in these cases: skipped, reported as such
    assert st["sensor_volts"]["ok"], st["sensor_volts"]
    assert st["sensor_volts"]["max_err"] < 1e-6
    assert st["sensor_current"]["ok"] and st["sensor_current"]["max_err"] < 1e-5
    if "sensor_dv" in data:
        assert st["sensor_dv"]["ok"] and st["sensor_dv"]["exact_fraction"] >= 0.999
        assert data["sensor_dv"].max() == 2 ** SYNTHETIC[name]["bits"]  # clipped at the swing -> 2^N (no clamp)
    else:
        assert st["sensor_dv"]["ok"] is None
    assert res["ok"] and res["notes"] == []
    assert (data["sensor_volts"] == 1.0).any() or name == "grbg_analog_small_pixels"


def test_wrong_volts_fail_and_exit_code(tmp_path, capsys):
    path = tmp_path / "bad.npz"
    data = make_case(path, seed=3, **SYNTHETIC["ycmy_10bit_gain2_k4"])
    data["sensor_volts"] = data["sensor_volts"].copy()
    data["sensor_volts"][4, 5] += 3e-5
    np.savez(path, **data)
    res = parity.run_case(path)
    assert not res["stages"]["sensor_volts"]["ok"]
    assert res["stages"]["sensor_volts"]["max_err"] == pytest.approx(3e-5, rel=1e-2)
    assert parity.run(SimpleNamespace(cases=[str(path)], json=False, repeat=0)) == 1
    # an unreadable case exits 2 and says why
    bad = tmp_path / "missing.npz"
    assert parity.run(SimpleNamespace(cases=[str(bad)], json=True, repeat=0)) == 2
    out = capsys.readouterr().out
    assert "missing.npz" in out


def test_cfa_string_must_match_pattern(tmp_path):
    path = tmp_path / "inconsistent.npz"
    data = make_case(path, seed=1, **SYNTHETIC["ycmy_10bit_gain2_k4"])
    data["sensor_cfa"] = np.str_("CYYM")
    np.savez(path, **data)
    with pytest.raises(ValueError, match="sensor_cfa"):
        parity.run_case(path)


@pytest.mark.skipif(not SHARED, reason="no shared ISETCam parity cases")
def test_shared_cases_pass_json(capsys):
    code = main(["parity", *map(str, SHARED), "--json", "--repeat", "1"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["ok"] is True
    assert len(out["cases"]) == len(SHARED)
    for case in out["cases"]:
        st = case["stages"]
        assert set(st["sensor_volts"]) >= {"mean_rel_err", "max_err", "ok", "seconds"}
        assert st["sensor_volts"]["max_err"] <= 1e-5
        assert st["mean_illuminance"]["max_err"] <= 2e-3
        if st["oi_photons"]["ok"] is not None:
            assert st["oi_photons"]["max_err"] <= 1e-4 and "seconds" in st["oi_photons"]
        assert "sensor_volts_from_our_oi" in st


def test_noise_statistics_stage_against_format_formula(tmp_path):
    # uniform field, ISETCam noise model: residual std = sqrt(prnu^2 v^2 + cg v + cg^2/12 + read^2 + dsnu^2)
    path = tmp_path / "noise.npz"
    spec = dict(SYNTHETIC["grbg_analog_small_pixels"], rows=40, cols=50, peak_volts=0.4)
    data = make_case(path, seed=9, **spec)
    oi = np.full_like(data["oi_photons"], data["oi_photons"].mean())
    data["oi_photons"] = oi
    current, volts, _ = reference_sensor(oi, spec["wave"], data["sensor_spectral_qe"], data["sensor_cfa_pattern"],
                                         spec["dx"], spec["pitch"], 0.75, 40, 50, float(data["sensor_exposure_s"]),
                                         1e-4, 1.0, 1.0, 0.0, 0)
    data.update(sensor_volts=volts, sensor_signal_current_a=current, sensor_read_noise_v=np.float64(1e-3),
                sensor_dark_voltage_v_per_s=np.float64(1e-3), sensor_dsnu_sigma_v=np.float64(2e-3),
                sensor_prnu_sigma_percent=np.float64(1.0), noise_nruns=np.int64(20))
    t = float(data["sensor_exposure_s"])
    idx = np.tile(data["sensor_cfa_pattern"] - 1, (20, 25))
    v = np.array([volts[idx == c].mean() for c in range(3)]) + 1e-3 * t
    data["noise_resid_std_v"] = np.sqrt((0.01 * v) ** 2 + 1e-4 * v + 1e-8 / 12 + 1e-6 + 4e-6)
    data["noise_resid_mean_v"] = np.full(3, 1e-3 * t)
    np.savez(path, **data)
    st = parity.run_case(path)["stages"]["noise_stats"]
    assert st["informational"] and st["ok"], st
    assert st["max_err"] < 0.02
    np.testing.assert_allclose(st["resid_mean_v"], 1e-3 * t, atol=6e-5)
