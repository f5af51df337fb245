"""Colour filter arrays: the unit cell of named filters, its index map and per-channel masks.

A CFA is an ``[ph, pw]`` grid of filter names (the unit cell) that tiles the sensor from pixel
``[0, 0]`` (top-left). Single-letter names give the ``pattern`` string, read row-major,
top-left first (``'GBRG'``: row 0 = G B, row 1 = R G), the convention of ISETCam parity files.

Channel order: by default the known letters come in the order R, G, B, C, Y, M, W, E, I (ISETCam
keeps r, g, b whatever the CFA, and c, y, m for its CMY sensor); other names follow in order of
first appearance. Pass ``channel_names`` to fix another order (e.g. a file's filter order).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from .._checks import is_integer

__all__ = ["BAYER_PATTERNS", "CFA", "CFA_LIBRARY", "KNOWN_LETTERS", "cfa", "tile"]

# Letter -> meaning. 'C' is cyan here; a clear (unfiltered) pixel is 'W' (RCCB/RCCC map C to clear).
KNOWN_LETTERS = {
    "R": "red", "G": "green", "B": "blue", "C": "cyan", "Y": "yellow", "M": "magenta",
    "W": "white / clear / panchromatic", "E": "emerald", "I": "infrared",
}
_CANONICAL_ORDER = "RGBCYMWEI"

# Named layouts (row-major letters, rows separated by '/').
CFA_LIBRARY: dict[str, str] = {
    "RGGB": "RG/GB", "BGGR": "BG/GR", "GRBG": "GR/BG", "GBRG": "GB/RG",
    "YCMY": "YC/MY", "CYYM": "CY/YM",
    # RGBW (Kodak-style 2x2 with one clear pixel).
    "RGBW": "RG/BW",
    # Automotive: red-clear-clear-blue and red-clear (clear pixels are 'W' in this library).
    "RCCB": "RW/WB", "RCCC": "RW/WW",
    # Quad Bayer (Sony, 2x2 same-colour blocks of an RGGB Bayer).
    "QUAD_BAYER": "RRGG/RRGG/GGBB/GGBB",
    # Fujifilm X-Trans 6x6: a valid X-Trans cell (20 G, 8 R, 8 B), one row and one column off rawspeed's absolute
    # array; a camera's phase depends on its sensor crop (isettorch.io.raw.read_raw gives a raw file's own).
    "XTRANS": "GBGGRG/RGRBGB/GBGGRG/GRGGBG/BGBRGR/GRGGBG",
    "MONO": "W", "MONOCHROME": "W", "W": "W",
}

# The four 2x2 RGB Bayer layouts of the table (the demosaic methods' patterns).
BAYER_PATTERNS: tuple[str, ...] = ("RGGB", "BGGR", "GRBG", "GBRG")


def tile(index_map: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Repeat a ``[ph, pw]`` map over an ``[H, W]`` grid, top-left aligned (the one CFA tiling: the sensor, the
    demosaic methods and the SFR metrics all call it)."""
    if not (is_integer(height) and is_integer(width) and height >= 1 and width >= 1):  # (2.5: repeat()'s TypeError)
        raise ValueError(f"height, width: expected whole numbers of pixels >= 1, got {height!r} and {width!r}")
    ph, pw = index_map.shape
    reps = (-(-height // ph), -(-width // pw))
    return index_map.repeat(*reps)[:height, :width]


def _parse(cell) -> list[list[str]]:
    if isinstance(cell, str):
        s = cell.strip()
        key = s.upper().replace(" ", "_").replace("-", "_")
        if key in CFA_LIBRARY:
            s = CFA_LIBRARY[key]
        if "/" in s:
            rows = [list(r.strip().upper()) for r in s.split("/")]
            if any(len(r) != len(rows[0]) for r in rows) or not rows[0]:  # (torch's 'expected sequence of length')
                raise ValueError(f"cell: expected rows of one length between the '/' separators (a rectangular "
                                 f"N x M pattern such as 'RG/GB'), got {cell!r} (rows of "
                                 f"{[len(r) for r in rows]} letters)")
        else:
            n = len(s)
            side = math.isqrt(n)
            if n == 0 or side * side != n:
                raise ValueError(
                    f"cell: a pattern string without '/' row separators must have a square number of letters "
                    f"(1, 4, 9, 16, 36, ...), got {cell!r} ({n} letters); write rows as 'RG/GB' or use one of "
                    f"{sorted(CFA_LIBRARY)}"
                )
            s = s.upper()
            rows = [list(s[i * side:(i + 1) * side]) for i in range(side)]
        for name in (x for r in rows for x in r):
            if name not in KNOWN_LETTERS:
                raise ValueError(
                    f"cell: unknown CFA letter {name!r} in {cell!r}; expected letters from "
                    f"{''.join(KNOWN_LETTERS)} ({', '.join(f'{k}={v}' for k, v in KNOWN_LETTERS.items())}), "
                    f"or a 2-D list of filter names for a user pattern"
                )
        return rows
    if isinstance(cell, Sequence) and cell and all(isinstance(r, Sequence) and not isinstance(r, str) for r in cell):
        rows = [[str(x) for x in r] for r in cell]
        if any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
            raise ValueError(f"cell: expected a rectangular N x M grid of filter names, got {cell!r}")
        if any(not x for r in rows for x in r):
            raise ValueError(f"cell: filter names must be non-empty strings, got {cell!r}")
        return rows
    raise TypeError(f"cell: expected a pattern string such as 'GBRG' or an N x M list of filter names, got {cell!r}")


class CFA:
    """A colour filter array unit cell.

    Args:
        cell: a pattern string (``'GBRG'``, ``'RG/GB'``, a library name such as ``'xtrans'``,
            ``'quad_bayer'``, ``'rccb'``, ``'mono'``) or an N x M list of filter names.
        channel_names: optional channel order (every name in the cell must appear; extra names
            are allowed and give channels that no pixel uses).

    Attributes:
        cell: the unit cell as a list of rows of names.
        channel_names: list of C channel names.
        index_map: ``[ph, pw]`` long tensor, channel index of each cell position.

    Example:
        >>> c = CFA('GBRG')
        >>> c.channel_names, c.index_map.tolist()
        (['R', 'G', 'B'], [[1, 2], [0, 1]])
    """

    def __init__(self, cell, channel_names: Sequence[str] | None = None) -> None:
        if isinstance(cell, CFA):
            channel_names = channel_names if channel_names is not None else cell.channel_names
            cell = cell.cell
        self.cell = _parse(cell)
        names_in_cell = []
        for name in (x for r in self.cell for x in r):
            if name not in names_in_cell:
                names_in_cell.append(name)
        if channel_names is None:
            known = [c for c in _CANONICAL_ORDER if c in names_in_cell]
            channel_names = known + [n for n in names_in_cell if n not in known]
        else:
            channel_names = [str(n) for n in channel_names]
            if len(set(channel_names)) != len(channel_names):
                raise ValueError(f"channel_names: expected unique names, got {channel_names}")
            missing = [n for n in names_in_cell if n not in channel_names]
            if missing:
                raise ValueError(f"channel_names: {channel_names} lacks the cell's filters {missing}")
        self.channel_names = list(channel_names)
        lookup = {n: i for i, n in enumerate(self.channel_names)}
        self.index_map = torch.tensor([[lookup[x] for x in r] for r in self.cell], dtype=torch.long)

    # --- descriptions --------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return len(self.cell), len(self.cell[0])

    @property
    def num_channels(self) -> int:
        return len(self.channel_names)

    @property
    def pattern(self) -> str:
        """Row-major letters of the unit cell (``'GBRG'``); only for single-letter filter names."""
        flat = [x for r in self.cell for x in r]
        if any(len(x) != 1 for x in flat):
            raise ValueError(f"pattern: the cell {self.cell} has multi-letter filter names; use index_map")
        return "".join(flat)

    @property
    def is_bayer(self) -> bool:
        """True for the four 2x2 RGB Bayer layouts (RGGB, BGGR, GRBG, GBRG: the two greens on a diagonal).

        Other orders of the same letters (``'RGBG'`` = RG/BG, greens in a column) are not Bayer: the ISP
        demosaics them with its generic method on the index map, and the Bayer-only functions reject them.
        """
        if self.shape != (2, 2) or sorted(x for r in self.cell for x in r) != ["B", "G", "G", "R"]:
            return False
        (a, b), (c, d) = self.cell
        return (a == d == "G") or (b == c == "G")

    @property
    def bayer_pattern(self) -> str | None:
        """The 4-letter Bayer string (``'RGGB'`` ...) or None if this is not a Bayer CFA."""
        return self.pattern if self.is_bayer else None

    @property
    def is_monochrome(self) -> bool:
        return self.num_channels == 1

    def __repr__(self) -> str:
        return f"CFA(cell={'/'.join(''.join(r) if all(len(x) == 1 for x in r) else str(r) for r in self.cell)!r}, " \
               f"channel_names={self.channel_names})"

    def __eq__(self, other) -> bool:
        return isinstance(other, CFA) and self.cell == other.cell and self.channel_names == other.channel_names

    def __hash__(self) -> int:
        return hash((tuple(map(tuple, self.cell)), tuple(self.channel_names)))

    # --- tiling --------------------------------------------------------------------------
    def channel_index(self, height: int, width: int, *, device=None) -> torch.Tensor:
        """Channel index of every pixel ``[H, W]`` (long), the cell tiled from pixel [0, 0]."""
        return self._tiled(height, width, device).clone()

    def _tiled(self, height: int, width: int, device) -> torch.Tensor:
        """:meth:`channel_index` from a small per-instance cache (read-only: callers must not modify it)."""
        if height < 1 or width < 1:
            raise ValueError(f"height, width: expected positive sizes, got {height}x{width}")
        key = (height, width, str(device))
        cache = self.__dict__.setdefault("_index_cache", {})
        if key not in cache:  # the tiling of a size repeats (e.g. every frame of a dataset): built once
            if len(cache) > 16:
                cache.clear()
            cache[key] = tile(self.index_map.to(device), height, width)
        return cache[key]

    def masks(self, height: int, width: int, *, dtype=None, device=None) -> torch.Tensor:
        """One-hot channel masks ``[C, H, W]`` (1 where the pixel has that filter)."""
        idx = self.channel_index(height, width, device=device)
        c = torch.arange(self.num_channels, device=device)[:, None, None]
        return (idx[None] == c).to(dtype or torch.get_default_dtype())

    def mosaic(self, channels: torch.Tensor) -> torch.Tensor:
        """Keep each pixel's own channel: ``[B, C, H, W]`` -> ``[B, 1, H, W]``."""
        if channels.dim() != 4 or channels.shape[1] != self.num_channels:
            raise ValueError(f"channels: expected shape [B, {self.num_channels}, H, W], got {tuple(channels.shape)}")
        idx = self._tiled(channels.shape[2], channels.shape[3], channels.device)
        return channels.gather(1, idx.expand(channels.shape[0], 1, -1, -1))


def cfa(cell, channel_names: Sequence[str] | None = None) -> CFA:
    """Shorthand for :class:`CFA`."""
    return CFA(cell, channel_names)
