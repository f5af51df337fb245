"""Image extension used by the blur, against numpy.pad on the same windows."""

import numpy as np
import pytest
import torch

from isettorch.optics.blur import extend

WINDOWS = [(-3, 10, -4, 13), (0, 7, 0, 9), (2, 5, -1, 4), (-5, 2, 8, 20), (8, 12, 0, 9), (-20, -10, -3, 3)]


@pytest.mark.parametrize("mode", ["zero", "mean", "edge", 2.5])
@pytest.mark.parametrize("window", WINDOWS)
def test_extend_matches_numpy_pad(mode, window):
    rng = np.random.default_rng(0)
    x = rng.random((2, 3, 7, 9))
    r0, r1, c0, c1 = window
    big = 40  # pad far enough that every window lies inside the padded array
    if mode == "edge":
        padded = np.pad(x, ((0, 0), (0, 0), (big, big), (big, big)), mode="edge")
    else:
        padded = np.empty((2, 3, 7 + 2 * big, 9 + 2 * big))
        fill = {"zero": np.zeros((2, 3, 1, 1)), "mean": x.mean(axis=(-2, -1), keepdims=True)}.get(
            mode, np.full((2, 3, 1, 1), mode))
        padded[:] = fill
        padded[..., big:big + 7, big:big + 9] = x
    ref = padded[..., r0 + big:r1 + big, c0 + big:c1 + big]
    out = extend(torch.from_numpy(x), (r0, r1), (c0, c1), mode).numpy()
    assert out.shape == ref.shape
    np.testing.assert_allclose(out, ref, rtol=1e-15, atol=0)  # means differ from numpy in the last bit


def test_an_optical_images_padding_is_whole_samples_inside_the_image():
    """OpticalImage took pad_rows of 2.7, -1, True or half the image or more (the scene's extent, height - 2 pad,
    is what a sensor without a set size fits: Sensor.size_for). A ValueError names it; 3 of 8 is fine."""
    from isettorch.optics import OpticalImage

    w = torch.arange(400.0, 701.0, 10.0)
    for kw in ({"pad_rows": 2.7}, {"pad_rows": -1}, {"pad_rows": 4}, {"pad_cols": True}):
        with pytest.raises(ValueError, match=f"^{next(iter(kw))}: expected an integer number of samples"):
            OpticalImage(torch.ones(1, 31, 8, 8), w, sample_spacing_m=1e-6, **kw)
    oi = OpticalImage(torch.ones(1, 31, 8, 8), w, sample_spacing_m=1e-6, pad_rows=3)
    assert oi.crop(oi.pad_rows, oi.pad_cols, oi.height - 2 * oi.pad_rows, oi.width).photons.shape[-2:] == (2, 8)


def test_a_factored_crop_outside_the_image_is_refused():
    """SpectralFactors.crop shortened a window past the edge without a word (crop(0, 0, 100, 100) of a 4 x 4 image
    gave 4 x 4); it now checks the window as the image's crop does, naming it."""
    from isettorch.image import SpectralFactors

    f = SpectralFactors(torch.ones(1, 2, 4, 4), torch.ones(1, 2, 3))
    assert f.crop(1, 1, 2, 3).maps.shape[-2:] == (2, 3)
    for window in ((0, 0, 100, 100), (-1, 0, 2, 2), (0, 0, 2.5, 2)):
        with pytest.raises(ValueError, match="crop: window .* does not fit in an image of 4x4"):
            f.crop(*window)


def test_thin_lens_helpers_refuse_what_has_no_image():
    """image_distance of a NaN or non-positive focal length gave NaN or a negative distance; image_sample_spacing
    of 0 columns inf, of 2.7 a spacing for a fraction of a sample."""
    import math

    from isettorch.optics import geometry

    assert float(geometry.image_distance(0.05, 1.0)) == pytest.approx(1 / (1 / 0.05 - 1))  # Hecht 5.17
    for f in (math.nan, 0.0, -0.05):
        with pytest.raises(ValueError, match="focal_length_m: expected finite positive"):
            geometry.image_distance(f, 1.0)
    with pytest.raises(ValueError, match="object_distance_m: expected a distance beyond"):
        geometry.image_distance(0.05, math.nan)
    for n in (0, 2.7, -3, True):
        with pytest.raises(ValueError, match="n_cols: expected an integer"):
            geometry.image_sample_spacing(10.0, n, 0.05)
