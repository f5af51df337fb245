"""PSF, LSF, MTF and encircled energy of shift-invariant optics, and their plots.

Every quantity comes from the optics' OTF (``optics.otf``), so it is what the optics applies to an image.
Plots return a matplotlib Figure (``fig.savefig("psf.png")``).
"""

from __future__ import annotations

import torch

from .._checks import as_tensor, check_finite, check_nanometres, check_wavelengths, is_integer, is_real

__all__ = ["psf", "lsf", "mtf", "encircled_energy", "plot_psf", "plot_lsf", "plot_mtf", "plot_encircled_energy"]


def _spacing(spacing_m) -> float:
    """A sample spacing (m): a positive finite number or one-value tensor (0 or NaN gave NaN, a negative one a
    mirrored curve), as a float."""
    if isinstance(spacing_m, torch.Tensor) and spacing_m.numel() == 1:  # e.g. an optical image's sample_spacing_m
        spacing_m = float(spacing_m)
    if not (is_real(spacing_m) and spacing_m > 0):
        raise ValueError(f"spacing_m: expected a finite spacing > 0 (m), got {spacing_m!r}")
    return float(spacing_m)


def _check_grid(spacing_m, size: int) -> None:
    """A sampling grid: a positive finite spacing (:func:`_spacing`) and a whole number of samples >= 2."""
    _spacing(spacing_m)
    if not (is_integer(size) and size >= 2):
        raise ValueError(f"size: expected a whole number of samples >= 2, got {size!r}")


def _prep(optics, wavelengths_nm, dtype=torch.float64):
    w = check_wavelengths(as_tensor(wavelengths_nm, "wavelengths_nm", dtype=dtype)).to(dtype)
    check_nanometres(w, "wavelengths_nm")  # (0.55 for 550 nm had given an f/4 MTF of 0.9997 at 100 c/mm for 0.722)
    n = optics.f_number.detach().to(dtype).reshape(-1)
    # the module's batch: its largest per-item parameter (WavefrontOptics' Zernike rows [B, J] beside one f-number
    # were refused: 'expected 1 or 1 rows')
    rows = [n.numel()]
    for name in ("focal_length_m", "defocus_diopters"):
        v = getattr(optics, name, None)
        rows.append(v.numel() if isinstance(v, torch.Tensor) else 1)
    z = getattr(optics, "zernike_um", None)
    rows.append(z.shape[0] if isinstance(z, torch.Tensor) and z.dim() == 2 else 1)
    b = max(rows)
    if n.numel() == 1 and b > 1:
        n = n.expand(b)
    return w, n


def psf(optics, wavelengths_nm, spacing_m: float, size: int = 64, oversample: int = 1, **otf_kwargs) -> torch.Tensor:
    """Point-spread function ``[B, L, size, size]`` sampled at ``spacing_m`` on the image plane, sum 1.

    The origin is sample ``(size // 2, size // 2)``. Computed as the inverse DFT of the OTF on the matching
    frequency grid, so it is the PSF periodised with period ``size * spacing_m`` (choose it wide enough).
    That grid holds the OTF's frequencies up to ``1 / (2 spacing_m)`` only: where the OTF reaches beyond (a pupil's
    cutoff is ``1 / (lambda N)``, so at a spacing coarser than ``lambda N / 2``) the result is the band-limited
    PSF, not its point samples (at ``1.5 lambda N``: the Airy peak 0.68 of the sum for 0.91, with negative lobes).
    ``oversample`` s computes it at ``spacing_m / s`` and keeps every s-th sample: point samples once
    ``spacing_m / s`` resolves the OTF (:func:`defocus_maps` and the renderers blur with the band-limited one, which
    is what a sampled image gets).
    ``otf_kwargs``: passed to ``optics.otf`` (e.g. :class:`~isettorch.optics.WavefrontOptics`'
    ``extra_defocus_diopters``). The lens focused at infinity: focused at an object distance, a pupil-limited
    lens (``optics.blur_at_image_distance``) has this PSF magnified by ``d_i / f`` (its working f-number).
    """
    _check_grid(spacing_m, size)
    if isinstance(oversample, bool) or not isinstance(oversample, int) or oversample < 1:
        raise ValueError(f"oversample: expected an integer >= 1, got {oversample!r}")
    w, n = _prep(optics, wavelengths_nm)
    fine = size * oversample
    f = torch.fft.fftfreq(fine, d=float(spacing_m) / oversample, dtype=w.dtype)[None, :].expand(n.numel(), -1)
    otf = optics.otf(f, f, w, n, **otf_kwargs)
    p = torch.fft.ifft2(otf).real
    p = torch.fft.fftshift(p, dim=(-2, -1))
    if oversample > 1:  # the samples at multiples of spacing_m from the origin (fine // 2)
        keep = fine // 2 + (torch.arange(size) - size // 2) * oversample
        p = p[..., keep, :][..., keep]
    return p / p.sum(dim=(-2, -1), keepdim=True)


def mtf(optics, wavelengths_nm, frequencies_cpm, axis: str = "x") -> torch.Tensor:
    """Modulation transfer ``|OTF|`` ``[B, L, F]`` at ``frequencies_cpm`` (cycles/m) along ``axis`` ('x' or 'y'),
    the lens focused at infinity (as :func:`psf`)."""
    w, n = _prep(optics, wavelengths_nm)
    fr = as_tensor(frequencies_cpm, "frequencies_cpm", dtype=w.dtype).reshape(1, -1)
    check_finite(fr, "frequencies_cpm")  # (NaN gave an MTF of NaN)
    fr = fr.expand(n.numel(), -1)
    zero = torch.zeros(n.numel(), 1, dtype=w.dtype)
    if axis == "x":
        return optics.otf(zero, fr, w, n).abs()[:, :, 0, :]
    if axis == "y":
        return optics.otf(fr, zero, w, n).abs()[:, :, :, 0]
    raise ValueError(f"axis: expected 'x' or 'y', got {axis!r}")


def lsf(optics, wavelengths_nm, spacing_m: float, size: int = 256, axis: str = "x") -> torch.Tensor:
    """Line-spread function ``[B, L, size]`` (sum 1) across a line along the other axis, origin at ``size // 2``."""
    _check_grid(spacing_m, size)
    w, n = _prep(optics, wavelengths_nm)
    f = torch.fft.fftfreq(size, d=float(spacing_m), dtype=w.dtype)[None, :].expand(n.numel(), -1)
    zero = torch.zeros(n.numel(), 1, dtype=w.dtype)
    if axis == "x":
        otf = optics.otf(zero, f, w, n)[:, :, 0, :]
    elif axis == "y":
        otf = optics.otf(f, zero, w, n)[:, :, :, 0]
    else:
        raise ValueError(f"axis: expected 'x' or 'y', got {axis!r}")
    line = torch.fft.fftshift(torch.fft.ifft(otf).real, dim=-1)
    return line / line.sum(dim=-1, keepdim=True)


def encircled_energy(psf_img: torch.Tensor, spacing_m: float, radii_m) -> torch.Tensor:
    """Fraction of a PSF ``[..., H, W]`` (origin at ``(H // 2, W // 2)``) within each radius ``[R]`` -> ``[..., R]``.

    Counts whole samples whose centre lies within the radius.
    """
    spacing_m = _spacing(spacing_m)  # (0 gave 1 at every radius)
    h, w = psf_img.shape[-2:]
    yy = (torch.arange(h, dtype=psf_img.dtype) - h // 2)[:, None] * spacing_m
    xx = (torch.arange(w, dtype=psf_img.dtype) - w // 2)[None, :] * spacing_m
    r = torch.sqrt(yy**2 + xx**2)
    radii = as_tensor(radii_m, "radii_m", dtype=psf_img.dtype).reshape(-1)
    if not bool((radii >= 0).all()):  # (a negative radius gave 0; NaN fails too)
        raise ValueError(f"radii_m: expected radii >= 0 (m), got {radii.tolist()}")
    inside = (r[None] <= radii[:, None, None]).to(psf_img.dtype)  # [R, H, W]
    tot = psf_img.sum(dim=(-2, -1))
    if not bool((torch.isfinite(tot) & (tot > 0)).all()):  # (an all-zero PSF gave NaN)
        raise ValueError("psf_img: expected finite PSFs with a positive sum (the fraction is of their total)")
    return torch.einsum("...hw,rhw->...r", psf_img, inside) / tot[..., None]


# --- plots ------------------------------------------------------------------------------------------

def plot_psf(optics, wavelength_nm: float = 550.0, spacing_m: float | None = None, size: int = 64, index: int = 0,
             ax=None):
    """Image of the PSF at one wavelength (sample ``index`` of the batch), axes in um."""
    n = float(optics.f_number.detach().reshape(-1)[index])
    dx = spacing_m or wavelength_nm * 1e-9 * n / 4
    from ..plot import _fig_ax

    p = psf(optics, [wavelength_nm], dx, size)[index, 0]
    fig, ax = _fig_ax(ax)
    # sample k sits at (k - size // 2) dx (psf's origin): cells span half a sample either side of it
    lo, hi = (-(size // 2) - 0.5) * dx * 1e6, (size - size // 2 - 0.5) * dx * 1e6
    im = ax.imshow(p.numpy() / p.max().item(), extent=[lo, hi, hi, lo], cmap="magma")
    fig.colorbar(im, ax=ax, label="relative PSF")
    ax.set_xlabel("x (um)")
    ax.set_ylabel("y (um)")
    ax.set_title(f"PSF {wavelength_nm:g} nm, f/{n:g}")
    return fig


def plot_lsf(optics, wavelengths_nm=(450.0, 550.0, 650.0), spacing_m: float = 0.25e-6, size: int = 256,
             index: int = 0, ax=None):
    from ..plot import plot_curves

    line = lsf(optics, wavelengths_nm, spacing_m, size)[index]
    x = (torch.arange(size, dtype=line.dtype) - size // 2) * spacing_m * 1e6
    return plot_curves(x, {f"{w:g} nm": line[k] for k, w in enumerate(wavelengths_nm)}, xlabel="x (um)",
                       ylabel="LSF (sum 1)", title="line-spread function", ax=ax)


def plot_mtf(optics, wavelengths_nm=(450.0, 550.0, 650.0), max_cpmm: float = 500.0, index: int = 0, ax=None):
    from ..plot import plot_curves

    f_cpmm = torch.linspace(0, max_cpmm, 201, dtype=torch.float64)
    m = mtf(optics, wavelengths_nm, f_cpmm * 1e3)[index]
    return plot_curves(f_cpmm, {f"{w:g} nm": m[k] for k, w in enumerate(wavelengths_nm)},
                       xlabel="spatial frequency (cycles/mm)", ylabel="MTF", title="modulation transfer", ax=ax)


def plot_encircled_energy(optics, wavelengths_nm=(450.0, 550.0, 650.0), spacing_m: float = 0.25e-6,
                          size: int = 128, index: int = 0, ax=None):
    from ..plot import plot_curves

    radii = torch.linspace(0, size // 2 * spacing_m, 100, dtype=torch.float64)
    p = psf(optics, wavelengths_nm, spacing_m, size)[index]
    ee = encircled_energy(p, spacing_m, radii)
    return plot_curves(radii * 1e6, {f"{w:g} nm": ee[k] for k, w in enumerate(wavelengths_nm)},
                       xlabel="radius (um)", ylabel="encircled energy", title="encircled energy", ax=ax)
