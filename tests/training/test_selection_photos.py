"""training/selection_photos.py: photographs are reduced to a 768-pixel long side by area averaging (checked against
a block mean in numpy), smaller ones are kept as they are, and the manifest names 30 photographs, none from the test
sets, each with a SHA-256 digest."""

from __future__ import annotations

import io
import json
import re

import numpy as np
from PIL import Image

from training import selection_photos as sp


def _png(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG")
    return buf.getvalue()


def test_reduction_is_the_block_mean_at_an_integer_factor():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (1000, 1536, 3), dtype=np.uint8)  # long side 2 x 768
    out = np.asarray(Image.open(io.BytesIO(sp._reduced_png(_png(a)))))
    assert out.shape == (500, 768, 3)
    mean = a.reshape(500, 2, 768, 2, 3).astype(np.float64).mean((1, 3))
    # the 2 x 2 mean to one 8-bit level: Pillow's fixed-point resampling rounds up by half a level on average
    # (documented in the script; the set was built and used with it)
    assert np.abs(out - mean).max() <= 1 and 0 <= float((out - mean).mean()) <= 0.6


def test_smaller_photographs_are_kept():
    a = np.random.default_rng(1).integers(0, 256, (300, 451, 3), dtype=np.uint8)
    np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(sp._reduced_png(_png(a))))), a)


def test_manifest_names_thirty_photographs_with_digests():
    digests = json.loads(sp.MANIFEST.read_text())
    assert len(digests) == 30
    assert all(re.fullmatch(r"[0-9a-f]{64}", d) for d in digests.values())
    n_named = len(sp.SKIMAGE) + 1 + len(sp.SKLEARN) + len(sp.MATE) + len(sp.PLASMA)
    assert n_named == 30 and len(set(digests.values())) == 30
    assert not any(re.search(r"kodak|mcmaster|kodim", n, re.I) for n in digests)
