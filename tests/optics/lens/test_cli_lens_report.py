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
    assert set(rep) == {"effective_focal_length_mm", "f_number", "max_field_deg", "rows"}
    assert rep["max_field_deg"] == 20.0 and rep["f_number"] == pytest.approx(rep["effective_focal_length_mm"] / 10)
    assert len(rep["rows"]) == 4
    keys = {"field", "wavelength_nm", "image_height_mm", "distortion_percent", "relative_illumination",
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
