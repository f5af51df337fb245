import pytest
import torch

from isettorch.sensor import CFA


@pytest.mark.parametrize("pattern,cell", [
    ("RGGB", [["R", "G"], ["G", "B"]]), ("BGGR", [["B", "G"], ["G", "R"]]),
    ("GRBG", [["G", "R"], ["B", "G"]]), ("GBRG", [["G", "B"], ["R", "G"]]),
])
def test_bayer_cells_row_major(pattern, cell):
    c = CFA(pattern)
    assert c.cell == cell
    assert c.pattern == pattern
    assert c.bayer_pattern == pattern
    assert c.channel_names == ["R", "G", "B"]  # ISETCam keeps r, g, b whatever the layout
    expected = [[{"R": 0, "G": 1, "B": 2}[x] for x in row] for row in cell]
    assert c.index_map.tolist() == expected
    assert c.index_map.dtype == torch.long


def test_gbrg_top_left_and_tiling():
    c = CFA("GBRG")
    idx = c.channel_index(5, 7)
    # FORMAT.md 2: row 0 = G B, row 1 = R G, tiled from pixel [0, 0]
    assert idx[0, :4].tolist() == [1, 2, 1, 2]
    assert idx[1, :4].tolist() == [0, 1, 0, 1]
    assert idx[4, 6].item() == 1
    m = c.masks(5, 7)
    assert m.shape == (3, 5, 7)
    assert torch.equal(m.sum(0), torch.ones(5, 7))


def test_red_count_odd_size():
    m = CFA("GBRG").masks(5, 7)
    # R sits at odd rows {1, 3} and even cols {0, 2, 4, 6}: 2 * 4 = 8 pixels
    assert m[0].sum().item() == 8
    assert m[2].sum().item() == 3 * 3  # B at even rows {0,2,4} and odd cols {1,3,5}


def test_cmy_matches_isetcam_order():
    # FORMAT.md 2: 'YCMY' = [[2,1],[3,2]] with names (cDefault, yDefault, mDefault)
    c = CFA("YCMY")
    assert c.channel_names == ["C", "Y", "M"]
    assert (c.index_map + 1).tolist() == [[2, 1], [3, 2]]
    assert CFA("CYYM").index_map.tolist() == [[0, 1], [1, 2]]


def test_library_layouts():
    xt = CFA("xtrans")
    assert xt.shape == (6, 6)
    counts = torch.bincount(xt.index_map.flatten(), minlength=3).tolist()
    assert counts == [8, 20, 8]  # X-Trans: 20 G, 8 R, 8 B per 6x6 cell
    # every row and column of the X-Trans cell holds all three colours
    for r in range(6):
        assert set(xt.index_map[r].tolist()) == {0, 1, 2}
        assert set(xt.index_map[:, r].tolist()) == {0, 1, 2}
    q = CFA("quad_bayer")
    assert q.index_map.tolist() == [[0, 0, 1, 1], [0, 0, 1, 1], [1, 1, 2, 2], [1, 1, 2, 2]]
    assert CFA("rccb").channel_names == ["R", "B", "W"]
    assert CFA("rccc").num_channels == 2
    assert CFA("rgbw").channel_names == ["R", "G", "B", "W"]
    mono = CFA("mono")
    assert mono.is_monochrome and mono.pattern == "W"
    assert not CFA("RGBW").is_bayer


def test_user_pattern_named_filters():
    c = CFA([["r", "g", "b"], ["g", "ir", "g"]])
    assert c.shape == (2, 3)
    assert c.channel_names == ["r", "g", "b", "ir"]
    assert c.index_map.tolist() == [[0, 1, 2], [1, 3, 1]]
    with pytest.raises(ValueError, match="multi-letter"):
        _ = c.pattern
    c2 = CFA("RG/GB", channel_names=["B", "G", "R"])
    assert c2.index_map.tolist() == [[2, 1], [1, 0]]


def test_errors():
    with pytest.raises(ValueError, match="unknown CFA letter 'X'"):
        CFA("RGXB")
    with pytest.raises(ValueError, match="square number"):
        CFA("RGB")
    for ragged in ("RG/G", "RG/GB/", "RGB/GB"):  # (torch's 'expected sequence of length 2 at dim 1 (got 1)')
        with pytest.raises(ValueError, match=r"^cell: expected rows of one length .*\(rows of \["):
            CFA(ragged)
    with pytest.raises(ValueError, match="rectangular"):
        CFA([["R", "G"], ["B"]])
    with pytest.raises(ValueError, match="lacks"):
        CFA("RGGB", channel_names=["R", "G"])
    with pytest.raises(TypeError):
        CFA(3)


def test_mosaic_gathers_own_channel():
    c = CFA("RGGB")
    x = torch.arange(3.0)[None, :, None, None].expand(2, 3, 4, 4)
    out = c.mosaic(x)
    assert out.shape == (2, 1, 4, 4)
    assert torch.equal(out[0, 0], c.channel_index(4, 4).float())


@pytest.mark.parametrize("pattern", ["RGBG", "GBGR", "BGRG", "GRGB"])
def test_non_bayer_orders_of_bayer_letters(pattern):
    # Friction 3 of issue 18: 'RGBG' (RG/BG: greens in a column) was taken for Bayer and crashed in the ISP.
    import isettorch
    from isettorch.isp import demosaic
    from isettorch.scene import uniform
    from isettorch.sensor import Sensor

    c = CFA(pattern)
    assert not c.is_bayer and c.bayer_pattern is None
    assert all(CFA(p).is_bayer for p in ("RGGB", "BGGR", "GRBG", "GBRG"))
    # the Bayer-only demosaic functions say what they expected
    with pytest.raises(ValueError, match=r"pattern: expected one of \('RGGB', 'BGGR', 'GRBG', 'GBRG'\)"):
        demosaic(torch.rand(1, 1, 8, 8), pattern, "bilinear")
    # the camera's ISP demosaics it with its generic method: a uniform grey renders the colour a Bayer sensor gives
    images = {}
    for p in (pattern, "RGGB"):
        cam = isettorch.Camera.from_config("default")
        cam.noise = False
        cam.sensor = Sensor.preset("isetcam_default", cfa=p)
        images[p] = cam(uniform(size=64))[0, :, 4:-4, 4:-4]
    assert torch.isfinite(images[pattern]).all()
    assert torch.allclose(images[pattern].mean((1, 2)), images["RGGB"].mean((1, 2)), rtol=1e-4)
    assert (images[pattern].amax((1, 2)) - images[pattern].amin((1, 2))).max() < 1e-3  # uniform, no CFA pattern
