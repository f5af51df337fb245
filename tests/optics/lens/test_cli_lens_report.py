"""The lens-report command prints exactly issue 16's JSON object; bad input exits 2 with a message."""

import json

import pytest

pytest.importorskip("opticalglass")

from isettorch.cli import main  # noqa: E402


def test_lens_report_json_shape(capsys):
    rc = main(["lens-report", "cooke_triplet", "--fields", "0,1", "--wavelengths-nm", "486.1,587.6",
               "--frequencies-cy-mm", "20,40", "--pupil-samples", "32", "--json"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep) == {"effective_focal_length_mm", "f_number", "max_field_deg", "image_plane", "rows"}
    assert rep["image_plane"] == "paraxial"
    assert rep["max_field_deg"] == 20.0 and rep["f_number"] == pytest.approx(rep["effective_focal_length_mm"] / 10)
    assert len(rep["rows"]) == 4
    keys = {"field", "wavelength_nm", "image_height_mm", "distortion_percent", "relative_illumination",
            "relative_illumination_flux",
            "chief_ray_angle_deg", "mtf_tangential", "mtf_sagittal"}
    for r in rep["rows"]:
        assert set(r) == keys and len(r["mtf_tangential"]) == len(r["mtf_sagittal"]) == 2
    assert [(r["field"], r["wavelength_nm"]) for r in rep["rows"]] == [(0, 486.1), (0, 587.6), (1, 486.1), (1, 587.6)]


def test_lens_report_bad_input(capsys, tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("aperture: {entrance_pupil_diameter_mm: 4}\ncatalogs: [SCHOTT]\nsurfaces:\n"
                 "  - {radius_mm: 20, thickness_mm: 3, material: NOPE-42, stop: true}\n"
                 "  - {radius_mm: -20, thickness_mm: 20}\n")
    assert main(["lens-report", str(f), "--json"]) == 2
    assert "NOPE-42" in capsys.readouterr().err
    assert main(["lens-report", "cooke_triplet", "--fields", "0,1.2", "--json"]) == 2
    assert "beyond the lens" in capsys.readouterr().err
    truncated = tmp_path / "truncated.zmx"
    truncated.write_text("ENPD 10\nSURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  CURV\nSURF 2\n")
    fast = ["--fields", "0", "--wavelengths-nm", "587.6", "--frequencies-cy-mm", "20"]
    # each: one line on stderr naming the argument (as isettorch.cli shows it), exit code 2, no traceback
    cases = [(["--pupil-samples", "0"], "--pupil-samples"), (["--pupil-samples", "-4"], "--pupil-samples"),
             (["--pupil-samples", "1"], "--pupil-samples"), (["--pupil-samples", "15"], "--pupil-samples"),
             (["--pupil-samples", "100000"], "--pupil-samples"),
             (["--wavelengths-nm", "0"], "--wavelengths-nm"), (["--wavelengths-nm", "-550"], "--wavelengths-nm"),
             (["--wavelengths-nm", "nan"], "--wavelengths-nm"), (["--wavelengths-nm", "inf"], "--wavelengths-nm"),
             (["--wavelengths-nm", "5000"], "outside its valid range"),
             (["--frequencies-cy-mm", "-1"], "--frequencies-cy-mm"),
             (["--frequencies-cy-mm", "nan"], "--frequencies-cy-mm"),
             (["--frequencies-cy-mm", "inf"], "--frequencies-cy-mm"),
             (["--fields", "-0.1"], "--fields"), (["--fields", "nan"], "--fields")]
    for args, named in cases:
        opts = dict(zip(fast[::2], fast[1::2]))
        opts.update(dict(zip(args[::2], args[1::2])))
        argv = ["lens-report", "cooke_triplet", *[x for kv in opts.items() for x in kv], "--json"]
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "Traceback" not in err and len(err.splitlines()) == 1, (argv, err)
        assert err.startswith("isettorch lens-report: ") and named in err, (argv, err)
    assert main(["lens-report", str(truncated), "--json"]) == 2
    assert "truncated.zmx: line 6: CURV: expected a value" in capsys.readouterr().err


def test_lens_report_defaults_to_the_files_wavelengths(capsys, tmp_path):
    f = tmp_path / "two.yaml"
    f.write_text("aperture: {entrance_pupil_diameter_mm: 4}\ncatalogs: [SCHOTT]\nwavelengths_nm: [500, 600]\n"
                 "surfaces:\n  - {radius_mm: 20, thickness_mm: 3, material: N-BK7, stop: true}\n"
                 "  - {radius_mm: -20, thickness_mm: 20}\n")
    assert main(["lens-report", str(f), "--fields", "0", "--pupil-samples", "16", "--json"]) == 0
    assert [r["wavelength_nm"] for r in json.loads(capsys.readouterr().out)["rows"]] == [500.0, 600.0]
