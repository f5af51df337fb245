"""LensOptics: camera equation x ray-traced RI, distortion/lateral colour, eigen-PSF accuracy, errors, and a
gradient fit of a surface curvature to a target spot size."""

import math

import pytest
import torch

pytest.importorskip("opticalglass")

from isettorch.optics.lens import LensAnalysis, TraceError  # noqa: E402
from isettorch.optics.lens.optics import LensOptics, render_brute_force  # noqa: E402
from isettorch.scene.scene import Scene  # noqa: E402

WAVES = torch.tensor([486.1, 587.6, 656.3], dtype=torch.float64)


def _hfov(optics, h, w, frac=0.98):
    t = math.tan(math.radians(optics.analysis.max_field_deg)) * frac
    return 2 * math.degrees(math.atan(t * w / math.hypot(w, h)))


@pytest.fixture(scope="module")
def cooke():
    return LensOptics("cooke_triplet", field_samples=5, azimuth_samples=8, components=8, distortion_samples=10)


def test_uniform_scene_gives_camera_equation_times_ray_traced_ri(cooke):
    h = w = 48
    s = Scene(torch.ones(1, 3, h, w, dtype=torch.float64), WAVES, hfov_deg=_hfov(cooke, h, w))
    oi = cooke(s)
    m = oi.pad_rows
    n = float(cooke.f_number)
    k0 = math.pi / (1 + 4 * n * n)  # ISETCam camera equation, object at infinity
    img = oi.photons[0, :, m:m + h, m:m + w]
    # centre samples: RI = 1 (the PSF conserves energy)
    c = img[:, h // 2 - 1:h // 2 + 1, w // 2 - 1:w // 2 + 1]
    torch.testing.assert_close(c, torch.full_like(c, k0), rtol=2e-3, atol=0)
    # along the +y axis, away from the edges: the analysis's RI at that field (distortion mapped)
    a = cooke.analysis
    dx_mm = float(oi.sample_spacing_m[0]) * 1e3
    row = int(h // 2 + 0.3 * h)
    y_mm = (row - (h - 1) / 2) * dx_mm
    # field whose chief ray (587.6 nm) lands at y_mm
    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = (lo + hi) / 2
        if float(a.chief_ray(mid, 587.6, image_z=a.image_plane_z(587.6))[0][1]) < y_mm:
            lo = mid
        else:
            hi = mid
    ri = float(a.relative_illumination(lo, 587.6, 128, method="flux"))
    got = float(img[1, row, w // 2 - 1:w // 2 + 1].mean()) / k0
    assert got == pytest.approx(ri, abs=5e-3)


def test_point_source_lands_at_chief_ray_height_per_wavelength(cooke):
    h = w = 64
    x = torch.zeros(1, 3, h, w, dtype=torch.float64)
    row = h // 2 + 22  # scene sample offset 22.5 from the centre (even size: centre between samples)
    x[0, :, row, w // 2] = 1.0
    x[0, :, row, w // 2 - 1] = 1.0
    s = Scene(x, WAVES, hfov_deg=_hfov(cooke, h, w))
    oi = cooke(s)
    m = oi.pad_rows
    dx_mm = float(oi.sample_spacing_m[0]) * 1e3
    t_pitch = 2 * math.tan(math.radians(float(s.hfov_deg[0]) / 2)) / w
    theta = math.degrees(math.atan((row - (h - 1) / 2) * t_pitch))
    a = cooke.analysis
    z = a.image_plane_z(587.6)
    for li, wl in enumerate(WAVES.tolist()):
        p = oi.photons[0, li]
        yy = torch.arange(p.shape[0], dtype=torch.float64) - (p.shape[0] - 1) / 2
        cy = float((p.sum(1) * yy).sum() / p.sum()) * dx_mm
        y_chief = float(a.chief_ray(theta / a.max_field_deg, wl, image_z=z)[0][1])
        # centroid = chief ray + the PSF's own (coma) centroid offset, a few um here; pitch ~ 0.4 mm
        assert cy == pytest.approx(y_chief, abs=0.05 * dx_mm), wl
    assert m >= 1


def test_eigen_psf_error_shrinks_with_components():
    h = w = 40
    g = torch.Generator().manual_seed(1)
    x = torch.rand(1, 2, h, w, generator=g, dtype=torch.float64)
    # a narrow field so the PSF spans several samples
    opt = LensOptics("double_gauss", field_samples=4, azimuth_samples=8, components=2, distortion_samples=6,
                     ri_samples=32)
    s = Scene(x, torch.tensor([486.1, 656.3], dtype=torch.float64), hfov_deg=_hfov(opt, h, w, 0.9) / 30)
    ref = render_brute_force(opt, s, field_samples=4, azimuth_samples=8).photons
    assert ref.shape[-1] > w + 2  # a real blur (PSF wider than 3 samples)
    errs = []
    for k in (2, 6, 24):
        o = LensOptics(opt.analysis, field_samples=4, azimuth_samples=8, components=k, distortion_samples=6,
                       ri_samples=32)
        o._cache = dict(opt._cache)
        e = (o(s).photons - ref).pow(2).mean().sqrt() / ref.pow(2).mean().sqrt()
        errs.append(float(e))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 1e-3


def test_scene_beyond_the_lens_field_is_an_error(cooke):
    s = Scene(torch.ones(1, 3, 16, 16, dtype=torch.float64), WAVES, hfov_deg=40.0)
    with pytest.raises(TraceError, match="hfov_deg"):
        cooke(s)


def _rms_spot(a: LensAnalysis, field, z):
    u = (torch.arange(16, dtype=torch.float64) - 7.5) / 8
    py, px = torch.meshgrid(u, u, indexing="ij")
    m = px * px + py * py <= 1
    b = a.rays(a.field_angle_deg(field), px[m], py[m], 587.6, clip=False)
    pts, _ = a.to_plane(b, z)
    d = pts[..., :2] - pts[..., :2].mean(0)
    return d.pow(2).sum(-1).mean().sqrt()


def test_fit_a_surface_curvature_to_a_target_spot_size():
    """Gradients from a ray-traced image quantity reach a surface curvature: the autograd derivative of the
    on-axis RMS spot radius (image plane fixed at the file's) matches a central difference, and Newton steps on
    the Cooke triplet's last curvature reach a target spot radius of 1.5x the starting one."""
    base = LensAnalysis("cooke_triplet")
    c0 = base.geometry.curvature.clone()
    z = torch.tensor(float(base.geometry.vertex_z[-1] + base.geometry.thickness[-1]), dtype=torch.float64)

    def spot(c):
        return _rms_spot(LensAnalysis("cooke_triplet", curvature_per_mm=c), 0.0, z)

    cur = c0.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(spot(cur), cur)
    h = 1e-7
    e = torch.zeros_like(c0)
    e[-1] = h
    fd = (spot(c0 + e) - spot(c0 - e)) / (2 * h)
    assert float(g[-1]) == pytest.approx(float(fd), rel=1e-5)
    target = 1.5 * float(spot(c0))
    c = c0.clone()
    for _ in range(12):
        cur = c.clone().requires_grad_(True)
        r = spot(cur) - target
        (g,) = torch.autograd.grad(r, cur)
        assert torch.isfinite(g).all()
        c = c.clone()
        c[-1] = c[-1] - r.detach() / g[-1]
    assert abs(float(spot(c)) - target) < 1e-9
    assert float(c[-1]) != float(c0[-1]) and torch.equal(c[:-1], c0[:-1])


def test_field_heights_dense_at_the_edge_where_the_psf_changes_fastest():
    """The PSF grid's field heights step 5/3 of the uniform step on axis down to 1/3 at the edge: the Cooke triplet's
    PSF changes fastest in the outermost part of its field, where a uniform grid of 13 heights interpolated its
    PSF with up to 47 % L1 error at 4 um pitch (this grid: 17 %) (benchmarks/lens_field_grid.py)."""
    from isettorch.optics.lens.optics import _interp, _lin_index, field_radii_mm
    from isettorch.optics.lens.psf import otf_sampler, psf_on_grid

    r = field_radii_mm(12.0, 13)
    u = torch.linspace(0, 1, 13, dtype=torch.float64)
    assert torch.allclose(r, 12.0 * (5 * u - 2 * u * u) / 3, rtol=0, atol=1e-12)
    step = r.diff()
    assert float(step[-1] / step[0]) < 0.25
    # the polar index on this non-uniform grid agrees with numpy.interp's piecewise-linear weights
    v = torch.tensor([0.0, 0.3, 5.5, 11.99, 12.0, 13.0], dtype=torch.float64)
    w, i = _lin_index(v, r)
    rec = r[i] * (1 - w) + r[i + 1] * w
    assert torch.allclose(rec, v.clamp(0, 12.0), rtol=0, atol=1e-12)
    assert bool(((w >= 0) & (w <= 1)).all()) and int(i.max()) == 11

    opt = LensOptics("cooke_triplet", field_samples=13, azimuth_samples=1, components=None)
    a = opt.analysis
    theta_ref, y_ref, _ = opt._radial_tables(a.reference_wavelength_nm)
    r_max = float(y_ref[-1]) * 0.999
    psfs, radii, size, _ = opt._psf_stack((550.0,), 4e-3, r_max)
    assert torch.allclose(radii, field_radii_mm(r_max, 13))
    rq = 0.5 * float(radii[-2] + radii[-1])  # the middle of the outermost interval
    w, i = _lin_index(torch.tensor([rq], dtype=torch.float64), radii)
    interp = (1 - w) * psfs[0, int(i), 0] + w * psfs[0, int(i) + 1, 0]
    f = float((_interp(torch.tensor([rq], dtype=torch.float64), y_ref, theta_ref) / a.max_field_deg)[0])
    direct = psf_on_grid(otf_sampler(a, f, 550.0), torch.zeros(1, dtype=torch.float64), 4e-3, size)[0]
    assert float((interp - direct).abs().sum()) < 0.2  # a uniform grid of 13: 0.46 here


def _singlet_optics(**kw):
    from isettorch.optics.lens import read_lens_yaml

    lens = read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 10.0}, "field_angles_deg": [0, 30],
                           "catalogs": ["SCHOTT"],
                           "surfaces": [{"radius_mm": 25.8, "thickness_mm": 5.3, "material": "N-BK7", "stop": True},
                                        {"radius_mm": math.inf, "thickness_mm": 46.6}]})
    return LensOptics(lens, max_kernel=257, **kw)


def test_uniform_scene_through_a_field_curved_singlet_at_a_coarse_pitch():
    """A plano-convex singlet (f 50 mm, F/5, stop at the lens), a uniform 128 x 128 scene over its field (0.31 mm
    samples): a Monte-Carlo irradiance of the scene (rays through the pupil binned where they land; the test of
    test_analysis.py) gives 1.01 k0 at the centre and 0.81 k0 at 2/3 of the field. The render read 1.08 at the centre
    (the band-limited samples of kernels narrower than a sample ring, and their clamped lobes added light) and its
    corners were brighter than its centre under Rimmer's relative illumination."""
    opt = _singlet_optics(field_samples=9, azimuth_samples=16, components=None)
    n = 128
    t = math.tan(math.radians(opt.analysis.max_field_deg)) * 0.99
    s = Scene(torch.ones(1, 1, n, n, dtype=torch.float64), torch.tensor([587.5618], dtype=torch.float64),
              hfov_deg=2 * math.degrees(math.atan(t / math.sqrt(2))))
    oi = opt(s)
    k0 = math.pi / (1 + 4 * float(opt.f_number) ** 2)
    img = oi.photons[0, 0] / k0
    hh = img.shape[0]
    c = (hh - 1) / 2
    dx = float(oi.sample_spacing_m[0]) * 1e3
    yy, xx = torch.meshgrid(torch.arange(hh) - c, torch.arange(hh) - c, indexing="ij")
    r = torch.sqrt(yy ** 2 + xx ** 2) * dx
    assert float(img[r < 1.5 * dx].mean()) == pytest.approx(1.01, abs=0.015)
    a = opt.analysis
    y = float(a.chief_ray(2 / 3, 587.5618, image_z=a.sensor_z)[0][1])
    diagonal = ((r - y).abs() < 1.5 * dx) & ((yy.abs() - xx.abs()).abs() < 2)
    assert float(img[diagonal].mean()) == pytest.approx(0.81, abs=0.03)


def test_kernels_of_a_wavefront_too_steep_for_the_pupil_grid_are_the_geometric_spot():
    """At the singlet's field edge the wavefront changes by 4 waves between samples of the largest pupil grid (256):
    the FFT PSF wraps into its 0.37 mm period (a kernel variance of 1.8 samples^2 where the rays' spot has 28). The
    kernel is then the geometric spot: its variance along the field direction is the ray intercepts' (computed here
    from the rays, about the chief ray)."""
    from isettorch.optics.lens.optics import field_radii_mm
    from isettorch.optics.lens.psf import ALIASED_STEP_WAVES, otf_sampler

    opt = _singlet_optics(field_samples=5, azimuth_samples=1, components=None)
    a = opt.analysis
    wl = 587.5618
    assert otf_sampler(a, 1.0, wl, 64, 256).max_step_waves > ALIASED_STEP_WAVES
    _, y_ref, _ = opt._radial_tables(a.reference_wavelength_nm)
    r_max = float(y_ref[-1]) * 0.999
    dx = 0.3
    psfs, radii, size, geometric = opt._psf_stack((wl,), dx, r_max)
    assert torch.allclose(radii, field_radii_mm(r_max, 5))
    assert any(f > 0.99 for f, _ in geometric) and opt.geometric_psfs == []  # (no render yet)
    k = psfs[0, -1, 0]
    m = size // 2
    rows = (torch.arange(size, dtype=torch.float64) - m) * dx
    mean = float((k.sum(1) * rows).sum())
    var = float((k.sum(1) * rows ** 2).sum()) - mean ** 2
    # the rays of that field (the last field height's chief ray at r_max)
    from isettorch.optics.lens.optics import _interp

    theta_ref, _, _ = opt._radial_tables(a.reference_wavelength_nm)
    f = float((_interp(torch.tensor([r_max], dtype=torch.float64), y_ref, theta_ref) / a.max_field_deg)[0])
    u = (torch.arange(200, dtype=torch.float64) - 99.5) / 100
    py, px = torch.meshgrid(u, u, indexing="ij")
    inside = px ** 2 + py ** 2 <= 1
    with torch.no_grad():
        b = a.rays(a.field_angle_deg(f), px[inside], py[inside], wl)
        p, _ = a.to_plane(b, a.sensor_z)
        ch, _ = a.chief_ray(f, wl, image_z=a.sensor_z)
    dy = p[b.valid, 1] - ch[1]
    dy = dy[dy.abs() <= (m + 0.5) * dx]
    assert mean == pytest.approx(float(dy.mean()), abs=0.1 * dx)
    assert var == pytest.approx(float(dy.var()), rel=0.1)
