"""Hand-written DNG files for the raw-reading tests (tifffile tags directly, not isettorch.io.raw.write_dng)."""

from __future__ import annotations

import numpy as np


def dng_by_hand(path, mosaic, *, cfa_codes=(0, 1, 1, 2), plane_colors=None, black=64, white=4095, version=True,
                 dim=(2, 2), extra=()):
    """An uncompressed CFA DNG written with tifffile's tags directly (Adobe DNG Specification 1.4, chapters 4-6),
    not through isettorch.io.raw.write_dng, which refuses what these files hold. ``black`` is one SHORT BlackLevel
    or None (then ``extra`` holds the black level's tags)."""
    import tifffile

    tags = [(33421, "H", 2, tuple(dim), True), (33422, "B", len(cfa_codes), tuple(cfa_codes), True),
            *([(50714, "H", 1, (black,), True)] if black is not None else []), (50717, "H", 1, (white,), True),
            (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True)]
    if version:
        tags = [(50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
                (50708, "s", 0, "test", True)] + tags
    if plane_colors is not None:
        tags.append((50710, "B", len(plane_colors), tuple(plane_colors), True))  # CFAPlaneColor
    tags += list(extra)
    tifffile.imwrite(str(path), np.asarray(mosaic, np.uint16), photometric=32803, subfiletype=0, extratags=tags,
                     metadata=None)
