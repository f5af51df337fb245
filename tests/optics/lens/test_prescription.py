"""Reading lens prescriptions (.zmx in its encodings, YAML) and bad input."""

import math

import pytest

from isettorch.optics.lens import PrescriptionError, bundled_lenses, load_lens, read_lens_yaml, read_zmx
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
    for enc in ("utf-8", "latin-1", "utf-16-le"):
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


@pytest.mark.parametrize("line,match", [("MODE NSC", "sequential"), ("UNIT IN", "IN"), ("FTYP 1 0 2", "field type"),
                                        ("FNUM 4 0", "FNUM")])
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
