"""`OpticalImage`: spectral irradiance at the sensor plane, in photons/s/m^2/nm."""

from __future__ import annotations

import dataclasses
import threading
from typing import ClassVar

import torch

from .._autograd import records_grad
from .._checks import is_integer
from ..image import SpectralImage, angle_for_extent, extent_for_angle, select_items

__all__ = ["OpticalImage", "FourierFactors"]

_SCRATCH = threading.local()
_SCRATCH_MAX_ELEMENTS = 4 * 2**20  # per buffer (16 MiB in float32): a 128^2-256^2 camera pair's intermediates


def _scratch(shape: tuple[int, ...], dtype: torch.dtype, device: torch.device, slot: str = "cube") -> torch.Tensor:
    """A per-thread reusable buffer (one per ``slot``) for a large intermediate that is consumed before the call
    returns (the ``[B, L, 2F]`` Fourier-domain cube: ~2.6 MB at 144^2 x 31 in float32; the optics' weighted maps
    before their rFFT). A fresh tensor of that size is a fresh ``mmap`` whose pages fault on first touch (glibc's
    default for blocks over 128 KiB). Never returned to a caller, never used when a gradient is needed."""
    n = 1
    for v in shape:
        n *= v
    if n > _SCRATCH_MAX_ELEMENTS:  # a large problem: its compute dwarfs the allocation; keep no big buffer alive
        return torch.empty(shape, dtype=dtype, device=device)
    buf = getattr(_SCRATCH, slot, None)
    if buf is None or buf.dtype != dtype or buf.device != device or buf.numel() < n:
        with torch.inference_mode(False):  # a normal tensor even when first made under inference_mode (an inference
            buf = torch.empty(n, dtype=dtype, device=device)  # buffer failed every later call outside it)
        setattr(_SCRATCH, slot, buf)
    return buf[:n].view(shape)


def _mm_by_halves(a: torch.Tensor, b: torch.Tensor, scratch: torch.Tensor | None = None) -> torch.Tensor:
    """``a @ b`` (``[M, K] x [K, N]``) as a two-matrix ``bmm`` over the two halves of ``b``'s columns: torch splits a
    plain 2-D product (or a batch of one) across its intra-op threads, which rounds differently with their number,
    and a batched one by matrix, which does not. ``scratch``: ``[2, M, N / 2]`` for the halves (none: out of place,
    for autograd). An odd N falls back to the plain product."""
    m, n = a.shape[0], b.shape[1]
    if n % 2:
        return torch.mm(a, b)
    halves = b.reshape(b.shape[0], 2, n // 2).transpose(0, 1)
    out = torch.bmm(a[None].expand(2, -1, -1), halves, out=scratch)
    return out.transpose(0, 1).reshape(m, n)


def stack_rows(rows) -> torch.Tensor:
    """Per-item OTF rows ``[1, ...]`` as one batch ``[B, ...]`` for reading: the rows concatenated, or, when every
    item holds the same cached row (a batch of one geometry, e.g. a design's flat patches), that row expanded over
    the batch without a copy."""
    first = rows[0]
    if all(r is first for r in rows):
        return first.expand(len(rows), *first.shape[1:])
    return torch.cat(rows)


class FourierFactors:
    """A factored optical image kept in the Fourier domain: the irradiance at wavelength ``l`` is

    ``E[b, l] = irfft2(otf[b, l] * sum_j spectra[b, j, l] * spec[b, j])[r0:r0 + h, c0:c0 + w]``

    with ``spec [B, J, My, Mx // 2 + 1]`` the rFFT of the J spatial maps (padded buffer, spatial factors such as
    relative illumination applied), ``spectra [B, J, L]`` (with the camera-equation factor and transmittance),
    ``otf [B or 1, L, My, Mx // 2 + 1]`` (real or complex; a real one may come interleaved, ``[..., 2]``, the same
    value for the real and imaginary parts) and ``window = (r0, c0, h, w)`` in the buffer. ``otf`` may also be a
    sequence of B per-item rows ``[1, L, My, Mx'(, 2)]`` (an optics' cached rows, never written to): they are
    applied item by item, and stacked into one tensor only where a path needs it (``.otf``).
    It is what a shift-invariant optics returns for a factored scene: J forward FFTs were done; :meth:`project`
    on K spectral weightings does K inverse FFTs (instead of L), which is how the sensor integrates its QE.
    """

    def __init__(self, spec: torch.Tensor, spectra: torch.Tensor, otf, size: tuple[int, int],
                 window: tuple[int, int, int, int], plain_otf: torch.Tensor | None = None, terms=None):
        self.spec, self.spectra = spec, spectra
        # item b's terms j >= terms[b] are 0 (spec and spectra): its products skip them (SpectralFactors.terms)
        self.terms = None if terms is None else tuple(int(t) for t in terms)
        if isinstance(otf, (list, tuple)):
            if len(otf) != spec.shape[0]:
                raise ValueError(f"otf: expected {spec.shape[0]} per-item rows, got {len(otf)}")
            self.otf_rows, self._otf = tuple(otf), None
        else:
            self.otf_rows, self._otf = None, otf
        self._plain_otf = plain_otf  # the real OTF [.., My, Mx'] when ``otf`` is its interleaved copy
        self.size = (int(size[0]), int(size[1]))
        self.window = tuple(int(v) for v in window)

    @property
    def otf(self) -> torch.Tensor:
        """The OTF as one tensor ``[B or 1, L, My, Mx'(, 2)]`` (per-item rows stacked on first use)."""
        if self._otf is None:
            self._otf = stack_rows(self.otf_rows)
        return self._otf

    @property
    def plain_otf(self) -> torch.Tensor | None:
        if self._plain_otf is None and self.otf_rows is not None and self.otf_rows[0].dim() == 5:
            self._plain_otf = self.otf[..., 0]
        return self._plain_otf

    def _otf_like(self):
        """What the derived factors carry: the per-item rows when this holds them, else the OTF tensor."""
        return self.otf_rows if self.otf_rows is not None else self._otf

    def _otf_is_complex(self) -> bool:
        return (self.otf_rows[0] if self.otf_rows is not None else self._otf).is_complex()

    def _grad_otf(self) -> torch.Tensor | None:
        """The stacked OTF that a gradient may flow through (none when the cached per-item rows are used)."""
        return None if self.otf_rows is not None else self._otf

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.spec.shape[0], self.window[2], self.window[3]

    @property
    def num_wavelengths(self) -> int:
        return self.spectra.shape[-1]

    @property
    def dtype(self) -> torch.dtype:
        return self.spectra.dtype

    @property
    def device(self) -> torch.device:
        return self.spectra.device

    def _planes(self, weights: torch.Tensor | None) -> torch.Tensor:
        b, j = self.spec.shape[:2]
        nf = self.spec.shape[-2] * self.spec.shape[-1]
        n_l = self.spectra.shape[-1]
        if weights is not None and not self._otf_is_complex():
            k = weights.shape[-1]
            # fewer operations folding the spectra and weights into the OTF first (J K L vs 2 (J + K + 1) L per
            # frequency); the rule decides the summation order, so it is kept fixed (items bitwise stable)
            if j * k < 2 * (j + k + 1):
                return self._planes_folded(weights.to(self.spectra))
        # Sum over the J terms first (J x L x F), then the per-wavelength OTF, then the K weightings (K x L x F):
        # the same real matrix products act on the real and imaginary parts (view_as_real).
        spec = torch.view_as_real(self.spec).reshape(b, j, 2 * nf)
        grad = records_grad(spec, self.spectra, self._grad_otf())
        if grad:
            cube = _mm_by_halves(self.spectra[0].T, spec[0])[None] if b == 1 else self.spectra.transpose(1, 2) @ spec
        elif b == 1 and self._item_wise(weights):
            # one item: the per-item products, whose rounding does not depend on the intra-op thread count (plain
            # 2-D products below are split across threads and round differently with their number)
            return self._planes_by_item(spec, weights)
        elif b == 1:  # one item (a complex OTF, or no or per-item weightings): its halves through a reused buffer
            halves = _scratch((2, n_l, nf), spec.dtype, spec.device)
            cube = _mm_by_halves(self.spectra[0].T.to(spec.dtype), spec[0], halves)[None]
        elif self.terms is not None and self._fused_items(weights):
            return self._planes_by_item(spec, weights)
        elif self.terms is not None:  # each item's own terms (a batch-of-one bmm: its rounding is the batch's)
            cube = _scratch((b, n_l, 2 * nf), spec.dtype, spec.device)
            s_t = self.spectra.transpose(1, 2).to(spec.dtype)
            for i, t in enumerate(self.terms):
                torch.bmm(s_t[i:i + 1, :, :t], spec[i:i + 1, :t], out=cube[i:i + 1])
        else:
            cube = torch.matmul(self.spectra.transpose(1, 2).to(spec.dtype), spec,
                                out=_scratch((b, n_l, 2 * nf), spec.dtype, spec.device))  # [B, L, 2F]
        if self.otf_rows is not None and not (grad or self._otf_is_complex()):
            # per-item real rows (interleaved or plain): each item's slice multiplied by its own cached row, the
            # products of the stacked OTF without stacking it
            for i, row in enumerate(self.otf_rows):
                cube[i].view(n_l, nf, 2).mul_(row.reshape(n_l, nf, -1))
        elif self._otf_is_complex():
            otf = self.otf.reshape(self.otf.shape[0], n_l, nf)
            cube = torch.view_as_real(torch.view_as_complex(cube.view(b, n_l, nf, 2)) * otf).view(b, n_l, 2 * nf)
        else:
            # a real OTF, [.., My, Mx'] or interleaved [.., My, Mx', 2] (the optics' cached, contiguous form)
            otf = self.otf.reshape(self.otf.shape[0], n_l, nf, -1)
            if cube.requires_grad or otf.requires_grad:
                cube = (cube.view(b, n_l, nf, 2) * otf).view(b, n_l, 2 * nf)
            else:
                cube.view(b, n_l, nf, 2).mul_(otf)
        if weights is not None and weights.dim() == 3:  # per item [B, L, K]
            wt = weights.to(cube).transpose(1, 2)
            cube = _mm_by_halves(wt[0], cube[0])[None] if b == 1 else wt @ cube  # [B, K, 2F]
        elif weights is not None:
            wt = weights.to(cube).T
            if b == 1 and not (grad or wt.requires_grad):  # into a reused buffer, consumed by the inverse FFT below
                proj = _scratch((2, wt.shape[0], nf), cube.dtype, cube.device, "proj")
                cube = _mm_by_halves(wt, cube[0], proj)[None]
            else:
                cube = _mm_by_halves(wt, cube[0])[None] if b == 1 else wt @ cube  # [B, K, 2F]
        return self._spatial(cube)

    def _spatial(self, interleaved: torch.Tensor) -> torch.Tensor:
        """The irradiance planes ``[B, K, h, w]`` of projected spectra held as interleaved (real, imaginary) Fourier
        planes ``[B, K, 2F]`` (or any shape holding them in that order): the inverse rFFT of the buffer, cropped to
        the window (the last step of every summation order)."""
        b = self.spec.shape[0]
        fy, fx = self.spec.shape[-2:]
        planes = torch.view_as_complex(interleaved.reshape(b, -1, fy, fx, 2).contiguous())
        r0, c0, h, w = self.window
        return torch.fft.irfft2(planes, s=self.size)[..., r0:r0 + h, c0:c0 + w]

    def _item_wise(self, weights: torch.Tensor | None) -> bool:
        """Whether :meth:`_planes_by_item` can run: a real OTF, projected on one ``[L, K]`` weighting, no gradient
        (checked by the caller)."""
        return (weights is not None and weights.dim() == 2 and not self._otf_is_complex()
                and not weights.requires_grad)

    def _fused_items(self, weights: torch.Tensor | None) -> bool:
        """Whether :meth:`_planes_by_item` applies to a batch: per-item terms and real per-item OTF rows."""
        return self.otf_rows is not None and self._item_wise(weights)

    def _planes_by_item(self, spec: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """:meth:`_planes` one item at a time (no gradient, a real OTF, ``[L, K]`` weights; each item's own terms and
        OTF row where the factors hold them, else all terms and the batch's OTF):
        the item's ``[L, 2F]`` cube (2.6 MB at 144^2 x 31 in float32) is built, multiplied by its OTF row and
        projected while it is in cache, in one reused buffer, instead of a ``[B, L, 2F]`` cube that leaves the
        cache between the three passes. The spectra's product is the batch-of-one ``bmm`` of the batched path; the
        projection runs as a ``bmm`` over the two halves of the item's frequencies (one GEMM each, as the batched
        ``bmm`` does one per item): a batch-of-one product would be split across intra-op threads and round
        differently with their number. So the result is bitwise the batched path's, on any thread count."""
        b = spec.shape[0]
        nf = self.spec.shape[-2] * self.spec.shape[-1]
        n_l = self.spectra.shape[-1]
        s_t = self.spectra.transpose(1, 2).to(spec.dtype)
        k = weights.shape[-1]
        wt = weights.to(spec.dtype).T[None].expand(2, k, n_l)  # [2, K, L]
        cube = _scratch((1, n_l, 2 * nf), spec.dtype, spec.device)
        proj = _scratch((2, k, nf), spec.dtype, spec.device, "proj")
        out = torch.empty(b, k, 2, nf, dtype=spec.dtype, device=spec.device)
        terms = self.terms if self.terms is not None else (spec.shape[1],) * b
        rows = self.otf_rows
        if rows is None:  # one OTF for the batch, or one per item
            rows = [self.otf[min(i, self.otf.shape[0] - 1)][None] for i in range(b)]
        for i, (t, row) in enumerate(zip(terms, rows)):
            torch.bmm(s_t[i:i + 1, :, :t], spec[i:i + 1, :t], out=cube)
            cube[0].view(n_l, nf, 2).mul_(row.reshape(n_l, nf, -1))
            torch.bmm(wt, cube[0].view(n_l, 2, nf).transpose(0, 1), out=proj)  # [2, K, F]: the two halves
            out[i].copy_(proj.transpose(0, 1))
        return self._spatial(out)

    def _planes_folded(self, weights: torch.Tensor) -> torch.Tensor:
        """The same projection summed in the other order (real OTF): ``H[j, k] = sum_l spectra[j, l] weights[l, k]
        otf[l]`` (a real [J K, L] x [L, F] product), then ``sum_j H[j, k] spec[j]``: J K L F operations instead of
        (J + K + 1) 2 L F, and no [L, F] intermediate (a rank-1 sweep: 3 L F instead of 10 L F)."""
        b, j = self.spec.shape[:2]
        fy, fx = self.spec.shape[-2:]
        n_l, k = weights.shape[-2:]
        nf = fy * fx
        wk = weights.T[None, None] if weights.dim() == 2 else weights.transpose(1, 2)[:, None]  # [1 or B, 1, K, L]
        coef = (self.spectra[:, :, None, :] * wk).reshape(b, j * k, n_l)  # [B, J K, L]
        spec = torch.view_as_real(self.spec).reshape(b, j, 2 * nf)
        grad = records_grad(spec, coef, self._grad_otf())
        if self.otf.dim() == 5 and not grad:
            # the interleaved OTF [.., L, My, Mx', 2] (the same value for the real and imaginary parts): H comes
            # out interleaved, [B, J K, 2F], and each term of the sum over j is a contiguous multiply-add on the
            # [K, 2F] real view (a broadcast [.., F, 1] x [.., F, 2] product is several times slower on CPU)
            otf = self.otf.reshape(self.otf.shape[0], n_l, 2 * nf)
            if b == 1:
                h = _mm_by_halves(coef[0], otf[0], _scratch((2, j * k, nf), spec.dtype, spec.device, "cube"))[None]
            else:
                h = torch.matmul(coef, otf, out=_scratch((b, j * k, 2 * nf), spec.dtype, spec.device, "cube"))
            h = h.view(b, j, k, 2 * nf)
            planes = torch.mul(h[:, 0], spec[:, 0, None], out=_scratch((b, k, 2 * nf), spec.dtype, spec.device,
                                                                       "proj"))
            for i in range(1, j):  # in the order of a sum over dim 1
                planes.add_(h[:, i].mul_(spec[:, i, None]))
        else:
            otf = self.otf if self.plain_otf is None else self.plain_otf
            if otf.dim() == 5:  # interleaved [.., My, Mx', 2]: the real part
                otf = otf[..., 0]
            otf = otf.reshape(otf.shape[0], n_l, nf)
            h = (_mm_by_halves(coef[0], otf[0])[None] if b == 1 and otf.shape[0] == 1 else coef @ otf
                 ).reshape(b, j, k, nf, 1)  # [B, J, K, F]
            planes = (h * spec.view(b, j, 1, nf, 2)).sum(dim=1) if j > 1 else (h[:, 0] * spec.view(b, 1, nf, 2))
        return self._spatial(planes)

    def project(self, weights: torch.Tensor) -> torch.Tensor:
        """``sum_l E[b, l] weights[l, k]`` ``[B, K, h, w]``: K inverse FFTs. ``weights`` ``[L, K]``, or per item
        ``[B, L, K]`` (``weights[b, l, k]``, e.g. a per-item sensor QE)."""
        if weights.dim() == 3 and weights.shape[0] != self.spec.shape[0]:
            raise ValueError(f"weights: expected [L, K] or per-item [{self.spec.shape[0]}, L, K] weightings, got "
                             f"{tuple(weights.shape)}")
        return self._planes(weights)

    def dense(self) -> torch.Tensor:
        """The irradiance cube ``[B, L, h, w]`` (L inverse FFTs)."""
        return self._planes(None)

    def select(self, index) -> FourierFactors:
        def pick(t):
            return t if t is None or t.shape[0] == 1 else t[index]
        terms = select_items(self.terms, index)
        if self.otf_rows is not None:
            rows = select_items(self.otf_rows, index)
            return FourierFactors(self.spec[index], self.spectra[index], rows if len(rows) > 1 else rows[0],
                                  self.size, self.window, None, terms)
        return FourierFactors(self.spec[index], self.spectra[index], pick(self.otf), self.size, self.window,
                              pick(self.plain_otf), terms)

    def scale(self, k: torch.Tensor) -> FourierFactors:
        return FourierFactors(self.spec, self.spectra * k.reshape(-1, 1, 1), self._otf_like(), self.size,
                              self.window, self._plain_otf, self.terms)

    def crop(self, top: int, left: int, height: int, width: int) -> FourierFactors:
        r0, c0 = self.window[:2]
        return FourierFactors(self.spec, self.spectra, self._otf_like(), self.size,
                              (r0 + top, c0 + left, height, width), self._plain_otf, self.terms)

    def to(self, device=None, dtype=None) -> FourierFactors:
        cdt = None if dtype is None else (torch.complex128 if dtype == torch.float64 else torch.complex64)
        otf_dt = None if dtype is None else (cdt if self._otf_is_complex() else dtype)
        spec, spectra = self.spec.to(device=device, dtype=cdt), self.spectra.to(device=device, dtype=dtype)
        if self.otf_rows is not None:
            rows = [r.to(device=device, dtype=otf_dt) for r in self.otf_rows]
            return FourierFactors(spec, spectra, rows, self.size, self.window, None, self.terms)
        plain = None if self.plain_otf is None else self.plain_otf.to(device=device, dtype=dtype)
        return FourierFactors(spec, spectra, self.otf.to(device=device, dtype=otf_dt), self.size, self.window, plain,
                              self.terms)

    def detach(self) -> FourierFactors:
        if self.otf_rows is not None:
            return FourierFactors(self.spec.detach(), self.spectra.detach(), self.otf_rows, self.size, self.window,
                                  None, self.terms)
        plain = None if self.plain_otf is None else self.plain_otf.detach()
        return FourierFactors(self.spec.detach(), self.spectra.detach(), self.otf.detach(), self.size, self.window,
                              plain, self.terms)

    def __repr__(self) -> str:
        return (f"FourierFactors(J={self.spec.shape[1]}, L={self.spectra.shape[-1]}, buffer={self.size}, "
                f"window={self.window})")


@dataclasses.dataclass(eq=False, repr=False)
class OpticalImage(SpectralImage):
    """Spectral irradiance ``photons [B, L, H, W]`` (photons/s/m^2/nm) on the image plane.

    The sample grid is centred on the optical axis: sample (i, j) sits at
    ``((j - (W-1)/2) dx, (i - (H-1)/2) dx)``.

    Args:
        sample_spacing_m: pitch of the irradiance samples on the image plane (m), ``[B]``.
        hfov_deg: horizontal field of view the image covers, as seen from the lens (deg), ``[B]``.
        focal_length_m, f_number, image_distance_m: the optics geometry that produced it (``[B]``),
            optional for images made by hand.
        pad_rows, pad_cols: samples added on each side by the optics beyond the scene's extent
            (ISETCam-compatible padding), so the scene's region is known.
    """

    sample_spacing_m: torch.Tensor | float = 1e-6
    hfov_deg: torch.Tensor | float | None = None
    focal_length_m: torch.Tensor | float | None = None
    f_number: torch.Tensor | float | None = None
    image_distance_m: torch.Tensor | float | None = None
    pad_rows: int = 0
    pad_cols: int = 0

    _batch_fields: ClassVar[tuple[str, ...]] = (
        "sample_spacing_m", "hfov_deg", "focal_length_m", "f_number", "image_distance_m",
    )
    _units: ClassVar[str] = "photons/s/m^2/nm"

    def __post_init__(self, validate: bool = True) -> None:
        super().__post_init__(validate)
        # the padding the optics added: whole samples, under half the image on each side (2.7, -1 or more than the
        # image were taken, and a sensor without a set size fits the unpadded extent: Sensor.size_for)
        for name, n, size in (("pad_rows", self.pad_rows, self.height), ("pad_cols", self.pad_cols, self.width)):
            if not (is_integer(n) and 0 <= n and 2 * n < size):
                raise ValueError(f"{name}: expected an integer number of samples from 0 to less than half the "
                                 f"image's {size}, got {n!r}")
        if self.hfov_deg is None:
            d = self.image_distance_m if self.image_distance_m is not None else self.focal_length_m
            if d is not None:
                self.hfov_deg = angle_for_extent(self.width_m, d)

    @property
    def width_m(self) -> torch.Tensor:
        return self.sample_spacing_m * self.width

    @property
    def height_m(self) -> torch.Tensor:
        return self.sample_spacing_m * self.height

    def sample_positions_m(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Sample centres (m) relative to the optical axis: (y [B, H], x [B, W])."""
        dx = self.sample_spacing_m[:, None]
        i = torch.arange(self.height, device=self.device, dtype=self.dtype)
        j = torch.arange(self.width, device=self.device, dtype=self.dtype)
        return (i - (self.height - 1) / 2) * dx, (j - (self.width - 1) / 2) * dx

    def illuminance(self) -> torch.Tensor:
        """Illuminance (lux) [B, 1, H, W]: 683 sum E V dl."""
        return self.photometric()

    def mean_illuminance(self) -> torch.Tensor:
        """Mean illuminance (lux) over the whole image [B]."""
        return self.illuminance().mean(dim=(1, 2, 3))

    def crop(self, top: int, left: int, height: int, width: int) -> OpticalImage:
        """A window of the optical image, keeping the sample spacing.

        The result is re-centred on its own window (the window's centre becomes the axis).
        """
        data = self._crop_changes(top, left, height, width)
        d = self.image_distance_m if self.image_distance_m is not None else self.focal_length_m
        if d is not None:
            hfov = angle_for_extent(self.sample_spacing_m * width, d)
        elif self.hfov_deg is not None:  # a field of view given without a distance: the window's share of its extent
            unit = torch.ones_like(self.hfov_deg)  # (at any distance: a unit one)
            hfov = angle_for_extent(extent_for_angle(self.hfov_deg, unit) * width / self.width, unit)
        else:
            hfov = None
        return self.replace(**data, hfov_deg=hfov, pad_rows=0, pad_cols=0)
