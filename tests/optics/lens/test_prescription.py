"""Reading lens prescriptions (.zmx in its encodings, YAML) and bad input."""

import math

import pytest

from isettorch.optics.lens import LensAnalysis, PrescriptionError, bundled_lenses, load_lens, read_lens_yaml, read_zmx
from isettorch.optics.lens.prescription import DATA_DIR


def test_bundled_lenses_listed():
    assert {"cooke_triplet", "double_gauss", "aspheric_singlet"} <= set(bundled_lenses())


def test_utf16_zmx_with_bom_read():
    path = DATA_DIR / "cooke_triplet.zmx"
    assert path.read_bytes()[:2] == b"\xff\xfe"  # the fixture really is UTF-16 LE with a BOM
    p = read_zmx(path)
    assert len(p.surfaces) == 8 and p.stop_index == 4
    assert p.surfaces[1].curvature_per_mm == pytest.approx(1 / 22.01359, rel=1e-12)
    assert p.surfaces[3].material == "F2" and p.surfaces[2].material is None
    assert p.entrance_pupil_diameter_mm == 10 and not p.float_by_stop
    assert p.field_angles_deg == (0.0, 14.0, 20.0) and p.max_field_deg == 20.0
    assert p.wavelengths_nm == pytest.approx((486.1327, 587.5618, 656.2725))
    assert p.catalogs == ("SCHOTT",)
    # CLAP clips, a bare DIAM does not
    assert p.surfaces[6].aperture_mm == 6.0 and p.surfaces[1].aperture_mm is None
    assert p.surfaces[1].semi_diameter_mm == 6.5


def test_utf8_and_latin1_zmx_read_the_same(tmp_path):
    src = (DATA_DIR / "cooke_triplet.zmx").read_bytes().decode("utf-16")
    for enc in ("utf-8", "latin-1", "utf-16-le", "utf-16-be"):  # (BE without a BOM read as 'no SURF blocks')
        f = tmp_path / f"l_{enc}.zmx"
        f.write_bytes(src.lstrip("\ufeff").encode(enc))
        p = read_zmx(f)
        assert [s.curvature_per_mm for s in p.surfaces] == [s.curvature_per_mm
                                                            for s in read_zmx(DATA_DIR / "cooke_triplet.zmx").surfaces]


def test_float_by_stop_and_flap():
    p = read_zmx(DATA_DIR / "double_gauss.zmx")
    assert p.float_by_stop and p.entrance_pupil_diameter_mm is None
    assert p.surfaces[6].is_stop and p.surfaces[6].semi_diameter_mm == pytest.approx(6.3412)
    assert p.surfaces[1].aperture_mm == p.surfaces[1].semi_diameter_mm == pytest.approx(21.567)
    assert p.surfaces[2].aperture_mm is None


def test_yaml_even_asphere():
    p = load_lens("aspheric_singlet")
    s = p.surfaces[1]
    assert s.kind == "EVENASPH" and s.aspheric == (-2.248851e-4, -4.690412e-6, -6.404376e-8)
    assert math.isinf(p.surfaces[2].curvature_per_mm) is False and p.surfaces[2].curvature_per_mm == 0.0
    assert p.entrance_pupil_diameter_mm == 20 and p.stop_index == 1


def _zmx(tmp_path, extra_surface_lines=(), header=()):
    lines = ["MODE SEQ", "UNIT MM", "ENPD 10", *header, "YFLN 0 5", "WAVM 1 0.5876 1",
             "SURF 0", "  DISZ INFINITY", "SURF 1", "  STOP", "  CURV 0.02", "  DISZ 5", "  GLAS N-BK7",
             *extra_surface_lines, "SURF 2", "  CURV -0.02", "  DISZ 40", "SURF 3"]
    f = tmp_path / "t.zmx"
    f.write_text("\n".join(lines))
    return f


@pytest.mark.parametrize("line,match", [("  TYPE TOROIDAL", "TOROIDAL"), ("  GLAS MIRROR", "mirror"),
                                        ("  SQAP 1 1", "SQAP")])
def test_unsupported_surface_content_named(tmp_path, line, match):
    with pytest.raises(PrescriptionError, match=match):
        read_zmx(_zmx(tmp_path, [line]))


@pytest.mark.parametrize("line,match", [("MODE NSC", "sequential"), ("UNIT FT", "lens units 'FT'"),
                                        ("FTYP 1 0 2", "field type"), ("FNUM 4 1", "FNUM: F-number type 1"),
                                        ("OBNA 0.1 0", "OBNA"), ("FNUM 4 0", "more than one system aperture"),
                                        ("FTYP 0 1 2 1 0 0 0", "FTYP: telecentric object space"),
                                        ("FTYP 0 0 2 1 0 0 1", "FTYP: afocal image space"),
                                        ("VDYN 0 0.1", "VDYN: nonzero vignetting"),
                                        ("VCXN 0.2 0", "VCXN: nonzero vignetting"),
                                        ("VANN 0 5", "VANN: nonzero vignetting")])
def test_unsupported_system_settings_named(tmp_path, line, match):
    with pytest.raises(PrescriptionError, match=match):
        read_zmx(_zmx(tmp_path, header=[line]))


def test_yaml_errors_named():
    with pytest.raises(PrescriptionError, match="radius_m"):
        read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 4}, "surfaces": [{"radius_m": 3, "stop": True}]})
    with pytest.raises(PrescriptionError, match="stop"):
        read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 4}, "surfaces": [{"radius_mm": 3}]})
    with pytest.raises(PrescriptionError, match="aperture"):
        read_lens_yaml({"surfaces": [{"radius_mm": 3, "stop": True}]})
    with pytest.raises(FileNotFoundError, match="no_such_lens"):
        load_lens("no_such_lens")


# --- dialects, truncated operands, geometry checks, units (the audit of the lens reader) ------------------------

_SINGLET_SURFACES = ["SURF 0", "  DISZ INFINITY", "SURF 1", "  STOP", "  CURV 0.02", "  DISZ 5", "  GLAS N-BK7",
                     "  DIAM 8", "SURF 2", "  CURV -0.02", "  DISZ 47", "SURF 3"]


def _file(tmp_path, lines, name="t.zmx"):
    f = tmp_path / name
    f.write_text("\n".join(lines))
    return f


def test_old_dialect_fields_and_wavelengths_read_like_the_new(tmp_path):
    old = read_zmx(_file(tmp_path, ["MODE SEQ", "UNIT MM NW NWC", "ENPD 10", "FTYP 0 0", "XFLD 0 0 0",
                                    "YFLD 0 5 10", "WAVL 4.861327E-001 5.875618E-001 6.562725E-001", "WWGT 1 1 1",
                                    "PWAV 2", *_SINGLET_SURFACES], "old.zmx"))
    new = read_zmx(_file(tmp_path, ["MODE SEQ", "UNIT MM", "ENPD 10", "FTYP 0 0 3 3 0 0 0", "XFLN 0 0 0",
                                    "YFLN 0 5 10", "WAVM 1 0.4861327 1", "WAVM 2 0.5875618 1",
                                    "WAVM 3 0.6562725 1", "PWAV 2", *_SINGLET_SURFACES], "new.zmx"))
    for p in (old, new):
        assert p.field_angles_deg == (0.0, 5.0, 10.0) and p.max_field_deg == 10.0
        assert p.wavelengths_nm == pytest.approx((486.1327, 587.5618, 656.2725), rel=1e-12)
        assert p.primary_wavelength_nm == pytest.approx(587.5618, rel=1e-12)
    # old dialect, x and y: radial angles hypot(x, y)
    p = read_zmx(_file(tmp_path, ["ENPD 10", "XFLD 0 3", "YFLD 0 4", *_SINGLET_SURFACES]))
    assert p.field_angles_deg == (0.0, 5.0)


def test_wavm_slots_beyond_ftyp_count_are_inactive(tmp_path):
    # OpticStudio writes 24 WAVM slots (0.55 um in the unused ones); FTYP's fourth value says how many are in use
    slots = ["WAVM 1 0.4861327 1", "WAVM 2 0.5875618 1"] + [f"WAVM {k} 0.55 1" for k in range(3, 25)]
    p = read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 0 0 2 2 0 0 0", "YFLN 0 5 0 0 0 0 0 0 0 0 0 0", *slots,
                                  "PWAV 1", *_SINGLET_SURFACES]))
    assert p.wavelengths_nm == pytest.approx((486.1327, 587.5618), rel=1e-12)
    assert p.primary_wavelength_nm == pytest.approx(486.1327, rel=1e-12) and p.field_angles_deg == (0.0, 5.0)
    with pytest.raises(PrescriptionError, match=r"line 27: PWAV: primary wavelength number 3 is not one of .* 2"):
        read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 0 0 2 2 0 0 0", *slots, "PWAV 3", *_SINGLET_SURFACES]))


@pytest.mark.parametrize("lines,match", [
    (["XFLD 0 0 0", "YFLD 0 5"], "YFLD: 2 field values but XFLD has 3"),
    (["XFLN 0 0", "YFLD 0 5"], "both the XFLN/YFLN and the older XFLD/YFLD"),
    (["WAVL 0.5 0.6", "WAVM 1 0.5 1"], "both WAVM .* and the older WAVL"),
    (["FTYP 0 0 3 1", "YFLN 0 5"], "FTYP declares 3 fields but the field lines hold 2"),
])
def test_ambiguous_field_and_wavelength_lines_refused(tmp_path, lines, match):
    with pytest.raises(PrescriptionError, match=match):
        read_zmx(_file(tmp_path, ["ENPD 10", *lines, *_SINGLET_SURFACES]))


@pytest.mark.parametrize("header,surface_line,op,what", [
    ("ENPD", None, "ENPD", "expected the entrance-pupil diameter"), ("FNUM", None, "FNUM", "expected the F-number"),
    ("UNIT", None, "UNIT", "expected the lens unit"), ("MODE", None, "MODE", "expected a mode"),
    ("GCAT", None, "GCAT", "expected one or more glass catalogue names"),
    ("FTYP", None, "FTYP", "expected the field type"), ("FTYP 0 x", None, "FTYP", "expected an integer, got 'x'"),
    ("YFLN", None, "YFLN", "expected one field angle per field"), ("WAVM 1", None, "WAVM", "expected the wavelength"),
    ("WAVL", None, "WAVL", "expected one wavelength"), ("PWAV", None, "PWAV", "expected the primary"),
    ("VDYN", None, "VDYN", "expected one value per field"),
    (None, "CURV", "CURV", "expected a value"), (None, "CURV abc", "CURV", "expected a number, got 'abc'"),
    (None, "CURV nan", "CURV", "expected a number, got 'nan'"), (None, "DISZ", "DISZ", "expected a value"),
    (None, "CONI", "CONI", "expected a value"), (None, "GLAS", "GLAS", "expected a glass name"),
    (None, "PARM", "PARM", "expected the parameter number"), (None, "PARM 2", "PARM", "expected the parameter value"),
    (None, "DIAM", "DIAM", "expected the semi-diameter"), (None, "CLAP 0", "CLAP", "expected the maximum radius"),
    (None, "FLAP 0", "FLAP", "surface 2: floating aperture without a semi-aperture"),
    (None, "TYPE", "TYPE", "expected a surface type"),
])
def test_truncated_operand_names_line_and_keyword(tmp_path, header, surface_line, op, what):
    lines = ["MODE SEQ", "ENPD 10" if header not in ("ENPD", "FNUM") else header, "YFLN 0 5",
             *([header] if header not in (None, "ENPD", "FNUM") else []), *_SINGLET_SURFACES]
    if surface_line is not None:
        lines.insert(lines.index("SURF 2") + 1, "  " + surface_line)
    lineno = next(i for i, t in enumerate(lines, 1) if t.split() and t.split()[0] == op and
                  (t.strip() == (header or surface_line) or t.strip() == surface_line))
    with pytest.raises(PrescriptionError, match=rf"t\.zmx: line {lineno}: {op}: {what}"):
        read_zmx(_file(tmp_path, lines))


@pytest.mark.parametrize("stop_surface,where", [(0, "object"), (3, "image")])
def test_stop_on_object_or_image_refused(tmp_path, stop_surface, where):
    lines = [t for t in _SINGLET_SURFACES if t.strip() != "STOP"]
    lines.insert(lines.index(f"SURF {stop_surface}") + 1, "  STOP")
    with pytest.raises(PrescriptionError, match=f"STOP on the {where} surface .*strictly between"):
        read_zmx(_file(tmp_path, ["ENPD 10", *lines]))


def test_negative_thickness_only_in_air(tmp_path):
    glass = [t.replace("DISZ 5", "DISZ -5") for t in _SINGLET_SURFACES]
    with pytest.raises(PrescriptionError, match="surface 1: negative thickness -5.0 mm inside glass 'N-BK7'"):
        read_zmx(_file(tmp_path, ["ENPD 10", *glass]))
    with pytest.raises(PrescriptionError, match="surface 1: negative thickness .* inside glass"):
        read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 4},
                        "surfaces": [{"radius_mm": 50, "thickness_mm": -5, "material": "N-BK7", "stop": True},
                                     {"radius_mm": -50, "thickness_mm": 47}]})
    air = [t.replace("DISZ 47", "DISZ -2") for t in _SINGLET_SURFACES] + ["  DISZ 0"]
    assert read_zmx(_file(tmp_path, ["ENPD 10", *air])).surfaces[2].thickness_mm == -2.0  # negative air gap: allowed


def test_curved_image_refused_flat_accepted(tmp_path):
    curved = _SINGLET_SURFACES + ["  CURV -0.02"]
    with pytest.raises(PrescriptionError, match="image surface 3: curvature -0.02 .*CURV.*flat"):
        read_zmx(_file(tmp_path, ["ENPD 10", *curved]))
    assert read_zmx(_file(tmp_path, ["ENPD 10", *_SINGLET_SURFACES, "  CURV 0.0"])).surfaces[3].curvature_per_mm == 0


def test_zero_vignetting_factors_and_ftyp_flags_accepted(tmp_path):
    p = read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0 0 0", "YFLN 0 5 0 0",
                                  "VDXN 0 0 0 0", "VDYN 0 0 0 0", "VCXN 0 0 0 0", "VCYN 0 0 0 0", "VANN 0 0 0 0",
                                  *_SINGLET_SURFACES]))
    assert p.field_angles_deg == (0.0, 5.0)
    # nonzero values in the inactive slots beyond FTYP's field count are not the lens's
    p = read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 0 0 2 1", "YFLN 0 5 7", "VDYN 0 0 0.3", *_SINGLET_SURFACES]))
    assert p.field_angles_deg == (0.0, 5.0)


def test_far_object_is_infinity_nearer_is_the_design_conjugate(tmp_path):
    far = [t.replace("DISZ INFINITY", "DISZ 1.0E+10") for t in _SINGLET_SURFACES]
    p = read_zmx(_file(tmp_path, ["ENPD 10", *far]))
    assert math.isinf(p.surfaces[0].thickness_mm) and math.isinf(p.object_distance_mm)
    # a finite object is the conjugate the file was designed for, in mm (it was refused); the surface list starts
    # at infinity whatever the file's object distance
    near = [t.replace("DISZ INFINITY", "DISZ 1.0E+8") for t in _SINGLET_SURFACES]
    assert read_zmx(_file(tmp_path, ["ENPD 10", *near])).object_distance_mm == 1e8
    cm = [t.replace("DISZ INFINITY", "DISZ 25") for t in _SINGLET_SURFACES]
    p = read_zmx(_file(tmp_path, ["UNIT CM X W X CM MR CPMM", "ENPD 1", *cm]))
    assert p.object_distance_mm == 250.0 and math.isinf(p.surfaces[0].thickness_mm)
    # a virtual object, or one on the first vertex, is refused naming the line; object heights need a finite object
    for bad in ("-300", "0"):
        lines = [t.replace("DISZ INFINITY", f"DISZ {bad}") for t in _SINGLET_SURFACES]
        with pytest.raises(PrescriptionError, match=rf"line 3: DISZ: object distance \(surface 0's DISZ\) {bad}; "):
            read_zmx(_file(tmp_path, ["ENPD 10", *lines]))
    with pytest.raises(PrescriptionError, match="line 2: FTYP: field type 1 .object heights. with the object at inf"):
        read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 1 0 2 1", "YFLN 0 5", *_SINGLET_SURFACES]))
    # object heights of a finite object: theta = atan(h / (D + z_EP)), the stop (entrance pupil) on the first
    # vertex here: z_EP = 0
    obj = [t.replace("DISZ INFINITY", "DISZ 500") for t in _SINGLET_SURFACES]
    p = read_zmx(_file(tmp_path, ["ENPD 10", "FTYP 1 0 2 1", "YFLN 0 40", *obj]))
    assert p.field_angles_deg == pytest.approx((0.0, math.degrees(math.atan(40 / 500))), abs=1e-12)


def test_yaml_object_distance(tmp_path):
    base = {"aperture": {"entrance_pupil_diameter_mm": 10}, "catalogs": ["SCHOTT"],
            "surfaces": [{"radius_mm": 50, "thickness_mm": 5, "material": "N-BK7", "stop": True},
                         {"radius_mm": -50, "thickness_mm": 47}]}
    assert math.isinf(read_lens_yaml(base).object_distance_mm)
    assert read_lens_yaml({**base, "object_distance_mm": 800}).object_distance_mm == 800.0
    for bad in (0, -5, "near", float("nan")):
        with pytest.raises(PrescriptionError, match="object_distance_mm"):
            read_lens_yaml({**base, "object_distance_mm": bad})


def _asphere_lines(mm_per_unit, unit):
    """A conic + even-asphere singlet with clear apertures, written in ``unit`` (``mm_per_unit`` mm each): lengths
    divided by it, CURV multiplied, the r^(2k) coefficient a_k (length^(1-2k)) multiplied by L^(2k-1)."""
    L = mm_per_unit
    a = (1e-4, -2e-6, 3e-9)
    return [f"UNIT {unit} X W X CM MR CPMM", f"ENPD {10 / L!r}", "YFLN 0 5 8", "WAVM 1 0.5875618 1",
            "SURF 0", "  DISZ INFINITY", "SURF 1", "  STOP", "  TYPE EVENASPH", f"  CURV {0.02 * L!r}",
            "  CONI -0.5", *[f"  PARM {k} {ak * L ** (2 * k - 1)!r}" for k, ak in enumerate(a, 1)],
            f"  DISZ {6 / L!r}", "  GLAS N-BK7", f"  DIAM {9 / L!r}", f"  CLAP 0 {8.5 / L!r} 0",
            "SURF 2", f"  CURV {-1 / 80 * L!r}", f"  DISZ {60 / L!r}", f"  FLAP 0 {9 / L!r} 0", "SURF 3"]


@pytest.mark.parametrize("unit,mm", [("CM", 10.0), ("IN", 25.4), ("M", 1000.0)])
def test_lens_units_converted_to_mm(tmp_path, unit, mm):
    ref = read_zmx(_file(tmp_path, _asphere_lines(1.0, "MM"), "mm.zmx"))
    p = read_zmx(_file(tmp_path, _asphere_lines(mm, unit), f"{unit}.zmx"))
    assert p.entrance_pupil_diameter_mm == pytest.approx(10.0, rel=1e-12)
    for s, r in zip(p.surfaces, ref.surfaces, strict=True):
        assert s.curvature_per_mm == pytest.approx(r.curvature_per_mm, rel=1e-12)
        assert s.thickness_mm == pytest.approx(r.thickness_mm, rel=1e-12)
        assert s.aspheric == pytest.approx(r.aspheric, rel=1e-12)
        for k in ("semi_diameter_mm", "aperture_mm", "aperture_min_mm"):
            if getattr(r, k) is None:
                assert getattr(s, k) is None
            else:
                assert getattr(s, k) == pytest.approx(getattr(r, k), rel=1e-12)
    assert ref.surfaces[1].aspheric == (1e-4, -2e-6, 3e-9) and ref.surfaces[1].aperture_mm == 8.5


def test_flap_takes_the_semi_diameter_in_any_order(tmp_path):
    lines = _SINGLET_SURFACES[:-1] + ["  FLAP 0 0 0", "  DIAM 7.5", "SURF 3"]
    assert read_zmx(_file(tmp_path, ["ENPD 10", *lines])).surfaces[2].aperture_mm == 7.5
    with pytest.raises(PrescriptionError, match="FLAP: surface 2: floating aperture .* no semi-diameter"):
        read_zmx(_file(tmp_path, ["ENPD 10", *_SINGLET_SURFACES[:-1], "  FLAP 0 0 0", "SURF 3"]))


def test_fnum_aperture_read(tmp_path):
    p = read_zmx(_file(tmp_path, ["FNUM 5 0", *_SINGLET_SURFACES]))
    assert p.image_f_number == 5.0 and p.entrance_pupil_diameter_mm is None and not p.float_by_stop


_YAML_SINGLET = ("aperture: {entrance_pupil_diameter_mm: 10}\nfield_angles_deg: [0, 5]\ncatalogs: [SCHOTT]\n"
                 "surfaces:\n  - {radius_mm: 50, thickness_mm: 5, material: N-BK7, stop: true}\n"
                 "  - {radius_mm: -50, thickness_mm: 47}\n")


@pytest.mark.parametrize("text,match", [
    ("name: bad\nsurfaces: [\n  - {radius_mm: 50\n", "bad.yaml: not valid YAML"),
    ("- just\n- a list\n", "bad.yaml: expected a mapping with a 'surfaces' list, got list"),
    ("name: no surfaces\n", "bad.yaml: expected a mapping with a 'surfaces' list"),
    (_YAML_SINGLET.replace("{entrance_pupil_diameter_mm: 10}", "10"), r"bad.yaml: aperture: expected a mapping"),
    (_YAML_SINGLET.replace("{entrance_pupil_diameter_mm: 10}", "{epd: 10}"), r"aperture: unknown keys \['epd'\]"),
    (_YAML_SINGLET.replace("[0, 5]", "10"), "bad.yaml: field_angles_deg: expected a list of angles"),
    (_YAML_SINGLET.replace("[0, 5]", "[0, five]"), r"bad.yaml: field_angles_deg\[1\]: expected a number"),
    (_YAML_SINGLET.replace("catalogs: [SCHOTT]", "catalogs: SCHOTT"), "bad.yaml: catalogs: expected a list"),
    (_YAML_SINGLET + "wavelengths_nm: 550\n", "bad.yaml: wavelengths_nm: expected a list"),
    (_YAML_SINGLET + "primary_wavelength_nm: green\n", "bad.yaml: primary_wavelength_nm: expected a number"),
    (_YAML_SINGLET + "focal_length_mm: 50\n", r"bad.yaml: unknown keys \['focal_length_mm'\]"),
    ("aperture: {entrance_pupil_diameter_mm: 10}\nsurfaces:\n  - 5\n  - 6\n",
     "bad.yaml: surface 1: expected a mapping"),
    ("aperture: {entrance_pupil_diameter_mm: 10}\nsurfaces: {radius_mm: 5}\n", "bad.yaml: surfaces: expected a list"),
    (_YAML_SINGLET.replace("radius_mm: 50", "radius_mm: abc"), "bad.yaml: surface 1: radius_mm: expected a number, "
                                                                 "got 'abc'"),
    (_YAML_SINGLET.replace("radius_mm: -50", "radius_mm: [1]"), "bad.yaml: surface 2: radius_mm: expected a number"),
    (_YAML_SINGLET.replace("stop: true", "stop: 'yes'"), "bad.yaml: surface 1: stop: expected true or false"),
    (_YAML_SINGLET.replace("thickness_mm: 47", "thickness_mm: 47, semi_diameter_mm: big"),
     "bad.yaml: surface 2: semi_diameter_mm: expected a number"),
    (_YAML_SINGLET.replace("material: N-BK7", "material: 7"), "bad.yaml: surface 1: material: expected a glass name"),
    (_YAML_SINGLET.replace("thickness_mm: 47", "thickness_mm: 47, aspheric: 1e-5"),
     "bad.yaml: surface 2: aspheric: expected a list"),
])
def test_bad_yaml_lens_named(tmp_path, text, match):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(PrescriptionError, match=match):
        read_lens_yaml(f)


def test_yaml_numbers_and_fnum(tmp_path):
    # PyYAML reads 1e-5 (no dot) as a string: still a number here
    f = tmp_path / "ok.yaml"
    f.write_text(_YAML_SINGLET.replace("{entrance_pupil_diameter_mm: 10}", "{image_f_number: 4}")
                 .replace("thickness_mm: 47", "thickness_mm: 47, aspheric: [0, 1e-5]"))
    p = read_lens_yaml(f)
    assert p.image_f_number == 4.0 and p.surfaces[2].aspheric == (0.0, 1e-5) and p.surfaces[2].kind == "EVENASPH"


def test_a_prescription_with_nan_or_negative_numbers_is_refused():
    """A NaN curvature or thickness gave a NaN focal length, a negative semi-diameter and a string is_stop were
    taken; the differentiable trace's curvatures too. Each is named with its surface."""
    import dataclasses

    import torch

    from isettorch.optics.lens import LensAnalysis, Prescription

    lens = load_lens("cooke_triplet")
    assert math.isfinite(LensAnalysis(lens).effective_focal_length_mm)
    for i, change, key in ((1, {"curvature_per_mm": math.nan}, "curvature_per_mm"),
                           (2, {"thickness_mm": math.nan}, "thickness_mm"),
                           (1, {"semi_diameter_mm": -1.0}, "semi_diameter_mm"),
                           (2, {"conic": math.inf}, "conic")):
        surfaces = list(lens.surfaces)
        surfaces[i] = dataclasses.replace(surfaces[i], **change)
        with pytest.raises(PrescriptionError, match=f"surface {i}: {key}: expected"):
            Prescription(**{**dataclasses.asdict(lens), "surfaces": surfaces})
    c = torch.tensor([s.curvature_per_mm for s in lens.surfaces[1:-1]], dtype=torch.float64)  # lens surfaces
    c[1] = math.nan
    with pytest.raises(ValueError, match="curvature_per_mm: expected finite curvatures"):
        LensAnalysis(lens, curvature_per_mm=c)


@pytest.mark.parametrize(("line", "match"), [
    ("CLAP -3 6 0", "aperture_min_mm .CLAP's minimum radius.: expected 0 <= minimum <= maximum radius 6.0, got -3.0"),
    ("CLAP 8 6 0", "aperture_min_mm .CLAP's minimum radius.: expected 0 <= minimum <= maximum radius 6.0, got 8.0"),
    ("FLAP 0 -6", "FLAP: expected a semi-aperture >= 0 .0: floating., got -6.0"),
])
def test_clear_aperture_radii_are_checked(tmp_path, line, match):
    """A negative CLAP minimum was a central obstruction of its size (the tracer keeps rho^2 >= rmin^2: 38 % of the
    axial rays blocked at -3 mm), one above the maximum blocked every ray with no word of CLAP, a negative FLAP
    semi-aperture became a floating aperture (the DIAM value)."""
    lines = ["ENPD 10", *_SINGLET_SURFACES]
    lines.insert(lines.index("SURF 2") + 1, "  " + line)
    with pytest.raises(PrescriptionError, match=match):
        read_zmx(_file(tmp_path, lines))
    lines[lines.index("  " + line)] = "  CLAP 0 6 0"  # the valid form reads
    assert read_zmx(_file(tmp_path, lines)).surfaces[2].aperture_mm == 6.0


def test_yaml_standard_surface_refuses_aspheric_terms_and_glass_needs_a_thickness():
    """An explicit STANDARD type with aspheric coefficients traced an asphere (the .zmx reader ignores PARM on a
    STANDARD surface: the same lens read two ways); a glass surface without thickness_mm was a lens 0 mm thick."""
    base = {"aperture": {"entrance_pupil_diameter_mm": 8.0}, "catalogs": ["SCHOTT"]}
    with pytest.raises(PrescriptionError, match="surface 1: aspheric: coefficients on a STANDARD surface"):
        read_lens_yaml({**base, "surfaces": [
            {"radius_mm": 50, "thickness_mm": 3, "material": "N-BK7", "stop": True, "type": "STANDARD",
             "aspheric": [1e-3]}, {"radius_mm": -50, "thickness_mm": 90}]})
    asph = read_lens_yaml({**base, "surfaces": [
        {"radius_mm": 50, "thickness_mm": 3, "material": "N-BK7", "stop": True, "aspheric": [1e-3]},
        {"radius_mm": -50, "thickness_mm": 90}]})
    assert asph.surfaces[1].kind == "EVENASPH" and asph.surfaces[1].aspheric == (1e-3,)
    with pytest.raises(PrescriptionError, match="surface 1: thickness_mm: a surface followed by glass .N-BK7."):
        read_lens_yaml({**base, "surfaces": [{"radius_mm": 50, "material": "N-BK7", "stop": True},
                                             {"radius_mm": -50}]})


def test_an_empty_field_list_is_named():
    """field_angles_deg: [] passed the check and failed later as 'max() arg is an empty sequence'."""
    with pytest.raises(PrescriptionError, match=r"field_angles_deg: expected one or more angles"):
        read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 8.0}, "catalogs": ["SCHOTT"],
                        "field_angles_deg": [], "surfaces": [
                            {"radius_mm": 50, "thickness_mm": 3, "material": "N-BK7", "stop": True},
                            {"radius_mm": -50, "thickness_mm": 90}]})


def test_yaml_air_in_any_case_and_mirrors_are_named():
    """``material: Air`` was taken as a glass (a thickness demanded, a negative air gap refused); a YAML mirror read as
    a glass not found or glass of negative thickness, where the .zmx reader says mirrors are not supported."""
    lens = {"aperture": {"entrance_pupil_diameter_mm": 10},
            "surfaces": [{"radius_mm": 40, "thickness_mm": 4, "material": "N-BK7", "stop": True},
                         {"radius_mm": -40, "material": "Air"},
                         {"radius_mm": 30, "thickness_mm": 3, "material": "N-BK7"},
                         {"radius_mm": 60, "thickness_mm": 40, "material": "AiR"}]}
    p = read_lens_yaml(lens)
    assert [s.material for s in p.surfaces[1:5]] == ["N-BK7", None, "N-BK7", None] and p.surfaces[2].thickness_mm == 0
    lens["surfaces"][1]["thickness_mm"] = -1.0  # a negative air gap is allowed
    assert read_lens_yaml(lens).surfaces[2].thickness_mm == -1.0
    for t in (-50.0, 5.0):
        mirror = {"surfaces": [{"radius_mm": -100, "thickness_mm": t, "material": "MIRROR", "stop": True}]}
        with pytest.raises(PrescriptionError, match=r"surface 1: material: mirrors are not supported"):
            read_lens_yaml(mirror)


def test_an_unknown_glass_in_a_zmx_names_the_file(tmp_path):
    from isettorch.optics.lens import GlassError, LensAnalysis

    f = tmp_path / "t.zmx"
    f.write_text(_zmx(tmp_path).read_text().replace("GLAS N-BK7", "GLAS XYZGLASS1").replace("MODE SEQ",
                                                                                          "NAME My singlet\nMODE SEQ"))
    with pytest.raises(GlassError, match=rf"My singlet \({f}\), the medium after surface 1: glass 'XYZGLASS1'"):
        LensAnalysis(f).paraxial(587.6)


def test_model_glasses_read_as_buchdahls_model_of_nd_and_vd(tmp_path):
    """A model glass (GLAS ___BLANK 1 0 n_d V_d ..., as designs from patents give their glasses; YAML "n_d/V_d") was
    refused. It is Buchdahl's model of n_d and V_d: n_d exact at the d line, n_F - n_C = (n_d - 1) / V_d, and within
    2.5e-4 of N-BK7 (n_d 1.5168, V_d 64.17) over 450-700 nm (opticalglass 1.1.1's own model glass has V_d 68.0)."""
    from isettorch.optics.lens.glass import GlassError, refractive_index

    name = "1.5168/64.17"
    assert refractive_index(name, 587.5618) == pytest.approx(1.5168, abs=1e-12)
    nf_nc = refractive_index(name, 486.1327) - refractive_index(name, 656.2725)
    assert nf_nc == pytest.approx(0.5168 / 64.17, rel=1e-9)
    for w in (450.0, 550.0, 700.0):
        assert refractive_index(name, w) == pytest.approx(refractive_index("N-BK7", w), abs=2.5e-4)
    with pytest.raises(GlassError, match="outside its valid range"):
        refractive_index(name, 2000.0)
    with pytest.raises(GlassError, match=r"model glass n_d/V_d needs 1 < n_d < 3"):
        refractive_index("0.9/64", 550.0)
    model = read_zmx(_zmx(tmp_path, ["  GLAS ___BLANK 1 0 1.5168 6.417E+1 0 0 0 0 0 0"]))
    assert model.surfaces[1].material == name
    catalogue = read_zmx(_zmx(tmp_path))
    f_model = float(LensAnalysis(model).effective_focal_length_mm)
    assert f_model == pytest.approx(float(LensAnalysis(catalogue).effective_focal_length_mm), rel=1e-5)
    # the thin-lens power (n - 1)(c1 - c2) of a 5 mm thick biconvex lens: the lensmaker's equation at n_d
    n, c1, c2, t = 1.5168, 0.02, -0.02, 5.0
    power = (n - 1) * (c1 - c2) + (n - 1) ** 2 * t * c1 * c2 / n
    assert f_model == pytest.approx(1 / power, rel=1e-4)  # (at the primary 587.6 nm, not quite the d line)
    yaml_lens = read_lens_yaml({"aperture": {"entrance_pupil_diameter_mm": 10}, "surfaces": [
        {"radius_mm": 50, "thickness_mm": 5, "material": name, "stop": True}, {"radius_mm": -50, "thickness_mm": 40}]})
    assert float(LensAnalysis(yaml_lens).effective_focal_length_mm) == pytest.approx(f_model, rel=1e-12)
    with pytest.raises(PrescriptionError, match=r"line 13: GLAS: expected the model glass's V_d after n_d"):
        read_zmx(_zmx(tmp_path, ["  GLAS ___BLANK 1 0 1.5168"]))


def test_a_zmx_glass_without_its_thickness_is_refused(tmp_path):
    """A surface followed by glass with no DISZ was read as glass 0 mm thick (the YAML reader refuses it)."""
    f = _zmx(tmp_path)
    f.write_text(f.read_text().replace("  DISZ 5\n", ""))
    with pytest.raises(PrescriptionError, match=r"line 8: SURF: surface 1 is followed by glass \(N-BK7\) but has no "
                                                 r"DISZ"):
        read_zmx(f)


def test_image_height_fields_are_read_as_the_angles_that_reach_them(tmp_path):
    """Zemax files of camera lenses often give their fields as image heights (FTYP 2 paraxial, 3 real), which were
    refused. A real height is the traced chief ray's at the paraxial image plane (Newton's method on the trace), a
    paraxial one f tan(theta); heights are in lens units like every length."""
    def lens(ftype, value, unit="MM"):
        f = _zmx(tmp_path, header=[f"FTYP {ftype} 0 2 1"])
        text = f.read_text().replace("UNIT MM", f"UNIT {unit}").replace("YFLN 0 5", f"YFLN 0 {value}")
        if unit == "CM":  # the same lens in cm
            text = (text.replace("CURV 0.02", "CURV 0.2").replace("CURV -0.02", "CURV -0.2")
                    .replace("DISZ 5", "DISZ 0.5").replace("DISZ 40", "DISZ 4").replace("ENPD 10", "ENPD 1"))
        f.write_text(text)
        return read_zmx(f)

    by_angle = LensAnalysis(lens(0, 12))
    real_mm = float(by_angle.image_height_mm(1.0, by_angle.prescription.primary_wavelength_nm))
    efl = float(by_angle.effective_focal_length_mm)
    assert abs(real_mm - efl * math.tan(math.radians(12))) > 1e-3  # (the lens distorts: the two kinds differ)
    assert lens(3, real_mm).field_angles_deg == pytest.approx((0.0, 12.0), abs=1e-9)
    assert lens(3, real_mm / 10, "CM").field_angles_deg == pytest.approx((0.0, 12.0), abs=1e-9)
    paraxial = lens(2, efl * math.tan(math.radians(12))).field_angles_deg
    assert paraxial == pytest.approx((0.0, 12.0), abs=1e-9)
    with pytest.raises(PrescriptionError, match=r"FTYP: field type 4; expected angles \(FTYP 0\), object heights"):
        lens(4, 5)


def test_catalogue_glass_names_and_arguments():
    """An audit found Hoya's FDS20-W refused as "not found" (opticalglass keeps its name as 'FDS20-W '), Hikari's
    J-PSKH8 (listed without dispersion coefficients) reported as "not found ... add its catalogue to GCAT" although
    HIKARI was given, and refractive_index's catalogs as a list failing as unhashable, as a bare string searched
    letter by letter."""
    import warnings

    from isettorch.optics.lens.glass import GlassError, refractive_index

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # opticalglass's own spreadsheet warnings
        assert refractive_index("FDS20-W", 587.5618, ("HOYA",)) == pytest.approx(1.86966, abs=5e-6)  # Hoya n_d
        assert refractive_index("fds20-w", 587.5618, ("HOYA",)) == refractive_index("FDS20-W", 587.5618, ("HOYA",))
        with pytest.raises(GlassError, match=r"^glass 'J-PSKH8': listed in \[.HIKARI .*without dispersion "
                                             r"coefficients"):
            refractive_index("J-PSKH8", 587.5618, ("HIKARI",))
        assert refractive_index("N-BK7", 587.5618, ["SCHOTT"]) == pytest.approx(1.5168, abs=1e-6)
        with pytest.raises(ValueError, match=r"^catalogs: expected a sequence of catalogue names"):
            refractive_index("N-BK7", 587.5618, "SCHOTT")
        with pytest.raises(ValueError, match=r"^name: expected a glass name \(str\) or None"):
            refractive_index(5, 587.5618)
