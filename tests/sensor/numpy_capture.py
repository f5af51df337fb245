"""Calibration captures simulated in plain NumPy (independent of isettorch), with known truth.

Model per pixel and frame (electrons, then DN): mean = QE_c x photons x (1 + PRNU z_p) + dark current x t;
e = min(Poisson(mean), full well); DN = clip(round(K (e + DSNU z_d + read n + row r_f(i)) + black), 0, 2^bits - 1),
with z_p, z_d fixed per pixel, n per pixel and frame, r per row and frame (all standard normal).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TRUTH = dict(gain_dn_per_e=0.4, read_noise_e=3.0, dark_current_e_per_s=60.0, dsnu_e=4.0, prnu_percent=1.0,
             row_noise_e=0.8, full_well_e=9000.0, black_level_dn=100.0, bits=12, qe={"W": 0.6})
BAYER_QE = {"R": 0.35, "G": 0.55, "B": 0.3}


def sensor_maps(truth: dict, shape, seed: int = 0):
    """``(rng, prnu, dsnu)``: the generator of a simulated sensor seeded ``seed`` and its fixed per-pixel patterns
    (PRNU gain ``1 + prnu% z_p``, DSNU electrons ``dsnu_e z_d``), drawn first from it."""
    rng = np.random.default_rng(seed)
    prnu = 1 + truth["prnu_percent"] / 100 * rng.standard_normal(shape)
    dsnu = truth["dsnu_e"] * rng.standard_normal(shape)
    return rng, prnu, dsnu


def expose(truth: dict, mean_e: np.ndarray, dsnu: np.ndarray, rng, quantise: bool = True) -> np.ndarray:
    """One frame in DN (uint16) of a sensor with DSNU ``dsnu`` for the mean electrons ``mean_e`` per pixel (PRNU
    and dark current already in it): Poisson, the well, read and row noise, gain, black level, rounding, clipping
    (``quantise=False``: float64, not rounded: an analog readout)."""
    h, w = mean_e.shape
    e = np.minimum(rng.poisson(mean_e).astype(np.float64), truth["full_well_e"])
    row = truth["row_noise_e"] * rng.standard_normal((h, 1))
    dn = (truth["gain_dn_per_e"] * (e + dsnu + truth["read_noise_e"] * rng.standard_normal((h, w)) + row)
          + truth["black_level_dn"])
    if not quantise:
        return np.clip(dn, 0, 2 ** truth["bits"] - 1)
    return np.clip(np.round(dn), 0, 2 ** truth["bits"] - 1).astype(np.uint16)


def qe_map(truth: dict, shape, cfa: str | None = None) -> np.ndarray:
    """Per-pixel quantum efficiency: ``truth["qe"]["W"]`` everywhere, or a 2 x 2 CFA's channels (e.g. "RGGB")."""
    out = np.empty(shape)
    if cfa is None:
        out[:] = truth["qe"]["W"]
    else:
        for dy in range(2):
            for dx in range(2):
                out[dy::2, dx::2] = truth["qe"][cfa[2 * dy + dx]]
    return out


def hot_pixel_mask(shape, count: int, seed: int = 0) -> np.ndarray:
    """``count`` hot pixel positions (a boolean map), drawn from their own generator (the frames' draws unchanged)."""
    mask = np.zeros(shape, dtype=bool)
    mask.flat[np.random.default_rng(seed + 7919).choice(mask.size, count, replace=False)] = True
    return mask


def simulate(truth: dict, *, shape=(256, 256), cfa: str | None = None, exposures_ms=None, frames: int = 3,
             saturate_ms: float = 45.0, seed: int = 0, hot_pixels: int = 0, hot_factor: float = 500.0,
             quantise: bool = True):
    """Returns (dark, flat, photons_per_pixel): {ms: (frames, H, W) uint16 DN}, {ms: photons}. The photon flux
    fills the well of the most sensitive channel at ``saturate_ms``. ``hot_pixels`` pixels (:func:`hot_pixel_mask`)
    have ``hot_factor`` x the dark current."""
    rng, prnu, dsnu = sensor_maps(truth, shape, seed)
    if exposures_ms is None:
        exposures_ms = np.round(np.linspace(1.0, 120.0, 15), 3)
    qe = qe_map(truth, shape, cfa)
    flux = truth["full_well_e"] / (max(truth["qe"].values()) * saturate_ms * 1e-3)  # photons / pixel / s
    dc = np.full(shape, float(truth["dark_current_e_per_s"]))
    dc[hot_pixel_mask(shape, hot_pixels, seed)] *= hot_factor
    dark, flat, photons = {}, {}, {}
    for ms in exposures_ms:
        t = ms * 1e-3
        dark[float(ms)] = np.stack([expose(truth, dc * t, dsnu, rng, quantise) for _ in range(frames)])
        mean = qe * flux * t * prnu + dc * t
        flat[float(ms)] = np.stack([expose(truth, mean, dsnu, rng, quantise) for _ in range(frames)])
        photons[float(ms)] = flux * t
    return dark, flat, photons


def write_capture(root, dark, flat, *, bits: int, pixel_size_m: float = 3.45e-6, cfa=None, photons=None,
                  suffix=".png", black_level_dn=None) -> Path:
    """Write the DIR layout of ``isettorch calibrate``: capture.yaml and dark_<ms>ms / flat_<ms>ms frame folders."""
    import yaml

    from isettorch.io.frames import write_frame

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    cfg = {"bit_depth": bits, "pixel_size_m": pixel_size_m}
    if cfa:
        cfg["cfa"] = cfa
    if black_level_dn is not None:
        cfg["black_level_dn"] = black_level_dn
    if photons is not None:
        cfg["photons_per_pixel"] = {float(k): float(v) for k, v in photons.items()}
    (root / "capture.yaml").write_text(yaml.safe_dump(cfg))
    for kind, stacks in (("dark", dark), ("flat", flat)):
        for ms, stack in stacks.items():
            d = root / f"{kind}_{ms:g}ms"
            d.mkdir(exist_ok=True)
            for i, f in enumerate(stack):
                write_frame(d / f"frame_{i:03d}{suffix}", f)
    return root


def relative_errors(result: dict, truth: dict, channel_qe: dict | None = None) -> dict[str, float]:
    """Relative errors (black level: absolute DN) of a mono calibration, or of a colour one's ``sensor`` values and
    per-channel QE."""
    s = result["sensor"] if result.get("cfa") else result
    err = {
        "gain": s["conversion_gain_dn_per_e"] / truth["gain_dn_per_e"] - 1,
        "read": s["read_noise_e"] / truth["read_noise_e"] - 1,
        "dark": s["dark_current_e_per_s"] / truth["dark_current_e_per_s"] - 1,
        "dsnu": s["dsnu_e"] / truth["dsnu_e"] - 1,
        "prnu": s["prnu_percent"] / truth["prnu_percent"] - 1,
        "row": s["row_noise_e"] / truth["row_noise_e"] - 1,
        "full_well": s["full_well_e"] / truth["full_well_e"] - 1,
        "black_dn": s["black_level_dn"] - truth["black_level_dn"],
    }
    qe = result["quantum_efficiency"]
    if isinstance(qe, dict):
        for n, v in qe.items():
            err[f"qe_{n}"] = v / truth["qe"][n] - 1
    elif qe is not None:
        err["qe"] = qe / truth["qe"]["W"] - 1
    return err


BOUNDS = {"gain": 0.02, "read": 0.03, "dark": 0.05, "dsnu": 0.10, "prnu": 0.10, "row": 0.15, "full_well": 0.05,
          "black_dn": 0.5, "qe": 0.03}


def bound(name: str) -> float:
    return BOUNDS["qe"] if name.startswith("qe") else BOUNDS[name]
