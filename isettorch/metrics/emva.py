"""EMVA 1288 release 4.0 (Linear) sensor characterisation from image stacks.

Follows EMVA Standard 1288 "Standard for Characterization of Image Sensors and Cameras", release 4.0 Linear
(2021), sections 4-8, with the choices of the EMVA's reference implementation (github.com/EMVA1288/emva1288,
``Results1288``) where the standard leaves room: saturation at the maximum temporal variance, regressions
through the origin over [0, 70 %] of saturation, sigma_y.dark floored at sqrt(0.24) DN.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from .._checks import as_tensor, check_finite, is_integer
from .snr import pixel_snr

S2_QUANTIZATION_DN2 = 1.0 / 12.0  # EMVA 1288 4.0 eq. 5: uniform quantisation noise variance, DN^2
S2_DARK_FLOOR_DN2 = 0.24  # EMVA 1288 4.0 section 6.4: below this sigma_y.dark is quantisation-limited


@dataclasses.dataclass
class EMVA1288Result:
    """EMVA 1288 characterisation. Scalars are 0-d float64 tensors; curves are [M] (one entry per exposure level).

    Units: DN (digital numbers), e (electrons), p (photons).
    """

    system_gain_dn_per_e: torch.Tensor  # K, slope of the photon transfer curve
    quantum_efficiency: torch.Tensor | None  # eta in [0, 1] (None without photons_per_pixel)
    responsivity_dn_per_p: torch.Tensor | None  # R = K eta
    dark_noise_dn: torch.Tensor  # sigma_y.dark (temporal, incl. quantisation; floored at sqrt(0.24))
    dark_noise_e: torch.Tensor  # sigma_d = sqrt(sigma_y.dark^2 - 1/12) / K
    saturation_capacity_e: torch.Tensor  # mu_e.sat
    saturation_capacity_p: torch.Tensor | None  # mu_p.sat
    sensitivity_threshold_e: torch.Tensor  # mu_e.min = sigma_y.dark / K + 1/2
    dynamic_range: torch.Tensor  # mu_e.sat / mu_e.min (= mu_p.sat / mu_p.min)
    dynamic_range_db: torch.Tensor  # 20 log10(DR)
    snr_max_db: torch.Tensor  # 20 log10(sqrt(mu_e.sat))
    dsnu1288_e: torch.Tensor  # sqrt(s^2_y.dark) / K
    dsnu1288_dn: torch.Tensor
    prnu1288_percent: torch.Tensor  # 100 sqrt(s^2_y - s^2_y.dark) / (mu_y - mu_y.dark)
    # curves, [M]
    mean_dn: torch.Tensor  # mu_y
    mean_dark_dn: torch.Tensor  # mu_y.dark
    var_dn2: torch.Tensor  # sigma^2_y (temporal)
    var_dark_dn2: torch.Tensor  # sigma^2_y.dark (temporal)
    snr: torch.Tensor  # measured (mu_y - mu_y.dark) / sigma_y
    photons_per_pixel: torch.Tensor | None  # mu_p
    saturation_index: int
    fit_max_index: int  # last level used by the linear fits (<= 70 % of saturation)
    spatial_index: int  # level used for DSNU/PRNU (closest to 50 % of saturation)
    # sigma^2_y.dark below 0.24 DN^2, floored there: the dark noise and the threshold are upper limits, the dynamic
    # range a lower one (EMVA 1288 4.0 section 6.4: "sigma_d < 0.40 / K")
    dark_noise_is_upper_limit: bool = False

    def snr_model(self, photons_per_pixel) -> torch.Tensor:
        """EMVA 1288 4.0 eq. 19: SNR(mu_p) = eta mu_p / sqrt(sigma_d^2 + sigma_q^2 / K^2 + eta mu_p).

        Needs the quantum efficiency; ``photons_per_pixel`` is a tensor of mu_p values."""
        if self.quantum_efficiency is None:
            raise ValueError("photons_per_pixel: the SNR model needs the quantum efficiency; call emva1288 with "
                             "photons_per_pixel")
        mu_p = as_tensor(photons_per_pixel, "photons_per_pixel", dtype=torch.float64)
        # the one pixel-SNR model (metrics.snr): dark noise as read noise; the quantisation step of 1 DN is 1/K
        # electrons, so LSB^2 / 12 = S2_QUANTIZATION_DN2 / K^2
        return pixel_snr(self.quantum_efficiency * mu_p, read_noise_e=self.dark_noise_e,
                         lsb_e=1.0 / self.system_gain_dn_per_e)

    def report(self) -> str:
        """The EMVA 1288 summary table as text."""
        def f(v, fmt=".4g", bound=""):
            return "n/a" if v is None else (bound if self.dark_noise_is_upper_limit else "") + format(float(v), fmt)

        qe = None if self.quantum_efficiency is None else 100 * self.quantum_efficiency
        rows = [
            ("System gain K", f(self.system_gain_dn_per_e), "DN/e-"),
            ("Inverse system gain 1/K", f(1 / self.system_gain_dn_per_e), "e-/DN"),
            ("Quantum efficiency", f(qe), "%"),
            ("Responsivity R", f(self.responsivity_dn_per_p), "DN/p"),
            ("Temporal dark noise", f(self.dark_noise_e, bound="< "), "e-"),
            ("Temporal dark noise", f(self.dark_noise_dn, bound="< "), "DN"),
            ("Absolute sensitivity threshold", f(self.sensitivity_threshold_e, bound="< "), "e-"),
            ("Saturation capacity", f(self.saturation_capacity_e), "e-"),
            ("Saturation capacity", f(self.saturation_capacity_p), "p"),
            ("Maximum SNR", f(self.snr_max_db, ".2f"), "dB"),
            ("Dynamic range", f(self.dynamic_range_db, ".2f", bound="> "), "dB"),
            ("DSNU1288", f(self.dsnu1288_e), "e-"),
            ("DSNU1288", f(self.dsnu1288_dn), "DN"),
            ("PRNU1288", f(self.prnu1288_percent), "%"),
        ]
        lines = ["EMVA 1288 (release 4.0 Linear) summary", "-" * 56]
        lines += [f"{name:<34}{val:>12}  {unit}" for name, val, unit in rows]
        lines.append(f"(saturation at level {self.saturation_index}, fits over levels 0..{self.fit_max_index}, "
                     f"DSNU/PRNU at level {self.spatial_index})")
        if self.dark_noise_is_upper_limit:
            lines.append(f"(dark variance below {S2_DARK_FLOOR_DN2} DN^2, quantisation-limited: the dark noise and the "
                         "threshold are upper limits, the dynamic range a lower one)")
        return "\n".join(lines)

    def plot(self):
        """Photon transfer, responsivity (or mean) and SNR plots in one Figure."""
        import matplotlib.pyplot as plt

        from .. import plot as _plot  # noqa: F401  (selects a headless backend when needed)

        fig, axes = plt.subplots(1, 3, figsize=(14, 4))
        x = (self.mean_dn - self.mean_dark_dn).numpy()
        y = (self.var_dn2 - self.var_dark_dn2).numpy()
        k, fm = float(self.system_gain_dn_per_e), self.fit_max_index
        ax = axes[0]
        ax.plot(x, y, "o", ms=4, label="data")
        ax.plot(x[: fm + 1], k * x[: fm + 1], "-", label=f"fit K = {k:.4g} DN/e-")
        ax.axvline(x[self.saturation_index], color="gray", ls=":", lw=1, label="saturation")
        ax.set_xlabel("mu_y - mu_y.dark (DN)")
        ax.set_ylabel("sigma^2_y - sigma^2_y.dark (DN^2)")
        ax.set_title("Photon transfer")
        ax.legend(fontsize=8)
        ax = axes[1]
        if self.photons_per_pixel is not None:
            mp = self.photons_per_pixel.numpy()
            ax.plot(mp, x, "o", ms=4, label="data")
            ax.plot(mp[: fm + 1], float(self.responsivity_dn_per_p) * mp[: fm + 1], "-",
                    label=f"R = {float(self.responsivity_dn_per_p):.4g} DN/p")
            ax.set_xlabel("mu_p (photons/pixel)")
            ax.set_title("Sensitivity")
            ax.legend(fontsize=8)
        else:
            ax.plot(range(len(x)), x, "o-", ms=4)
            ax.set_xlabel("exposure level")
            ax.set_title("Mean signal")
        ax.set_ylabel("mu_y - mu_y.dark (DN)")
        ax = axes[2]
        good = self.snr > 0
        if self.photons_per_pixel is not None:
            mp = self.photons_per_pixel
            ax.loglog(mp[good].numpy(), self.snr[good].numpy(), "o", ms=4, label="measured")
            grid = torch.logspace(math.log10(max(float(mp[mp > 0].min()), 1.0)), math.log10(float(mp.max())), 100,
                                  dtype=torch.float64)
            ax.loglog(grid.numpy(), self.snr_model(grid).numpy(), "-", label="EMVA model")
            ax.loglog(grid.numpy(), torch.sqrt(self.quantum_efficiency * grid).numpy(), ":", label="ideal")
            ax.set_xlabel("mu_p (photons/pixel)")
        else:
            e = torch.as_tensor(x) / k
            ax.loglog(e[good].numpy(), self.snr[good].numpy(), "o", ms=4, label="measured")
            ax.set_xlabel("mu_e (electrons/pixel)")
        ax.set_ylabel("SNR")
        ax.set_title("Signal-to-noise ratio")
        ax.legend(fontsize=8)
        for a in axes:
            a.grid(True, alpha=0.3)
        fig.tight_layout()
        return fig


def _temporal_stats(stack: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and temporal variance of [..., N, H, W] frame stacks (EMVA 1288 4.0 eqs. 28-29).

    The variance is the per-pixel variance over the N frames (ddof = 1) of the frames with their own spatial
    mean removed, averaged over pixels; for N = 2 it is 1/(2HW) sum ((y_A - mu_A) - (y_B - mu_B))^2."""
    frame_means = stack.mean(dim=(-2, -1), keepdim=True)
    mu = frame_means.mean(dim=(-3, -2, -1))
    centred = stack - frame_means
    var = centred.var(dim=-3, unbiased=True).mean(dim=(-2, -1))
    return mu, var


def _spatial_var(stack: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Spatial variance of the frame average with the temporal part removed (EMVA 1288 4.0 section 8.2):
    s^2_y = s^2_y.measured - sigma^2_y.stack / L. Returns (s^2_y, mean)."""
    L = stack.shape[-3]
    avg = stack.mean(dim=-3)
    s2_measured = avg.var(unbiased=True)
    s2_stack = stack.var(dim=-3, unbiased=True).mean()
    return s2_measured - s2_stack / L, avg.mean()


def _fit_origin(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Least-squares slope of y = a x through the origin (EMVA reference implementation ``LinearB0``)."""
    return (x * y).sum() / (x * x).sum()


def _saturation_index(var: torch.Tensor) -> int:
    """Index of the maximum temporal variance, EMVA 1288's saturation point (release 4.0 Linear, section 6.5).

    The whole curve's maximum, not the first local maximum met scanning down from the brightest level (the EMVA
    reference implementation's loop, ``Results1288.index_u_ysat``): where the well saturates below the ADC's full
    scale, the levels past saturation keep their read and quantisation noise, a flat, noisy plateau on which that
    scan stops at a random bump (an audit of 2026-11-30: the wrong level in 7 of 10 simulated stacks, saturation
    capacity +40 %, PRNU from the wrong level). Below saturation the variance grows with the signal (shot noise
    K^2 mu_e), so the maximum is at saturation."""
    return int(torch.argmax(var))


def emva1288(bright: torch.Tensor, dark: torch.Tensor, photons_per_pixel=None, saturation_index: int | None = None,
             spatial_index: int | None = None) -> EMVA1288Result:
    """EMVA 1288 release 4.0 (Linear) characterisation from image stacks.

    Method (EMVA 1288 4.0; every step at each exposure level m):

    * temporal statistics over the N frames: mu_y = mean DN; sigma^2_y = per-pixel variance over frames
      (ddof = 1) after removing each frame's spatial mean (EMVA eq. 29 generalised to N frames), averaged over
      pixels; the same for the dark stack (mu_y.dark, sigma^2_y.dark).
    * saturation: the level of maximum sigma^2_y over the whole curve (or ``saturation_index``); a series whose
      variance is largest at its brightest level is refused (it may stop below saturation, which would then be
      reported as the saturation capacity) unless ``saturation_index`` says that level saturates.
    * system gain K (DN/e-): slope through the origin of sigma^2_y - sigma^2_y.dark against mu_y - mu_y.dark
      (photon transfer, EMVA eq. 9) over levels with mu_y - mu_y.dark <= 70 % of its value at saturation.
    * responsivity R = K eta (DN/photon): slope through the origin of mu_y - mu_y.dark against mu_p, same
      range; quantum efficiency eta = R / K.
    * dark noise: sigma_y.dark = sqrt(sigma^2_y.dark) of the first level, floored at sqrt(0.24) DN;
      sigma_d = sqrt(sigma^2_y.dark - 1/12) / K electrons (1/12 DN^2 = quantisation noise). Both assume one DN
      per ADC step: right-align left-aligned data first (12-bit values in 16-bit words divided by 16;
      ``isettorch calibrate`` does, with its ``quantisation_step_dn``), else sigma_d reads high (+3.2 % for
      12-bit data x 16 with 6 e- of read noise).
    * saturation capacity mu_e.sat = eta mu_p.sat (with photons) or (mu_y.sat - mu_y.dark) / K (without).
    * sensitivity threshold mu_e.min = sigma_y.dark / K + 1/2; dynamic range DR = mu_e.sat / mu_e.min,
      DR_dB = 20 log10 DR; SNR_max = sqrt(mu_e.sat).
    * SNR curve: measured (mu_y - mu_y.dark) / sigma_y (temporal noise only), and the model
      :meth:`EMVA1288Result.snr_model`.
    * DSNU/PRNU at the level closest to 50 % of saturation (or ``spatial_index``): spatial variance of the
      N-frame average minus its temporal part, s^2 = s^2_measured - sigma^2_stack / N (EMVA 4.0 section 8.2);
      DSNU1288 = s_y.dark / K (e-), PRNU1288 = sqrt(s^2_y - s^2_y.dark) / (mu_y - mu_y.dark) (%).
      No high-pass filtering: the illumination must be uniform over the frame.

    Args:
        bright: illuminated frames in DN, shape :math:`(M, N, H, W)`: M exposure levels (irradiance or exposure
            time steps, increasing, up to and past saturation), N >= 2 frames each.
        dark: dark frames in DN, :math:`(M, N, H, W)` (one dark stack per level, same exposure time) or
            :math:`(N, H, W)` (one stack for every level, when only the irradiance changes).
        photons_per_pixel: mean number of photons per pixel mu_p at each level, :math:`(M)` (mu_p = A E t_exp
            lambda / (h c)); without it QE, R and the photon quantities are None.
        saturation_index: force the saturation level (index into M).
        spatial_index: force the level used for DSNU/PRNU.

    Returns:
        :class:`EMVA1288Result` (``.report()`` gives the summary table, ``.plot()`` the PTC/sensitivity/SNR plots).

    Example:
        >>> res = emva1288(bright_dn, dark_dn, photons_per_pixel=mu_p)  # doctest: +SKIP
        >>> float(res.system_gain_dn_per_e), float(res.quantum_efficiency), print(res.report())  # doctest: +SKIP

    Reference: EMVA Standard 1288, release 4.0 Linear, European Machine Vision Association, 2021.
    """
    for name, t in (("bright", bright), ("dark", dark)):
        if not isinstance(t, torch.Tensor):
            raise TypeError(f"{name}: expected a torch.Tensor, got {type(t).__name__}")
    if bright.dim() != 4 or bright.shape[1] < 2:
        raise ValueError(f"bright: expected (M, N, H, W) with N >= 2 frames per level, got {tuple(bright.shape)}")
    M = bright.shape[0]
    if M < 3:
        raise ValueError(f"bright: expected at least 3 exposure levels, got {M}")
    b = bright.detach()
    d = dark.detach()
    if d.dim() == 3:
        d = d.unsqueeze(0)
    if d.dim() != 4 or d.shape[1] < 2 or d.shape[-2:] != b.shape[-2:] or d.shape[0] not in (1, M):
        raise ValueError(f"dark: expected (M, N, H, W) with M = {M} or (N, H, W), N >= 2, H x W = "
                         f"{tuple(b.shape[-2:])}, got {tuple(dark.shape)}")
    check_finite(b, "bright")
    check_finite(d, "dark")
    # level by level in float64, so a large stack is never copied whole
    stats_b = [_temporal_stats(b[m].to(torch.float64)) for m in range(M)]
    stats_d = [_temporal_stats(d[m].to(torch.float64)) for m in range(d.shape[0])]
    mu_y, var_y = (torch.stack(t) for t in zip(*stats_b))
    mu_d, var_d = (torch.stack(t).expand(M) for t in zip(*stats_d))

    mu_p = None
    if photons_per_pixel is not None:
        mu_p = as_tensor(photons_per_pixel, "photons_per_pixel", dtype=torch.float64).detach().cpu().reshape(-1)
        check_finite(mu_p, "photons_per_pixel")
        if mu_p.numel() != M or (mu_p < 0).any():
            raise ValueError(f"photons_per_pixel: expected {M} non-negative values (one per level), got "
                             f"{mu_p.tolist()}")
        if (mu_p.diff() < 0).any():
            raise ValueError(f"photons_per_pixel: expected the levels in increasing exposure (non-decreasing), got "
                             f"{mu_p.tolist()}")
    mu_y, var_y, mu_d, var_d = (t.cpu() for t in (mu_y, var_y, mu_d, var_d))

    for name, idx in (("saturation_index", saturation_index), ("spatial_index", spatial_index)):
        if idx is not None and not (is_integer(idx) and 0 <= idx < M):  # (2.5 was truncated to 2)
            raise ValueError(f"{name}: expected None or an integer level 0..{M - 1}, got {idx!r}")
    sat = _saturation_index(var_y) if saturation_index is None else int(saturation_index)
    if saturation_index is None and sat == M - 1 and M > 1:
        # the variance still rising at the brightest level: the series stops below saturation, and the brightest
        # level would be reported as the saturation capacity (an audit: 1,793 e- for a 7,990 e- sensor, DR -12 dB)
        raise ValueError(f"bright: the temporal variance is largest at the brightest level ({M - 1}), so the series "
                         f"may not reach saturation; EMVA 1288 asks for levels up to and past it: add brighter levels, "
                         f"or give saturation_index={M - 1} if that level saturates")
    signal = mu_y - mu_d
    if signal[sat] <= 0:
        raise ValueError("bright: the signal at saturation is not above the dark level; are bright and dark swapped?")
    if sat > 0 and signal[0] >= signal[sat]:
        raise ValueError(f"bright: expected the exposure levels in increasing order (the first level's signal below "
                         f"the signal at saturation, level {sat}), got {float(signal[0]):.4g} and "
                         f"{float(signal[sat]):.4g} DN above dark")
    in_fit = (signal[: sat + 1] <= 0.7 * signal[sat]).nonzero().reshape(-1)
    if in_fit.numel() < 2:
        raise ValueError("bright: fewer than 2 levels below 70 % of saturation; add lower exposure levels")
    fit_max = int(in_fit.max())
    sel = slice(0, fit_max + 1)
    K = _fit_origin(signal[sel], (var_y - var_d)[sel])
    if K <= 0:
        raise ValueError(f"bright: the photon transfer slope is not positive (K = {float(K):.4g})")

    s2_dark = torch.clamp(var_d[0], min=S2_DARK_FLOOR_DN2)
    sigma_y_dark = torch.sqrt(s2_dark)
    sigma_d = torch.sqrt(s2_dark - S2_QUANTIZATION_DN2) / K
    if mu_p is not None:
        if not bool((mu_p[sel] > 0).any()):  # (QE, R, saturation capacity and DR were NaN: 0 / 0)
            raise ValueError(f"photons_per_pixel: expected photons above 0 at some of the fitted levels 0..{fit_max}, "
                             f"got {mu_p[sel].tolist()}")
        R = _fit_origin(mu_p[sel], signal[sel])
        eta = R / K
        mu_p_sat = mu_p[sat]
        mu_e_sat = eta * mu_p_sat
    else:
        R = eta = mu_p_sat = None
        mu_e_sat = signal[sat] / K
    mu_e_min = sigma_y_dark / K + 0.5
    DR = mu_e_sat / mu_e_min

    if spatial_index is None:
        spatial_index = int((signal[: sat + 1] - 0.5 * signal[sat]).abs().argmin())
    si = int(spatial_index)
    if si > sat:  # (a saturated level's frames are flat: PRNU 0 %, reported without a word)
        raise ValueError(f"spatial_index: level {si} is past saturation (level {sat}); DSNU/PRNU are measured at "
                         f"about 50 % of saturation (EMVA 1288 4.0, section 8)")
    s2_y, mean_b = _spatial_var(b[si].to(torch.float64))
    s2_yd, mean_d = _spatial_var(d[si if d.shape[0] == M else 0].to(torch.float64))
    s2_y, s2_yd, mean_b, mean_d = (t.cpu() for t in (s2_y, s2_yd, mean_b, mean_d))
    if not bool(mean_b - mean_d > sigma_y_dark):
        # PRNU1288 divides by the signal (EMVA 1288 4.0, 8): below the sensitivity threshold (SNR 1, a signal of the
        # dark noise) it is noise over noise (-1277 % at an unlit level 0)
        raise ValueError(f"spatial_index: level {si}'s signal, {float(mean_b - mean_d):.4g} DN above the dark level, "
                         f"is not above the dark noise ({float(sigma_y_dark):.4g} DN); PRNU needs a lit level (about "
                         f"50 % of saturation)")
    dsnu_dn = torch.sqrt(s2_yd.clamp_min(0.0))
    prnu = 100.0 * torch.sqrt((s2_y - s2_yd).clamp_min(0.0)) / (mean_b - mean_d)

    snr = signal / torch.sqrt(var_y.clamp_min(torch.finfo(torch.float64).tiny))
    return EMVA1288Result(
        system_gain_dn_per_e=K, quantum_efficiency=eta, responsivity_dn_per_p=R, dark_noise_dn=sigma_y_dark,
        dark_noise_e=sigma_d, saturation_capacity_e=mu_e_sat, saturation_capacity_p=mu_p_sat,
        sensitivity_threshold_e=mu_e_min, dynamic_range=DR, dynamic_range_db=20 * torch.log10(DR),
        snr_max_db=10 * torch.log10(mu_e_sat), dsnu1288_e=dsnu_dn / K, dsnu1288_dn=dsnu_dn, prnu1288_percent=prnu,
        mean_dn=mu_y, mean_dark_dn=mu_d, var_dn2=var_y, var_dark_dn2=var_d, snr=snr, photons_per_pixel=mu_p,
        saturation_index=sat, fit_max_index=fit_max, spatial_index=si,
        dark_noise_is_upper_limit=bool(var_d[0] < S2_DARK_FLOOR_DN2),
    )


# --- noise components for calibration (used by isettorch.sensor.calibration) ---------------------------------


def temporal_noise_components(stack: torch.Tensor) -> dict[str, torch.Tensor]:
    """Mean and temporal variance components of an ``(N, H, W)`` frame stack (N >= 2), DN and DN^2.

    Model per frame f: y = m(i, j) + g_f + r_f(i) + c_f(j) + e_f(i, j): fixed pattern m, a global offset g, row
    offsets r (var s_r^2), column offsets c (s_c^2) and pixel-wise noise e (s_e^2; shot, read, quantisation).
    After removing each frame's spatial mean (EMVA 1288 4.0 eq. 29), the per-pixel temporal variance V_p, the
    temporal variance of the row means V_R and of the column means V_C are, in expectation (a = 1 - 1/H,
    b = 1 - 1/W): V_R = a (s_r^2 + s_e^2 / W), V_C = b (s_c^2 + s_e^2 / H),
    V_p = (1 - 1/HW) s_e^2 + a s_r^2 + b s_c^2, solved here for s_e^2, s_r^2, s_c^2 (row-noise estimation from
    row means: Wei et al. CVPR 2020, ELD, section 3.2; EMVA 1288 4.0 section 8.3 row/column spectrograms).

    Returns ``mean`` (mu_y), ``var`` (V_p, EMVA sigma^2_y), ``var_pixel`` (s_e^2), ``var_row`` (s_r^2),
    ``var_col`` (s_c^2), ``average`` (the frame average ``(H, W)``), ``frames`` (N); all float64.
    """
    x = stack.to(torch.float64)
    n, h, w = x.shape[-3:]
    centred = x - x.mean(dim=(-2, -1), keepdim=True)
    v_p = centred.var(dim=-3, unbiased=True).mean(dim=(-2, -1))
    v_r = centred.mean(dim=-1).var(dim=-2, unbiased=True).mean(dim=-1)
    v_c = centred.mean(dim=-2).var(dim=-2, unbiased=True).mean(dim=-1)
    a, b = 1 - 1 / h, 1 - 1 / w
    s_e = (v_p - v_r - v_c) / (1 - 1 / (h * w) - a / w - b / h)
    s_r = v_r / a - s_e / w
    s_c = v_c / b - s_e / h
    return {"mean": x.mean(dim=(-3, -2, -1)), "var": v_p, "var_pixel": s_e, "var_row": s_r, "var_col": s_c,
            "average": x.mean(dim=-3), "frames": n}


def spatial_variance(average: torch.Tensor, temporal_var, frames: int, reference: torch.Tensor | None = None,
                     reference_temporal_var=0.0, reference_frames: int = 1) -> torch.Tensor:
    """Spatial variance of a frame-averaged image with the temporal residue removed (EMVA 1288 4.0 section 8.2):
    ``s^2 = var(average - reference) - sigma^2 / N - sigma^2_ref / N_ref`` (``reference``: e.g. the dark average at
    the same exposure, subtracted pixel by pixel so the DSNU cancels in a PRNU estimate)."""
    img = average if reference is None else average - reference
    resid = temporal_var / frames + (0.0 if reference is None else reference_temporal_var / reference_frames)
    return img.var(unbiased=True) - resid


def linearity_error(exposure, signal_dn) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """EMVA 1288 linearity (Releases 3.1 and 4.0 Linear: 5-95 % of saturation): the levels whose signal (mean less
    dark, DN) lies within 5-95 % of the saturation signal (the largest), a least-squares line with offset through
    them against ``exposure`` (or irradiance, any unit), and the relative deviation from it in percent. Returns (the
    levels' mask, their deviations in %, (offset, slope)); no deviations with fewer than 3 levels in the band."""
    t, x = np.asarray(exposure, dtype=np.float64), np.asarray(signal_dn, dtype=np.float64)
    band = (x >= 0.05 * x.max()) & (x <= 0.95 * x.max())
    if band.sum() < 3:
        return band & False, np.empty(0), (math.nan, math.nan)
    slope, offset = np.polyfit(t[band], x[band], 1)
    fit = offset + slope * t[band]
    return band, 100 * (x[band] - fit) / fit, (float(offset), float(slope))


def spectrogram(image: torch.Tensor, axis: str = "horizontal") -> tuple[torch.Tensor, torch.Tensor]:
    """EMVA 1288 4.0 section 8.3 spectrogram of a frame-averaged image ``(H, W)``: the square root of the mean power
    spectrum of its rows (``'horizontal'``) or columns (``'vertical'``), mean removed, in the image's units.
    Returns (frequency in cycles/pixel [0, 0.5], amplitude); a flat spectrogram is white (pixel-wise) noise, peaks are
    periodic patterns, a rise at low frequency is shading."""
    x = image.to(torch.float64)
    if axis == "vertical":
        x = x.T
    elif axis != "horizontal":
        raise ValueError(f"axis: expected 'horizontal' or 'vertical', got {axis!r}")
    x = x - x.mean()
    n = x.shape[-1]
    power = (torch.fft.rfft(x, dim=-1).abs() ** 2 / n).mean(dim=0)
    return torch.fft.rfftfreq(n, dtype=torch.float64), torch.sqrt(power)


def calibration_figures(result: dict, capture, out_dir) -> list[str]:
    """The EMVA 1288 report figures of a calibration (``isettorch calibrate --report``) as PNG in ``out_dir``:
    photon transfer, SNR, linearity, and DSNU / PRNU spectrograms (EMVA 1288 4.0 sections 6-8). ``capture`` is the
    :class:`~isettorch.io.frames.Capture` (or its directory). Returns the written paths."""
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not hasattr(capture, "dark"):
        from ..io.frames import read_capture

        capture = read_capture(capture)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    colour = result["cfa"] is not None
    ptcs = result["photon_transfer"] if colour else {"W": result["photon_transfer"]}
    gain = result["conversion_gain_dn_per_e"]
    gain = gain if colour else {"W": gain}
    written = []

    def save(fig, name):
        p = out / name
        fig.tight_layout()
        fig.savefig(p, dpi=100)
        plt.close(fig)
        written.append(str(p))

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for n, p in ptcs.items():
        x, y, lin = np.array(p["signal_dn"]), np.array(p["variance_minus_dark_dn2"]), np.array(p["linear"])
        h = ax.plot(x, y, "o", ms=4, label=f"{n}")[0]
        ax.plot(x[lin], gain[n] * x[lin], "-", color=h.get_color(), label=f"{n}: K = {gain[n]:.4g} DN/e-")
    ax.set(xlabel="mu_y - mu_y.dark (DN)", ylabel="sigma^2_y - sigma^2_y.dark (DN^2)", title="Photon transfer")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, "photon_transfer.png")

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for n, p in ptcs.items():
        x, v = np.array(p["signal_dn"]), np.array(p["variance_dn2"])
        ok = (x > 0) & (v > 0)  # saturated levels have no temporal variance (no SNR to plot)
        e = x[ok] / gain[n]
        ax.loglog(e, x[ok] / np.sqrt(v[ok]), "o", ms=4, label=f"{n} measured")
        grid = np.logspace(np.log10(max(e.min(), 1.0)), np.log10(e.max()), 100)
        dark_var = np.array(p["dark_variance_dn2"])[0] / gain[n] ** 2  # e-^2 (read + quantisation)
        ax.loglog(grid, grid / np.sqrt(grid + dark_var), "-", lw=1, label=f"{n} model (EMVA eq. 19)")
    ax.set(xlabel="mu_e (electrons)", ylabel="SNR", title="Signal-to-noise ratio")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    save(fig, "snr.png")

    fig, axes = plt.subplots(2, 1, figsize=(6, 6), sharex=True)
    for n, p in ptcs.items():
        # (the gain fit's levels, at most 70 % of saturation and without its outliers, had hidden the deviation near
        # saturation that the figure is for)
        t, x = np.array(p["exposure_ms"]), np.array(p["signal_dn"])
        band, err, (offset, slope) = linearity_error(t, x)
        axes[0].plot(t, x, "o", ms=4, label=n)
        axes[0].plot(t[band], offset + slope * t[band], "-", lw=1)
        axes[1].plot(t[band], err, "o-", ms=4, label=n)
    axes[0].set(ylabel="mu_y - mu_y.dark (DN)", title="Linearity")
    axes[1].set(xlabel="exposure (ms)", ylabel="linearity error (%, 5-95 % of saturation)")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    save(fig, "linearity.png")

    d0 = torch.from_numpy(capture.dark[min(capture.dark)]).double().mean(dim=0)
    ms = result["photon_transfer"][next(iter(ptcs))]["prnu_exposure_ms"] if colour else \
        result["photon_transfer"]["prnu_exposure_ms"]
    dms = ms if ms in capture.dark else min(capture.dark, key=lambda k: abs(k - ms))
    flat = (torch.from_numpy(capture.flat[ms]).double().mean(dim=0)
            - torch.from_numpy(capture.dark[dms]).double().mean(dim=0))
    for name, img, unit in (("dsnu", d0, "DN"), ("prnu", flat, "DN")):
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for axis in ("horizontal", "vertical"):
            f, a = spectrogram(img, axis)
            ax.semilogy(f[1:].numpy(), a[1:].numpy(), lw=0.8, label=axis)
        ax.set(xlabel="frequency (cycles/pixel)", ylabel=f"amplitude ({unit})",
               title=f"{name.upper()} spectrogram (EMVA 1288 section 8.3)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3, which="both")
        save(fig, f"spectrogram_{name}.png")
    return written
