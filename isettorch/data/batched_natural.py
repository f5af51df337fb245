"""Batched natural scenes on any device: the distribution of :func:`isettorch.data.natural.generate_natural` as
tensor programs over a batch (for :class:`isettorch.data.PairStream`, ``scene.generator: natural``).

:func:`draw_natural_scenes` draws ``B`` scenes with one ``torch.Generator`` on the batch's device. Every component of
:mod:`.natural` is reproduced with the same parameter ranges, switches (``enabled``) and probabilities, but with other
random numbers: each quantity is drawn as a ``[B]`` (or ``[B, N]``) tensor, variable counts (materials, leaves, detail
items) are padded to the batch's maximum with inactive entries.

Sequential dependencies are kept exactly:

* dead leaves are painted large to small by a loop over leaf *slots* (the ``j``-th largest leaf of every item at
  once); each slot's anti-aliased coverage is evaluated on a window that holds every item's bounding box (masked to
  that box, as :func:`.natural._leaf_coverage`), composited over what is painted, and a leaf reads the material under
  its centre from the maps at its own paint time (the colour-correlation rule);
* fine-detail items are composited in their order, one slot per step.

Textures on a leaf are power-law fields on the leaf's own box (:func:`isettorch.scene.textures.power_law_noise` on a
``hh x ww`` periodic grid, normalised to unit std over the box). Boxes differ per item, so the field is synthesised
as the real part of a sum of complex Gaussian Fourier coefficients on each item's own frequency grid (a batched
matrix product): a zero-mean Gaussian field whose covariance is proportional to the FFT synthesis' (both are
``sum_f A(f)^2 cos(2 pi f d)`` on the same grid), so after the same normalisation it has the same distribution.
Saturation draws of the recovered palette (Beta by inverse CDF) use a tabulated quantile function (scipy's, 2^14
intervals, linear interpolation).

``tests/data/test_stream_natural.py`` compares summary statistics with the per-item generator.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .._autograd import tensor_cache
from ..scene import textures as _tex
from . import spectra as _spectra
from .batched import ILLUMINANT_KIND_CODES, _choice, _illuminants, _log_uniform, _reflectances, _white_photons
from .config import natural_config
from .scenes import _luminance_weights

__all__ = ["draw_natural_scenes"]

_PALETTE_KINDS = ("measured", "random", "recovery")
_TEXTURE_KINDS = ("colour_line", "grating", "noise")
_DEFAULT_CCT = {"daylight": (4000.0, 25000.0), "blackbody": (2000.0, 10000.0), "led": (2700.0, 6500.0)}


def _u(g, shape, lo=0.0, hi=1.0, *, device):
    return torch.rand(shape, generator=g, device=device, dtype=torch.float64) * (hi - lo) + lo


def _rng(r):
    return float(r[0]), float(r[1])


# --- palette ------------------------------------------------------------------------------------------------------

@tensor_cache(maxsize=8)
def _beta_quantiles(a: float, b: float, n: int = 16384) -> torch.Tensor:
    from scipy.stats import beta

    return torch.from_numpy(beta.ppf(torch.linspace(0, 1, n + 1, dtype=torch.float64).numpy(), a, b))


def _beta_ppf(u: torch.Tensor, a: float, b: float) -> torch.Tensor:
    table = _beta_quantiles(a, b).to(u.device)
    n = table.numel() - 1
    x = u * n
    i = x.floor().long().clamp(0, n - 1)
    t = x - i
    return table[i] * (1 - t) + table[i + 1] * t


def _recovered(nb, k, wl, g, device):
    """``[B, K, L]`` :func:`isettorch.data.spectra.recovery_reflectances` (default Beta(1.2, 4) saturation, albedo
    log-uniform 0.03-0.9, HSV -> linear sRGB -> Mallett & Yuksel 2019 basis), batched."""
    hue = _u(g, (nb, k), device=device)
    sat = _beta_ppf(_u(g, (nb, k), device=device), *_spectra.RECOVERY_CHROMA_BETA)
    lo, hi = (math.log(v) for v in _spectra.RECOVERY_ALBEDO_RANGE)
    val = torch.exp(lo + (hi - lo) * _u(g, (nb, k), device=device))
    return _spectra.hsv_reflectances(hue, sat, val, wl)


def _palette(nb, cfg, wl, g, device):
    """Reflectances ``[B, K, L]`` (K the most materials), the material counts ``[B]`` and dye concentrations."""
    p = cfg["components"]["palette"]
    lo, hi = int(p["materials"][0]), int(p["materials"][1])
    kmax = hi
    n_mat = torch.randint(lo, hi + 1, (nb,), generator=g, device=device)
    if p["enabled"]:
        kind = _choice({"measured": p["measured"], "recovery": p["recovery"], "random": p["random"]},
                       _u(g, (nb * kmax,), device=device), _PALETTE_KINDS).reshape(nb, kmax)
    else:
        kind = torch.full((nb, kmax), 1, device=device)
    measured = _spectra.measured_reflectances(wl.cpu()).to(device)
    pick = torch.randint(0, measured.shape[0], (nb, kmax), generator=g, device=device)
    meas = (measured[pick] * _u(g, (nb, kmax, 1), 0.3, 1.2, device=device)).clamp(0, 1)
    rec = _recovered(nb, kmax, wl, g, device)
    rnd = _reflectances(nb, kmax, wl, g, "mixed", 0.5, device)
    refl = torch.where((kind == 0)[..., None], meas, torch.where((kind == 2)[..., None], rec, rnd))
    conc = torch.ones(nb, kmax, dtype=torch.float64, device=device)
    if p["enabled"]:
        grey = _u(g, (nb, kmax), device=device) < float(p["grey_probability"])
        level = torch.exp(_u(g, (nb, kmax), math.log(0.03), math.log(0.9), device=device))
        refl = torch.where(grey[..., None], level[..., None].expand_as(refl), refl)
        dye = p["dye"]
        if dye["probability"] > 0:
            dyed = (~grey) & (_u(g, (nb, kmax), device=device) < float(dye["probability"]))
            c = torch.exp(_u(g, (nb, kmax), *map(math.log, _rng(dye["concentration"])), device=device))
            conc = torch.where(dyed, c, conc)
            refl = torch.where(dyed[..., None], _spectra.dye_concentration(refl, conc[..., None]), refl)
    return refl, n_mat, conc


# --- dead leaves --------------------------------------------------------------------------------------------------

def _paint_leaves(cfg, g, maps, alpha, active, n_leaves, n_mat, r_min, r_max, exponent):
    """Paint each active item's ``n_leaves [B]`` dead leaves, large to small, onto ``maps [B, K, n, n]`` in place
    (and ``alpha [B, n, n]``, the layer's coverage, when given): :func:`isettorch.data.natural._paint_leaves`, one
    leaf slot per step over the batch. Radii ``p(r) ~ r^-exponent`` on ``[r_min, r_max]`` by inverse CDF. Returns the
    drawn radii ``[B, N]`` (sorted, descending; 0 beyond an item's count)."""
    dev = maps.device
    nb, kmax, h, w = maps.shape
    comp = cfg["components"]
    cc = comp["colour_correlation"]
    r_chroma = float(cc["chromatic_radius_px"]) if cc["enabled"] else 0.0
    b_lo, b_hi = _rng(comp["dead_leaves"]["brightness"])
    tl = comp["textured_leaves"]
    nmax = int(n_leaves.max()) if nb else 0
    on = active[:, None] & (torch.arange(nmax, device=dev)[None] < n_leaves[:, None])
    u = _u(g, (nb, nmax), device=dev)
    a = 1.0 - exponent
    radii = (r_min**a + u * (r_max**a - r_min**a)) ** (1 / a)  # inverse CDF (natural._paint_leaves)
    radii = torch.where(on, radii, torch.zeros((), dtype=torch.float64, device=dev)).sort(1, descending=True).values
    if nmax == 0:
        return radii
    uy, ux, us, ua, ut, ub, um = _u(g, (7, nb, nmax), device=dev).unbind(0)
    k_all = (_u(g, (nb, nmax), device=dev) * n_mat[:, None]).long().clamp_max(n_mat[:, None] - 1)
    cy, cx = (-0.1 + 1.2 * uy) * h, (-0.1 + 1.2 * ux) * w
    shape = (3 * us).long().clamp_max(2)  # 0 disk, 1 ellipse, 2 rectangle
    aspect, theta = 0.3 + 0.7 * ua, math.pi * ut
    bright = b_lo * (b_hi / b_lo) ** ub
    # bounding boxes (natural._leaf_coverage): they depend on the geometry only, so all are known before painting
    ext = radii * aspect.clamp_min(1.0) * torch.where(shape == 2, 1.5, 1.0) + 1.5
    y0 = torch.floor(cy - ext).clamp_min(0).long()
    y1 = (torch.ceil(cy + ext).long() + 1).clamp_max(h)
    x0 = torch.floor(cx - ext).clamp_min(0).long()
    x1 = (torch.ceil(cx + ext).long() + 1).clamp_max(w)
    paint = on & (y0 < y1) & (x0 < x1)
    hh, ww = torch.where(paint, y1 - y0, 0), torch.where(paint, x1 - x0, 0)
    # textures (natural._leaf_texture): a box of at least min_size_px, with probability; drawn per leaf
    min_size = max(2, int(tl["min_size_px"]))
    textured = paint & (torch.minimum(hh, ww) >= min_size) & (_u(g, (nb, nmax), device=dev) < float(tl["probability"]))
    if not tl["enabled"]:
        textured = torch.zeros_like(textured)
    t_kind = _choice(tl["kinds"], _u(g, (nb, nmax), device=dev), _TEXTURE_KINDS)
    t_s = _u(g, (nb, nmax), *_rng(tl["noise_exponent"]), device=dev)
    t_contrast = _u(g, (nb, nmax), 0.1, 0.5, device=dev)  # noise: log-std of the shading
    t_freq = torch.exp(_u(g, (nb, nmax), *map(math.log, _rng(tl["grating_cpp"])), device=dev))
    t_angle, t_warp = _u(g, (nb, nmax), 0, math.pi, device=dev), _u(g, (nb, nmax), 0.0, 3.0, device=dev)
    t_phase = _u(g, (nb, nmax), 0, 2 * math.pi, device=dev)
    t_line = _u(g, (nb, nmax), 0.5, 2.0, device=dev)  # colour_line contrast
    second = _second_material_draws(cfg, g, (nb, nmax), n_mat, dev)
    # one host read for the slots' windows and the textured items' boxes (per slot: their largest box and their
    # number; a read per textured slot stalled a GPU's queue three times per leaf)
    wins = torch.stack([hh.amax(0), ww.amax(0), textured.any(0).long(), paint.any(0).long(),
                        torch.where(textured, hh, 0).amax(0), torch.where(textured, ww, 0).amax(0),
                        textured.sum(0)]).tolist()
    tex_items = textured.T.nonzero()[:, 1] if any(wins[2]) else None  # by slot, items ascending
    tex_start = [0]
    for n_tex in wins[6]:
        tex_start.append(tex_start[-1] + n_tex)
    bidx = torch.arange(nb, device=dev)
    kidx = torch.arange(kmax, device=dev)
    flat = maps.view(-1)
    flat_a = None if alpha is None else alpha.view(-1)
    base = (bidx[:, None] * kmax + kidx[None]) * (h * w)  # [B, K]: where map (b, k) starts in ``flat``
    if r_chroma > 0:  # a leaf of radius r keeps the material under its centre unless u < r / chromatic_radius_px
        keep_rule = um >= radii / r_chroma
        centre = cy.trunc().long().clamp(0, h - 1) * w + cx.trunc().long().clamp(0, w - 1)  # [B, N]
    j = 0
    while j < nmax:
        wy, wx, any_tex = wins[0][j], wins[1][j], wins[2][j]
        if not wins[3][j]:
            j += 1
            continue
        # a chunk of consecutive slots whose boxes fit the first one's window, without texture: coverage in one pass
        e = j + 1
        while (not any_tex and e < nmax and e - j < 64 and wins[0][e] <= wy and wins[1][e] <= wx
               and not wins[2][e]):
            e += 1
        sl = slice(j, e)

        def tr(v, sl=sl):
            return v[:, sl].transpose(0, 1)  # [S, B]

        oy = torch.minimum(tr(y0), torch.full_like(tr(y0), h - wy))
        ox = torch.minimum(tr(x0), torch.full_like(tr(x0), w - wx))
        iy = oy[..., None] + torch.arange(wy, device=dev)  # [S, B, wy]
        ix = ox[..., None] + torch.arange(wx, device=dev)
        inside = (((iy >= tr(y0)[..., None]) & (iy < tr(y1)[..., None]))[..., :, None]
                  & ((ix >= tr(x0)[..., None]) & (ix < tr(x1)[..., None]))[..., None, :] & tr(paint)[..., None, None])
        cov = torch.where(inside, _coverage(iy, ix, tr(cy), tr(cx), tr(radii).clamp_min(1e-3), tr(aspect),
                                            tr(theta), tr(shape)), torch.zeros((), device=dev))
        contrib = cov * tr(bright)[..., None, None].float()
        pix = iy[..., :, None] * w + ix[..., None, :]  # [S, B, wy, wx]
        idx = base[None, :, :, None, None] + pix[:, :, None]  # [S, B, K, wy, wx]
        tex = None
        if any_tex:  # one slot (j): the textured items' fields on their boxes (natural._leaf_texture)
            tj = textured[:, j]
            ly, lx = iy[0] - y0[:, j, None], ix[0] - x0[:, j, None]
            sel = tex_items[tex_start[j]:tex_start[j + 1]]  # the fields of the textured items only
            n_ = torch.zeros(nb, wy, wx, dtype=torch.float64, device=dev)
            n_[sel] = _tex.power_law_noise_on_boxes(hh[sel, j], ww[sel, j], ly[sel], lx[sel], inside[0][sel],
                                                    torch.where(t_kind[sel, j] == 1, 2.0, t_s[sel, j]), g,
                                                    size=(wins[4][j], wins[5][j]))
            ang = t_angle[:, j, None, None]
            uu = lx.to(torch.float64)[:, None, :] * torch.cos(ang) + ly.to(torch.float64)[:, :, None] * torch.sin(ang)
            grating = 0.5 + 0.5 * torch.sin(2 * math.pi * t_freq[:, j, None, None]
                                            * (uu + n_ * t_warp[:, j, None, None]) + t_phase[:, j, None, None])
            tt = torch.where((t_kind[:, j] == 1)[:, None, None], grating,
                             _tex.normal_cdf(n_ * t_line[:, j, None, None])).float()
            shade_noise = torch.exp(n_ * t_contrast[:, j, None, None]).float()
            tex = tj, tt, shade_noise
        for s in range(e - j):
            jj = j + s
            k = k_all[:, jj]
            if r_chroma > 0:
                under = torch.take(flat, base + centre[:, jj, None])  # [B, K]: at the centre, as painted so far
                keep = keep_rule[:, jj] & (under.amax(1) > 0)
                k = torch.where(keep, under.argmax(1), k)
            c_s = contrib[s]
            region = torch.take(flat, idx[s]) * (1 - cov[s])[:, None]
            if tex is None:
                region += (kidx[None] == k[:, None]).float()[:, :, None, None] * c_s[:, None]
            else:
                tj, tt, shade_noise = tex
                k2 = torch.where(second[0][:, jj], second[1][:, jj], k)  # the blend's material (or the same one)
                same = (k2 == k)[:, None, None]
                noise_kind = (t_kind[:, jj] == 2)[:, None, None]
                # noise: the leaf's own log-normal shading; a blend with the same material: an intensity texture
                shade = torch.where(noise_kind, shade_noise, torch.where(same, 0.4 + 0.8 * tt, torch.ones_like(tt)))
                c_s = torch.where(tj[:, None, None] & inside[s], c_s * shade, c_s)
                t = torch.where(tj[:, None, None] & ~noise_kind & ~same & inside[s], tt, torch.zeros_like(tt))
                region += (kidx[None] == k[:, None]).float()[:, :, None, None] * (c_s * (1 - t))[:, None]
                region += (kidx[None] == k2[:, None]).float()[:, :, None, None] * (c_s * t)[:, None]
            flat.put_(idx[s], region)  # indices are unique: one window per item
            if flat_a is not None:
                ia = bidx[:, None, None] * (h * w) + pix[s]
                flat_a.put_(ia, torch.take(flat_a, ia) * (1 - cov[s]) + cov[s])
        j = e
    return radii


def _coverage(iy, ix, cy, cx, r, aspect, theta, shape):
    """Anti-aliased coverage ``clip(0.5 - d, 0, 1)`` ``[..., wy, wx]`` (float32) of leaves by their signed distance
    ``d`` at the pixel centres ``iy [..., wy]``, ``ix [..., wx]`` (:func:`isettorch.data.natural._leaf_coverage`:
    disk, ellipse by the scaled radius, rectangle); the leaf parameters are ``[...]``."""
    f32 = torch.float32

    def per(v):
        return v.to(f32)[..., None, None]

    yy = (iy.to(f32) - cy.to(f32)[..., None] + 0.5)[..., :, None]
    xx = (ix.to(f32) - cx.to(f32)[..., None] + 0.5)[..., None, :]
    ct, st = per(torch.cos(theta)), per(torch.sin(theta))
    r_, a_ = per(r), per(aspect)
    u, v = xx * ct + yy * st, yy * ct - xx * st
    disk = torch.sqrt(u * u + v * v) - r_
    ell = (torch.sqrt((u / r_) ** 2 + (v / (r_ * a_)) ** 2) - 1) * (r_ * a_.clamp_max(1.0))
    rect = torch.maximum(u.abs() - r_, v.abs() - r_ * a_)
    sh = shape[..., None, None]
    d = torch.where(sh == 0, disk, torch.where(sh == 1, ell, rect))
    return (0.5 - d).clamp(0, 1)


def _second_material_draws(cfg, g, shape, n_mat, device):
    """(another material drawn? ``[...]`` bool, that material ``[...]``): :func:`.natural._second_material` (with
    ``colour_correlation`` on, another one with ``chromatic_detail_probability``; off, always a random one)."""
    cc = cfg["components"]["colour_correlation"]
    u = _u(g, shape, device=device)
    other = u < float(cc["chromatic_detail_probability"]) if cc["enabled"] else torch.ones_like(u, dtype=torch.bool)
    nm = n_mat.reshape(-1, *([1] * (len(shape) - 1)))
    k = (_u(g, shape, device=device) * nm).long().clamp_max(nm - 1)
    return other, k


# --- fine detail --------------------------------------------------------------------------------------------------

def _fine_detail(cfg, g, maps, active, n_mat):
    """Band-limited items (:func:`isettorch.data.natural._fine_detail`): gratings, thin lines, edges rendered
    ``supersample`` x finer and box-averaged (pixel-area integration), composited one item slot at a time."""
    c = cfg["components"]["fine_detail"]
    dev = maps.device
    nb, kmax, h, w = maps.shape
    ss = int(c["supersample"])
    lo, hi = int(c["items"][0]), int(c["items"][1])
    count = torch.where(active, torch.randint(lo, hi + 1, (nb,), generator=g, device=dev), 0)
    yy = ((torch.arange(h * ss, device=dev, dtype=torch.float32) + 0.5) / ss)[None, :, None]
    xx = ((torch.arange(w * ss, device=dev, dtype=torch.float32) + 0.5) / ss)[None, None, :]
    kidx = torch.arange(kmax, device=dev)
    for i in range(hi):
        on = count > i
        kind = torch.randint(0, 3, (nb,), generator=g, device=dev)  # 0 grating, 1 line, 2 edge
        ang = _u(g, (nb,), 0.0, math.pi, device=dev)
        other, k = _second_material_draws(cfg, g, (nb,), n_mat, dev)
        cy, cx = _u(g, (nb,), 0.2 * h, 0.8 * h, device=dev), _u(g, (nb,), 0.2 * w, 0.8 * w, device=dev)
        f = _u(g, (nb,), *_rng(c["grating_cpp"]), device=dev)
        square = _u(g, (nb,), device=dev) < 0.5
        half = _u(g, (nb,), 0.15, 0.5, device=dev) * min(h, w)
        width = _u(g, (nb,), *_rng(c["line_width_px"]), device=dev)
        bright = torch.exp(_u(g, (nb,), math.log(0.2), 0.0, device=dev)).float()
        sel = on.nonzero().reshape(-1)  # the items with an i-th detail item: rendered on those only
        if sel.numel() == 0:
            continue
        ca, sa = torch.cos(ang[sel]), torch.sin(ang[sel])
        u0 = cx[sel] * ca + cy[sel] * sa
        v0 = -cx[sel] * sa + cy[sel] * ca

        def per(v):
            return v.to(torch.float32)[:, None, None]

        du = xx * per(ca) + yy * per(sa) - per(u0)
        dv = -xx * per(sa) + yy * per(ca) - per(v0)
        wave = torch.sin(2 * math.pi * per(f[sel]) * du)
        pattern = torch.where(square[sel, None, None], (wave > 0).float(), 0.5 + 0.5 * wave)
        grating = ((du.abs() < per(half[sel])) & (dv.abs() < per(half[sel]))).float() * pattern
        line = (dv.abs() < per(width[sel]) / 2).float()
        edge = (dv > 0).float()
        kk = kind[sel, None, None]
        cov = torch.where(kk == 0, grating, torch.where(kk == 1, line, edge))
        cov4 = F.avg_pool2d(cov[:, None], ss)  # pixel-area integration [b, 1, h, w]
        b = bright[sel, None, None, None]
        sub = maps[sel]
        achrom = sub * (1 - cov4 + cov4 * b)
        chrom = sub * (1 - cov4) + (kidx[None] == k[sel, None]).float()[:, :, None, None] * cov4 * b
        maps[sel] = torch.where(other[sel, None, None, None], chrom, achrom)
    return maps, count


# --- scenes -------------------------------------------------------------------------------------------------------

def draw_natural_scenes(nb: int, g: torch.Generator, cfg: dict, *, size: tuple[int, int], device,
                        dtype=torch.float32) -> dict:
    """``nb`` scenes of the natural distribution (:func:`isettorch.data.natural.generate_natural` with the options
    ``cfg["natural"]`` and the grid ``cfg["wavelengths_nm"]``; ``cfg`` a merged scene config) drawn with ``g`` on
    ``device``, as :class:`~isettorch.data.camera_pairs.CameraPairDataset` makes them
    (:func:`isettorch.data.camera_pairs._natural_scene`): generated square at ``max(16, H, W)``, cropped to ``size``
    about the centre and scaled to a mean luminance drawn log-uniformly from ``cfg["mean_luminance_cd_m2"]``.

    Returns the dict of :func:`isettorch.data.batched.draw_layout_scenes`: ``maps [B, J, H, W]`` (``dtype``),
    ``used [B, J]``, ``spectra [B, J, L]`` and ``white [B, L]`` (float64, photons/s/sr/m^2/nm), ``wavelengths_nm``
    and ``meta`` (``[B, ...]`` tensors): ``cct_k``, ``illuminant_code``
    (:data:`~isettorch.data.camera_pairs.ILLUMINANT_CODES`), ``hdr_decades`` (0), ``mean_luminance_cd_m2``,
    ``materials``, ``mixed_light``, ``leaf_radius [B, N]`` / ``leaf_count`` (the drawn background radii, sorted
    descending), ``foreground`` (a depth layer drawn), ``foreground_coverage`` (its mean coverage before defocus),
    ``defocus_back_diopters`` / ``defocus_front_diopters``, ``fine_detail_items``, ``grain``, ``relative_grain``,
    ``specular``.

    Example:
        >>> from isettorch.data.config import SCENE_DEFAULTS, merge_config
        >>> cfg = merge_config({"generator": "natural"}, SCENE_DEFAULTS, "scene")
        >>> out = draw_natural_scenes(2, torch.Generator().manual_seed(0), cfg, size=(32, 32), device="cpu")
        >>> out["maps"].shape[-2:], out["spectra"].shape[-1]
        (torch.Size([32, 32]), 31)
    """
    from .natural import _layer_optics, _wavelengths, grain_dyes

    if isinstance(nb, bool) or not isinstance(nb, int) or nb < 1:
        raise ValueError(f"nb: expected a positive number of scenes, got {nb!r}")
    if len(size) != 2 or min(int(size[0]), int(size[1])) < 1:
        raise ValueError(f"size: expected (height, width) of at least 1 pixel, got {size!r}")
    h, w = int(size[0]), int(size[1])
    n = max(16, h, w)
    ncfg = natural_config(dict(cfg.get("natural") or {}, size=n, wavelengths_nm=list(cfg["wavelengths_nm"])))
    comp = ncfg["components"]
    dev = torch.device(device)
    f64 = torch.float64
    wl = _wavelengths(ncfg).to(dev)
    refl, n_mat, _ = _palette(nb, ncfg, wl, g, dev)
    kmax = refl.shape[1]
    # illuminants (natural._illuminants): the main light, and with mixed_probability a second one over a field
    c = comp["illuminant"]
    kinds = c["kinds"] if c["enabled"] else {"daylight": 1.0}
    ui = _u(g, (nb, 6), device=dev)
    kind1 = _choice(kinds, ui[:, 0], ILLUMINANT_KIND_CODES)
    mixed = (ui[:, 3] < float(c["mixed_probability"])) if c["enabled"] else torch.zeros(nb, dtype=torch.bool,
                                                                                          device=dev)
    kind2 = _choice(kinds, ui[:, 4], ILLUMINANT_KIND_CODES)
    lo_k, hi_k = {}, {}
    for name, (lo, hi) in _DEFAULT_CCT.items():
        lo_k[name] = torch.full((2 * nb,), lo, dtype=f64, device=dev)
        hi_k[name] = torch.full((2 * nb,), hi, dtype=f64, device=dev)
    if not c["enabled"]:  # ablation: D65-like daylight at 6500 K
        lo_k["daylight"][:nb], hi_k["daylight"][:nb] = 6500.0, 6500.0
    spd, cct_both = _illuminants(torch.cat([kind1, kind2]), torch.cat([ui[:, 1], _u(g, (nb,), device=dev)]),
                                 torch.cat([ui[:, 2], ui[:, 5]]), wl, lo_k, hi_k)
    e1, e2 = _white_photons(spd[:nb], wl), _white_photons(spd[nb:], wl)
    cct1 = cct_both[:nb]
    def field(exponent):  # [B, n, n] power-law fields, one exponent per item (scene.textures.power_law_noise)
        return _tex.power_law_noise(n, n, exponent, g, dtype=f64, device=dev)

    mix_field = torch.sigmoid(field(torch.full((nb,), 2.5, dtype=f64, device=dev))
                              * _u(g, (nb, 1, 1), 1.0, 4.0, device=dev)).float()
    ratio = torch.exp(_u(g, (nb,), math.log(0.3), math.log(3.0), device=dev))
    # background material, then dead leaves
    kidx = torch.arange(kmax, device=dev)
    bg = (_u(g, (nb,), device=dev) * n_mat).long().clamp_max(n_mat - 1)
    maps = (kidx[None] == bg[:, None]).float()[:, :, None, None].expand(nb, kmax, n, n).contiguous()
    dl = comp["dead_leaves"]
    everyone = torch.ones(nb, dtype=torch.bool, device=dev)
    if dl["enabled"]:
        n_leaves = torch.randint(int(dl["leaves"][0]), int(dl["leaves"][1]) + 1, (nb,), generator=g, device=dev)
        radii = _paint_leaves(ncfg, g, maps, None, everyone, n_leaves, n_mat, float(dl["r_min_px"]),
                              float(dl["r_max_fraction"]) * n, float(dl["exponent"]))
    else:  # ablation: 12 large leaves of uniform size
        n_leaves = torch.full((nb,), 12, device=dev)
        radii = _paint_leaves(ncfg, g, maps, None, everyone, n_leaves, n_mat, 0.25 * n, 0.2500001 * n, 0.0)
    # depth layers: a foreground dead-leaves layer, each layer defocused by the optics, composited front over back
    depth = comp["depth_layers"]
    fg_on = (_u(g, (nb,), device=dev) < float(depth["probability"])) if depth["enabled"] else torch.zeros(
        nb, dtype=torch.bool, device=dev)
    levels = torch.tensor([float(v) for v in depth["defocus_diopters"]], dtype=f64, device=dev)
    d_back = levels[torch.randint(0, levels.numel(), (nb,), generator=g, device=dev)]
    d_front = levels[torch.randint(0, levels.numel(), (nb,), generator=g, device=dev)]
    fg_cov = torch.zeros(nb, dtype=f64, device=dev)
    if bool(fg_on.any()):
        fg = torch.zeros_like(maps)
        alpha = torch.zeros(nb, n, n, device=dev)
        lo, hi = int(depth["foreground_leaves"][0]), int(depth["foreground_leaves"][1])
        n_fg = torch.where(fg_on, torch.randint(lo, hi + 1, (nb,), generator=g, device=dev), 0)
        _paint_leaves(ncfg, g, fg, alpha, fg_on, n_fg, n_mat, 0.08 * n, 0.35 * n, 3.0)
        fg_cov = alpha.to(f64).mean((1, 2))
        optics = _layer_optics(float(depth["f_number"]), float(depth["focal_length_m"]))
        pitch = float(depth["pixel_size_m"])
        for level in sorted(set(levels.tolist())):
            if level <= 0:
                continue
            back = (fg_on & (d_back == level)).nonzero().reshape(-1)
            if back.numel():
                maps[back] = optics.defocus_maps(maps[back].reshape(-1, n, n), pitch, level).reshape(-1, kmax, n, n)
            front = (fg_on & (d_front == level)).nonzero().reshape(-1)
            if front.numel():
                both = torch.cat([fg[front], alpha[front, None]], 1).reshape(-1, n, n)
                both = optics.defocus_maps(both, pitch, level).reshape(-1, kmax + 1, n, n)
                fg[front], alpha[front] = both[:, :-1], both[:, -1]
        a4 = alpha[:, None]
        maps = torch.where(fg_on[:, None, None, None], maps * (1 - a4) + fg, maps)  # fg premultiplied by coverage
    fd = comp["fine_detail"]
    fd_on = (_u(g, (nb,), device=dev) < float(fd["probability"])) if fd["enabled"] else torch.zeros(
        nb, dtype=torch.bool, device=dev)
    fd_count = torch.zeros(nb, dtype=torch.long, device=dev)
    if bool(fd_on.any()):
        maps, fd_count = _fine_detail(ncfg, g, maps, fd_on, n_mat)
    # colour correlation: one achromatic 1/f^s shading field (on), or a fine blend towards another material (off)
    cc = comp["colour_correlation"]
    s = _u(g, (nb,), *_rng(cc["exponent"]), device=dev)
    contrast = _u(g, (nb,), *_rng(cc["contrast"]), device=dev)
    shading = field(s)
    if cc["enabled"]:
        maps = maps * torch.exp(shading * contrast[:, None, None]).float()[:, None]
    else:
        t = (_tex.normal_cdf(shading) * (2 * contrast).clamp_max(1.0)[:, None, None]).float()[:, None]
        prev = torch.remainder(kidx[None] - 1, n_mat[:, None])  # natural: maps.roll(1, 0) over the n_mat materials
        rolled = torch.gather(maps, 1, prev[:, :, None, None].expand_as(maps)) * (kidx[None] < n_mat[:, None]).float(
        )[:, :, None, None]
        maps = maps * (1 - t) + rolled * t
    body = maps
    # grain: three independent log-normal layers (Newson et al. 2017) with the dye bands' spectra
    gr = comp["grain"]
    dyes = grain_dyes(ncfg, wl.cpu()).to(dev)
    grain_on = (_u(g, (nb,), device=dev) < float(gr["probability"])) if gr["enabled"] else torch.zeros(
        nb, dtype=torch.bool, device=dev)
    spectra_r = refl
    if bool(grain_on.any()):
        glo, ghi = _rng(gr["amplitude"])
        if not 0 < glo <= ghi:
            raise ValueError(f"grain: expected 0 < amplitude[0] <= amplitude[1] (fractions of a white), got "
                             f"{[glo, ghi]}")
        amp = torch.exp(_u(g, (nb,), math.log(glo), math.log(ghi), device=dev))
        sg = _u(g, (nb,), *_rng(gr["exponent"]), device=dev)
        cg = float(gr["contrast"])
        noise3 = torch.stack([field(sg) for _ in range(3)], 1)
        grain = (amp[:, None, None, None] * torch.exp(cg * noise3 - 0.5 * cg**2)).float()
        maps = torch.cat([maps, grain * grain_on[:, None, None, None]], 1)
        spectra_r = torch.cat([spectra_r, dyes[None].expand(nb, -1, -1)], 1)
    rel = gr["relative"]
    rel_on = (_u(g, (nb,), device=dev) < float(rel["probability"])) if gr["enabled"] and rel["probability"] > 0 \
        else torch.zeros(nb, dtype=torch.bool, device=dev)
    if bool(rel_on.any()):
        # r(l) sum_k d_k(l) m_k(x) per material (Beer-Lambert); items without it keep their map in layer 0
        rc = _u(g, (nb,), *_rng(rel["contrast"]), device=dev)
        s_rel = _u(g, (nb,), *_rng(gr["exponent"]), device=dev)
        mod = torch.stack([torch.exp(rc[:, None, None] * field(s_rel) - 0.5 * rc[:, None, None] ** 2)
                           for _ in range(3)], 1).float()  # [B, 3, n, n]
        keep = torch.tensor([1.0, 0.0, 0.0], device=dev)[None, :, None, None]
        mod = torch.where(rel_on[:, None, None, None], mod, keep)
        split = (maps[:, :kmax, None] * mod[:, None]).flatten(1, 2)
        layer_spec = torch.where(rel_on[:, None, None, None], refl[:, :, None] * dyes[None, None],
                                 refl[:, :, None].expand(-1, -1, 3, -1)).flatten(1, 2)
        maps = torch.cat([split, maps[:, kmax:]], 1)
        spectra_r = torch.cat([layer_spec, spectra_r[:, kmax:]], 1)
    sp = comp["specular"]
    spec_on = (_u(g, (nb,), device=dev) < float(sp["probability"])) if sp["enabled"] and sp["probability"] > 0 \
        else torch.zeros(nb, dtype=torch.bool, device=dev)
    if bool(spec_on.any()):
        # dichromatic reflection (Shafer 1985), neutral interface (Lee, Breneman & Schulte 1990): a log-normal sheen
        # in proportion to the glossy materials' body maps, with the illuminant's spectrum
        samp = torch.exp(_u(g, (nb,), *map(math.log, _rng(sp["amplitude"])), device=dev))
        ss_ = _u(g, (nb,), *_rng(sp["exponent"]), device=dev)
        sc = _u(g, (nb,), *_rng(sp["contrast"]), device=dev)
        glossy = (_u(g, (nb, kmax), device=dev) < float(sp["glossy_fraction"])).float()
        tex = torch.exp(sc[:, None, None] * field(ss_) - 0.5 * sc[:, None, None] ** 2)
        spec = (samp[:, None, None] * tex).float() * (glossy[:, :, None, None] * body).sum(1)
        maps = torch.cat([maps, (spec * spec_on[:, None, None])[:, None]], 1)
        spectra_r = torch.cat([spectra_r, torch.ones(nb, 1, spectra_r.shape[-1], dtype=f64, device=dev)], 1)
    # lights: maps x (1 - m) under light 1 and maps x m under light 2 (mixed items), the crop, the mean luminance
    scale_cfg = float(ncfg["mean_radiance_scale"])
    top, left = (n - h) // 2, (n - w) // 2
    maps = maps[:, :, top:top + h, left:left + w]
    mix_field = mix_field[:, top:top + h, left:left + w][:, None]
    spectra = spectra_r * (e1 * scale_cfg)[:, None]
    if bool(mixed.any()):
        m = torch.where(mixed[:, None, None, None], mix_field, torch.zeros((), device=dev))
        maps = torch.cat([maps * (1 - m), maps * m], 1)
        spectra = torch.cat([spectra, spectra_r * (e2 * ratio[:, None] * scale_cfg)[:, None]], 1)
    maps = maps.to(dtype)
    lum = spectra @ _luminance_weights(wl.cpu()).to(dev)  # [B, J]
    mean_lum = (maps.sum((-2, -1)).to(f64) * lum).sum(-1) / (h * w)
    target = _log_uniform(cfg["mean_luminance_cd_m2"], _u(g, (nb,), device=dev))
    k_scale = target / mean_lum.clamp_min(torch.finfo(f64).tiny)
    f_code = 10 + (ui[:, 2] * 12).long().clamp(0, 11) + 1
    codes = torch.tensor([1, 0, -1, 2], device=dev)  # blackbody, daylight, (fluorescent), led
    ill_code = torch.where(kind1 == 2, f_code, codes[kind1])
    meta = {"cct_k": cct1, "illuminant_code": ill_code, "hdr_decades": torch.zeros(nb, dtype=f64, device=dev),
            "mean_luminance_cd_m2": target, "materials": n_mat, "mixed_light": mixed, "leaf_radius": radii,
            "leaf_count": n_leaves, "foreground": fg_on, "foreground_coverage": fg_cov,
            "defocus_back_diopters": torch.where(fg_on, d_back, 0.0),
            "defocus_front_diopters": torch.where(fg_on, d_front, 0.0), "fine_detail_items": fd_count,
            "grain": grain_on, "relative_grain": rel_on, "specular": spec_on}
    used = maps.flatten(2).amax(-1) > 0
    return {"maps": maps, "used": used, "spectra": spectra * k_scale[:, None, None],
            "white": e1 * scale_cfg * k_scale[:, None], "wavelengths_nm": wl, "meta": meta}
