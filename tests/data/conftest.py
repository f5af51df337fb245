"""Shared checks of the data tests."""

import pytest
import torch

from isettorch.data.config import one_thread, seed_for
from isettorch.data.stream import STREAM_DOMAIN


def _normalised(raw, values):
    black, white = raw.levels()  # (floats, or [B] levels as [B, 1, 1, 1]: per-call gains)
    return (values - black) / (white - black)


@pytest.fixture
def stream_equals_camera():
    """``check(stream, k, one_group_stream, k1)``: every group of ``stream.draw(k)`` rendered by its own Camera gives
    the stream's noise-free raw (float rounding), and the one group of ``one_group_stream.draw(k1)`` rendered with
    the stream's noise generator (seed ``seed_for(seed, k1, STREAM_DOMAIN + 2)``) gives its noisy raw bitwise."""

    def check(stream, k, one, k1):
        batch = stream.batch(k)
        for grp in stream.draw(k):
            raw = grp.camera(grp.scene, return_intermediates=True, **grp.kwargs).raw
            torch.testing.assert_close(_normalised(raw, raw.noise_free), batch["noise_free_raw"][grp.index],
                                       rtol=2e-5, atol=2e-6)
        (grp,) = one.draw(k1)
        g = torch.Generator().manual_seed(seed_for(one.seed, k1, stream=STREAM_DOMAIN + 2))
        # on one intra-op thread, as the stream renders a CPU batch: with two, an FFT of some sizes rounds otherwise,
        # an exposure an ulp apart draws another Poisson realisation
        with one_thread():
            raw = grp.camera(grp.scene, return_intermediates=True, generator=g, **grp.kwargs).raw
        assert torch.equal(_normalised(raw, raw.data), one.batch(k1)["raw"])

    return check
