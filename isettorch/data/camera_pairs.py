"""Camera training pairs: random scene -> diffraction-limited optics -> noisy sensor, with aligned targets.

Built on :class:`isettorch.optics.DiffractionLimitedOptics` and :class:`isettorch.sensor.Sensor` directly
(a local adapter until ``isettorch.Camera`` is available). For each index:

1. a random camera: f-number and pixel pitch from discrete lists (so OTFs are cached), full well, read
   noise, dark current, DSNU, PRNU, analog gain (log-uniform), exposure (auto-exposure x 2^EV), CFA phase,
   optionally shifted QE curves. Spectral QE: the Nikon D5100 camera sensitivities measured by NPL (Darrodi
   et al., "Reference data set for camera spectral sensitivity estimation", JOSA A 32(3), 2015; shipped by
   colour-science), scaled to a random peak QE.
2. a random scene (:func:`generate_scene`) rendered ``margin_px`` samples beyond the sensor on each side,
   with its FOV chosen so that one scene sample maps to one pixel (no resampling); the optics blur only
   the sensor's window plus that margin (``crop``) with OTFs cached per (f-number, pitch, grid).
3. the sensor (area sampling, Poisson shot noise, dark current, read noise, DSNU/PRNU drawn per item).

Outputs (a dict of tensors; images in **normalised raw units**: 0 = black level, 1 = white level):

* ``raw`` ``[1, H, W]``: noisy, quantised mosaic ``(DN - black) / (white - black)``.
* ``noise_free_raw`` ``[1, H, W]``: the sensor's ``noise_free`` output in the same units (not quantised).
* ``camera_rgb`` ``[3, H, W]``: every channel at every pixel (R, G, B), the same chain without the CFA
  (clipped at white like the raw): what a demosaic network should recover. Mosaicking it gives
  ``noise_free_raw``.
* ``xyz`` ``[3, H, W]``: CIE 1931 XYZ of the optical image at sensor resolution, scaled by the exposure so that
  a perfect white under the main light has ``Y`` equal to its ``camera_rgb`` green value (not clipped).
* ``linear_srgb`` ``[3, H, W]``: ``xyz`` adapted from the main light's white to D65 (Bradford CAT) and
  converted with the IEC 61966-2-1 matrix (not clipped); ``srgb``: clipped to [0, 1] and encoded.
* ``meta``: a dict of tensors (see :data:`META_KEYS`), batched by :func:`collate_pairs`.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np
import torch

from .. import constants, spectral
from ..image import XYZ_TO_LINEAR_SRGB, srgb_encode
from .config import CAMERA_DEFAULTS, SCENE_DEFAULTS, merge_config, one_thread, seed_for
from .scenes import _uniform, generate_scene

__all__ = ["CameraPairDataset", "collate_pairs", "render_pair", "META_KEYS", "nikon_d5100_qe"]

CHANNELS = ("R", "G", "B")
ILLUMINANT_CODES = {"daylight": 0, "blackbody": 1, "led": 2}  # F<n> -> 10 + n
META_KEYS = ("index", "exposure_s", "analog_gain", "iso", "f_number", "focal_length_m", "pixel_size_m",
             "full_well_e", "read_noise_e", "dark_current_e_per_s", "dsnu_sigma_e", "prnu_sigma_percent",
             "black_level_dn", "white_level_dn", "noise_gain", "noise_floor_var", "cfa", "cct_k", "illuminant_code",
             "white_camera_rgb", "white_xyz", "qe", "wavelengths_nm", "hdr_decades", "mean_luminance_cd_m2")

# Bradford cone response matrix (Lam 1985; as in colour-science CHROMATIC_ADAPTATION_TRANSFORMS['Bradford']).
_BRADFORD = ((0.8951, 0.2664, -0.1614), (-0.7502, 1.7135, 0.0367), (0.0389, -0.0685, 1.0296))
_D65_XYZ = (0.95047, 1.0, 1.08883)  # IEC 61966-2-1 white, Y = 1


@functools.cache
def _nikon_native() -> tuple[np.ndarray, np.ndarray]:
    import colour

    m = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    vals = np.asarray(m.values, float).T  # [3, Ln] R, G, B
    return np.asarray(m.wavelengths, float), vals / vals.max()


def nikon_d5100_qe(wavelengths_nm, peak_qe: float = 0.5, shift_nm=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Spectral QE ``[3, L]`` (R, G, B) of the Nikon D5100 (NPL data), peak ``peak_qe``, each channel shifted."""
    w_src, vals = _nikon_native()
    w = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
    rows = [spectral.resample(torch.from_numpy(vals[c]), torch.from_numpy(w_src) + float(shift_nm[c]), w)
            for c in range(3)]
    return torch.stack(rows) * peak_qe


@functools.lru_cache(maxsize=16)
def _xyz_weights(grid: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    """``(W [3, L], dl [L])`` in float64 with ``XYZ = W @ photons``: 683 cmf(l) h c / l dl (CIE 015:2018)."""
    w = torch.tensor(grid, dtype=torch.float64)
    dl = spectral.wavelength_weights(w)
    to_watts = (constants.PLANCK_J_S * constants.SPEED_OF_LIGHT_M_PER_S) / (w * 1e-9)
    return constants.KM_LM_PER_W * spectral.cmfs(w, dtype=torch.float64) * to_watts * dl, dl


def _bradford(src_xyz: torch.Tensor, dst_xyz: torch.Tensor) -> torch.Tensor:
    """von Kries adaptation in Bradford cone space: ``M^-1 diag(M dst / M src) M`` (CIE 160:2004)."""
    m = torch.tensor(_BRADFORD, dtype=torch.float64)
    s, d = m @ src_xyz.to(torch.float64), m @ dst_xyz.to(torch.float64)
    return torch.linalg.inv(m) @ torch.diag(d / s) @ m


def _matmul_fixed_order(a: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``a [K, C] @ x [C, N]`` summed in a fixed order, so results are bitwise identical whatever the number
    of threads (a multi-threaded GEMM may split the sum differently in the main process and in DataLoader
    workers, which would break bitwise reproducibility by (seed, index))."""
    out = a[:, :1] * x[:1]
    for c in range(1, a.shape[1]):
        out = out.addcmul_(a[:, c:c + 1], x[c:c + 1])
    return out


def _pick(values, g: torch.Generator):
    if isinstance(values, (int, float)):
        return float(values)
    return values[int(torch.randint(len(values), (), generator=g))]


class _Clock:
    """Adds the CPU time (``time.process_time``: robust to other processes sharing the cores) since the previous
    call to ``timings[stage]`` (no-op without a dict)."""

    def __init__(self, timings: dict | None):
        self.timings = timings
        self.last = time.process_time()

    def __call__(self, stage: str) -> None:
        if self.timings is not None:
            now = time.process_time()
            self.timings[stage] = self.timings.get(stage, 0.0) + now - self.last
            self.last = now


class _Cache:
    """Per-process caches of optics modules (one per f-number and focal length, each with its OTF cache)."""

    def __init__(self):
        self.optics = {}

    def get_optics(self, f_number: float, focal_length_m: float, margin: int):
        from ..optics import DiffractionLimitedOptics

        key = (f_number, focal_length_m, margin)
        if key not in self.optics:
            self.optics[key] = DiffractionLimitedOptics(f_number=f_number, focal_length_m=focal_length_m,
                                                        margin=margin, pad_mode="zero")
        return self.optics[key]


def render_pair(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype=torch.float32,
                cache: _Cache | None = None, timings: dict | None = None) -> dict:
    """One camera training pair for ``(seed, index)`` (see the module notes for the outputs).

    ``timings``: optional dict accumulating the CPU seconds spent per stage (scene, optics, sensor, targets,
    setup), for benchmarks. Runs single-threaded (see :func:`config.one_thread`).
    """
    with one_thread():
        return _render_pair(index, seed, scene_cfg, camera_cfg, dtype=dtype, cache=cache, timings=timings)


def _render_pair(index: int, seed: int, scene_cfg: dict, camera_cfg: dict, *, dtype, cache, timings) -> dict:
    clock = _Clock(timings)
    from ..optics.blur import full_padding
    from ..optics.geometry import image_distance
    from ..sensor import CFA, Sensor, SpectralQE
    from ..sensor.sampling import sample_area

    cache = cache or _Cache()
    cam = camera_cfg
    g = torch.Generator().manual_seed(seed_for(seed, index, stream=1))
    h, w = int(scene_cfg["height"]), int(scene_cfg["width"])
    m = int(cam["margin_px"])
    f_number = float(_pick(cam["f_number"], g))
    pitch = float(_pick(cam["pixel_size_m"], g))
    focal = float(_pick(cam["focal_length_m"], g))
    fill = float(cam["fill_factor"])
    full_well = _uniform(cam["full_well_e"], g, log=True)
    read_e = _uniform(cam["read_noise_e"], g)
    dark = _uniform(cam["dark_current_e_per_s"], g, log=True)
    dsnu_e = _uniform(cam["dsnu_sigma_e"], g)
    prnu = _uniform(cam["prnu_sigma_percent"], g)
    gain = _uniform(cam["analog_gain"], g, log=True)
    ev = _uniform(cam["exposure_ev"], g)
    peak = _uniform(cam["peak_qe"], g)
    pattern = str(_pick(cam["cfa_patterns"], g))
    var = float(cam["qe_variation"])
    shifts = ((torch.rand(3, generator=g, dtype=torch.float64) * 2 - 1) * 10.0 * var).tolist()
    bits, black = int(cam["bits"]), float(cam["black_level_dn"])
    noise_seed = seed_for(seed, index, stream=2)

    # Scene FOV so that one scene sample lands on one pixel: pitch = 2 d_i tan(hfov / 2) / W_s.
    distance = _uniform(scene_cfg["distance_m"], torch.Generator().manual_seed(seed_for(seed, index)))
    d_i = float(image_distance(torch.tensor(focal, dtype=torch.float64), torch.tensor(distance,
                                                                                       dtype=torch.float64)))
    ws = w + 2 * m
    hfov = math.degrees(2 * math.atan(pitch * ws / (2 * d_i)))
    clock("setup")
    scene = generate_scene(index, seed, scene_cfg, dtype=dtype, hfov_deg=hfov, size=(h + 2 * m, ws))
    clock("scene")
    optics = cache.get_optics(f_number, focal, m)
    pr, pc = full_padding(h + 2 * m, m), full_padding(ws, m)
    with torch.no_grad():
        oi = optics(scene, crop=(pr + m, pc + m, h, w))
    wave = scene.wavelengths_nm
    clock("optics")

    cfa = CFA(pattern)
    qe_native = nikon_d5100_qe(_nikon_native()[0], peak, shifts)
    qe_module = SpectralQE(qe_native, _nikon_native()[0], cfa.channel_names)
    cg = 1.0 / full_well  # volts per electron with a 1 V swing: well capacity = full_well
    sensor = Sensor(rows=h, cols=w, pixel_size_m=pitch, fill_factor=fill, cfa=cfa, spectral_qe=qe_module,
                    conversion_gain_v_per_e=cg, voltage_swing_v=1.0, analog_gain=gain, adc_bits=bits,
                    black_level_dn=black, shot_noise="poisson", read_noise_v=read_e * cg,
                    dark_current_e_per_s=dark, dsnu_sigma_v=dsnu_e * cg, prnu_sigma_percent=prnu,
                    fpn_mode="per_frame", seed=noise_seed)
    qe = sensor.qe(oi)  # [3, L]
    clock("setup")
    # One pass over the spectral cube: per-channel electron-rate density (e-/s/m^2, as the sensor's
    # electron_rate_density) and absolute XYZ (683 sum E cmf dl, CIE 015:2018) at every OI sample.
    xyz_w, dl = _xyz_weights(tuple(wave.tolist()))
    weights = torch.cat([qe.to(dtype) * dl.to(dtype), xyz_w.to(dtype)])
    dens6 = _matmul_fixed_order(weights, oi.photons.reshape(oi.num_wavelengths, -1)).reshape(1, 6, h, w)
    if abs(float(oi.sample_spacing_m[0]) / pitch - 1) < 1e-4:
        # One OI sample per pixel and the photodiode (side pitch sqrt(fill)) inside it: area sampling of a
        # piecewise-constant irradiance returns the sample itself.
        sampled6 = dens6
    else:  # pragma: no cover - the dataset always matches the grids
        sampled6 = sample_area(dens6, oi.sample_spacing_m, pitch, h, w, fill)
    rate_rgb = sampled6[:, :3] * (fill * pitch * pitch)  # e-/s per pixel and channel
    xyz_img = sampled6[:, 3:]
    # Auto-exposure: the 98th percentile of the brightest channel at 80 % of full scale (after gain), x 2^EV.
    peak = rate_rgb.amax(dim=1).flatten()
    p98 = peak.kthvalue(max(1, math.ceil(0.98 * peak.numel()))).values.double().clamp_min(1e-30)
    exposure = float(0.8 * full_well / gain / p98) * 2.0**ev
    lsb = 1.0 / 2**bits
    white = float(2**bits - 1)
    span = white - black
    ng = torch.Generator().manual_seed(noise_seed)
    clock("targets")
    with torch.no_grad():
        raw = sensor(oi, exposure_s=exposure, analog_gain=gain, noise=True, generator=ng)
    clock("sensor")
    # electrons -> normalised units: e * cg * gain / lsb / span (Sensor: volts = e cg, x gain, / lsb, + black)
    to_norm = cg * gain / lsb / span
    cam_rgb = (rate_rgb * exposure * cg * gain).clamp(max=1.0) / lsb
    cam_rgb = cam_rgb.clamp(max=span) / span

    # XYZ at sensor resolution, exposure-matched: white under light 1 has Y = its green camera value.
    white_p = scene.illuminant_photons[0].to(torch.float64)
    white_xyz = (xyz_w * white_p).sum(dim=1)
    white_cam = (qe.to(torch.float64) * dl * white_p).sum(dim=1)
    k_white = white_cam[1] / white_xyz[1]  # e-/s/m^2 per (cd/m^2-equivalent) on both sides of the optics
    scale = float(k_white) * fill * pitch * pitch * exposure * to_norm
    xyz = xyz_img * scale
    cat = _bradford(white_xyz / white_xyz[1], torch.tensor(_D65_XYZ, dtype=torch.float64))
    m_srgb = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ cat
    lin = _matmul_fixed_order(m_srgb.to(dtype), xyz.reshape(3, -1)).reshape(1, 3, h, w)
    srgb = srgb_encode(lin.clamp(0, 1))

    meta_s = scene.metadata
    name = meta_s["illuminant"]
    code = ILLUMINANT_CODES.get(name, 10 + int(name[1:]) if name.startswith("F") else -1)
    quant_var = 1.0 / 12.0 / span**2
    meta = {
        "index": torch.tensor(index, dtype=torch.long),
        "exposure_s": exposure, "analog_gain": gain, "iso": 100.0 * gain, "f_number": f_number,
        "focal_length_m": focal, "pixel_size_m": pitch, "full_well_e": full_well, "read_noise_e": read_e,
        "dark_current_e_per_s": dark, "dsnu_sigma_e": dsnu_e, "prnu_sigma_percent": prnu,
        "black_level_dn": black, "white_level_dn": white,
        # Poisson-Gaussian noise model in normalised units: var(x) = noise_gain * x + noise_floor_var
        # (Foi et al., "Practical Poissonian-Gaussian noise modeling", IEEE TIP 17(10), 2008).
        "noise_gain": to_norm,
        "noise_floor_var": (read_e**2 + dsnu_e**2 + dark * exposure) * to_norm**2 + quant_var,
        "cfa": cfa.index_map.clone(),
        "cct_k": meta_s["cct_k"], "illuminant_code": torch.tensor(code, dtype=torch.long),
        "white_camera_rgb": (white_cam / white_cam[1]).to(dtype),
        "white_xyz": (white_xyz / white_xyz[1]).to(dtype),
        "qe": qe.to(dtype), "wavelengths_nm": wave.to(dtype),
        "hdr_decades": meta_s["hdr_decades"], "mean_luminance_cd_m2": meta_s["mean_luminance_cd_m2"],
    }
    meta = {k: (v if isinstance(v, torch.Tensor) else torch.tensor(v, dtype=dtype)) for k, v in meta.items()}
    clock("targets")
    return {
        "raw": ((raw.data[0] - black) / span).to(dtype),
        "noise_free_raw": ((raw.noise_free[0] - black) / span).to(dtype),
        "camera_rgb": cam_rgb[0].to(dtype),
        "xyz": xyz[0].to(dtype),
        "linear_srgb": lin[0].to(dtype),
        "srgb": srgb[0].to(dtype),
        "meta": meta,
    }


class CameraPairDataset(torch.utils.data.Dataset):
    """Map-style dataset of camera training pairs; item ``i`` depends only on ``(seed, i)``.

    Args:
        length: number of items.
        seed: dataset seed.
        scene: scene config (keys of ``SCENE_DEFAULTS``), camera: camera config (keys of ``CAMERA_DEFAULTS``).
        dtype: float32 (default) or float64.

    Example:
        >>> ds = CameraPairDataset(8, seed=0, scene={"height": 32, "width": 32})
        >>> batch = collate_pairs([ds[0], ds[1]])
        >>> batch["raw"].shape, batch["meta"]["exposure_s"].shape
        (torch.Size([2, 1, 32, 32]), torch.Size([2]))
    """

    def __init__(self, length: int, seed: int = 0, scene: dict | None = None, camera: dict | None = None, *,
                 dtype=torch.float32):
        if int(length) < 0:
            raise ValueError(f"length: expected a non-negative number of items, got {length}")
        self.length, self.seed, self.dtype = int(length), int(seed), dtype
        self.scene_config = merge_config(scene, SCENE_DEFAULTS, "scene")
        self.camera_config = merge_config(camera, CAMERA_DEFAULTS, "camera")
        if self.scene_config["height"] % 2 or self.scene_config["width"] % 2:
            raise ValueError(f"scene.height/width: expected even sizes (whole Bayer cells), got "
                             f"{self.scene_config['height']}x{self.scene_config['width']}")
        self._cache = _Cache()

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> dict:
        if not -self.length <= index < self.length:
            raise IndexError(f"index: expected 0 <= index < {self.length}, got {index}")
        return render_pair(index % self.length, self.seed, self.scene_config, self.camera_config, dtype=self.dtype,
                           cache=self._cache)


def collate_pairs(items: list[dict]) -> dict:
    """Stack items into batched tensors: images ``[B, C, H, W]``, every metadata field ``[B, ...]``."""
    if not items:
        raise ValueError("items: expected at least one item")
    out = {}
    for key, value in items[0].items():
        if isinstance(value, dict):
            out[key] = {k: torch.stack([it[key][k] for it in items]) for k in value}
        else:
            out[key] = torch.stack([it[key] for it in items])
    return out
