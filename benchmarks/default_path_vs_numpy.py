"""Default optics + sensor (float64, 512^2 x 31 frequency sweep, noise off) against benchmarks/numpy_reference.py in
the same process: median wall time of repeats, the ratio, and the volts' relative RMS difference. The sweep is a
factored scene (rank 1); ``dense`` is the same scene as a [31, H, W] cube through the same modules.

Usage: ``PYTHONPATH=. python benchmarks/default_path_vs_numpy.py`` (from a source checkout).
"""
import argparse
import importlib.util
import math
import statistics
import time
from pathlib import Path

import torch

from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import frequency_sweep
from isettorch.sensor import Sensor

# the configuration of `isettorch bench`'s isettorch_optics_sensor_512x512x31 row (ISETCam's default lens and sensor)
PITCH_M, FOCAL_M, DISTANCE_M = 2.8e-6, 3.862755099e-3, 1.2
argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()  # (--help ran the whole benchmark)
torch.set_num_threads(2)
spec = importlib.util.spec_from_file_location("nref", Path(__file__).with_name("numpy_reference.py"))  # (any cwd)
ref = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ref)
n = 512
d_i = 1 / (1 / FOCAL_M - 1 / DISTANCE_M)  # thin lens
hfov = math.degrees(2 * math.atan(PITCH_M * n / (2 * d_i)))  # one scene sample per pixel
sc = frequency_sweep(n, wavelengths=torch.arange(400.0, 705.0, 10.0, dtype=torch.float64), hfov_deg=hfov,
                     distance_m=DISTANCE_M, dtype=torch.float64)
dense = sc.to_dense() if hasattr(sc, "to_dense") else sc
optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=FOCAL_M)
sensor = Sensor.preset("isetcam_default", rows=n, cols=n, exposure_s=0.01, read_noise_v=0.0, dark_current_e_per_s=0.0,
                       shot_noise="off")


def med(fn, r=5):
    fn()
    ts = []
    for _ in range(r):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), out



with torch.no_grad():
    t_f, raw_f = med(lambda: sensor(optics(sc), noise=False))
    t_d, raw_d = med(lambda: sensor(optics(dense), noise=False))
    oi = optics(dense)
qe = sensor.qe(oi).numpy()
cell = sensor.cfa.index_map.numpy()
kw = dict(hfov_deg=float(sc.hfov_deg[0]), distance_m=DISTANCE_M, f_number=4.0, focal_length_m=FOCAL_M,
          pad=(oi.pad_rows, oi.pad_cols), qe=qe, cfa_index=cell, rows=n, cols=n, pixel_size_m=PITCH_M,
          fill_factor=sensor.fill_factor, exposure_s=0.01, conversion_gain_v_per_e=sensor.conversion_gain_v_per_e,
          voltage_swing_v=sensor.voltage_swing_v)
p, w = dense.photons[0].numpy(), dense.wavelengths_nm.numpy()
t_n, v = med(lambda: ref.simulate(p, w, **kw), 3)
vt = torch.from_numpy(v)


def rel_rms(a):
    return float((a - vt).pow(2).mean().sqrt() / vt.pow(2).mean().sqrt())


print(f"numpy_reference {t_n:.3f} s | isettorch factored (default scene) {t_f:.3f} s ({t_n / t_f:.2f}x, rel RMS "
      f"{rel_rms(raw_f.data[0, 0]):.1e}) | dense {t_d:.3f} s ({t_n / t_d:.2f}x, rel RMS "
      f"{rel_rms(raw_d.data[0, 0]):.1e})")
