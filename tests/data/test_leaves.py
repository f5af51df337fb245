"""The bounding-box dead-leaves painter equals the brute-force painter (every leaf tested on every pixel)."""

import math

import torch

from isettorch.data import layouts


def test_painter_equals_brute_force_for_all_shapes():
    g = torch.Generator().manual_seed(7)
    h, w = 48, 40
    for _ in range(3):
        n = 300
        r = layouts.dead_leaves_radii(n, 1.5, 30.0, g)
        cy = torch.rand(n, generator=g, dtype=torch.float64) * 1.2 * h - 0.1 * h
        cx = torch.rand(n, generator=g, dtype=torch.float64) * 1.2 * w - 0.1 * w
        shape = torch.randint(0, 3, (n,), generator=g)
        theta = torch.rand(n, generator=g, dtype=torch.float64) * math.pi
        aspect = 0.3 + 0.7 * torch.rand(n, generator=g, dtype=torch.float64)
        top = layouts._paint_leaves(h, w, cy, cx, r, theta, aspect, shape, None, torch.float32)
        yy = torch.arange(h, dtype=torch.float32)[None, :, None]
        xx = torch.arange(w, dtype=torch.float32)[None, None, :]

        def v(t):
            return t.float()[:, None, None]

        inside = layouts._leaf_inside(yy - v(cy), xx - v(cx), v(r), v(aspect), torch.cos(v(theta)),
                                      torch.sin(v(theta)), shape[:, None, None])
        brute = (inside * torch.arange(1, n + 1)[:, None, None]).amax(dim=0)
        assert torch.equal(top, brute.clamp_min(1) - 1)
        assert len(set(shape[brute[brute > 0] - 1].tolist())) == 3  # every shape is on top somewhere


def test_stroke_cover_equals_full_image_evaluation():
    """Strokes evaluated on their bounding boxes give the same coverage as every stroke on every pixel."""
    g = torch.Generator().manual_seed(3)
    h, w, n = 40, 52, 30
    p0 = torch.rand(n, 2, generator=g) * torch.tensor([h * 1.2, w * 1.2]) - 4
    seg = torch.cat([p0, p0 + (torch.rand(n, 2, generator=g) - 0.5) * 30], dim=1)  # some leave the image
    wid = 0.5 + 2.5 * torch.rand(n, generator=g)
    yy, xx = layouts._grid(h, w, None, torch.float32)
    dist = layouts._segment_distance(yy, xx, seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3])
    brute = (wid[:, None, None] / 2 + 0.5 - dist).clamp(0, 1).amax(dim=0)
    got = layouts._stroke_cover(h, w, seg, wid)
    assert torch.equal(got, brute) and float(brute.max()) == 1.0 and float((brute > 0).float().mean()) > 0.1
