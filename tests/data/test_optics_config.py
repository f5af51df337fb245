"""camera.optics of a data config is checked by the optics config factory (isettorch.optics.factory.build_optics,
what Camera.from_config uses): merge_config builds it once, so a bad type, a mistyped key or a missing PSF file
is reported when the config is read, with the factory's own message under the argument camera.optics."""

import pytest

from isettorch.data.config import CAMERA_DEFAULTS, merge_config


@pytest.mark.parametrize("optics, message", [
    ({"type": "pinhole"}, r"camera\.optics\[type='pinhole'\]: .*unknown optics\.type 'pinhole'.*'lens'"),
    ({"type": "lens", "lenz": "cooke_triplet"},
     r"camera\.optics\[type='lens'\]: .*unknown key 'lenz'.*did you mean 'lens'"),
    ({"type": "psf_file"}, r"camera\.optics\[type='psf_file'\]: .*needs 'path'"),
    ({"type": "psf_file", "path": "no_such_psf.npz"}, r"camera\.optics\[type='psf_file'\]: .*no_such_psf\.npz"),
    ({"f_number": -1.0}, r"camera\.optics\[type='diffraction_limited'\]: f_number"),
])
def test_bad_optics_sections_name_camera_optics(optics, message):
    with pytest.raises(ValueError, match=message):
        merge_config({"optics": optics}, CAMERA_DEFAULTS, "camera")


def test_good_optics_sections_pass_unchanged():
    for optics in ({}, {"type": "wavefront", "f_number": 2.0}, {"type": "lens", "lens": "cooke_triplet"}):
        assert merge_config({"optics": optics}, CAMERA_DEFAULTS, "camera")["optics"] == optics
