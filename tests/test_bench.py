"""Smoke test of ``isettorch bench --json --quick`` on tiny sizes: the JSON schema, finite errors, reference rows
at error 0, and the cross-checks the benchmark makes (independent NumPy pipeline, colour-demosaicing, the
grouped-OTF identity). Timings are never asserted."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest
import torch

from isettorch.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench  # noqa: E402  benchmarks/bench.py (not part of the package)

KNOB_GROUPS = ("wavelength_step", "otf_grouping", "padding", "sampling", "dtype", "shot_noise")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    torch.set_num_threads(1)
    png = tmp_path_factory.mktemp("bench") / "pareto.png"
    import io
    from contextlib import redirect_stdout

    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = main(["bench", "--json", "--quick", "--sizes", "32", "--stable-size", "32", "--knob-patch", "4",
                   "--repeats", "1", "--plot", str(png)])
    assert rc == 0
    out = json.loads(buf.getvalue())
    out["_png"] = png
    return out


def _rows(result, group=None):
    return {r["name"]: r for r in result["rows"] if group is None or r["group"] == group}


def test_schema(result):
    assert set(result) >= {"rows", "skipped", "pairs_per_s", "pairs_note", "machine", "settings"}
    names = [r["name"] for r in result["rows"]]
    assert len(names) == len(set(names)), "row names must be unique"
    for r in result["rows"]:
        assert set(bench.ROW_KEYS) <= set(r)
        assert isinstance(r["name"], str) and r["name"]
        assert isinstance(r["seconds_median"], float) and r["seconds_median"] > 0
        assert 0 < r["seconds_min"] <= r["seconds_median"]  # fastest run <= median
        if "cpu_seconds_median" in r:  # process CPU time per run, all threads
            assert r["cpu_seconds_median"] >= 0
        assert (r["error"] is None) == (r["error_unit"] is None)
        if r["error"] is not None:
            assert math.isfinite(r["error"]) and r["error"] >= 0
    rows = _rows(result)
    assert "optics_32x32x31" in rows and "sensor_32x32x31" in rows  # stable names (512 in the standard run)
    assert result["pairs_per_s"] is None or (math.isfinite(result["pairs_per_s"]) and result["pairs_per_s"] > 0)
    assert result["_png"].stat().st_size > 10_000  # the time-vs-error plot was written


def test_isetcam_rows_and_peer_rows(result):
    """The acceptance rows: the ISETCam-mode optics/sensor (float32, error against float64 <= 1e-4, the parity
    bound; nonzero since float32 rounds) and the float64 library pipeline next to the NumPy reference."""
    rows = _rows(result)
    for name in ("optics_32x32x31", "sensor_32x32x31", "isettorch_optics_sensor_32x32x31",
                 "numpy_reference_32x32x31"):
        assert {"name", "seconds_median", "seconds_min", "error", "error_unit"} <= set(rows[name]), name
    for name in ("optics_32x32x31", "sensor_32x32x31", "optics_dense_32x32x31"):
        assert 0 < rows[name]["error"] <= 1e-4, (name, rows[name]["error"])


def test_rank1_factors():
    g = torch.Generator().manual_seed(0)
    maps, spectra = torch.rand(2, 1, 5, 6, generator=g), torch.rand(2, 1, 4, generator=g) + 0.1
    cube = torch.einsum("bjhw,bjl->blhw", maps, spectra)
    m, s = bench.rank1_factors(cube)
    torch.testing.assert_close(torch.einsum("bjhw,bjl->blhw", m, s), cube)
    with pytest.raises(ValueError, match="rank-1"):
        bench.rank1_factors(cube + torch.rand(cube.shape, generator=g))


def test_package_never_imports_benchmarks():
    """Importing every isettorch module loads nothing from benchmarks/ (checked in a fresh interpreter)."""
    import subprocess

    code = ("import importlib, pkgutil, sys, isettorch\n"
            "for m in pkgutil.walk_packages(isettorch.__path__, 'isettorch.'):\n"
            "    importlib.import_module(m.name)\n"
            "bad = [n for n, m in list(sys.modules.items()) if 'benchmarks' in (getattr(m, '__file__', '') or '')]\n"
            "print(len(sys.modules), bad)\n"
            "sys.exit(1 if bad else 0)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_every_knob_group_has_one_reference_at_zero_error(result):
    for g in KNOB_GROUPS:
        rows = _rows(result, g)
        assert len(rows) >= 2, g
        refs = [r for r in rows.values() if r.get("reference")]
        assert len(refs) == 1, g
        assert refs[0]["error"] == 0.0
        assert all(r["error"] is not None for r in rows.values())
        for r in rows.values():
            if "errors" in r and r.get("reference"):
                assert r["errors"]["de2000_mean"] == 0.0 and r["errors"]["cpsnr_db"] is None


def test_knob_errors_physically_ordered(result):
    ws = _rows(result, "wavelength_step")
    # coarser spectral sampling of the same scene: larger error against 1 nm
    assert 0 < ws["wavelength_step_5nm"]["error"] < ws["wavelength_step_20nm"]["error"]
    dt = _rows(result, "dtype")
    assert 0 < dt["dtype_float32"]["error"] < 1e-5  # float32 rounding, relative to float64
    pad = _rows(result, "padding")
    # light wrapping around without padding vs the optics' default margin (tolerance 1e-3 of the LSF energy)
    assert pad["pad_tol_1e-3_default"]["error"] < pad["pad_margin_0px"]["error"]
    noise = _rows(result, "shot_noise")
    assert noise["shot_noise_off"]["error"] == pytest.approx(1.0)  # no noise at all: 100 % of the std missing


def test_peers_agree(result):
    peers = _rows(result, "peer_pipeline")
    np_rows = [r for n, r in peers.items() if n.startswith("numpy_reference")]
    assert np_rows and all(r["error"] < 1e-10 for r in np_rows)  # independent NumPy physics, float64
    dem = _rows(result, "peer_demosaic")
    # bilinear demosaic: isettorch, colour-demosaicing and kornia score the same CPSNR on the same mosaic
    ours, theirs = dem["demosaic_isettorch_bilinear_32"]["error"], dem["demosaic_colour_bilinear_32"]["error"]
    assert ours == pytest.approx(theirs, abs=0.05)
    crop = _rows(result, "proportional")
    on = [r for n, r in crop.items() if n.startswith("crop_on")]
    assert on and on[0]["error"] < 1e-3  # crop before blur: only the PSF energy beyond the margin is missed


def test_pareto_front():
    pts = [(1.0, 0.5), (2.0, 0.1), (1.5, 0.6), (3.0, 0.1), (0.5, 1.0)]
    assert bench.pareto_front(pts) == [4, 0, 1]


def test_group_centres():
    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    c = bench.group_centres(w, 4)  # 31 bands -> groups of 8, 8, 8, 7
    assert c[0] == 435.0 and c[7] == 435.0 and c[8] == 515.0 and c[-1] == 670.0
    assert c.unique().numel() == 4
    assert torch.equal(bench.group_centres(w, 31), w)


def test_bad_arguments(capfd):
    # the script runs in a child process: its error lines reach file descriptor 2
    assert main(["bench", "--sizes", "abc"]) == 2
    assert "--sizes" in capfd.readouterr().err
    assert main(["bench", "--threads", "0"]) == 2
    assert "--threads" in capfd.readouterr().err
    if not torch.cuda.is_available():
        assert main(["bench", "--device", "cuda"]) == 2
        assert "CUDA is not available" in capfd.readouterr().err


def test_report_lists_every_row(result):
    text = bench.format_report(result)
    assert "### Knobs" in text and "Training pairs/s" in text
    for r in result["rows"]:
        assert f"| {r['name']}" in text


@pytest.mark.parametrize("levels", [{}, {"black_level_dn": 64, "adc_bits": 10}, {"full_well_e": 5000}])
def test_the_benchmarks_exposure_is_the_sensors_auto_exposure(levels):
    """The benchmark's fixed exposure puts the brightest noise-free pixel at 80 % of saturation by the sensor's own
    rule: a formula of its own (80 % of the swing over the electron rate) overexposed a 5000 e- well 2x and a
    64 DN black level by 7 %."""
    sensor = bench.make_sensor(32, 32, **levels)
    oi = bench.make_optics()(bench.sweep_scene(32, None, torch.float64, "cpu"))
    t = bench.fixed_exposure(sensor, oi)
    raw = sensor(oi, exposure_s=t, noise=False)
    top = 0.8 * sensor.saturation_v(1.0)  # volts above black at 80 % of the well or the ADC's range
    if sensor.adc_bits is None:
        assert float(raw.data.max()) == pytest.approx(top, rel=1e-9)
    else:  # DN: the ADC rounds
        assert float(raw.data.max()) - sensor.black_level_dn == pytest.approx(top / sensor.lsb_v, abs=0.5)
