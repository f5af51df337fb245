"""An independent NumPy implementation of ISETCam's oiCompute for a diffraction-limited lens (isetcam-parity
FORMAT.md 4.2-4.4) and of its mean illuminance (4.1), for parity cases not in the shared files; imported by the
tests as ``isetcam_numpy`` (pytest puts ``tests/`` on the path for its conftest). Checked against
``isettorch.optics.isetcam.compute_oi`` in tests/optics/test_isetcam_parity.py."""

import math

import numpy as np

# ISETCam's constants (vcConstants): Planck's constant and the speed of light
ISETCAM_H_J_S = 6.626176e-34
ISETCAM_C_M_PER_S = 2.99792458e8


def mean_illuminance(photons, wave, vlambda):
    """Mean (il)luminance of a photon cube ``[L, H, W]`` (photons/s/m^2/nm or /sr): 683 lm/W x bin width x the
    mean over pixels of sum_l E_l V_l, with E the energy of the photons (ieLuminanceFromPhotons; FORMAT.md 4.1)."""
    energy = np.asarray(photons, np.float64) * ISETCAM_H_J_S * ISETCAM_C_M_PER_S / (np.asarray(wave)[:, None, None]
                                                                                   * 1e-9)
    return 683 * (wave[1] - wave[0]) * np.einsum("lhw,l->hw", energy, np.asarray(vlambda, np.float64)).mean()


def _ufl(n):
    k = np.arange(1, n + 1, dtype=float)
    mid = n / 2 + 1 if n % 2 == 0 else (n + 1) / 2
    return (k - mid) / np.max(np.abs(k - mid))


def numpy_oi(radiance, wave, hfov, dist, fnum, f, trans, details=None):
    """oiCompute of a radiance cube ``[L, H, W]`` (photons/s/sr/m^2/nm) through a diffraction-limited lens: the
    irradiance ``[L, H2, W2]`` on the padded grid, the pads ``(rows, cols)``, the sample spacing (m) and the padded
    horizontal field of view (deg). A dict passed as ``details`` receives the off-axis factor ``cos4th`` [H, W] and
    the OTF at 550 nm ``otf_550`` [H2, W2] (DC at [0, 0]), the case's optional keys."""
    nl, h, w = radiance.shape
    dimg = 1 / (1 / f - 1 / dist)
    m = dimg / dist
    irr = math.pi / (1 + 4 * fnum**2 * (1 + m) ** 2) * radiance * trans[:, None, None]
    dx = 2 * f * math.tan(math.radians(hfov / 2)) / w
    ys = np.linspace(-h * dx / 2 + dx / 2, h * dx / 2 - dx / 2, h)
    xs = np.linspace(-w * dx / 2 + dx / 2, w * dx / 2 - dx / 2, w)
    x, y = np.meshgrid(xs, ys)
    s = np.sqrt(f**2 + x**2 + y**2)
    if f > 10 * math.hypot(h * dx, w * dx):
        fall = (f / s) ** 4
    else:
        cphi = f / s
        sphi = np.sqrt(1 - cphi**2)
        tphi = sphi / cphi
        st = 1 / (1 + 4 * (fnum * (1 - 0)) ** 2)
        ct = math.sqrt(1 - st**2)
        tt = st / ct
        fall = (math.pi / 2) * (1 - (1 - tt**2 + tphi**2) / np.sqrt(tphi**4 + 2 * tphi**2 * (1 - tt**2) + 1 / ct**4))
        fall = fall / (math.pi * st**2)
    irr = irr * fall
    pr, pc = int(math.floor(h / 8 + 0.5)), int(math.floor(w / 8 + 0.5))
    h2, w2 = h + 2 * pr, w + 2 * pc
    pad = np.full((nl, h2, w2), irr.max() * 1e-9)
    pad[:, pr:pr + h, pc:pc + w] = irr
    hfov2 = 2 * math.degrees(math.atan(w2 / w * math.tan(math.radians(hfov / 2))))
    vfov2 = 2 * math.degrees(math.atan(0.5 * h2 * dx / f))
    fx = _ufl(w2) * (w2 / 2) / hfov2
    fy = _ufl(h2) * (h2 / 2) / vfov2
    width = 2 * f * math.tan(math.radians(hfov2 / 2))

    def otf_at(lam):
        fc = (1 / fnum) / (lam * 1e-9) * width / hfov2
        rho = np.sqrt(fx[None, :] ** 2 + fy[:, None] ** 2) / fc
        r = np.minimum(rho, 1)
        return np.fft.ifftshift(np.where(rho < 1, 2 / np.pi * (np.arccos(r) - r * np.sqrt(1 - r**2)), 0.0))

    out = np.empty_like(pad)
    for i, lam in enumerate(wave):
        out[i] = np.abs(np.fft.ifft2(otf_at(lam) * np.fft.fft2(pad[i])))
    if details is not None:
        details.update(cos4th=fall, otf_550=otf_at(550.0))
    spacing = 2 * dimg * math.tan(math.radians(hfov2 / 2)) / w2
    return out, (pr, pc), spacing, hfov2
