"""Batched scene draws on any device: the layouts distribution of :mod:`.scenes` as tensor programs over a batch.

:func:`draw_layout_scenes` draws ``B`` scenes at once with one ``torch.Generator`` on the batch's device: the same
distribution as :func:`isettorch.data.scenes.generate_scene` (the same layouts, palettes, illuminants, second
lights, shadows, HDR illumination and mean luminance, with the same parameter ranges; see that module's notes), but
not the same random numbers: a per-item generator draws scalars one by one, this module draws each parameter as a
``[B]`` (or ``[B, N]``) tensor, so a batch is one pass of tensor operations per layout kind instead of a Python loop
over items. ``tests/data/test_stream.py`` checks that both give the same summary statistics (luminance, colour,
gradients, leaf sizes).

Variable counts (400-800 leaves, 1-5 edges, 3-12 lines, 2-6 glyphs of 2-5 strokes) are drawn per item and padded to
the maximum with inactive entries, so every item of a batch has the same tensor shapes.
"""

from __future__ import annotations

import functools
import math

import torch

from . import spectra as _spectra
from .scenes import _luminance_weights, _white_photons

__all__ = ["draw_layout_scenes", "LAYOUT_CODES", "ILLUMINANT_KIND_CODES", "paint_leaves"]

LAYOUT_CODES = ("dead_leaves", "edges", "gradients", "lines", "textures")  # sorted, as scenes._choice orders them
ILLUMINANT_KIND_CODES = ("blackbody", "daylight", "fluorescent", "led")  # sorted
_DEFAULT_CCT = {"daylight": (4000.0, 25000.0), "blackbody": (2000.0, 10000.0), "led": (2700.0, 6500.0)}


def _u(g, shape, lo=0.0, hi=1.0, *, device, dtype=torch.float64):
    r = torch.rand(shape, generator=g, device=device, dtype=dtype)
    if lo == 0.0 and hi > 0.0:  # the same values without the no-op multiply by 1 and add of 0
        return r if hi == 1.0 else r * hi
    return r * (hi - lo) + lo


def _ri(g, lo: int, hi: int, shape, *, device):
    """Integers in [lo, hi] inclusive."""
    return torch.randint(lo, hi + 1, shape, generator=g, device=device)


def _log_uniform(rng, u: torch.Tensor) -> torch.Tensor:
    lo, hi = (float(rng), float(rng)) if isinstance(rng, (int, float)) else (float(rng[0]), float(rng[1]))
    if lo > 0:
        return torch.exp(math.log(lo) + u * (math.log(hi) - math.log(lo)))
    return lo + u * (hi - lo)


def _uniform(rng, u: torch.Tensor) -> torch.Tensor:
    lo, hi = (float(rng), float(rng)) if isinstance(rng, (int, float)) else (float(rng[0]), float(rng[1]))
    return lo + u * (hi - lo)


def _choice(weights: dict, u: torch.Tensor, names: tuple) -> torch.Tensor:
    """Codes (indices into ``names``, which are sorted) drawn with probability proportional to ``weights`` by the
    inverse CDF of ``u`` [B] (as :func:`isettorch.data.scenes._choice`); zero weights are never drawn."""
    cum, total = _cumulative(tuple(float(weights.get(n, 0.0)) for n in names), str(u.device))
    idx = torch.searchsorted(cum, (u * total).contiguous(), right=True)
    return idx.clamp_max(len(names) - 1)


@functools.lru_cache(maxsize=64)
def _cumulative(weights: tuple, device: str) -> tuple[torch.Tensor, float]:
    """The cumulative weights on ``device`` and their total (memoised: drawn a few times per batch)."""
    cum = torch.cumsum(torch.tensor(weights, dtype=torch.float64), 0)
    return cum.to(device), float(cum[-1])


@functools.lru_cache(maxsize=32)
def _grid(h, w, device, dtype):
    """Row and column coordinates ``[H, W]`` (read-only views, memoised per size, device and dtype)."""
    y = torch.arange(h, device=device, dtype=dtype)[:, None].expand(h, w)
    x = torch.arange(w, device=device, dtype=dtype)[None, :].expand(h, w)
    return y, x


def _grating(arg: torch.Tensor, square: torch.Tensor) -> torch.Tensor:
    s = torch.sin(arg)
    return torch.where(square, (s >= 0).to(s.dtype), 0.5 + 0.5 * s)


# --- dead leaves -----------------------------------------------------------------------------------------------

def paint_leaves(h: int, w: int, batch: torch.Tensor, cy, cx, r, theta, aspect, shape, nb: int) -> torch.Tensor:
    """Index (drawing order within its item) of the topmost leaf at each pixel ``[nb, H, W]``; 0 where none covers.

    ``batch`` (long), ``cy, cx, r, theta, aspect`` (float64) and ``shape`` (0 disk, 1 rotated rectangle, 2 ellipse)
    are ``[N]`` over the leaves of all items, in drawing order within each item. The algorithm of
    :func:`isettorch.data.layouts._paint_leaves`: a convex leaf covers one run of pixel centres per image row,
    solved in closed form; the covered pixels are enumerated and the painter's order resolved by a scatter-max,
    here in torch over the whole batch (one program, any device).
    """
    dev = cy.device
    if cy.numel() == 0:
        return torch.zeros(nb, h, w, dtype=torch.long, device=dev)
    counts = torch.bincount(batch, minlength=nb)
    starts = torch.cumsum(counts, 0) - counts
    # each leaf's rank among its item's leaves, also when the items' leaves are interleaved (arange - start alone
    # assumed them grouped: [0, 1, 0, 1] had painted item 0's second leaf as 2 and item 1's first as none)
    perm = torch.argsort(batch, stable=True)
    order = torch.empty_like(batch)
    order[perm] = torch.arange(batch.numel(), device=dev) - starts[batch[perm]]
    sn, cs = torch.sin(theta), torch.cos(theta)
    ra = r * aspect
    asn, acs = sn.abs(), cs.abs()
    ey = torch.where(shape == 1, r * asn + ra * acs, torch.sqrt((r * asn) ** 2 + (ra * acs) ** 2))
    ey = torch.where(shape == 0, r, ey)
    y0 = torch.clamp(torch.ceil(cy - ey), 0, h).long()
    nrows = (torch.clamp(torch.floor(cy + ey).long() + 1, 0, h) - y0).clamp_min(0)
    leaf = torch.repeat_interleave(torch.arange(cy.numel(), device=dev), nrows)
    y = y0[leaf] + (torch.arange(leaf.numel(), device=dev) - torch.repeat_interleave(torch.cumsum(nrows, 0) - nrows,
                                                                                         nrows))
    dy = y.to(torch.float64) - cy[leaf]
    rr, rra, c, s, sh = r[leaf], ra[leaf], cs[leaf], sn[leaf], shape[leaf]
    inf = torch.full_like(dy, math.inf)
    # disk: dx^2 <= r^2 - dy^2
    q = rr * rr - dy * dy
    hd = torch.sqrt(q.clamp_min(0))
    lo_d, hi_d = torch.where(q >= 0, -hd, inf), torch.where(q >= 0, hd, -inf)

    def interval(k, o, b):  # |k dx + o| <= b, for k == 0 everything or nothing
        safe = torch.where(k == 0, torch.ones_like(k), k)
        e1, e2 = (-b - o) / safe, (b - o) / safe
        ok = o.abs() <= b
        lo = torch.where(k == 0, torch.where(ok, -inf, inf), torch.minimum(e1, e2))
        hi = torch.where(k == 0, torch.where(ok, inf, -inf), torch.maximum(e1, e2))
        return lo, hi

    # rectangle: two slabs
    l1, h1 = interval(c, dy * s, rr)
    l2, h2 = interval(-s, dy * c, rra)
    lo_r, hi_r = torch.maximum(l1, l2), torch.minimum(h1, h2)
    # ellipse: A dx^2 + B dx + C <= 0
    ir2, ia2 = 1 / (rr * rr), 1 / (rra * rra)
    qa = c * c * ir2 + s * s * ia2
    qb = 2 * dy * c * s * (ir2 - ia2)
    qc = dy * dy * (s * s * ir2 + c * c * ia2) - 1
    disc = qb * qb - 4 * qa * qc
    sd = torch.sqrt(disc.clamp_min(0))
    lo_e = torch.where(disc >= 0, (-qb - sd) / (2 * qa), inf)
    hi_e = torch.where(disc >= 0, (-qb + sd) / (2 * qa), -inf)
    lo = torch.where(sh == 0, lo_d, torch.where(sh == 1, lo_r, lo_e))
    hi = torch.where(sh == 0, hi_d, torch.where(sh == 1, hi_r, hi_e))
    c_x = cx[leaf]
    xl = torch.clamp(torch.ceil(c_x + lo), 0, w).long()
    xr = torch.clamp(torch.floor(c_x + hi), -1, w - 1).long()
    cnt = (xr - xl + 1).clamp_min(0)
    base = (batch[leaf] * h + y) * w + xl - (torch.cumsum(cnt, 0) - cnt)
    pix = torch.repeat_interleave(base, cnt) + torch.arange(int(cnt.sum()), device=dev)
    top = torch.zeros(nb * h * w, dtype=torch.long, device=dev)
    top.scatter_reduce_(0, pix, torch.repeat_interleave(order[leaf] + 1, cnt), reduce="amax")
    return (top.clamp_min(1) - 1).reshape(nb, h, w)


def _dead_leaves(nb, h, w, k, g, device, dtype):
    n_max = 800
    n = _ri(g, 400, 800, (nb,), device=device)
    rmin, rmax = 2.5, 0.6 * max(h, w)
    u = _u(g, (nb, n_max), device=device)
    r = (rmin**-2 - u * (rmin**-2 - rmax**-2)) ** -0.5  # p(r) ~ r^-3 (Lee, Mumford & Huang 2001), inverse CDF
    lo = torch.tensor([-0.1 * h, -0.1 * w, 0.0, 0.3, 0.02, 0.0, 0.0], dtype=torch.float64, device=device)
    hi = torch.tensor([1.1 * h, 1.1 * w, math.pi, 1.0, 0.45, math.pi, 2 * math.pi], dtype=torch.float64,
                      device=device)
    cy, cx, theta, aspect, freq, tdir, phase = (torch.rand(7, nb, n_max, generator=g, device=device,
                                                           dtype=torch.float64) * (hi - lo)[:, None, None]
                                                + lo[:, None, None]).unbind(0)
    shape = _ri(g, 0, 2, (nb, n_max), device=device)
    ca, cb = _ri(g, 0, k - 1, (nb, n_max), device=device), _ri(g, 0, k - 1, (nb, n_max), device=device)
    tex = _ri(g, 0, 3, (nb, n_max), device=device)  # 0, 1 flat, 2 grating, 3 gradient
    sq = _ri(g, 0, 1, (nb, n_max), device=device)
    active = torch.arange(n_max, device=device)[None, :] < n[:, None]
    bi, li = active.nonzero(as_tuple=True)
    top = paint_leaves(h, w, bi, cy[bi, li], cx[bi, li], r[bi, li], theta[bi, li], aspect[bi, li], shape[bi, li], nb)
    flat = top.reshape(nb, -1)

    def at(v):
        return torch.gather(v, 1, flat).reshape(nb, h, w)

    ca_, sa_ = torch.cos(tdir), torch.sin(tdir)
    k_g = 2 * math.pi * freq
    half = 0.5 / r
    y, x = _grid(h, w, device, dtype)
    gx, gy, g0, rx, ry, r0 = (at(v).to(dtype) for v in (k_g * ca_, k_g * sa_, phase, ca_ * half, sa_ * half,
                                                        0.5 - (cx * ca_ + cy * sa_) * half))
    tx = at(tex)
    grat = _grating(gx * x + gy * y + g0, at(sq) == 1)
    rel = (rx * x + ry * y + r0).clamp(0, 1)
    t = torch.where(tx == 2, grat, torch.where(tx == 3, rel, torch.zeros_like(grat)))
    return at(ca), at(cb), t, {"leaf_radius": r, "leaf_count": n}


def _gradients(nb, h, w, k, g, device, dtype):
    y, x = _grid(h, w, device, dtype)
    yn, xn = y / max(h - 1, 1), x / max(w - 1, 1)
    radial = _ri(g, 0, 1, (nb, 1, 1), device=device) == 1
    a, cy, cx, f1, f2, p1 = (v.to(dtype) for v in _u(g, (6, nb, 1, 1), device=device).unbind(0))
    a, f1, f2, p1 = a * 2 * math.pi, 0.2 + 1.8 * f1, f2 * math.pi, p1 * 2 * math.pi
    rad = torch.sqrt((yn - cy) ** 2 + (xn - cx) ** 2 + 1e-12) / math.sqrt(2)
    lin = (xn - 0.5) * torch.cos(a) + (yn - 0.5) * torch.sin(a) + 0.5
    mod = 0.15 * torch.sin(2 * math.pi * f1 * (xn * torch.cos(f2) + yn * torch.sin(f2)) + p1)
    t = torch.where(radial, rad, lin) + mod
    t_min, t_max = t.amin(dim=(1, 2), keepdim=True), t.amax(dim=(1, 2), keepdim=True)
    t = (t - t_min) / (t_max - t_min).clamp_min(1e-6)
    ia = _ri(g, 0, k - 1, (nb, 1, 1), device=device).expand(nb, h, w)
    ib = _ri(g, 0, k - 1, (nb, 1, 1), device=device).expand(nb, h, w)
    return ia, ib, t, {}


def _cells(nb, h, w, g, n_lines: torch.Tensor, n_max: int, device, dtype):
    """Cell code of an arrangement of ``n_lines`` [B] random lines (bit i = side of line i), ``[B, H, W]``."""
    y, x = _grid(h, w, device, dtype)
    a = _u(g, (nb, n_max, 1, 1), hi=math.pi, device=device).to(dtype)
    py = _u(g, (nb, n_max, 1, 1), 0.15 * h, 0.85 * h, device=device).to(dtype)
    px = _u(g, (nb, n_max, 1, 1), 0.15 * w, 0.85 * w, device=device).to(dtype)
    side = ((x - px) * torch.sin(a) - (y - py) * torch.cos(a)) > 0  # [B, n, H, W]
    bit = torch.arange(n_max, device=device)
    active = (bit[None, :] < n_lines[:, None]).long()
    return (side.long() * (active << bit)[:, :, None, None]).sum(1)


def _edges(nb, h, w, k, g, device, dtype):
    n_lines = _ri(g, 1, 5, (nb,), device=device)
    code = _cells(nb, h, w, g, n_lines, 5, device, dtype)
    colours = _ri(g, 0, k - 1, (nb, 32), device=device)
    ia = torch.gather(colours, 1, code.reshape(nb, -1)).reshape(nb, h, w)
    return ia, ia, torch.zeros(nb, h, w, device=device, dtype=dtype), {}


def _segment_cover(y, x, ay, ax, by, bx, wid):
    """Coverage ``clamp(wid / 2 + 0.5 - distance, 0, 1)`` of segments ``[..., 1, 1]`` at pixels ``(y, x)``."""
    vy, vx = by - ay, bx - ax
    wy, wx = y - ay, x - ax
    tt = ((wy * vy + wx * vx) / (vy * vy + vx * vx).clamp_min(1e-9)).clamp(0, 1)
    dist = torch.sqrt((wy - tt * vy) ** 2 + (wx - tt * vx) ** 2 + 1e-12)
    return (wid / 2 + 0.5 - dist).clamp(0, 1)


def _lines(nb, h, w, k, g, device, dtype):
    y, x = _grid(h, w, device, dtype)
    n_lines = _ri(g, 3, 12, (nb,), device=device)
    a = _u(g, (nb, 12, 1, 1), hi=math.pi, device=device)
    py, px = _u(g, (nb, 12, 1, 1), hi=h, device=device), _u(g, (nb, 12, 1, 1), hi=w, device=device)
    lw = _u(g, (nb, 12, 1, 1), 0.5, 3.0, device=device)
    on = torch.arange(12, device=device)[None, :, None, None] < n_lines[:, None, None, None]
    dist = ((y - py.to(dtype)) * torch.cos(a).to(dtype) - (x - px.to(dtype)) * torch.sin(a).to(dtype)).abs()
    cover = torch.where(on, (lw.to(dtype) / 2 + 0.5 - dist).clamp(0, 1), torch.zeros((), dtype=dtype,
                                                                                        device=device)).amax(1)
    # 2-6 glyphs of 2-5 strokes (stroke 0.7-2.5 px), each a polyline of random points in a box of its size
    n_glyphs = _ri(g, 2, 6, (nb,), device=device)
    size = _u(g, (nb, 6, 1), 6.0, 0.3 * min(h, w) + 6.0, device=device)
    gy, gx = _u(g, (nb, 6, 1), hi=h, device=device), _u(g, (nb, 6, 1), hi=w, device=device)
    ns = _ri(g, 2, 5, (nb, 6), device=device)
    pts_y = gy + size * _u(g, (nb, 6, 6), device=device)
    pts_x = gx + 0.7 * size * _u(g, (nb, 6, 6), device=device)
    sw = _u(g, (nb, 6), 0.7, 2.5, device=device)
    stroke_on = ((torch.arange(6, device=device)[None, :] < n_glyphs[:, None])[:, :, None]
                 & (torch.arange(5, device=device)[None, None, :] < ns[:, :, None]))

    # each glyph's strokes lie in [gy, gy + size] x [gx, gx + 0.7 size]: evaluated on a window of that size (plus
    # the strokes' reach, <= 1.75 px) at the glyph, not on the whole image, and scatter-maxed into the image
    reach = 2
    largest = 0.3 * min(h, w) + 6.0
    sy, sx = int(math.ceil(largest)) + 2 * reach + 1, int(math.ceil(0.7 * largest)) + 2 * reach + 1
    oy, ox = torch.floor(gy).long() - reach, torch.floor(gx).long() - reach  # [B, 6, 1]
    wy = (oy[..., None] + torch.arange(sy, device=device)[None, None, :, None])  # [B, 6, sy, 1]
    wx = (ox[..., None] + torch.arange(sx, device=device)[None, None, None, :])  # [B, 6, 1, sx]

    def seg(v):
        return v.to(dtype)[:, :, :, None, None]  # [B, 6, 5, 1, 1]

    cov = _segment_cover(wy.to(dtype)[:, :, None], wx.to(dtype)[:, :, None], seg(pts_y[:, :, :-1]),
                         seg(pts_x[:, :, :-1]), seg(pts_y[:, :, 1:]), seg(pts_x[:, :, 1:]),
                         seg(sw[:, :, None].expand(nb, 6, 5)))  # [B, 6, 5, sy, sx]
    cov = torch.where(stroke_on.reshape(nb, 6, 5, 1, 1), cov, torch.zeros((), dtype=dtype, device=device)).amax(2)
    inside = (wy >= 0) & (wy < h) & (wx >= 0) & (wx < w)  # [B, 6, sy, sx]
    pix = (torch.arange(nb, device=device)[:, None, None, None] * h + wy.clamp(0, h - 1)) * w + wx.clamp(0, w - 1)
    strokes = torch.zeros(nb * h * w, dtype=dtype, device=device)
    strokes.scatter_reduce_(0, pix[inside], cov[inside], reduce="amax")
    strokes = strokes.reshape(nb, h, w)
    ia = _ri(g, 0, k - 1, (nb, 1, 1), device=device).expand(nb, h, w)
    ib = _ri(g, 0, k - 1, (nb, 1, 1), device=device).expand(nb, h, w)
    return ia, ib, torch.maximum(cover, strokes), {}


def _textures(nb, h, w, k, g, device, dtype):
    y, x = _grid(h, w, device, dtype)
    n_split = _ri(g, 0, 1, (nb,), device=device)
    code = _cells(nb, h, w, g, n_split, 1, device, dtype)  # region 0 or 1
    kind = _ri(g, 0, 3, (nb, 2, 1, 1), device=device)
    f, a, ph, cy, cx = (v.to(dtype) for v in _u(g, (5, nb, 2, 1, 1), device=device).unbind(0))
    f, a, ph, cy, cx = 0.15 + 0.8 * f, a * math.pi, ph * 2 * math.pi, cy * h, cx * w
    ca, sa = torch.cos(a), torch.sin(a)
    u_ = x * ca + y * sa
    grat = _grating(2 * math.pi * f * u_ + ph, kind == 1)
    checker = (torch.floor(2 * f * u_) + torch.floor(2 * f * (-x * sa + y * ca))) % 2
    zone = 0.5 + 0.5 * torch.cos(math.pi * f / max(h, w) * ((x - cx) ** 2 + (y - cy) ** 2) + ph)
    pat = torch.where(kind <= 1, grat, torch.where(kind == 2, checker, zone))  # [B, 2, H, W]
    cols = _ri(g, 0, k - 1, (nb, 2, 2), device=device)
    sel = code[:, None]
    t = torch.gather(pat, 1, sel)[:, 0]
    ia = torch.gather(cols[:, :, 0], 1, code.reshape(nb, -1)).reshape(nb, h, w)
    ib = torch.gather(cols[:, :, 1], 1, code.reshape(nb, -1)).reshape(nb, h, w)
    return ia, ib, t, {}


_LAYOUT_FNS = {"dead_leaves": _dead_leaves, "edges": _edges, "gradients": _gradients, "lines": _lines,
               "textures": _textures}


# --- spectra -----------------------------------------------------------------------------------------------------

def _reflectances(nb, k, wl, g, model, pca_fraction, device):
    """``[B, K, L]`` palette reflectances: PCA of measured sets or sigmoid polynomials (Jakob & Hanika 2019), the
    models of :func:`isettorch.data.spectra.random_reflectances`, on the device (float64)."""
    grid = tuple(wl.tolist())
    mean, basis, std = _spectra._pca_on_grid(8, grid, torch.float64, str(device))
    margin = 1e-3
    u = (wl - 550.0) / 150.0
    pca_coef = torch.randn(nb, k, std.numel(), generator=g, device=device, dtype=torch.float64)
    sig_coef = torch.randn(nb, k, 3, generator=g, device=device, dtype=torch.float64)
    pick = torch.rand(nb, k, 1, generator=g, device=device, dtype=torch.float64)
    scale = torch.tensor([3.0, 2.5, 1.5], dtype=torch.float64, device=device)
    pca = _spectra._pca_reflectances(pca_coef, mean, basis, std, 1 - margin - mean, mean - margin, xp=torch)
    sig = _spectra._sigmoid_polynomial((sig_coef * scale).reshape(-1, 3), u, torch).reshape(nb, k, -1)
    if model == "pca":
        return pca
    if model == "sigmoid":
        return sig
    return torch.where(pick < pca_fraction, pca, sig)


def _illuminants(kind: torch.Tensor, u: torch.Tensor, u_f: torch.Tensor, wl, lo_k: dict, hi_k: dict):
    """Illuminant SPDs ``[B, L]`` (energy) and CCTs ``[B]`` for kind codes (:data:`ILLUMINANT_KIND_CODES`): CCT
    uniform in mired within each item's range for its kind (``lo_k[name], hi_k[name]``: ``[B]``; from ``u``),
    fluorescent F1-F12 (from ``u_f``), as :func:`isettorch.data.spectra.random_illuminant` (the same spectral
    models, batched). Each continuous model is evaluated only on the items of its kind."""
    grid = tuple(wl.tolist())
    nb, dev = kind.shape[0], wl.device
    spd = torch.zeros(nb, len(grid), dtype=torch.float64, device=dev)
    cct = torch.zeros(nb, dtype=torch.float64, device=dev)
    for code, name in enumerate(ILLUMINANT_KIND_CODES):
        idx = (kind == code).nonzero().reshape(-1)
        if idx.numel() == 0:
            continue
        if name == "fluorescent":
            num = (u_f[idx] * 12).long().clamp(0, 11)
            spd[idx] = torch.from_numpy(_spectra._fluorescent_table(grid)).to(dev)[num]
            cct[idx] = torch.tensor([_spectra._fluorescent_cct(i + 1) for i in range(12)], dtype=torch.float64,
                                    device=dev)[num]
            continue
        lo, hi = lo_k[name][idx], hi_k[name][idx]
        t = 1e6 / (1e6 / hi + u[idx] * (1e6 / lo - 1e6 / hi))
        if name == "daylight":
            spd[idx] = _spectra._daylight(t, grid, torch)
        elif name == "blackbody":
            spd[idx] = _spectra._blackbody(t[:, None], grid, torch)
        else:
            spd[idx] = _spectra._led(t, *_spectra._led_params(t, None, None, None, torch), grid, None, torch)
        cct[idx] = t
    return spd, cct


def _smooth_field(nb, h, w, g, device, dtype, max_cycles: float = 1.5) -> torch.Tensor:
    """Sum of three random low-frequency plane waves per item, rescaled to span exactly [0, 1] ``[B, H, W]``
    (:func:`isettorch.data.scenes._smooth_field`)."""
    fr = _u(g, (nb, 3, 1), 0.3, max_cycles, device=device)
    a = _u(g, (nb, 3, 1), hi=math.pi, device=device)
    ph = _u(g, (nb, 3, 1), hi=2 * math.pi, device=device)
    y = torch.linspace(0.0, 1.0, h, dtype=torch.float64, device=device)[None, None, :]
    x = torch.linspace(0.0, 1.0, w, dtype=torch.float64, device=device)[None, None, :]
    # each plane wave is separable, sin(A x + B y + p) = sin(A x) cos(B y + p) + cos(A x) sin(B y + p): a rank-6
    # product [H, 6] @ [6, W] per item instead of three full-image sines
    ay, ax = 2 * math.pi * fr * torch.sin(a) * y + ph, 2 * math.pi * fr * torch.cos(a) * x  # [B, 3, H], [B, 3, W]
    f = torch.cat([torch.cos(ay), torch.sin(ay)], 1).transpose(1, 2) @ torch.cat([torch.sin(ax), torch.cos(ax)], 1)
    lo, hi = f.amin(dim=(1, 2), keepdim=True), f.amax(dim=(1, 2), keepdim=True)
    return ((f - lo) / (hi - lo).clamp_min(1e-6)).to(dtype)


# --- scenes ------------------------------------------------------------------------------------------------------

def draw_layout_scenes(nb: int, g: torch.Generator, cfg: dict, *, size: tuple[int, int], device,
                       dtype=torch.float32) -> dict:
    """``nb`` scenes of the layouts distribution ``cfg`` (a merged scene config, :data:`SCENE_DEFAULTS`) drawn with
    ``g`` on ``device``: the factors of ``L(x, l) = k gain(x) R(x, l) (a(x) E1(l) + b(x) E2(l))``
    (:mod:`isettorch.data.scenes`), returned as

    ``maps [B, J, H, W]`` (``dtype``), ``terms [B]`` (item b's terms are its first ``terms[b]``: the palette
    colours it uses under each of its lights; its later maps and spectra are 0), ``used [B, J]`` (``j < terms[b]``),
    ``spectra [B, J, L]`` and ``white [B, L]`` (float64, photons/s/sr/m^2/nm, mean luminance set), ``wavelengths_nm
    [L]`` (float64) and
    ``meta``: ``[B]`` tensors ``layout`` (code in
    :data:`LAYOUT_CODES`), ``illuminant_kind`` (code in :data:`ILLUMINANT_KIND_CODES`), ``illuminant_code``
    (:data:`isettorch.data.camera_pairs.ILLUMINANT_CODES`), ``cct_k``, ``two_lights``, ``shadow``,
    ``hdr_decades``, ``mean_luminance_cd_m2`` and, for dead leaves, ``leaf_radius [B, 800]`` / ``leaf_count``.
    J is the most terms an item has (at most ``2 K``: K palette colours under each of two lights).
    """
    h, w = size
    k = int(cfg["palette_size"])
    start, stop, step = cfg["wavelengths_nm"]
    from .. import spectral

    wl = spectral.default_wavelengths(start, stop, step, dtype=torch.float64, device=device)
    layout = _choice(cfg["layouts"], _u(g, (nb,), device=device), LAYOUT_CODES)
    pal = _reflectances(nb, k, wl, g, cfg["reflectance_model"], float(cfg["pca_fraction"]), device)
    ia = torch.zeros(nb, h, w, dtype=torch.long, device=device)
    ib = torch.zeros_like(ia)
    t = torch.zeros(nb, h, w, dtype=dtype, device=device)
    extra = {}
    for code, name in enumerate(LAYOUT_CODES):
        idx = (layout == code).nonzero().reshape(-1)
        if idx.numel() == 0:
            continue
        a_, b_, t_, ex = _LAYOUT_FNS[name](idx.numel(), h, w, k, g, device, dtype)
        ia[idx], ib[idx], t[idx] = a_, b_, t_
        for key, v in ex.items():
            full = torch.zeros((nb, *v.shape[1:]), dtype=v.dtype, device=device)
            full[idx] = v
            extra[key] = full
    ill_w = cfg["illuminants"]
    u = _u(g, (nb, 8), device=device)
    kind1 = _choice(ill_w, u[:, 0], ILLUMINANT_KIND_CODES)
    two = u[:, 3] < float(cfg["two_light_probability"])
    shadow = (~two) & (u[:, 4] < float(cfg["shadow_probability"]))
    kind2 = torch.where(two, _choice(ill_w, u[:, 5], ILLUMINANT_KIND_CODES), 1)  # shadow: skylight (daylight)
    # CCT ranges per item: the config's, and for a shadow's skylight 7000-20000 K daylight; both lights in one call
    lo_k, hi_k = {}, {}
    for name in ("daylight", "blackbody", "led"):
        lo, hi = cfg["cct_range_k"].get(name) or _DEFAULT_CCT[name]
        lo_k[name] = torch.full((2 * nb,), float(lo), dtype=torch.float64, device=device)
        hi_k[name] = torch.full((2 * nb,), float(hi), dtype=torch.float64, device=device)
    lo_k["daylight"][nb:] = torch.where(two, lo_k["daylight"][nb:], 7000.0)
    hi_k["daylight"][nb:] = torch.where(two, hi_k["daylight"][nb:], 20000.0)
    spd, cct_both = _illuminants(torch.cat([kind1, kind2]), torch.cat([u[:, 1], u[:, 6]]),
                                 torch.cat([u[:, 2], u[:, 7]]), wl, lo_k, hi_k)
    spd1, spd2, cct1 = spd[:nb], spd[nb:], cct_both[:nb]
    e1, e2 = _white_photons(spd1, wl), _white_photons(spd2, wl)
    v = _u(g, (nb, 9), device=device)
    ratio = torch.where(two, _log_uniform(cfg["second_light_ratio"], v[:, 0]),
                        _log_uniform(cfg["shadow_ambient"], v[:, 0]))
    ang = v[:, 1] * 2 * math.pi
    py, px = (0.2 + 0.6 * v[:, 2]) * h, (0.2 + 0.6 * v[:, 3]) * w
    yy, xx = _grid(h, w, device, dtype)

    def per(v_):  # a [B] draw as a [B, 1, 1] factor in the maps' dtype
        return v_.to(dtype)[:, None, None]

    signed = (xx - per(px)) * per(torch.cos(ang)) + (yy - per(py)) * per(torch.sin(ang))
    width = (0.1 + 0.5 * v[:, 4]) * max(h, w)  # two lights: a smooth transition over 10-60 % of the image
    m = torch.sigmoid(signed / per(width / 4))
    soft = 0.3 + 2.7 * v[:, 5]  # shadow: half-plane or disk, soft edge 0.3-3 px (penumbra)
    rad = (0.15 + 0.3 * v[:, 7]) * min(h, w)
    disk = per(rad) - torch.sqrt((xx - per(px)) ** 2 + (yy - per(py)) ** 2 + 1e-12)
    sh = torch.sigmoid(torch.where((v[:, 6] < 0.5)[:, None, None], disk, signed) / per(soft))
    two_, shadow_ = two[:, None, None], shadow[:, None, None]
    decades = _uniform(cfg["hdr_decades"], v[:, 8])
    field = _smooth_field(nb, h, w, g, device, dtype)
    gain = torch.exp((field - 0.5) * per(math.log(10) * decades))  # 10^(D (f - 1/2))
    target = _log_uniform(cfg["mean_luminance_cd_m2"], _u(g, (nb,), device=device))
    lights = 2 if bool((two | shadow).any()) else 1
    # light l's field x gain: a = 1 - m, b = r m (two lights); a = 1 - s, b = r (shadow); a = 1, b = 0 (one light)
    light = torch.empty(nb, lights, h, w, dtype=dtype, device=device)
    light[:, 0] = torch.where(two_, 1 - m, torch.where(shadow_, 1 - sh, 1.0)) * gain
    if lights == 2:
        light[:, 1] = torch.where(two_, per(ratio) * m, torch.where(shadow_, per(ratio), 0.0)) * gain
    # the terms light_l [(1 - t) 1(ia = c) + t 1(ib = c)] x P_c E_l (scenes._factored_radiance) of the palette
    # colours c an item uses (as ia or ib) under its lights (two with a second light or a shadow), and only those,
    # in a compact order: item b's n_b colours (palette order) under light 1, then under light 2. The other terms
    # would be 0 everywhere; the items' terms beyond their count are 0 (maps and spectra).
    present = torch.zeros(nb, k, dtype=torch.bool, device=device)
    present.scatter_(1, ia.reshape(nb, -1), True)
    present.scatter_(1, ib.reshape(nb, -1), True)
    n_col = present.sum(1)  # [B] >= 1
    item_lights = 1 + (two | shadow).long() if lights == 2 else torch.ones_like(n_col)
    terms = n_col * item_lights
    n_terms = int(terms.max())  # one host read
    rank = present.cumsum(1) - 1  # [B, K]: a used colour's place among the item's colours
    ra, rb = rank.gather(1, ia.reshape(nb, -1)), rank.gather(1, ib.reshape(nb, -1))
    maps = torch.zeros(nb, n_terms, h * w, dtype=dtype, device=device)
    tt = t.reshape(nb, -1)
    for li in range(lights):  # a one-light item's light 2 is 0 everywhere: added (+0) to its light-1 terms
        off = (li * n_col * (item_lights - 1))[:, None]
        lt = light[:, li].reshape(nb, -1)
        maps.scatter_add_(1, (ra + off)[:, None], (lt * (1 - tt))[:, None])
        maps.scatter_add_(1, (rb + off)[:, None], (lt * tt)[:, None])
    full = torch.cat([pal * e1[:, None], pal * e2[:, None]], 1) if lights == 2 else pal * e1[:, None]
    j = torch.arange(n_terms, device=device)[None, :]
    per_light = n_col[:, None]
    colour = torch.argsort((~present).to(torch.uint8), dim=1, stable=True).gather(1, j % per_light)
    src = (j // per_light).clamp_max(lights - 1) * k + colour  # [B, J] -> the term of `full`
    used = j < terms[:, None]
    spectra = full.gather(1, src[..., None].expand(-1, -1, full.shape[-1])) * used[..., None]
    lum = spectra @ _luminance_weights(wl.cpu()).to(device)  # [B, J]
    mean_lum = (maps.sum(-1).to(torch.float64) * lum).sum(-1) / (h * w)
    scale = target / mean_lum.clamp_min(torch.finfo(dtype).tiny)
    f_code = 10 + (u[:, 2] * 12).long().clamp(0, 11) + 1
    codes = torch.tensor([1, 0, -1, 2], device=device)  # blackbody, daylight, (fluorescent), led
    ill_code = torch.where(kind1 == 2, f_code, codes[kind1])
    meta = {"layout": layout, "illuminant_kind": kind1, "illuminant_code": ill_code, "cct_k": cct1,
            "two_lights": two, "shadow": shadow, "hdr_decades": decades, "mean_luminance_cd_m2": target, **extra}
    return {"maps": maps.reshape(nb, -1, h, w), "used": used, "terms": terms, "spectra": spectra * scale[:, None, None],
            "white": e1 * scale[:, None], "wavelengths_nm": wl, "meta": meta}
