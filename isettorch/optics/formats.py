"""Named optical (sensor) formats and the focal length / field-of-view relation.

The "inch" names are the vidicon-tube convention: the sensor diagonal is about 2/3 of the nominal inch size
(1/2.3" -> 7.66 mm diagonal). Sizes (width x height, mm) as commonly published for the 4:3 small formats and the
3:2 large ones (e.g. Wikipedia "Image sensor format" table; 1" = 13.2 x 8.8 mm as in Sony's 1" sensors; APS-C =
Nikon/Sony DX 23.5 x 15.6 mm; full frame = 36 x 24 mm).
Field of view of a rectilinear lens focused at infinity: FOV = 2 atan(d / (2 f)) (pinhole/thin-lens geometry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .._checks import is_real

__all__ = ["OpticalFormat", "FORMATS", "optical_format", "field_of_view_deg", "focal_length_for_fov_mm",
           "crop_factor"]


@dataclass(frozen=True)
class OpticalFormat:
    name: str
    width_mm: float
    height_mm: float

    @property
    def diagonal_mm(self) -> float:
        return math.hypot(self.width_mm, self.height_mm)


FORMATS = {f.name: f for f in (
    OpticalFormat('1/4"', 3.6, 2.7),
    OpticalFormat('1/3"', 4.8, 3.6),
    OpticalFormat('1/2.3"', 6.17, 4.55),
    OpticalFormat('1"', 13.2, 8.8),
    OpticalFormat("APS-C", 23.5, 15.6),
    OpticalFormat("full frame", 36.0, 24.0),
)}
_ALIASES = {"ff": "full frame", "full_frame": "full frame", "35mm": "full frame", "apsc": "APS-C", "aps-c": "APS-C"}


def optical_format(name: str) -> OpticalFormat:
    """An :class:`OpticalFormat` by name (``'1/2.3"'``, ``'1/2.3'``, ``'APS-C'``, ``'full frame'``, ...)."""
    key = str(name).strip()
    if key in FORMATS:
        return FORMATS[key]
    if key + '"' in FORMATS:
        return FORMATS[key + '"']
    alias = _ALIASES.get(key.lower())
    if alias:
        return FORMATS[alias]
    raise ValueError(f"name: unknown optical format {name!r}; expected one of {list(FORMATS)}")


def _fmt(fmt) -> OpticalFormat:
    return fmt if isinstance(fmt, OpticalFormat) else optical_format(fmt)


def field_of_view_deg(fmt, focal_length_mm: float, along: str = "diagonal") -> float:
    """Full field of view (deg) of a rectilinear lens of ``focal_length_mm`` on ``fmt`` (object at infinity)."""
    if not (is_real(focal_length_mm) and focal_length_mm > 0):  # (NaN gave a NaN field of view)
        raise ValueError(f"focal_length_mm: expected a finite number > 0, got {focal_length_mm!r}")
    f = _fmt(fmt)
    d = {"diagonal": f.diagonal_mm, "horizontal": f.width_mm, "vertical": f.height_mm}.get(along)
    if d is None:
        raise ValueError(f"along: expected 'diagonal', 'horizontal' or 'vertical', got {along!r}")
    return 2 * math.degrees(math.atan(d / (2 * focal_length_mm)))


def focal_length_for_fov_mm(fmt, fov_deg: float, along: str = "diagonal") -> float:
    """The focal length (mm) giving a full field of view ``fov_deg`` on ``fmt``."""
    if not (is_real(fov_deg) and 0 < fov_deg < 180):
        raise ValueError(f"fov_deg: expected a value in (0, 180), got {fov_deg!r}")
    f = _fmt(fmt)
    d = {"diagonal": f.diagonal_mm, "horizontal": f.width_mm, "vertical": f.height_mm}.get(along)
    if d is None:  # (a bare KeyError)
        raise ValueError(f"along: expected 'diagonal', 'horizontal' or 'vertical', got {along!r}")
    return d / (2 * math.tan(math.radians(fov_deg) / 2))


def crop_factor(fmt) -> float:
    """Diagonal of full frame over the format's diagonal (35 mm-equivalent focal length multiplier)."""
    return FORMATS["full frame"].diagonal_mm / _fmt(fmt).diagonal_mm
