"""Spatial layouts for synthetic scenes.

Every layout returns a *material map*: two palette indices per pixel and a blend weight,
``(index_a [H, W] long, index_b [H, W] long, t [H, W] in [0, 1])``; the scene's reflectance at a pixel is
``(1 - t) R[index_a] + t R[index_b]``, a convex combination, so it stays in [0, 1]. Geometry is drawn from
one ``torch.Generator`` (CPU) and evaluated on the requested device.

Statistics (documented, and what the defaults produce):

* ``dead_leaves``: 400-800 occluding leaves (disks, rotated rectangles and ellipses, 1/3 each) with radii
  from the scale-invariant density p(r) ~ r^-3 on [2.5 px, 0.6 * size] (Lee, Mumford & Huang, "Occlusion
  models for natural images", IJCV 41, 2001), uniform positions over the image +-10 %. The mean disk area
  ``2 pi rmin^2 ln(rmax / rmin)`` (~130 px^2 at 128 px) makes the leaves cover ~93 % of a 128 x 128 image
  on average (Boolean model, 1 - exp(-density); the rest shows the first leaf). 50 % of leaves are
  textured: a sine or square grating (0.02-0.45 cycles/px, any orientation) or a linear gradient blending
  two palette colours.
* ``gradients``: a smooth linear or radial ramp between two colours, plus a low-frequency
  (<= 2 cycles per image) modulation.
* ``edges``: 1-5 straight lines at uniform orientations in [0, pi), through uniform points; each cell of
  the arrangement takes its own colour (sharp, 1-sample transitions).
* ``lines``: 3-12 thin lines (0.5-3 px wide) and 2-6 text-like glyphs of 2-5 short strokes each
  (stroke 0.7-2.5 px), anti-aliased by the distance to each segment.
* ``textures``: 1 or 2 regions (split by straight edges) each holding a fine periodic pattern: sine or
  square gratings and checkerboards at 0.15-0.95 cycles/px (beyond the 0.5 cycles/px Nyquist limit and
  beyond a Bayer sensor's 0.25 cycles/px per-colour limit, to provoke aliasing), or a zone plate.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["LAYOUTS", "render_layout", "dead_leaves", "dead_leaves_radii", "gradients", "edges", "lines", "textures"]


def _u(g: torch.Generator, *shape, lo: float = 0.0, hi: float = 1.0) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=torch.float64)


def _ri(g: torch.Generator, lo: int, hi: int, *shape) -> torch.Tensor:
    """Integers in [lo, hi] inclusive."""
    return torch.randint(lo, hi + 1, shape if shape else (), generator=g)


def _grid(h: int, w: int, device, dtype=torch.float32):
    y = torch.arange(h, device=device, dtype=dtype)[:, None].expand(h, w)
    x = torch.arange(w, device=device, dtype=dtype)[None, :].expand(h, w)
    return y, x


def _grating(phase_arg: torch.Tensor, kind: torch.Tensor) -> torch.Tensor:
    """0.5 + 0.5 * wave, kind 0 = sine, 1 = square."""
    s = torch.sin(phase_arg)
    sq = (s >= 0).to(s.dtype)
    return torch.where(kind == 1, sq, 0.5 + 0.5 * s)


def dead_leaves_radii(n: int, rmin: float, rmax: float, g: torch.Generator) -> torch.Tensor:
    """``n`` radii with density p(r) ~ r^-3 on [rmin, rmax] (scale invariance; Lee, Mumford & Huang 2001),
    by inverse CDF: ``r = (rmin^-2 - u (rmin^-2 - rmax^-2))^(-1/2)``, float64 [n]."""
    if not 0 < rmin < rmax:
        raise ValueError(f"rmin, rmax: expected 0 < rmin < rmax, got {rmin}, {rmax}")
    u = _u(g, n)
    return (rmin**-2 - u * (rmin**-2 - rmax**-2)) ** -0.5


def _leaf_inside(dy, dx, r, aspect, cos_t, sin_t, shape):
    """Whether offsets (dy, dx) from a leaf's centre fall inside it; shape 0 disk, 1 rotated rectangle,
    2 rotated ellipse (all tensors broadcast)."""
    pu, pv = (dx * cos_t + dy * sin_t) / r, (-dx * sin_t + dy * cos_t) / (r * aspect)
    rect = torch.maximum(pu.abs(), pv.abs())
    ell = pu * pu + pv * pv
    disk = (dx * dx + dy * dy) / (r * r)
    return torch.where(shape == 1, rect, torch.where(shape == 2, ell, disk)) <= 1


def _interval(k: np.ndarray, o: np.ndarray, b: np.ndarray):
    """The range ``[lo, hi]`` of ``dx`` with ``|k dx + o| <= b`` (elementwise, float64); for ``k == 0`` it is
    everything or nothing."""
    safe = np.where(k == 0, 1.0, k)
    e1, e2 = (-b - o) / safe, (b - o) / safe
    ok = np.abs(o) <= b
    lo = np.where(k == 0, np.where(ok, -np.inf, np.inf), np.minimum(e1, e2))
    hi = np.where(k == 0, np.where(ok, np.inf, -np.inf), np.maximum(e1, e2))
    return lo, hi


def _paint_leaves(h, w, cy, cx, r, theta, aspect, shape, device):
    """Index (0-based, drawing order) of the topmost leaf at each pixel [H, W]; 0 where no leaf covers.

    Leaves are convex, so on each image row a leaf covers one run of pixel centres ``x`` in ``[cx + lo, cx +
    hi]``, solved in closed form (float64) from :func:`_leaf_inside`'s inequalities at that row's ``dy``: disk
    ``dx^2 <= r^2 - dy^2``; ellipse ``A dx^2 + B dx + C <= 0`` (the rotated quadratic form); rectangle the
    intersection of two slabs ``|dx cos t + dy sin t| <= r``, ``|-dx sin t + dy cos t| <= r a``. Only the
    covered pixels are then enumerated (the leaves' total area, ~50k points at 144 x 144, instead of their
    bounding boxes) and the painter's order is resolved by a scatter-max of the drawing order. Exact up to the
    float64 rounding of the run ends (the tests compare with the brute-force per-pixel test). The per-row stage
    (~5k rows of a few elementwise formulas) runs in numpy: at that size its per-call cost is ~2x lower than
    torch's (same IEEE float64 operations).
    """
    sn, cs = (v.numpy() for v in (theta.sin(), theta.cos()))
    cy, cx, r, aspect, shape = (v.numpy() for v in (cy, cx, r, aspect, shape))
    ra = r * aspect
    asn, acs = np.abs(sn), np.abs(cs)
    # half-height of each leaf: rectangle r |sin t| + r a |cos t|; ellipse sqrt((r sin t)^2 + (r a cos t)^2)
    ey = np.where(shape == 1, r * asn + ra * acs, np.sqrt((r * asn) ** 2 + (ra * acs) ** 2))
    ey = np.where(shape == 0, r, ey)
    y0 = np.clip(np.ceil(cy - ey), 0, h).astype(np.int64)
    nrows = np.maximum(np.clip(np.floor(cy + ey).astype(np.int64) + 1, 0, h) - y0, 0)
    # (leaf, row) pairs grouped by shape, so each shape's run formula is evaluated on its own rows only
    perm = np.argsort(shape, kind="stable")
    nrows_p = nrows[perm]
    leaf = np.repeat(perm, nrows_p)
    rows_per_shape = np.bincount(shape[perm], weights=nrows_p, minlength=3).astype(np.int64).tolist()
    y = y0[leaf] + (np.arange(leaf.size) - np.repeat(np.cumsum(nrows_p) - nrows_p, nrows_p))
    c_x, rr, rra, c, s = cx[leaf], r[leaf], ra[leaf], cs[leaf], sn[leaf]
    dy = y - cy[leaf]
    los, his = [], []
    start = 0
    for shape_id, count in enumerate(rows_per_shape):
        sl = slice(start, start + count)
        start += count
        if not count:
            continue
        dy_, rr_ = dy[sl], rr[sl]
        if shape_id == 0:  # disk: dx^2 <= r^2 - dy^2
            q = rr_ * rr_ - dy_ * dy_
            hd = np.sqrt(np.maximum(q, 0))
            los.append(np.where(q >= 0, -hd, np.inf))
            his.append(np.where(q >= 0, hd, -np.inf))
        elif shape_id == 1:  # rectangle: |dx cos t + dy sin t| <= r and |-dx sin t + dy cos t| <= r a
            c_, s_ = c[sl], s[sl]
            l1, h1 = _interval(c_, dy_ * s_, rr_)
            l2, h2 = _interval(-s_, dy_ * c_, rra[sl])
            los.append(np.maximum(l1, l2))
            his.append(np.minimum(h1, h2))
        else:  # ellipse: ((dx c + dy s) / r)^2 + ((-dx s + dy c) / (r a))^2 <= 1, i.e. A dx^2 + B dx + C <= 0
            c_, s_, rra_ = c[sl], s[sl], rra[sl]
            ir2, ia2 = 1 / (rr_ * rr_), 1 / (rra_ * rra_)
            qa = c_ * c_ * ir2 + s_ * s_ * ia2
            qb = 2 * dy_ * c_ * s_ * (ir2 - ia2)
            qc = dy_ * dy_ * (s_ * s_ * ir2 + c_ * c_ * ia2) - 1
            disc = qb * qb - 4 * qa * qc
            sd = np.sqrt(np.maximum(disc, 0))
            los.append(np.where(disc >= 0, (-qb - sd) / (2 * qa), np.inf))
            his.append(np.where(disc >= 0, (-qb + sd) / (2 * qa), -np.inf))
    if not los:  # no leaf reaches the image
        return torch.zeros(h, w, dtype=torch.long, device=device)
    lo, hi = np.concatenate(los), np.concatenate(his)
    xl = np.clip(np.ceil(c_x + lo), 0, w).astype(np.int64)
    xr = np.clip(np.floor(c_x + hi), -1, w - 1).astype(np.int64)
    cnt = np.maximum(xr - xl + 1, 0)
    # pixel = y w + xl + (position within the run): one repeat of a per-run base plus a global arange
    base = y * w + xl - (np.cumsum(cnt) - cnt)
    # (numpy's repeat: ~3x faster than torch.repeat_interleave at these ~50k entries, the same integers)
    pix = np.repeat(base, cnt)
    pix += np.arange(pix.size)
    top = torch.zeros(h * w, dtype=torch.long)
    top.scatter_reduce_(0, torch.from_numpy(pix), torch.from_numpy(np.repeat(leaf + 1, cnt)), reduce="amax")
    return (top.clamp_min(1) - 1).reshape(h, w).to(device)


def dead_leaves(h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Textured dead-leaves layout (see module notes)."""
    n = int(_ri(g, 400, 800))
    r = dead_leaves_radii(n, 2.5, 0.6 * max(h, w), g)
    # uniform per-leaf parameters in one draw: centre y, x (image +-10 %), orientation, aspect, grating frequency
    # (cycles/px), texture direction, phase
    lo = torch.tensor([-0.1 * h, -0.1 * w, 0.0, 0.3, 0.02, 0.0, 0.0], dtype=torch.float64)[:, None]
    hi = torch.tensor([1.1 * h, 1.1 * w, math.pi, 1.0, 0.45, math.pi, 2 * math.pi], dtype=torch.float64)[:, None]
    cy, cx, theta, aspect, freq, tdir, phase = torch.rand(7, n, generator=g, dtype=torch.float64).mul_(hi - lo).add_(lo)
    shape = _ri(g, 0, 2, n)  # 0 disk, 1 rotated rectangle, 2 ellipse
    ca, cb = _ri(g, 0, k - 1, n), _ri(g, 0, k - 1, n)
    tex = _ri(g, 0, 3, n)  # 0, 1 flat, 2 grating, 3 gradient
    sq = _ri(g, 0, 1, n)

    top = _paint_leaves(h, w, cy, cx, r, theta, aspect, shape, device)
    y, x = _grid(h, w, device, dtype)
    # per-pixel leaf attributes: 1-D gathers (3x faster on CPU than one gather along dim 1 of a [4, n] table)
    flat = top.reshape(-1)
    ia, ib, tx, sq_px = (v.to(device).index_select(0, flat).reshape(h, w) for v in (ca, cb, tex, sq))
    # Both textures are affine in (x, y) per leaf, so each leaf's three coefficients are computed once (float64)
    # and gathered: grating phase 2 pi f (x cos a + y sin a) + p; gradient across the leaf, the position along
    # the texture direction relative to the leaf's centre and size, ((x - cx) cos a + (y - cy) sin a) / (2 r) + 1/2.
    ca_, sa_ = torch.cos(tdir), torch.sin(tdir)
    k_g = 2 * math.pi * freq
    half = 0.5 / r
    coef = torch.stack([k_g * ca_, k_g * sa_, phase, ca_ * half, sa_ * half, 0.5 - (cx * ca_ + cy * sa_) * half])
    gx, gy, g0, rx, ry, r0 = (v.to(device=device, dtype=dtype).index_select(0, flat).reshape(h, w) for v in coef)
    grat = _grating(gx.mul_(x).addcmul_(gy, y).add_(g0), sq_px)
    rel = rx.mul_(x).addcmul_(ry, y).add_(r0)
    t = torch.where(tx == 2, grat, torch.where(tx == 3, rel.clamp_(0, 1), torch.zeros_like(grat)))
    return ia, ib, t


def gradients(h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Smooth linear or radial ramps between two colours with a gentle modulation."""
    y, x = _grid(h, w, device, dtype)
    yn, xn = y / max(h - 1, 1), x / max(w - 1, 1)
    radial = bool(_ri(g, 0, 1))
    a = float(_u(g, 1, hi=2 * math.pi))
    cy, cx = float(_u(g, 1)), float(_u(g, 1))
    if radial:
        base = torch.sqrt((yn - cy) ** 2 + (xn - cx) ** 2 + 1e-12) / math.sqrt(2)
    else:
        base = (xn - 0.5) * math.cos(a) + (yn - 0.5) * math.sin(a) + 0.5
    f1, f2, p1 = float(_u(g, 1, lo=0.2, hi=2.0)), float(_u(g, 1, hi=math.pi)), float(_u(g, 1, hi=2 * math.pi))
    mod = 0.15 * torch.sin(2 * math.pi * f1 * (xn * math.cos(f2) + yn * math.sin(f2)) + p1)
    t = (base + mod)
    t = (t - t.min()) / (t.max() - t.min()).clamp_min(1e-6)
    ia = torch.full((h, w), int(_ri(g, 0, k - 1)), device=device)
    ib = torch.full((h, w), int(_ri(g, 0, k - 1)), device=device)
    return ia, ib, t


def _cells(h, w, g, n_lines, device, dtype):
    """Cell code of an arrangement of ``n_lines`` random lines (bit i = side of line i)."""
    y, x = _grid(h, w, device, dtype)
    code = torch.zeros(h, w, dtype=torch.long, device=device)
    for i in range(n_lines):
        a = float(_u(g, 1, hi=math.pi))
        py, px = float(_u(g, 1, lo=0.15 * h, hi=0.85 * h)), float(_u(g, 1, lo=0.15 * w, hi=0.85 * w))
        side = ((x - px) * math.sin(a) - (y - py) * math.cos(a)) > 0
        code = code + (side.long() << i)
    return code


def edges(h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Sharp straight edges at uniformly random orientations; each cell has its own colour."""
    n_lines = int(_ri(g, 1, 5))
    code = _cells(h, w, g, n_lines, device, dtype)
    colours = _ri(g, 0, k - 1, 2**n_lines).to(device)
    ia = colours.index_select(0, code.reshape(-1)).reshape(h, w)
    return ia, ia, torch.zeros(h, w, device=device, dtype=dtype)


def _stroke_cover(h: int, w: int, seg: torch.Tensor, wid: torch.Tensor) -> torch.Tensor:
    """Max coverage ``clamp(wid / 2 + 0.5 - distance, 0, 1)`` of short strokes ``seg [N, 4]`` (y0, x0, y1, x1) at
    each pixel ``[H, W]``, evaluated only on each stroke's bounding box (widened by its reach ``wid / 2 + 0.5``,
    beyond which the coverage is 0), the distance to each segment (clamped projection) per (pixel, stroke)."""
    top = torch.zeros(h * w, dtype=seg.dtype)
    if seg.shape[0] == 0:
        return top.reshape(h, w)
    s64, reach = seg.detach().cpu().double(), wid.detach().cpu().double() / 2 + 0.5 + 1e-3
    y0 = torch.ceil(torch.minimum(s64[:, 0], s64[:, 2]) - reach).long().clamp(0, h)
    y1 = (torch.floor(torch.maximum(s64[:, 0], s64[:, 2]) + reach).long() + 1).clamp(0, h)
    x0 = torch.ceil(torch.minimum(s64[:, 1], s64[:, 3]) - reach).long().clamp(0, w)
    x1 = (torch.floor(torch.maximum(s64[:, 1], s64[:, 3]) + reach).long() + 1).clamp(0, w)
    y1, x1 = torch.maximum(y0, y1), torch.maximum(x0, x1)
    sx = x1 - x0
    cnt = (y1 - y0) * sx
    k = torch.repeat_interleave(torch.arange(seg.shape[0]), cnt)
    local = torch.arange(k.numel()) - torch.repeat_interleave(cnt.cumsum(0) - cnt, cnt)
    # gathers with index_select (much faster than advanced indexing on CPU; the same values)
    y0k, x0k, sxk = torch.stack([y0, x0, sx]).index_select(1, k).unbind(0)
    row = torch.div(local, sxk, rounding_mode="floor")
    py, px = y0k + row, x0k + (local - row * sxk)
    sc, wc = seg.cpu(), wid.cpu()
    a_y, a_x, b_y, b_x, wk = torch.cat([sc.T, wc[None]]).index_select(1, k).unbind(0)
    vy, vx = b_y - a_y, b_x - a_x
    wy, wx = py.to(seg.dtype) - a_y, px.to(seg.dtype) - a_x
    tt = ((wy * vy + wx * vx) / (vy * vy + vx * vx).clamp_min(1e-9)).clamp(0, 1)
    dist = torch.sqrt((wy - tt * vy) ** 2 + (wx - tt * vx) ** 2 + 1e-12)
    cover = (wk / 2 + 0.5 - dist).clamp(0, 1)
    return top.scatter_reduce_(0, py * w + px, cover, reduce="amax").reshape(h, w)


def _line_cover(h: int, w: int, py: torch.Tensor, px: torch.Tensor, a: torch.Tensor, wid: torch.Tensor, device,
                dtype) -> torch.Tensor:
    """Max coverage ``clamp(wid / 2 + 0.5 - distance, 0, 1)`` over lines through ``(py, px)`` with direction
    ``(sin a, cos a)`` (float64 [N]) at each pixel ``[H, W]``. The distance to a line is the perpendicular one,
    ``|(y - py) cos a - (x - px) sin a|``, separable: ``[N, H, 1] - [N, 1, W]`` of float64 factors."""
    yy = torch.arange(h, dtype=torch.float64)[None, :] - py[:, None]
    xx = torch.arange(w, dtype=torch.float64)[None, :] - px[:, None]
    along_y = (yy * torch.cos(a)[:, None]).to(device=device, dtype=dtype)[:, :, None]
    along_x = (xx * torch.sin(a)[:, None]).to(device=device, dtype=dtype)[:, None, :]
    dist = (along_y - along_x).abs_()
    # Coverage of a pixel by a stroke of width wid: linear ramp over one pixel (box-filtered edge).
    return dist.neg_().add_(wid.to(device=device, dtype=dtype)[:, None, None] / 2 + 0.5).clamp_(0, 1).amax(dim=0)


def lines(h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Thin lines across the image and text-like glyphs made of short strokes, anti-aliased."""
    n_lines = int(_ri(g, 3, 12))
    a = _u(g, n_lines, hi=math.pi)  # direction (sin a, cos a) in (y, x)
    py, px = _u(g, n_lines, hi=h), _u(g, n_lines, hi=w)
    line_width = _u(g, n_lines, lo=0.5, hi=3.0)
    segs, widths = [], []
    n_glyphs = int(_ri(g, 2, 6))
    for _ in range(n_glyphs):
        size = float(_u(g, 1, lo=6.0, hi=0.3 * min(h, w) + 6.0))
        gy, gx = float(_u(g, 1, hi=h)), float(_u(g, 1, hi=w))
        ns = int(_ri(g, 2, 5))
        pts = torch.stack([gy + size * _u(g, ns + 1), gx + 0.7 * size * _u(g, ns + 1)], 1)
        segs.append(torch.cat([pts[:-1], pts[1:]], 1))
        widths.append(torch.full((ns,), float(_u(g, 1, lo=0.7, hi=2.5)), dtype=torch.float64))
    cover = _line_cover(h, w, py, px, a, line_width.to(dtype), device, dtype)
    strokes = _stroke_cover(h, w, torch.cat(segs).to(device=device, dtype=dtype),
                            torch.cat(widths).to(device=device, dtype=dtype))
    cover = torch.maximum(cover, strokes.to(cover.device))
    ia = torch.full((h, w), int(_ri(g, 0, k - 1)), device=device)
    ib = torch.full((h, w), int(_ri(g, 0, k - 1)), device=device)
    return ia, ib, cover


def textures(h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Fine periodic textures (gratings, checkerboards, zone plates) in 1 or 2 regions."""
    n_split = int(_ri(g, 0, 1))
    code = _cells(h, w, g, n_split, device, dtype) if n_split else torch.zeros(h, w, dtype=torch.long,
                                                                               device=device)
    y, x = _grid(h, w, device, dtype)
    t = torch.zeros(h, w, device=device, dtype=dtype)
    ia = torch.zeros(h, w, dtype=torch.long, device=device)
    ib = torch.zeros(h, w, dtype=torch.long, device=device)
    for region in range(2**n_split):
        m = code == region
        kind = int(_ri(g, 0, 3))
        f = float(_u(g, 1, lo=0.15, hi=0.95))
        a = float(_u(g, 1, hi=math.pi))
        ph = float(_u(g, 1, hi=2 * math.pi))
        if kind <= 1:  # sine / square grating
            arg = 2 * math.pi * f * (x * math.cos(a) + y * math.sin(a)) + ph
            pat = _grating(arg, torch.tensor(kind, device=device))
        elif kind == 2:  # checkerboard (period 1/f px, rotated)
            u_, v_ = x * math.cos(a) + y * math.sin(a), -x * math.sin(a) + y * math.cos(a)
            pat = ((torch.floor(2 * f * u_) + torch.floor(2 * f * v_)) % 2).to(dtype)
        else:  # zone plate: local frequency grows linearly to f_max at the corners
            cy, cx = float(_u(g, 1, hi=h)), float(_u(g, 1, hi=w))
            r2 = (x - cx) ** 2 + (y - cy) ** 2
            kk = math.pi * f / max(h, w)
            pat = 0.5 + 0.5 * torch.cos(kk * r2 + ph)
        t = torch.where(m, pat, t)
        ia = torch.where(m, int(_ri(g, 0, k - 1)), ia)
        ib = torch.where(m, int(_ri(g, 0, k - 1)), ib)
    return ia, ib, t


LAYOUTS = {"dead_leaves": dead_leaves, "gradients": gradients, "edges": edges, "lines": lines,
           "textures": textures}


def render_layout(name: str, h: int, w: int, k: int, g: torch.Generator, device=None, dtype=torch.float32):
    """Dispatch to a layout by name; returns ``(index_a, index_b, t)`` (see module notes)."""
    if name not in LAYOUTS:
        raise ValueError(f"name: expected a layout in {sorted(LAYOUTS)}, got {name!r}")
    if h < 2 or w < 2 or k < 1:
        raise ValueError(f"layout size: expected h, w >= 2 and k >= 1, got h={h}, w={w}, k={k}")
    return LAYOUTS[name](h, w, k, g, device=device, dtype=dtype)
