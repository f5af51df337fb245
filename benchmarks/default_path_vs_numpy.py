"""Default optics + sensor (float64, 512^2 x 31 frequency sweep, noise off) against benchmarks/numpy_reference.py in
the same process: median wall time of repeats, the ratio, and the volts' relative RMS difference. The sweep is a
factored scene (rank 1); ``dense`` is the same scene as a [31, H, W] cube through the same modules.

Usage: ``PYTHONPATH=. python benchmarks/default_path_vs_numpy.py`` (from a source checkout).
"""
import importlib.util
import statistics
import time

import torch

from isettorch import bench as B
torch.set_num_threads(2)
spec = importlib.util.spec_from_file_location("nref", "benchmarks/numpy_reference.py")
ref = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ref)
n = 512
sc = B.sweep_scene(n, B.wavelengths(10.0), torch.float64, "cpu")
dense = sc.to_dense() if hasattr(sc, "to_dense") else sc
optics, sensor = B.make_optics(), B.make_sensor(n, n)


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
kw = dict(hfov_deg=float(sc.hfov_deg[0]), distance_m=B.DISTANCE_M, f_number=4.0, focal_length_m=B.FOCAL_M,
          pad=(oi.pad_rows, oi.pad_cols), qe=qe, cfa_index=cell, rows=n, cols=n, pixel_size_m=B.PITCH_M,
          fill_factor=sensor.fill_factor, exposure_s=0.01, conversion_gain_v_per_e=sensor.conversion_gain_v_per_e,
          voltage_swing_v=sensor.voltage_swing_v)
p, w = dense.photons[0].numpy(), dense.wavelengths_nm.numpy()
t_n, v = med(lambda: ref.simulate(p, w, **kw), 3)
vt = torch.from_numpy(v)


def rel_rms(a):
    return float((a - vt).pow(2).mean().sqrt() / vt.pow(2).mean().sqrt())


print(f"numpy_reference {t_n:.3f} s | isettorch factored (default scene) {t_f:.3f} s ({t_n / t_f:.2f}x, rel RMS "
      f"{rel_rms(raw_f.data[0, 0]):.1e}) | dense {t_d:.3f} s ({t_n / t_d:.2f}x, rel RMS {rel_rms(raw_d.data[0, 0]):.1e})")
