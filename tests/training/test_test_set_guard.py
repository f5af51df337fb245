"""The test sets (Kodak, McMaster) are never trained, tuned or selected on: the scripts that take photographs for
those purposes refuse any of their images, recognised by pixels (any file format, any name)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from training import codesign, common, fit_joint_gate, heldout_screen, photo_select  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"


@pytest.fixture
def planted(tmp_path, monkeypatch):
    """A folder holding a 'test-set' image saved as TIFF under another name, the fingerprints naming it."""
    g = np.random.default_rng(3)
    test_image = (g.random((24, 20, 3)) * 255).astype(np.uint8)
    prints = tmp_path / "prints.json"
    prints.write_text(json.dumps({"kodak24": [common.pixel_fingerprint(test_image)]}))
    monkeypatch.setattr(common, "TEST_SET_FINGERPRINTS", prints)
    folder = tmp_path / "photos"
    folder.mkdir()
    Image.fromarray((g.random((24, 20, 3)) * 255).astype(np.uint8)).save(folder / "a.png")
    Image.fromarray(test_image).save(folder / "holiday.tif")
    return folder


def test_a_test_image_is_refused_by_every_script_that_learns_or_selects(planted):
    with pytest.raises(ValueError, match="holiday.tif is an image of the test set kodak24"):
        common.refuse_test_images(planted, "data.folder")
    cfg = codesign.merged_config({"data": {"source": "photos", "folder": str(planted)}})
    with pytest.raises(ValueError, match="data.folder: holiday.tif"):  # (codesign trained on Kodak, rc 0)
        codesign.source_photos(2, 1, 16, None, cfg, 0)
    with pytest.raises(SystemExit, match="--sets: holiday.tif"):  # (a ship decision on McMaster)
        heldout_screen.main(["--incumbent", "a.pt", "--candidate", "b.pt", "--sets", str(planted)])
    with pytest.raises(SystemExit):  # argparse's error (exit 2) naming --sets
        fit_joint_gate.main(["--sets", str(planted)])
    with pytest.raises(ValueError, match="--photos: holiday.tif"):  # (the ship rule's photographs were unchecked)
        photo_select.main(["a.pt", "--variant", "tiny", "--photos", str(planted), "--scales", "0.5"])
    (planted / "holiday.tif").unlink()
    common.refuse_test_images(planted, "data.folder")  # other photographs pass


def test_the_recorded_fingerprints_are_the_shared_test_sets():
    if not SHARED.is_dir():
        pytest.skip("the shared test sets are not beside this checkout")
    recorded = json.loads(common.TEST_SET_FINGERPRINTS.read_text())
    from isettorch.isp.evaluation import load_images

    for name in ("kodak24", "mcmaster18"):
        assert sorted(common.pixel_fingerprint(a) for _, a in load_images(SHARED / name)) == recorded[name]
