"""`optics.blur.convolve_psf` (the sampled-PSF convolution scene layers are defocused with) against SciPy."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from isettorch.optics.blur import convolve_psf


def test_matches_scipy_convolution_with_mirrored_borders():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 23, 31, generator=g, dtype=torch.float64)
    psf = torch.rand(7, 7, generator=g, dtype=torch.float64)
    psf /= psf.sum()
    out = convolve_psf(x, psf).numpy()
    # torch's 'reflect' padding is SciPy's 'mirror' (the edge sample is not repeated)
    ref = np.stack([ndimage.convolve(c, psf.numpy(), mode="mirror") for c in x.numpy()])
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


def test_rejects_even_or_non_square_psf():
    with pytest.raises(ValueError, match="odd square psf"):
        convolve_psf(torch.zeros(1, 8, 8), torch.ones(4, 4))
