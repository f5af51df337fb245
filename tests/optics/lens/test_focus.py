"""Finite object distance and focus (issue 16, item 2): paraxial conjugates against Newton's thick-lens
relations, finite-object chief rays against optiland 0.6.3, defocus blur against the thin-lens prediction,
longitudinal colour against the thick-lens chromatic focal shift, and LensOptics focused off infinity."""

import math

import pytest
import torch

pytest.importorskip("opticalglass")

from isettorch.optics.lens import LensAnalysis, read_lens_yaml  # noqa: E402
from isettorch.optics.lens.glass import refractive_index  # noqa: E402
from isettorch.optics.lens.optics import LensOptics  # noqa: E402
from isettorch.optics.lens.prescription import DATA_DIR  # noqa: E402
from isettorch.optics.lens.psf import otf_sampler, psf_on_grid, spot_radius_mm  # noqa: E402
from isettorch.scene.scene import Scene  # noqa: E402

C1, C2, T = 1 / 50.0, -1 / 80.0, 6.0  # N-BK7 singlet, stop at the first surface


def _singlet(epd_mm=8.0):
    return read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": epd_mm}, "field_angles_deg": [0, 10],
                           "catalogs": ["SCHOTT"],
                           "surfaces": [{"radius_mm": 1 / C1, "thickness_mm": T, "material": "N-BK7", "stop": True},
                                        {"radius_mm": 1 / C2, "thickness_mm": 60.0}]})


def _thick(n):
    """Focal length, back and front focal distances of the singlet (Hecht, *Optics*, 5th ed., eqs. 6.2-6.3)."""
    f = 1 / ((n - 1) * (C1 - C2 + (n - 1) * T * C1 * C2 / n))
    return f, f * (1 - (n - 1) * T * C1 / n), f * (1 + (n - 1) * T * C2 / n)


@pytest.mark.parametrize("d_mm", [150.0, 400.0, 2000.0])
def test_paraxial_image_distance_is_newtons(d_mm):
    a = LensAnalysis(_singlet()).at(d_mm)
    for wl in (486.1, 587.6, 656.3):
        f, bfd, ffd = _thick(refractive_index("N-BK7", wl, ("SCHOTT",)))
        x = -(d_mm - ffd)  # object from the front focal point (Newton: x x' = -f^2; Hecht eq. 5.13)
        xp = -f * f / x
        assert float(a.paraxial_image_distance_mm(wl)) == pytest.approx(bfd + xp, rel=1e-10)
        assert float(a.magnification(wl)) == pytest.approx(-xp / f, rel=1e-10)  # m = -x'/f
    # the object at infinity is the back focal distance; bad distances are named
    assert float(LensAnalysis(_singlet()).paraxial_image_distance_mm(587.6)) == pytest.approx(_thick(
        refractive_index("N-BK7", 587.6, ("SCHOTT",)))[1], rel=1e-10)
    with pytest.raises(ValueError, match="object_distance_mm"):
        LensAnalysis(_singlet()).at(-5.0)


def _chief_optiland(o, hy, wl):
    import numpy as np

    o.trace_generic(Hx=0.0, Hy=hy, Px=0.0, Py=0.0, wavelength=wl / 1000)
    sg = o.surface_group
    return tuple(float(np.asarray(getattr(sg, k))[-1].ravel()[0]) for k in ("y", "M", "N"))


@pytest.mark.parametrize("name", ["cooke_triplet", "double_gauss"])
def test_finite_object_chief_rays_against_optiland(name):
    pytest.importorskip("optiland")
    import warnings

    warnings.filterwarnings("ignore")
    from optiland.fileio import load_zemax_file

    d_mm = 800.0
    a0 = LensAnalysis(name)
    a = a0.at(d_mm)
    o = load_zemax_file(str(DATA_DIR / f"{name}.zmx"))
    if a0.prescription.float_by_stop:  # optiland's FLOA trap (see test_analysis.py)
        o.set_aperture(aperture_type="EPD", value=float(a0.ref["epd"]))
    o.set_thickness(d_mm, 0)  # optiland's object surface 800 mm before the first vertex
    th = math.radians(a0.max_field_deg)
    h_max = (d_mm + float(a0.ref["ep_z"])) * math.tan(th)  # object height of the largest field angle (from the EP)
    o.fields.fields.clear()
    o.fields.set_type(field_type="object_height")
    o.fields.add(y=0.0)
    o.fields.add(y=h_max)
    last = a.geometry.n_surfaces
    for wl in (486.1, 587.6, 656.3):
        o.set_thickness(float(a.paraxial_image_distance_mm(wl)), last)  # optiland's image at our paraxial image
        for f in (0.7, 1.0):
            # our object point is at -(D + z_EP) tan(theta): optiland's normalised height -tan(theta)/tan(max)
            y, m, nn = _chief_optiland(o, -math.tan(f * th) / math.tan(th), wl)
            assert float(a.image_height_mm(f, wl)) == pytest.approx(y, abs=2e-5)
            assert float(a.chief_ray_angle_deg(f, wl)) == pytest.approx(math.degrees(math.atan2(m, nn)), abs=1e-3)


def _rays_on_axis(a, n_rim=64, wl=587.6):
    phi = torch.arange(n_rim, dtype=torch.float64) * (2 * math.pi / n_rim)
    return a.rays(0.0, torch.cos(phi), torch.sin(phi), wl)


@pytest.mark.parametrize("d_mm", [1000.0, 3000.0])
def test_defocus_blur_diameter_is_the_thin_lens_one(d_mm):
    # a slow singlet (f/30: spherical aberration negligible against the defocus) focused at infinity
    a = LensAnalysis(_singlet(epd_mm=2.0), focus_distance_mm=math.inf).at(d_mm, math.inf)
    b = _rays_on_axis(a)
    pts, _ = a.to_plane(b, a.sensor_z)
    blur = 2 * float(torch.linalg.vector_norm(pts[..., :2], dim=-1).mean())
    f = float(a.effective_focal_length_mm)
    v = f * d_mm / (d_mm - f)  # thin lens 1/u + 1/v = 1/f (Smith, ch. 2)
    thin = 2.0 * (v - f) / v  # aperture x (image shift) / image distance
    assert blur == pytest.approx(thin, rel=0.03)


def _ee_radius_mm(psf, dx_mm, frac=0.8):
    """The radius holding ``frac`` of the PSF: the encircled energy at each distinct sample radius, interpolated
    linearly between them (a sample's radius alone moves in steps of a sample, coarser than a small defocus)."""
    s = psf.shape[-1]
    c = (torch.arange(s, dtype=torch.float64) - s // 2) * dx_mm
    yy, xx = torch.meshgrid(c, c, indexing="ij")
    r = torch.sqrt(xx * xx + yy * yy).flatten()
    radii, inverse = torch.unique(r, return_inverse=True)
    ee = torch.cumsum(torch.zeros_like(radii).index_add_(0, inverse, psf.flatten()), 0)
    k = int(torch.searchsorted(ee, torch.tensor(frac, dtype=torch.float64)))
    if k == 0:
        return float(radii[0])
    t = (frac - float(ee[k - 1])) / float(ee[k] - ee[k - 1])
    return float(radii[k - 1] + t * (radii[k] - radii[k - 1]))


def test_diffraction_psf_broadens_monotonically_with_dioptric_defocus():
    # the f/30 singlet (nearly diffraction-limited: its spherical aberration would otherwise move the best focus
    # off the paraxial one, as it does for the Cooke triplet) focused at 2 m
    base = LensAnalysis(_singlet(epd_mm=2.0))
    focus_mm = 2000.0
    dx_mm, size = 4e-3, 129
    dists = [2000.0, 2500.0, 1500.0, 5000.0, 1000.0, 700.0]  # |1/d - 1/d_f| = 0, 0.1, 0.17, 0.3, 0.5, 0.93 per m
    radii = []
    for d in dists:
        a = base.at(d, focus_mm)
        psf = psf_on_grid(otf_sampler(a, 0.0, 587.6, 64, 512), torch.zeros(1, dtype=torch.float64), dx_mm, size)[0]
        radii.append(_ee_radius_mm(psf, dx_mm))
    assert all(r1 > r0 for r0, r1 in zip(radii, radii[1:])), radii
    # in focus: the Airy pattern's 80 % encircled-energy radius, 0.897 lambda N (Rayleigh's EE = 1 - J0^2(v) -
    # J1^2(v) = 0.8 at v = pi r / (lambda N) = 2.818; Born & Wolf, sec. 8.5.2), within one sample
    n = float(base.f_number)
    assert radii[0] == pytest.approx(0.897 * 587.6e-6 * n, abs=dx_mm)
    # far off focus the geometric disc: radius = (image shift) / (2 N_w), 80 % of its energy within 0.894 of it
    a = base.at(dists[-1], focus_mm)
    dz = float(a.image_plane_z(587.6) - a.sensor_z)
    geo = 0.894 * dz / (2 * float(a.working_f_number()))
    assert math.hypot(geo, radii[0]) == pytest.approx(radii[-1], rel=0.15)


def test_longitudinal_colour_best_focus_shift_is_the_chromatic_focal_shift():
    # slow singlet, object at 1 m: the real-ray best focus (least RMS spot) of F and C against the thick lens's
    # paraxial image distances with the glass's n_F and n_C (Newton, as above)
    d_mm = 1000.0
    a = LensAnalysis(_singlet(epd_mm=2.0)).at(d_mm)
    best = {}
    for wl in (486.1, 656.3):
        b = _rays_on_axis(a, wl=wl)
        p, d = b.position, b.direction
        sx, sy = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
        x0, y0 = p[:, 0] - p[:, 2] * sx, p[:, 1] - p[:, 2] * sy  # lateral position at z = 0, slope per unit z
        # least squares in z of sum |r_i(z) - mean|^2 for r_i = r0_i + z s_i
        dx0, dy0, dsx, dsy = (v - v.mean() for v in (x0, y0, sx, sy))
        best[wl] = float(-(dx0 * dsx + dy0 * dsy).sum() / (dsx * dsx + dsy * dsy).sum())
        f, bfd, ffd = _thick(refractive_index("N-BK7", wl, ("SCHOTT",)))
        best[("paraxial", wl)] = float(a.geometry.vertex_z[-1]) + bfd + f * f / (d_mm - ffd)
    shift = best[656.3] - best[486.1]
    paraxial_shift = best[("paraxial", 656.3)] - best[("paraxial", 486.1)]
    assert paraxial_shift > 1.0  # BK7: ~f / V = 1.0 mm of longitudinal colour for f ~ 61 mm
    assert shift == pytest.approx(paraxial_shift, rel=0.02)
    # the analysis's own per-wavelength paraxial image planes carry the same shift
    assert float(a.image_plane_z(656.3) - a.image_plane_z(486.1)) == pytest.approx(paraxial_shift, rel=1e-9)


def _point_scene(distance_m, h=32):
    x = torch.zeros(1, 1, h, h, dtype=torch.float64)
    x[0, 0, h // 2, h // 2] = 1.0
    return Scene(x, torch.tensor([587.6], dtype=torch.float64), hfov_deg=0.2, distance_m=distance_m)


def test_lens_optics_blurs_scenes_off_the_focus_distance():
    kw = {"field_samples": 2, "azimuth_samples": 1, "components": None, "distortion_samples": 4, "ri_samples": 16,
          "max_kernel": 257}
    opt = LensOptics("cooke_triplet", focus_distance_m=3.0, object_distance="scene", **kw)
    peaks, spacing = [], []
    for d in (3.0, 2.0, 1.5):
        oi = opt(_point_scene(d))
        p = oi.photons[0, 0]
        peaks.append(float(p.max() / p.sum()))
        spacing.append(float(oi.sample_spacing_m[0]))
        assert oi.metadata["object_distance_m"] == d
    assert peaks[0] > 3 * peaks[1] > 3 * peaks[2] > 0, peaks  # sharp at 3 m, blurred more the farther off
    # the image pitch follows the focus (sensor behind F' by Newton's x'), not the object distance
    a = opt.analysis
    f = float(a.effective_focal_length_mm)
    assert spacing[0] == spacing[1] == spacing[2]
    inf = LensOptics("cooke_triplet", **kw)(_point_scene(3.0))
    xp = float(a.sensor_z - LensAnalysis("cooke_triplet").sensor_z)
    # paraxial chief ray (through the exit pupil centre): height scales by 1 + x' / (F' - exit pupil)
    exit_to_focus = float(a.ref["bfl"] - a.ref["xp_z"])
    assert spacing[0] / float(inf.sample_spacing_m[0]) == pytest.approx(1 + xp / exit_to_focus, rel=1e-9)
    assert xp == pytest.approx(f * f / (3000.0 - f), rel=0.05)  # ~ Newton's x' = f^2 / (d - f)
    # a fixed object distance in m is the same conjugate whatever the scene says
    fixed = LensOptics("cooke_triplet", focus_distance_m=3.0, object_distance=2.0, **kw)(_point_scene(7.0))
    torch.testing.assert_close(fixed.photons, opt(_point_scene(2.0)).photons, rtol=0, atol=0)
    # default: scenes imaged as if at infinity whatever their distance (the existing behaviour)
    assert torch.equal(inf.photons, LensOptics("cooke_triplet", **kw)(_point_scene(1.2)).photons)
    with pytest.raises(ValueError, match="focus_distance_m"):
        LensOptics("cooke_triplet", focus_distance_m=0.0)
    with pytest.raises(ValueError, match="object_distance"):
        LensOptics("cooke_triplet", object_distance="near")


def test_the_flux_on_the_sensor_is_the_pupils_whatever_the_focus():
    """A uniform scene of a fixed field of view sends the same flux through the pupil at any object distance; on the
    sensor it spreads over a pitch that follows the chief-ray height per tan(field angle), h. With the camera
    equation at the sensor's working f-number N h / f the flux E x pitch^2 is the pupil's, up to the ISETCam form's
    finite-aperture term: (h/f)^2 (1 + 4 N^2) / (1 + 4 N^2 (h/f)^2). With the object plane's 1 + |m| it followed
    the object, not the sensor (the Cooke triplet: 1.22x for an object at infinity and focus at 0.5 m, 0.82x for an
    object at 0.5 m and focus at infinity)."""
    kw = {"field_samples": 2, "azimuth_samples": 1, "components": None, "pupil_samples": 16, "max_pupil_samples": 32,
          "max_kernel": 65}
    scene = Scene(torch.ones(1, 1, 9, 13, dtype=torch.float64), torch.tensor([587.5618]), hfov_deg=10.0,
                  distance_m=1.0)
    lens = _singlet()

    def flux(opt):
        oi = opt(scene)
        return float(oi.photons.sum()) * float(oi.sample_spacing_m[0]) ** 2, oi

    ref, _ = flux(LensOptics(lens, **kw))
    for focus, obj in ((1.0, "infinity"), (math.inf, "scene"), (1.0, "scene")):
        opt = LensOptics(lens, focus_distance_m=focus, object_distance=obj, **kw)
        got, oi = flux(opt)
        a = opt._use(math.inf if obj == "infinity" else 1.0)
        n, r = float(a.f_number), float(a.image_height_per_tan_mm() / a.effective_focal_length_mm)
        assert float(oi.sample_spacing_m[0]) / (float(a.effective_focal_length_mm) * 1e-3) == pytest.approx(
            r * 2 * math.tan(math.radians(5.0)) / 13, rel=1e-12)
        if focus == 1.0:
            assert r > 1.05  # the sensor 5 % farther than at infinity focus: the old factor was off there
        assert got / ref == pytest.approx(r * r * (1 + 4 * n * n) / (1 + 4 * n * n * r * r), rel=2e-4), (focus, obj)


def test_build_optics_accepts_focus_distance():
    from isettorch.optics.factory import build_optics

    o = build_optics({"type": "lens", "lens": "cooke_triplet", "focus_distance_m": 2.0, "object_distance": "scene"})
    assert o.focus_distance_m == 2.0 and o.object_distance == "scene"
    assert float(o.analysis.sensor_z) > float(LensAnalysis("cooke_triplet").sensor_z)


def test_camera_yaml_accepts_focus_distance():
    from pathlib import Path

    import yaml

    from isettorch.camera import Camera

    cfg = yaml.safe_load((Path(__file__).resolve().parents[3] / "configs" / "cameras" / "cooke_lens.yaml").read_text())
    cfg["optics"].update(yaml.safe_load("focus_distance_m: 1.5\nobject_distance: scene\n"))
    cam = Camera.from_config(cfg)
    assert isinstance(cam.optics, LensOptics) and cam.optics.focus_distance_m == 1.5
    with pytest.raises(ValueError, match="focus_distance_m"):
        Camera.from_config({**cfg, "optics": {**cfg["optics"], "focus_distance_m": -1.0}})


def test_far_object_pupil_function_tends_to_the_infinity_one():
    # the defocus of an object at D on the infinity focus falls as f^2 / D; far objects must not lose the OPD to
    # float64 cancellation of their long optical paths (rays start on the object's wavefront sphere near the EP)
    a = LensAnalysis("cooke_triplet")
    w_inf = a.pupil_function(0.7, 587.6, 32)["opd_waves"]
    diffs = [float((a.at(d).pupil_function(0.7, 587.6, 32)["opd_waves"] - w_inf).abs().max())
             for d in (1e5, 1e7, 1e12)]
    assert diffs[0] == pytest.approx(100 * diffs[1], rel=0.01)  # ~1 / D
    assert diffs[2] < 1e-6


def _pupil_dft_psf(a, field, wl, dx_mm, half, sign, samples=256):
    """An independent PSF: the direct (matrix) DFT of a ``samples``-point pupil function at image points
    ``j dx`` (|j| <= half), rows along the field direction (tangential), cut to the disc the kernel keeps; sum 1."""
    pf = a.pupil_function(field, wl, samples)
    ct, cs = (float(c) for c in pf["cutoff_cy_mm"])
    u = (torch.arange(samples, dtype=torch.float64) - (samples - 1) / 2) * (2.0 / samples)
    x = torch.arange(-half, half + 1, dtype=torch.float64) * dx_mm
    et = torch.exp(2j * math.pi * sign * x[:, None] * (u[None] * ct / 2))
    es = torch.exp(2j * math.pi * sign * x[:, None] * (u[None] * cs / 2))
    amp = et @ pf["pupil"].to(torch.complex128) @ es.T
    psf = amp.real**2 + amp.imag**2
    psf = torch.where(x[:, None] ** 2 + x[None, :] ** 2 <= ((half + 0.5) * dx_mm) ** 2, psf, 0)  # the window's disc
    return psf / psf.sum()


@pytest.mark.parametrize(("field", "samples", "bound"), [(0.0, 64, 0.022), (0.7, 128, 0.011)])
def test_kernel_matches_a_direct_transform_of_the_pupil(field, samples, bound):
    # The Cooke triplet's kernel at 1 um pitch (finer than lambda N / 2: point samples are the band-limited ones)
    # against the direct DFT of a 256-sample pupil. Bilinear interpolation of the OTF table replicated the PSF every
    # samples x lambda N and wrapped the window's tail: L1 0.045 (field 0, 64 samples) and 0.033 (0.7, 128)
    a = LensAnalysis("cooke_triplet")
    wl, dx = 587.5618, 1e-3
    reach = spot_radius_mm(a, field, wl) + 3.0 * wl * 1e-6 * float(a.f_number)
    half = int(math.ceil(reach / dx))
    kernel = psf_on_grid(otf_sampler(a, field, wl, samples, 256), torch.zeros(1, dtype=torch.float64), dx,
                         2 * half + 1)[0]
    # the reference's orientation (a mirror image along the field) is whichever matches: coma's direction is
    # checked by the chief-ray and centroid tests
    err = min(float((kernel - _pupil_dft_psf(a, field, wl, dx, half, s)).abs().sum()) for s in (1.0, -1.0))
    assert err < bound


def _finite_object_file(tmp_path, ftyp, heights, object_mm=600.0, name="double_gauss"):
    """The bundled lens's file rewritten with a finite object (surface 0's DISZ) and fields of type ``ftyp``."""
    out, in_object = [], False
    for line in (DATA_DIR / f"{name}.zmx").read_text().splitlines():
        t = line.split()
        if t[:1] == ["SURF"]:
            in_object = t[1] == "0"
        if t[:1] == ["FTYP"]:
            line = f"FTYP {ftyp} 0 {len(heights)} 3 0 0 0"
        elif t[:1] == ["XFLN"]:
            line = "XFLN" + " 0" * len(heights)
        elif t[:1] == ["YFLN"]:
            line = "YFLN " + " ".join(str(h) for h in heights)
        elif in_object and t[:1] == ["DISZ"]:
            line = f"  DISZ {object_mm}"
        out.append(line)
    f = tmp_path / f"{name}_{ftyp}.zmx"
    f.write_text("\n".join(out))
    return f


@pytest.mark.parametrize("ftyp, heights", [(1, (0, 70, 120)), (2, (0, 12, 20)), (3, (0, 12, 20))])
def test_finite_object_file_fields_against_optiland(tmp_path, ftyp, heights):
    """A file designed for an object 600 mm away is read at that conjugate (it was refused) with its fields as
    object heights (FTYP 1) or paraxial / real image heights (2, 3): optiland 0.6.3 reads the same file and traces
    its normalised fields; the chief rays land at the same image heights (1e-9 mm)."""
    pytest.importorskip("optiland")
    import warnings

    warnings.filterwarnings("ignore")
    from optiland.fileio import load_zemax_file

    from isettorch.optics.lens import read_zmx

    path = _finite_object_file(tmp_path, ftyp, heights)
    p = read_zmx(path)
    a = LensAnalysis(p)
    assert p.object_distance_mm == 600.0 and math.isinf(p.surfaces[0].thickness_mm)
    assert a.object_distance_mm == a.focus_distance_mm == 600.0  # the analysis defaults to the file's conjugate
    assert float(a.magnification()) == pytest.approx(-0.1752, abs=1e-4)  # a 1:5.7 conjugate, not infinity's 0
    o = load_zemax_file(str(path))
    if p.float_by_stop:
        o.set_aperture(aperture_type="EPD", value=float(a.ref["epd"]))
    last = a.geometry.n_surfaces
    wavelengths = (486.1, p.primary_wavelength_nm, 656.3) if ftyp == 1 else (p.primary_wavelength_nm,)
    for wl in wavelengths:  # (image heights are defined at the primary wavelength)
        o.set_thickness(float(a.paraxial_image_distance_mm(wl)), last)
        for k in (1, 2):
            y, _, _ = _chief_optiland(o, -heights[k] / heights[-1], wl)
            assert float(a.image_height_mm(p.field_angles_deg[k] / p.max_field_deg, wl)) == pytest.approx(
                abs(y), abs=1e-9)
    if ftyp == 3:
        assert float(a.image_height_mm(1.0, p.primary_wavelength_nm)) == pytest.approx(20.0, abs=1e-9)


def test_finite_object_file_image_surface_is_the_designers_focus(tmp_path):
    """``image_plane='prescription'`` is the file's image surface when focused at the file's object distance, and
    moves by the paraxial back-focus shift from there (it was shifted as if the file were focused at infinity)."""
    from isettorch.optics.lens import read_zmx

    p = read_zmx(_finite_object_file(tmp_path, 0, (0, 10, 14)))
    a = LensAnalysis(p, image_plane="prescription")
    wl = p.primary_wavelength_nm
    file_z = float(a.geometry.vertex_z[-1]) + a.prescription_image_distance_mm
    assert float(a.sensor_z) == pytest.approx(file_z, abs=1e-12)
    at_inf = a.at(math.inf, math.inf)
    shift = float(a.paraxial_image_distance_mm(wl, math.inf) - a.paraxial_image_distance_mm(wl, 600.0))
    assert shift < -10.0  # an object at 600 mm images 17.5 mm behind the infinity focus of this 100 mm lens
    assert float(at_inf.sensor_z) == pytest.approx(file_z + shift, abs=1e-12)
