"""The run-based dead-leaves painter equals the brute-force painter (every leaf tested on every pixel)."""

import math

import torch

from isettorch.data import layouts


def _segment_distance(y, x, y0, x0, y1, x1):
    """Brute-force reference: distance of each pixel to each segment [N, H, W] (clamped projection on the segment;
    the same expressions as layouts._stroke_cover per (pixel, stroke))."""
    vy, vx = (y1 - y0)[:, None, None], (x1 - x0)[:, None, None]
    wy, wx = y[None] - y0[:, None, None], x[None] - x0[:, None, None]
    tt = ((wy * vy + wx * vx) / (vy * vy + vx * vx).clamp_min(1e-9)).clamp(0, 1)
    return torch.sqrt((wy - tt * vy) ** 2 + (wx - tt * vx) ** 2 + 1e-12)


def test_painter_equals_brute_force_for_all_shapes():
    g = torch.Generator().manual_seed(7)
    h, w = 48, 40
    for trial in range(4):
        n = 300
        r = layouts.dead_leaves_radii(n, 1.5, 30.0, g)
        cy = torch.rand(n, generator=g, dtype=torch.float64) * 1.2 * h - 0.1 * h
        cx = torch.rand(n, generator=g, dtype=torch.float64) * 1.2 * w - 0.1 * w
        shape = torch.randint(0, 3, (n,), generator=g)
        theta = torch.rand(n, generator=g, dtype=torch.float64) * math.pi
        if trial == 3:  # axis-aligned leaves: sin t = 0 exactly (a slab with a zero coefficient)
            theta = torch.zeros(n, dtype=torch.float64)
        aspect = 0.3 + 0.7 * torch.rand(n, generator=g, dtype=torch.float64)
        top = layouts._paint_leaves(h, w, cy, cx, r, theta, aspect, shape, None)
        yy = torch.arange(h, dtype=torch.float32)[None, :, None]
        xx = torch.arange(w, dtype=torch.float32)[None, None, :]

        def v(t):
            return t.double()[:, None, None]

        # float64 brute force; the painter solves each row's run in float64 too, so they may only disagree
        # where a pixel centre lies within rounding of a leaf's boundary
        yy, xx = yy.double(), xx.double()
        dy, dx = yy - v(cy), xx - v(cx)
        inside = layouts._leaf_inside(dy, dx, v(r), v(aspect), torch.cos(v(theta)), torch.sin(v(theta)),
                                      shape[:, None, None])
        brute = (inside * torch.arange(1, n + 1)[:, None, None]).amax(dim=0)
        differ = top != brute.clamp_min(1) - 1
        assert int(differ.sum()) <= 2
        if differ.any():  # every disagreement is a boundary tie: some leaf's metric within 1e-9 of 1
            pu = (dx * torch.cos(v(theta)) + dy * torch.sin(v(theta))) / v(r)
            pv = (-dx * torch.sin(v(theta)) + dy * torch.cos(v(theta))) / (v(r) * v(aspect))
            sh = shape[:, None, None]
            metric = torch.where(sh == 1, torch.maximum(pu.abs(), pv.abs()),
                                 torch.where(sh == 2, pu * pu + pv * pv, (dx * dx + dy * dy) / v(r) ** 2))
            assert bool(((metric - 1).abs() < 1e-9).any(dim=0)[differ].all())
        assert top.sum() > 0
        assert len(set(shape[brute[brute > 0] - 1].tolist())) == 3  # every shape is on top somewhere


def test_stroke_cover_equals_full_image_evaluation():
    """Strokes evaluated on their bounding boxes give the same coverage as every stroke on every pixel."""
    g = torch.Generator().manual_seed(3)
    h, w, n = 40, 52, 30
    p0 = torch.rand(n, 2, generator=g) * torch.tensor([h * 1.2, w * 1.2]) - 4
    seg = torch.cat([p0, p0 + (torch.rand(n, 2, generator=g) - 0.5) * 30], dim=1)  # some leave the image
    wid = 0.5 + 2.5 * torch.rand(n, generator=g)
    yy, xx = layouts._grid(h, w, None, torch.float32)
    dist = _segment_distance(yy, xx, seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3])
    brute = (wid[:, None, None] / 2 + 0.5 - dist).clamp(0, 1).amax(dim=0)
    got = layouts._stroke_cover(h, w, seg, wid)
    assert torch.equal(got, brute) and float(brute.max()) == 1.0 and float((brute > 0).float().mean()) > 0.1


def test_long_lines_cover_equals_segment_distance():
    """The lines layout's separable perpendicular distance equals the distance to segments reaching far beyond
    the image (how the lines are defined), to float32 rounding."""
    g = torch.Generator().manual_seed(4)
    h, w, n = 36, 44, 9
    a = torch.rand(n, generator=g, dtype=torch.float64) * math.pi
    py = torch.rand(n, generator=g, dtype=torch.float64) * h
    px = torch.rand(n, generator=g, dtype=torch.float64) * w
    wid = 0.5 + 2.5 * torch.rand(n, generator=g, dtype=torch.float64)
    got = layouts._line_cover(h, w, py, px, a, wid, None, torch.float32)
    big = 2.0 * (h + w)
    yy, xx = layouts._grid(h, w, None, torch.float64)
    dist = _segment_distance(yy, xx, py - big * a.sin(), px - big * a.cos(), py + big * a.sin(),
                                     px + big * a.cos())
    ref = (wid[:, None, None] / 2 + 0.5 - dist).clamp(0, 1).amax(dim=0)
    assert float((got.double() - ref).abs().max()) < 1e-5 and float(ref.max()) == 1.0
    assert 0.05 < float((ref > 0).double().mean()) < 0.9
