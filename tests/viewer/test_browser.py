"""``isettorch view`` in a real headless browser (Debian's Chromium driven by playwright): the test starts the
server on a free loopback port, clicks controls, drags regions of interest on the images and reads back the
plotted values, which must equal independent computations of the same quantities.

Skips, saying why, when Bokeh, playwright or a Chromium binary is missing (``.ci/browser.sh`` installs
Debian's chromium in CI). The browser never downloads anything: playwright is pointed at the system binary.
"""

from __future__ import annotations

import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("bokeh", reason="the viewer extra (bokeh) is not installed")
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")

ROOT = Path(__file__).resolve().parents[2]
SIZE = 96  # scene samples: a 6 x 4 Macbeth chart of 16-sample patches
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _chromium() -> str | None:
    for candidate in (os.environ.get("ISETTORCH_CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                      shutil.which("chromium-browser"), shutil.which("google-chrome")):
        if candidate and Path(candidate).is_file():
            return candidate
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server():
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OMP_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "isettorch.cli", "view", "--port", str(port), "--no-browser",
                             "--size", str(SIZE), "--config", "default", "--scene", "macbeth"],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    url = f"http://127.0.0.1:{port}/"
    try:
        deadline = time.monotonic() + 120
        while True:
            if proc.poll() is not None:
                pytest.fail(f"isettorch view exited with {proc.returncode}: {proc.stdout.read()}")
            try:
                urllib.request.urlopen(url, timeout=5).read()
                break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail("isettorch view did not answer within 120 s")
                time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def browser():
    exe = _chromium()
    if exe is None:
        pytest.skip("no Chromium binary found (/usr/bin/chromium; apt-get install chromium, see .ci/browser.sh)")
    with sync_api.sync_playwright() as p, tempfile.TemporaryDirectory() as profile:
        try:
            ctx = p.chromium.launch_persistent_context(profile, executable_path=exe, headless=True, args=CHROMIUM_ARGS,
                                                       viewport={"width": 1400, "height": 1300})
        except Exception as err:  # noqa: BLE001 - a browser that cannot start is a missing browser
            pytest.skip(f"Chromium at {exe} could not be started: {err}")
        yield ctx
        ctx.close()


def _model(page, name: str, attr: str = "data"):
    """A Bokeh model's property, read in the page (typed arrays as lists)."""
    return page.evaluate(
        """([name, attr]) => {
            const m = Bokeh.documents[0].get_model_by_name(name);
            const v = m[attr];
            if (attr !== 'data') return v;
            const out = {};
            for (const [k, col] of v.entries ? v.entries() : Object.entries(v)) out[k] = Array.from(col);
            return out;
        }""", [name, attr])


@pytest.fixture()
def page(server, browser):
    pg = browser.new_page()
    pg.goto(server)
    pg.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0 && "
                         "Bokeh.documents[0].get_model_by_name('status') && "
                         "Bokeh.documents[0].get_model_by_name('status').data.renders[0] >= 1", timeout=120_000)
    yield pg
    pg.close()


def _renders(page) -> int:
    return int(_model(page, "status")["renders"][0])


def _wait_render(page, before: int) -> None:
    page.wait_for_function(f"() => Bokeh.documents[0].get_model_by_name('status').data.renders[0] > {before}",
                           timeout=60_000)


def _drag(page, window: str, frac0: tuple[float, float], frac1: tuple[float, float]) -> dict:
    """Drag a box on a window's image between two points given as fractions (x, y) of the image (y down);
    returns the ROI the page then shows."""
    before = _model(page, f"{window}_roi")
    box = page.locator(f".isettorch-{window}").bounding_box()
    x0, y0 = box["x"] + frac0[0] * box["width"], box["y"] + frac0[1] * box["height"]
    x1, y1 = box["x"] + frac1[0] * box["width"], box["y"] + frac1[1] * box["height"]
    page.mouse.move(x0, y0)
    page.mouse.down()
    for k in range(1, 6):
        page.mouse.move(x0 + (x1 - x0) * k / 5, y0 + (y1 - y0) * k / 5)
    page.mouse.up()
    page.wait_for_function(
        f"() => Bokeh.documents[0].get_model_by_name('{window}_roi').data.row0[0] !== {before['row0'][0]} || "
        f"Bokeh.documents[0].get_model_by_name('{window}_roi').data.col0[0] !== {before['col0'][0]}",
        timeout=30_000)
    # The drag sends intermediate boxes (row0/col0 change at the first one): wait until the ROI and the
    # server's answer to it have settled (two reads 0.4 s apart agree) before the test reads them.
    roi, deadline = _model(page, f"{window}_roi"), time.monotonic() + 30
    while time.monotonic() < deadline:
        page.wait_for_timeout(400)
        again = _model(page, f"{window}_roi")
        if again == roi:
            break
        roi = again
    page.wait_for_timeout(400)
    return {k: int(roi[k][0]) for k in ("row0", "row1", "col0", "col1")}


def test_scene_roi_spectrum_is_the_mean_radiance_of_the_dragged_region(page):
    from isettorch.scene import macbeth

    img = _model(page, "scene_image")
    h, w = int(img["dh"][0]), int(img["dw"][0])
    assert (h, w) == (4 * (SIZE // 6), 6 * (SIZE // 6))
    roi = _drag(page, "scene", (0.52, 0.30), (0.64, 0.45))
    # The box lands where it was dragged (to a pixel or two of mouse rounding).
    assert abs(roi["col0"] - 0.52 * w) <= 2 and abs(roi["col1"] - 0.64 * w) <= 2
    assert abs(roi["row0"] - 0.30 * h) <= 2 and abs(roi["row1"] - 0.45 * h) <= 2
    spectrum = _model(page, "scene_spectrum")
    # Independent: the same chart's radiance averaged over the region here (hfov does not change radiance).
    ref = macbeth("D65", patch_size=SIZE // 6).photons[0, :, roi["row0"]:roi["row1"], roi["col0"]:roi["col1"]]
    expected = ref.double().mean(dim=(-2, -1)).numpy()
    np.testing.assert_allclose(spectrum["wavelength_nm"], np.arange(400.0, 701.0, 10.0))
    np.testing.assert_allclose(spectrum["photons"], expected, rtol=1e-5)
    # The region sits inside one patch (row 2, column 4: 'purple', reflectance rising into the red).
    assert spectrum["photons"][-1] > 2 * spectrum["photons"][15]


def test_f_number_click_updates_the_mtf_to_the_diffraction_limit(page):
    before = _renders(page)
    page.locator("select").nth(1).select_option("8")  # the f-number control
    _wait_render(page, before)
    mtf = _model(page, "mtf")
    nu = np.asarray(mtf["frequency_cpmm"]) * 1e3  # cycles/m
    # Diffraction-limited incoherent MTF of a circular pupil (Goodman, Introduction to Fourier Optics, 3rd ed.,
    # eq. 6-32): 2/pi (acos s - s sqrt(1 - s^2)), s = nu lambda N, zero beyond the cutoff 1 / (lambda N).
    for wl in (450, 550, 650):
        s = np.clip(nu * wl * 1e-9 * 8.0, 0, 1)
        expected = 2 / math.pi * (np.arccos(s) - s * np.sqrt(1 - s ** 2))
        np.testing.assert_allclose(mtf[f"mtf_{wl}"], expected, atol=1e-6)
    # The frequency axis runs to the 450 nm cutoff at f/8.
    assert nu[-1] == pytest.approx(1 / (450e-9 * 8.0), rel=1e-9)
    assert _model(page, "f_number_select", "value") == "8"


def test_cfa_click_and_sensor_roi_histogram_count_the_cfa_pixels(page):
    before = _renders(page)
    page.get_by_role("button", name="RGGB").click()
    _wait_render(page, before)
    roi = _drag(page, "sensor", (0.10, 0.12), (0.30, 0.40))
    stats = _model(page, "sensor_stats")
    hist = _model(page, "sensor_histogram")
    # Pixels of each channel of an RGGB cell (R at even row and column, B at odd, G elsewhere) in the region.
    rows = np.arange(roi["row0"], roi["row1"])[:, None]
    cols = np.arange(roi["col0"], roi["col1"])[None, :]
    is_r = (rows % 2 == 0) & (cols % 2 == 0)
    is_b = (rows % 2 == 1) & (cols % 2 == 1)
    expected = {"R": int(is_r.sum()), "G": int((~is_r & ~is_b).sum()), "B": int(is_b.sum())}
    assert dict(zip(stats["channel"], stats["n"])) == expected
    # The histogram holds every pixel of each channel once (values lie between black and white level).
    for ch, n in expected.items():
        counts = [c for name, c in zip(hist["channel"], hist["count"]) if name == ch]
        assert sum(counts) == n
    # SNR in dB is 20 log10(mean / std).
    for m, sd, snr in zip(stats["mean"], stats["std"], stats["snr_db"]):
        assert snr == pytest.approx(20 * math.log10(m / sd), rel=1e-9)


def test_processed_window_delta_e_matches_the_library_for_the_same_camera(page):
    from isettorch.camera import Camera
    from isettorch.isp.chart import macbeth_delta_e, patch_means
    from isettorch.scene import macbeth
    from isettorch.viewer.session import resolve_config

    de = _model(page, "delta_e")
    assert de["patch"] == list(range(1, 25))
    cam = Camera.from_config(resolve_config("default"))
    f = float(cam.optics.focal_length_m.reshape(-1)[0])
    # the viewer's geometry: one optical-image sample per 0.999 pixel at the scene distance (thin lens, 1.2 m)
    d_i = 1.0 / (1.0 / f - 1.0 / 1.2)
    hfov = math.degrees(2 * math.atan(0.999 * SIZE * cam.sensor.pixel_size_m / (2 * d_i)))
    with torch.no_grad():
        out = cam(macbeth("D65", patch_size=-(-SIZE // 6), hfov_deg=hfov), return_intermediates=True,
                  generator=torch.Generator().manual_seed(0))
    acc = macbeth_delta_e(patch_means(out.isp.xyz.double()), "D65")
    np.testing.assert_allclose(de["delta_e"], acc.delta_e[0].numpy(), rtol=1e-6)
    # Dragging on the processed image moves the ROI's chromaticity point to that region's xy.
    roi = _drag(page, "ip", (0.05, 0.80), (0.12, 0.95))  # inside the white patch (row 4, column 1)
    xy = _model(page, "roi_xy")
    region = out.isp.xyz[0, :, roi["row0"]:roi["row1"], roi["col0"]:roi["col1"]].double().mean(dim=(-2, -1))
    expected = (region[:2] / region.sum()).numpy()  # CIE 15:2004 eq. 7.3
    np.testing.assert_allclose([xy["x"][0], xy["y"][0]], expected, rtol=1e-6)
