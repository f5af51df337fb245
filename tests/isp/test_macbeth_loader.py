"""One Macbeth loader: the ISP's reflectance set, the chart's true colours and the scene read the same data
(isettorch.scene.macbeth_reflectances, colour-science's BabelColor average)."""

import colour
import numpy as np
import torch

from isettorch.isp.chart import macbeth_true_xyz
from isettorch.isp.colour import reflectance_set
from isettorch.scene import macbeth, macbeth_reflectances


def test_reflectance_set_is_the_scene_loader():
    w = torch.arange(395.0, 736.0, 5.0, dtype=torch.float64)  # beyond 380-730 nm: end values held
    assert torch.equal(reflectance_set("macbeth", w), macbeth_reflectances(w, dtype=torch.float64))
    native = colour.SDS_COLOURCHECKERS["BabelColor Average"]
    ref = np.stack([sd[np.arange(400, 701, 10)] for sd in native.values()])
    np.testing.assert_allclose(reflectance_set("macbeth", torch.arange(400.0, 701.0, 10.0)).numpy(), ref, atol=1e-12)


def test_chart_truth_matches_colour_science():
    """The chart's true XYZ under D65 (white Y = 1) = colour-science's sd_to_XYZ of the BabelColor patches
    (rectangle-rule integration on the same 400:10:700 grid, CIE 1931 2 deg); measured 6e-16."""
    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    shape = colour.SpectralShape(400, 700, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    ref = np.stack([colour.sd_to_XYZ(sd.copy().align(shape), cmfs, ill, method="Integration") / 100
                    for sd in colour.SDS_COLOURCHECKERS["BabelColor Average"].values()])
    np.testing.assert_allclose(macbeth_true_xyz("D65", w).numpy(), ref, atol=1e-12)
    assert macbeth(wavelengths=w, patch_size=2).photons.shape[-2:] == (8, 12)
