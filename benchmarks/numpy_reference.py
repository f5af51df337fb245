"""A straightforward NumPy implementation of the same physics as isettorch's default optics + sensor path, used
as the reference peer in ``isettorch bench`` (speed and agreement, same inputs, float64, single thread).

scene radiance L [L, H, W] (photons/s/sr/m^2/nm)
  -> camera equation  E = pi L / (1 + 4 N^2 (1 + |m|)^2)                 (ISETCam oiCalculateIrradiance)
  -> cos^4 relative illumination at the image distance                    (cos4th law)
  -> zero padding, diffraction-limited OTF (2/pi)(acos s - s sqrt(1-s^2)), s = rho lambda N d_i/f (Goodman 6.31, 6.3.2)
  -> QE integration  sum_lambda E QE_c dlambda (rectangle rule with ISETCam's bin widths)    (SignalCurrentDensity)
  -> area sampling over the photodiode (centred square of side pitch sqrt(ff)) or bilinear point sampling
  -> Bayer mosaic, x fill factor x pixel area x exposure x conversion gain, clipped to the swing  (sensorCompute)

Only numpy; no torch. Every array is float64. Usable on its own:

    volts = numpy_reference.simulate(photons, wavelengths_nm, hfov_deg=..., ...)
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["image_distance", "irradiance", "dl_mtf", "blur", "integrate_qe", "sample_area", "sample_point",
           "mosaic", "simulate"]


def image_distance(focal_length_m: float, distance_m: float) -> float:
    """Thin lens: 1/f = 1/s + 1/s'."""
    return 1.0 / (1.0 / focal_length_m - 1.0 / distance_m)


def irradiance(photons: np.ndarray, hfov_deg: float, distance_m: float, f_number: float, focal_length_m: float):
    """Camera equation and cos^4 falloff; returns (irradiance [L, H, W], sample spacing (m), image distance (m))."""
    _, h, w = photons.shape
    d_i = image_distance(focal_length_m, distance_m)
    m = d_i / distance_m
    dx = 2 * d_i * math.tan(math.radians(hfov_deg) / 2) / w
    k = math.pi / (1 + 4 * f_number**2 * (1 + m) ** 2)  # ISETCam camera equation
    y = (np.arange(h) - (h - 1) / 2) * dx
    x = (np.arange(w) - (w - 1) / 2) * dx
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    cos4 = (d_i**2 / (d_i**2 + r2)) ** 2  # cos^4 of the field angle at the image distance
    return photons * (k * cos4)[None], dx, d_i


def dl_mtf(s: np.ndarray) -> np.ndarray:
    """Diffraction-limited MTF of a circular pupil at normalised frequency s = f lambda N (Goodman 6.31)."""
    ss = np.minimum(s, 1.0)
    return np.where(s < 1, (2 / math.pi) * (np.arccos(ss) - ss * np.sqrt(1 - ss * ss)), 0.0)


def blur(irr: np.ndarray, wavelengths_nm: np.ndarray, dx: float, f_number: float, pad: tuple[int, int]
         ) -> np.ndarray:
    """Zero-pad by ``pad`` (rows, cols) per side and apply the OTF with real FFTs (a linear convolution as long
    as the PSF fits in the padding). Returns the padded optical image [L, H + 2 pr, W + 2 pc]."""
    pr, pc = pad
    buf = np.pad(irr, ((0, 0), (pr, pr), (pc, pc)))
    my, mx = buf.shape[-2:]
    fy = np.fft.fftfreq(my) / dx
    fx = np.fft.rfftfreq(mx) / dx
    rho = np.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)
    out = np.empty_like(buf)
    for i, lam in enumerate(wavelengths_nm):  # one plane at a time: what a simple implementation does
        otf = dl_mtf(rho * lam * 1e-9 * f_number)
        out[i] = np.fft.irfft2(np.fft.rfft2(buf[i]) * otf, s=(my, mx))
    return out


def bin_widths(wavelengths_nm: np.ndarray) -> np.ndarray:
    """ISETCam's rectangle rule: interior samples get the mean of the neighbouring gaps, ends the end gap."""
    w = np.asarray(wavelengths_nm, dtype=np.float64)
    if w.size == 1:
        return np.ones(1)
    d = np.diff(w)
    out = np.empty_like(w)
    out[0], out[-1] = d[0], d[-1]
    out[1:-1] = 0.5 * (d[1:] + d[:-1])
    return out


def integrate_qe(oi: np.ndarray, qe: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Electron-rate density per channel [C, H, W] (e-/s/m^2): sum_lambda E QE_c dlambda."""
    wts = qe * bin_widths(wavelengths_nm)[None]
    return np.tensordot(wts, oi, axes=([1], [0]))


def _centres(n_oi: int, n_pix: int, pitch: float, dx: float) -> np.ndarray:
    return (n_oi - 1) / 2 + (np.arange(n_pix) - (n_pix - 1) / 2) * pitch / dx


def _box_mean(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Mean over [lo, hi] (sample units) of the piecewise-constant x along the last axis, zero outside."""
    n = x.shape[-1]
    s = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1)], axis=-1)

    def integral(edge):
        e = np.clip(edge + 0.5, 0, n)
        i = np.minimum(np.floor(e), n - 1).astype(np.int64)
        return s[..., i] + (e - i) * x[..., i]

    return (integral(hi) - integral(lo)) / (hi - lo)


def sample_area(dens: np.ndarray, dx: float, pitch: float, rows: int, cols: int, fill_factor: float) -> np.ndarray:
    """Mean of each channel over each photodiode (exact for piecewise-constant irradiance), [C, rows, cols]."""
    half = pitch * math.sqrt(fill_factor) / 2 / dx
    px = _centres(dens.shape[-1], cols, pitch, dx)
    py = _centres(dens.shape[-2], rows, pitch, dx)
    out = _box_mean(dens, px - half, px + half)
    return np.swapaxes(_box_mean(np.swapaxes(out, -1, -2), py - half, py + half), -1, -2)


def sample_point(dens: np.ndarray, dx: float, pitch: float, rows: int, cols: int) -> np.ndarray:
    """Bilinear samples at the pixel centres (zero outside), [C, rows, cols] (no ISETCam pre-blur)."""
    py = _centres(dens.shape[-2], rows, pitch, dx)
    px = _centres(dens.shape[-1], cols, pitch, dx)

    def lerp(a, pos):
        n = a.shape[-1]
        i0 = np.clip(np.floor(pos), 0, n - 2).astype(np.int64)
        t = pos - i0
        valid = (pos >= 0) & (pos <= n - 1)
        return (a[..., i0] * (1 - t) + a[..., i0 + 1] * t) * valid

    out = lerp(dens, px)
    return np.swapaxes(lerp(np.swapaxes(out, -1, -2), py), -1, -2)


def mosaic(channels: np.ndarray, cfa_index: np.ndarray) -> np.ndarray:
    """Keep each pixel's channel: [C, rows, cols] -> [rows, cols]; ``cfa_index`` is the unit cell of channel
    indices (e.g. GRBG with channels R, G, B: [[1, 0], [2, 1]])."""
    rows, cols = channels.shape[-2:]
    ph, pw = cfa_index.shape
    idx = np.tile(cfa_index, (rows // ph + 1, cols // pw + 1))[:rows, :cols]
    return np.take_along_axis(channels, idx[None], axis=0)[0]


def simulate(photons: np.ndarray, wavelengths_nm: np.ndarray, *, hfov_deg: float, distance_m: float,
             f_number: float, focal_length_m: float, pad: tuple[int, int], qe: np.ndarray, cfa_index: np.ndarray,
             rows: int, cols: int, pixel_size_m: float, fill_factor: float, exposure_s: float,
             conversion_gain_v_per_e: float, voltage_swing_v: float, sampling: str = "area") -> np.ndarray:
    """Noise-free sensor volts [rows, cols] of a scene [L, H, W]; see the module docstring."""
    photons = np.asarray(photons, dtype=np.float64)
    wave = np.asarray(wavelengths_nm, dtype=np.float64)
    irr, dx, d_i = irradiance(photons, hfov_deg, distance_m, f_number, focal_length_m)
    # diffraction at the working f-number N d_i / f: the converging wave's radius is d_i (Goodman, Introduction to
    # Fourier Optics, 3rd ed., 6.3.2)
    oi = blur(irr, wave, dx, f_number * d_i / focal_length_m, pad)
    dens = integrate_qe(oi, np.asarray(qe, dtype=np.float64), wave)
    if sampling == "area":
        sampled = sample_area(dens, dx, pixel_size_m, rows, cols, fill_factor)
    elif sampling == "point":
        sampled = sample_point(dens, dx, pixel_size_m, rows, cols)
    else:
        raise ValueError(f"sampling: expected 'area' or 'point', got {sampling!r}")
    rate = mosaic(sampled, np.asarray(cfa_index)) * (fill_factor * pixel_size_m**2)
    return np.clip(rate * exposure_s * conversion_gain_v_per_e, 0.0, voltage_swing_v)
