"""`RawImage`: a sensor mosaic with the metadata a real raw file carries."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch

from .._checks import _small_values, is_integer
from .cfa import CFA

__all__ = ["RawImage", "RAW_UNITS"]

RAW_UNITS = ("electrons", "volts", "dn")


@dataclasses.dataclass(eq=False, repr=False)
class RawImage:
    """The sensor's mosaic ``data [B, 1, H, W]`` in ``units`` (``'electrons'``, ``'volts'`` or ``'dn'``).

    Args:
        data: the (noisy) mosaic.
        units: what ``data`` holds.
        cfa: the colour filter array (its unit cell tiles from pixel [0, 0]).
        black_level, white_level: in ``units`` (DN for quantised raws), the value of no light and of
            saturation (a float, or ``[B]`` per item). A sensor's capture puts its zero level here, the black level
            plus any analog offset (``Sensor.zero_level``).
        offset_level: the analog offset's part of ``black_level`` (0 without one), for ISETCam's monochrome
            processing, which subtracts no zero level.
        exposure_s, analog_gain: per-sample ``[B]``.
        conversion_gain_v_per_e, voltage_swing_v, pixel_size_m, fill_factor: the pixel.
        adc_bits: ADC bit depth (None for an analog readout).
        noise: the noise parameters used (dict of floats / strings).
        noise_free: optional mosaic without any noise, same units (a training target).
        electrons: optional mean electrons per pixel (noise-free, before clipping).
        spectral_qe: the sensor's spectral QE per channel (a :class:`~isettorch.sensor.filters.SpectralQE`: its
            QE on any wavelength grid), so an image processor fits its colour matrix from the raw itself.

    Example:
        >>> raw = RawImage(torch.zeros(1, 1, 4, 4), 'volts', CFA('RGGB'))
        >>> raw.channel_masks().shape
        torch.Size([3, 4, 4])
    """

    data: torch.Tensor
    units: str
    cfa: CFA
    black_level: float = 0.0
    white_level: float | torch.Tensor | None = None
    exposure_s: torch.Tensor | None = None
    analog_gain: torch.Tensor | None = None
    analog_offset_v: float = 0.0
    conversion_gain_v_per_e: float | None = None
    voltage_swing_v: float | None = None
    pixel_size_m: float | torch.Tensor | None = None  # [B] for a per-call pitch (Sensor.forward)
    fill_factor: float | None = None
    adc_bits: int | None = None
    noise: dict[str, Any] = dataclasses.field(default_factory=dict)
    noise_free: torch.Tensor | None = None
    electrons: torch.Tensor | None = None
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)
    spectral_qe: Any = None
    offset_level: float | torch.Tensor = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.data, torch.Tensor):
            raise TypeError(f"data: expected a torch.Tensor [B, 1, H, W], got {type(self.data).__name__}")
        if self.data.dim() != 4 or self.data.shape[1] != 1:
            raise ValueError(f"data: expected shape [B, 1, H, W], got {tuple(self.data.shape)}")
        if self.units not in RAW_UNITS:
            raise ValueError(f"units: expected one of {RAW_UNITS}, got {self.units!r}")
        if not isinstance(self.cfa, CFA):
            self.cfa = CFA(self.cfa)
        # the levels normalized() divides by (white == black gave inf, NaN levels NaN); [B] tensors, which a
        # sensor's capture makes, are its own (checked there, and not read back to the host here)
        for name in ("black_level", "white_level"):
            v = getattr(self, name)
            if v is None and name == "white_level" or isinstance(v, torch.Tensor) and not isinstance(v, bool):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name}: expected a finite number (or a [B] tensor) in {self.units}, got {v!r}")
        levels = {}  # each level's values where reading them costs no device sync (a float; a CPU [B] tensor)
        for name in ("black_level", "white_level"):
            v = getattr(self, name)
            if isinstance(v, torch.Tensor):
                # (a per-item level was not checked at all: 3 levels for a batch of 2 failed in a broadcast, white
                # below black gave a NaN image)
                if v.dtype == torch.bool or v.is_complex() or v.dim() > 1 or v.numel() not in (1, self.batch_size):
                    raise ValueError(f"{name}: expected a number or a [B] tensor of 1 or {self.batch_size} real "
                                     f"levels, got {v.dtype} of shape {tuple(v.shape)}")
                vals = _small_values(v.detach())
                if vals is not None and not all(math.isfinite(x) for x in vals):
                    raise ValueError(f"{name}: expected finite levels in {self.units}, got {vals}")
                levels[name] = vals
            elif v is not None:
                levels[name] = [v]
        black, white = levels.get("black_level"), levels.get("white_level")
        if black is not None and white is not None:
            pairs = zip(black * len(white), white) if len(black) == 1 else zip(black, white * len(black))
            if not all(w > b for b, w in pairs):
                raise ValueError(f"white_level: expected a level above black_level {self.black_level!r}, got "
                                 f"{self.white_level!r}")
        if self.adc_bits is not None and not (is_integer(self.adc_bits) and self.adc_bits >= 1):
            raise ValueError(f"adc_bits: expected None or an integer >= 1, got {self.adc_bits!r}")
        for name in ("noise_free", "electrons"):
            v = getattr(self, name)
            if v is not None and v.shape != self.data.shape:
                raise ValueError(f"{name}: expected shape {tuple(self.data.shape)} like data, got {tuple(v.shape)}")

    @property
    def batch_size(self) -> int:
        return self.data.shape[0]

    @property
    def height(self) -> int:
        return self.data.shape[2]

    @property
    def width(self) -> int:
        return self.data.shape[3]

    def replace(self, **changes) -> RawImage:
        return dataclasses.replace(self, **changes)

    def _map(self, fn) -> RawImage:
        changes = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, torch.Tensor):
                changes[f.name] = fn(v)
        return self.replace(**changes)

    def to(self, device=None, dtype=None) -> RawImage:
        """Move every tensor to a device and/or floating dtype."""
        return self._map(lambda t: t.to(device=device, dtype=dtype) if t.is_floating_point() else t.to(device))

    def detach(self) -> RawImage:
        return self._map(lambda t: t.detach())

    def channel_masks(self) -> torch.Tensor:
        """One-hot CFA masks ``[C, H, W]`` in the data's dtype/device."""
        return self.cfa.masks(self.height, self.width, dtype=self.data.dtype, device=self.data.device)

    def levels(self) -> tuple:
        """``(black, white)`` ready to broadcast against ``data``: floats, or ``[B, 1, 1, 1]`` tensors on the data's
        device and in its dtype for per-item levels (``[B]``: a per-call gain with a full well, or with an analog
        offset; a level made on the CPU, e.g. by a user). ``white`` None without one."""
        return self.broadcast(self.black_level), self.broadcast(self.white_level)

    def broadcast(self, level):
        """A level (a float, or ``[B]`` per item) ready to broadcast against ``data``: a float as it is, a ``[B]``
        tensor as ``[B, 1, 1, 1]`` on the data's device and, for floating data, in its dtype."""
        if not (isinstance(level, torch.Tensor) and level.dim() > 0):
            return level
        return level.reshape(-1, 1, 1, 1).to(device=self.data.device,
                                              dtype=self.data.dtype if self.data.is_floating_point() else None)

    def normalized(self) -> torch.Tensor:
        """``(data - black) / (white - black)``: 0 at black, 1 at saturation ``[B, 1, H, W]``."""
        if self.white_level is None:
            raise ValueError("normalized: this raw has no white_level")
        black, white = self.levels()
        return (self.data - black) / (white - black)

    def __repr__(self) -> str:
        return (f"RawImage(data={tuple(self.data.shape)} {self.data.dtype} on {self.data.device}, "
                f"units={self.units!r}, "
                f"cfa={self.cfa!r}, black={self.black_level}, white={self.white_level}, bits={self.adc_bits})")
