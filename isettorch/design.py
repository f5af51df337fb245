"""Camera designs: a sensor design (filter bank + mosaic, :mod:`isettorch.sensor.design`) in a camera with fixed
optics and a stated exposure rule, a reconstruction network per scene light level, and the design file.

**Light level.** A scene is a surface of reflectance ``R(x, l)`` lit by an illuminant (D65 by default) of
illuminance ``E`` lux; a Lambertian surface has radiance ``L = E R / pi`` (so a perfect white has luminance
``E / pi`` cd/m^2; Wyszecki & Stiles, Color Science, 2nd ed., 1982, section 4.3).

**Exposure rule** (``incident``: an incident-light meter on a white card, then shutter, then gain). ``t_white``
is the sensor's own luminance auto-exposure (:func:`isettorch.sensor.auto_exposure`, ``'luminance'``: the
brightest pixel to ``target`` x the usable swing) of a perfect white under the scene's light, through the same
optics and mosaic, at unit gain. The exposure is ``t = min(t_white, max_exposure_s)`` (the exposure limit) and the
analog gain ``min(t_white / t, max_analog_gain)`` (ISO raised once the shutter is at its limit, as a camera's
program mode does): bright scenes are exposed so a white reads ``target`` of full scale in the most sensitive
filter (a design with clear pixels gets a shorter exposure), dim scenes get ``max_exposure_s``, fewer photons and
more gain (the read noise is added before the gain, the ADC after it). By default the rule is a decision taken from
the current design at every capture, not a path for gradients (the white card's exposure is detached; the shipped
designs were trained so): gradients reach the filters, mosaic and f-number through the photo-electrons, the noise and
the ADC at the chosen exposure, which is the whole derivative wherever the exposure and gain are both at their
limits (for the shipped designs' camera: 1 lux for every design, 10 lux for ``bayer_rgb`` and ``learned``;
elsewhere the f-number's gradient differs from the rule-in-the-graph one by a few per cent: 5.4 % for
``bayer_rgb`` at 100 lux, 3.6 % for ``rgbw`` at 10 lux). ``config.exposure.differentiable: true`` keeps the
rule in the graph (the sensor's auto-exposure is differentiable), so the gradient also holds "a brighter filter or a
faster lens shortens the exposure" and equals a finite difference that re-runs the rule at every level.

**Network input.** The raw mosaic, black-subtracted, divided by the noise-free capture of that white card
(pixel by pixel): a perfect white reads 1 in every pixel whatever the filter, exposure or vignetting; the
network (:class:`~isettorch.isp.mosaic_net.MosaicReconstructionNet`) maps it, with the filter weights, to linear
sRGB relative to the white.

**Design file** (``torch.save`` of a dict, read with ``torch.load(weights_only=True)``): ``format``,
``version``, ``name``, ``config`` (optics, sensor, exposure, scene, network, training: plain values),
``wavelengths_nm [L]``, ``filter_names``, ``filter_spec`` (``'learned'`` or a letter per filter), ``filters
[K, L]`` (transmittances, checked manufacturable on save and load), ``pixel_qe [L]`` (the rest of the QE),
``mosaic [P, Q]`` (hard filter indices), ``levels`` (``[{"lux", "network": {"kwargs", "state_dict"}}]``) and
``card`` (markdown).
"""

from __future__ import annotations

import copy
import math
import numbers
from pathlib import Path
from typing import Any

import torch
from torch import nn

from . import spectral
from ._autograd import full_precision, records_grad
from ._checks import check_bool, check_float_dtype, check_seed, check_zip_crc, first_line
from .image import XYZ_TO_LINEAR_SRGB
from .isp.mosaic_net import MosaicReconstructionNet
from .optics import DiffractionLimitedOptics
from .optics.geometry import image_distance, relative_illumination
from .scene import Scene
from .sensor.design import design_sensor, fixed_design, learned_design
from .sensor.filter_bank import FilterBank, check_manufacturable
from .sensor.mosaic import LearnedMosaic

__all__ = ["DESIGN_DEFAULTS", "DESIGN_FORMAT", "DesignCamera", "SHIPPED_DESIGNS", "bound_patches",
           "colour_bound_loss", "colour_estimate_mse", "design_card", "design_path", "evaluate_design",
           "illuminant_photons", "linear_srgb_of_reflectance", "load_design", "make_design", "patch_signals",
           "predesign_filters", "save_design"]

DESIGN_FORMAT = "isettorch-design"
DESIGN_VERSION = 1

#: designs shipped with the package (``isettorch/assets/design_<name>.pt``), produced by ``training/codesign.py``
SHIPPED_DESIGNS = ("bayer_rgb", "ycmy", "rgbw", "learned")

#: the camera every design shares (``config`` overrides any key); units in the names
DESIGN_DEFAULTS: dict[str, dict[str, Any]] = {
    # the library's fixed filters divided by their set's peak (FilterBank fixed_scale), so a fixed filter can
    # transmit as much as a learned one (ISETCam's r, g, b tables peak at 0.39)
    "filters": {"fixed_scale": "peak"},
    "optics": {"f_number": 2.0, "focal_length_m": 3.862755099e-3},
    # ISETCam's default pixel (2.8 um, fill 0.75, 1e-4 V/e-, 1 V swing: 10000 e- well) with a modern 2 e- read
    # noise, 10 e-/s dark current and a 10-bit ADC
    "sensor": {"pixel_size_m": 2.8e-6, "fill_factor": 0.75, "conversion_gain_v_per_e": 1e-4, "voltage_swing_v": 1.0,
               "read_noise_v": 2e-4, "dark_current_e_per_s": 10.0, "adc_bits": 10, "shot_noise": "poisson"},
    "exposure": {"rule": "incident", "target": 0.9, "max_exposure_s": 1.0 / 30, "max_analog_gain": 16.0},
    "scene": {"illuminant": "D65", "distance_m": 1.2, "wavelengths_nm": [400.0, 700.0, 10.0]},
    "network": {"width": 32, "depth": 4},
}
#: keys a section may have beyond :data:`DESIGN_DEFAULTS`' (the network's context path is off unless asked for)
_OPTIONAL_KEYS = {"network": ("context_scale",), "exposure": ("differentiable",)}


def _merge(defaults: dict, overrides: dict | None) -> dict:
    out = copy.deepcopy(defaults)
    for section, values in (overrides or {}).items():
        if section in out and isinstance(out[section], dict):
            if not isinstance(values, dict):
                raise ValueError(f"config.{section}: expected a mapping, got {values!r}")
            unknown = [k for k in values if k not in out[section] and k not in _OPTIONAL_KEYS.get(section, ())]
            if unknown and section != "sensor":  # the sensor takes any Sensor argument
                raise ValueError(f"config.{section}.{unknown[0]}: unknown key; expected one of {sorted(out[section])}")
            out[section].update(values)
        else:
            out[section] = copy.deepcopy(values)
    return out


def _design_config(config: dict | None) -> dict:
    """``config`` merged over :data:`DESIGN_DEFAULTS` and checked (the exposure rule and the fixed filters' scale):
    what :class:`DesignCamera` and :func:`make_design` build from."""
    cfg = _merge(DESIGN_DEFAULTS, config)
    if cfg["exposure"]["rule"] != "incident":
        raise ValueError(f"config.exposure.rule: expected 'incident', got {cfg['exposure']['rule']!r}")
    for key in ("target", "max_exposure_s", "max_analog_gain"):
        v = cfg["exposure"][key]
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"config.exposure.{key}: expected a positive number, got {v!r}")
    if not isinstance(cfg["exposure"].get("differentiable", False), bool):
        raise ValueError(f"config.exposure.differentiable: expected true or false, got "
                         f"{cfg['exposure']['differentiable']!r}")
    if cfg["exposure"]["max_analog_gain"] < 1:
        raise ValueError(f"config.exposure.max_analog_gain: expected >= 1 (the rule raises the gain once the "
                         f"exposure is at its limit; below 1 it would attenuate), got "
                         f"{cfg['exposure']['max_analog_gain']!r}")
    if cfg["filters"]["fixed_scale"] not in ("table", "peak"):
        raise ValueError(f"config.filters.fixed_scale: expected 'table' or 'peak', got "
                         f"{cfg['filters']['fixed_scale']!r}")
    # the scene section (a design file's too), checked here rather than at the first render, whose errors named
    # neither the key nor the design
    scene = cfg["scene"]
    try:
        lo, hi, step = (float(v) for v in scene["wavelengths_nm"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"config.scene.wavelengths_nm: expected [first, last, step] (nm), got "
                         f"{scene['wavelengths_nm']!r}") from err
    illuminant_photons(spectral.default_wavelengths(lo, hi, step).to(torch.float64), 1.0, scene["illuminant"])
    d = scene["distance_m"]
    if isinstance(d, bool) or not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0):
        raise ValueError(f"config.scene.distance_m: expected a positive distance (m), got {d!r}")
    return cfg


def lux_key(lux: float) -> str:
    """A light level as a module name (``10`` -> ``'10'``, ``0.5`` -> ``'0p5'``)."""
    return f"{float(lux):g}".replace(".", "p").replace("-", "m")


def _check_lux(lux) -> float:
    """A light level: a positive finite number (not a bool), else a ValueError naming ``lux``."""
    if isinstance(lux, bool) or not (isinstance(lux, numbers.Real) and math.isfinite(lux) and lux > 0):
        raise ValueError(f"lux: expected a positive finite illuminance, got {lux!r}")
    return float(lux)


def illuminant_photons(wavelengths_nm: torch.Tensor, lux: float, illuminant: str = "D65") -> torch.Tensor:
    """Radiance of a perfect white Lambertian surface ``[L]`` (photons/s/sr/m^2/nm) under ``lux`` of the named
    illuminant: luminance ``lux / pi`` cd/m^2 (module docstring)."""
    _check_lux(lux)
    wl = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
    ph = spectral.energy_to_photons(spectral.illuminant(illuminant, wl, dtype=torch.float64), wl, dim=0)
    lum = spectral.luminance(ph[:, None, None], wl).reshape(())
    if not float(lum) > 0:
        raise ValueError(f"wavelengths_nm: {wl.min().item():g}-{wl.max().item():g} nm holds no luminance of "
                         f"{illuminant!r} (V(lambda) is 0 there), so a light level in lux cannot be set; expected a "
                         f"grid within the visible range")
    return ph * (lux / math.pi / lum)


def linear_srgb_of_reflectance(reflectance: torch.Tensor, wavelengths_nm, illuminant: str = "D65") -> torch.Tensor:
    """Linear sRGB ``[..., 3]`` of reflectances ``[..., L]`` under ``illuminant``, relative to a perfect white
    (Y_white = 1): CIE 1931 XYZ (:func:`isettorch.spectral.xyz`) through the library's XYZ -> linear sRGB matrix
    (:data:`isettorch.image.XYZ_TO_LINEAR_SRGB`, IEC 61966-2-1). The target of a reconstruction network (for the lift
    of a photograph under D65: the photograph's values)."""
    r = torch.as_tensor(reflectance, dtype=torch.float64)
    wl = torch.as_tensor(wavelengths_nm, dtype=torch.float64, device=r.device)
    e = illuminant_photons(wl, 1.0, illuminant)
    xyz = spectral.xyz((r * e)[..., None, None], wl, dim=-3)[..., 0, 0]
    white = spectral.xyz(e[:, None, None], wl, dim=-3)[1, 0, 0]
    return (xyz / white) @ torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64, device=xyz.device).T


class DesignCamera(nn.Module):
    """A sensor design in the shared camera: optics, the design's sensor, the exposure rule and one
    reconstruction network per light level (module docstring).

    Args:
        bank, mosaic: the sensor design (:func:`isettorch.sensor.design.fixed_design` / ``learned_design``).
        config: overrides of :data:`DESIGN_DEFAULTS` (sections ``optics``, ``sensor``, ``exposure``, ``scene``,
            ``network``; others, e.g. ``training``, are kept as they are).
        lux: the light levels to hold a network for.
        name: the design's name.
    """

    def __init__(self, bank: FilterBank, mosaic: LearnedMosaic, config: dict | None = None, lux=(), *,
                 name: str = "", learn_f_number: bool = False) -> None:
        super().__init__()
        self.config = _design_config(config)
        self.name = name
        cfg = self.config
        self.optics = DiffractionLimitedOptics(f_number=float(cfg["optics"]["f_number"]),
                                               focal_length_m=float(cfg["optics"]["focal_length_m"]),
                                               learn_f_number=learn_f_number)
        self.sensor = design_sensor(bank, mosaic, auto_exposure="luminance",
                                    ae_target=float(cfg["exposure"]["target"]), **cfg["sensor"])
        self.networks = nn.ModuleDict()
        for level in lux:
            self.add_level(level if isinstance(level, bool) else float(level))

    @property
    def bank(self) -> FilterBank:
        return self.sensor.spectral_qe

    @property
    def mosaic(self) -> LearnedMosaic:
        return self.sensor.cfa

    @property
    def lux_levels(self) -> list[float]:
        return sorted(float(n.replace("p", ".").replace("m", "-")) for n in self.networks)

    def add_level(self, lux: float, network: nn.Module | None = None) -> nn.Module:
        """Add (or replace) the network of light level ``lux``; a new one has ``config.network``'s size."""
        _check_lux(lux)
        if network is None:
            network = MosaicReconstructionNet(self.bank.num_channels, **self.config["network"])
        self.networks[lux_key(lux)] = network
        return network

    def network(self, lux: float) -> nn.Module:
        key = lux_key(_check_lux(lux))
        if key not in self.networks:
            raise ValueError(f"lux: the design {self.name!r} has no network for {lux:g} lux; it has "
                             f"{self.lux_levels}")
        return self.networks[key]

    # --- scenes ---------------------------------------------------------------------------------
    @property
    def wavelengths_nm(self) -> torch.Tensor:
        lo, hi, step = (float(v) for v in self.config["scene"]["wavelengths_nm"])
        return spectral.default_wavelengths(lo, hi, step).to(torch.float64)

    @property
    def image_distance_m(self) -> float:
        """The thin-lens image distance of ``config.scene.distance_m`` (the sensor's distance behind the lens)."""
        return float(image_distance(torch.tensor(float(self.config["optics"]["focal_length_m"]), dtype=torch.float64),
                                    torch.tensor(float(self.config["scene"]["distance_m"]), dtype=torch.float64)))

    def corner_light(self, height: int, width: int) -> float:
        """The irradiance at the corner pixel of a ``height`` x ``width`` capture relative to its centre's, by the
        optics' relative illumination (cos^4 by default: the field of view grows with the pixel count, one scene
        sample per pixel, so a large photograph is a wide-angle capture: about 0.81 at 768 x 512, 0.06 at
        4000 x 3000 for the shipped designs' 2.8 um pixels and 3.9 mm lens). 1 with no relative illumination."""
        pitch = self.sensor.pixel_size_m
        ys = torch.tensor([[0.0, (height - 1) / 2 * pitch]], dtype=torch.float64)
        xs = torch.tensor([[0.0, (width - 1) / 2 * pitch]], dtype=torch.float64)
        ri = relative_illumination(self.optics.relative_illumination, ys, xs, self.image_distance_m,
                                   float(self.optics.f_number))
        return 1.0 if ri is None else float(ri[0, 0, 1, 1] / ri[0, 0, 0, 0])

    def scene(self, maps: torch.Tensor, reflectance: torch.Tensor, lux: float, *, dtype=None) -> Scene:
        """The factored scene ``sum_j maps_j(x) R_j(l) E(l)``: ``maps [B, J, H, W]``, ``reflectance [B, J, L]`` or
        ``[J, L]`` on :attr:`wavelengths_nm`, lit by ``lux`` of ``config.scene.illuminant``, one scene sample per
        pixel (the FOV ``2 atan(pitch W / 2 d_i)``, ``d_i`` the thin-lens image distance)."""
        for name, value in (("maps", maps), ("reflectance", reflectance)):
            if not isinstance(value, torch.Tensor) or not value.is_floating_point():
                raise TypeError(f"{name}: expected a floating-point torch.Tensor, got {type(value).__name__}"
                                + (f" of {value.dtype}" if isinstance(value, torch.Tensor) else ""))
        if maps.dim() != 4 or 0 in maps.shape:
            raise ValueError(f"maps: expected a non-empty (B, J, H, W) tensor, got {tuple(maps.shape)}")
        if reflectance.dim() not in (2, 3):
            raise ValueError(f"reflectance: expected (B, J, L) or (J, L), got {tuple(reflectance.shape)}")
        dtype = dtype or maps.dtype
        check_float_dtype(dtype)
        wl = self.wavelengths_nm
        refl = reflectance if reflectance.dim() == 3 else reflectance[None].expand(maps.shape[0], -1, -1)
        if refl.shape[:2] != maps.shape[:2] or refl.shape[-1] != wl.numel():
            raise ValueError(f"reflectance: expected ({maps.shape[0]}, {maps.shape[1]}, {wl.numel()}), got "
                             f"{tuple(refl.shape)}")
        e = illuminant_photons(wl, lux, self.config["scene"]["illuminant"])
        d = self.config["scene"]["distance_m"]
        d_i = self.image_distance_m
        hfov = math.degrees(2 * math.atan(self.sensor.pixel_size_m * maps.shape[-1] / (2 * d_i)))
        dev = maps.device
        return Scene.from_factors(maps.to(dtype), (refl.to(dev, torch.float64) * e.to(dev)).to(dtype),
                                  wl.to(device=dev, dtype=dtype), hfov_deg=hfov, distance_m=d,
                                  illuminant_photons=e.to(device=dev, dtype=dtype)[None].expand(maps.shape[0], -1),
                                  validate=False)

    # --- capture --------------------------------------------------------------------------------
    @full_precision
    def capture(self, scene: Scene, *, generator: torch.Generator | None = None, noise: bool = True,
                with_noise_free: bool = False) -> dict:
        """Render ``scene`` through the optics and the design's sensor with the exposure rule.

        Returns ``{"input": [B, 1, H, W] white-normalised raw, "weights": [K, H, W] filter weights, "raw":
        RawImage, "exposure_s": [B], "analog_gain": [B]}``; ``with_noise_free`` adds ``"input_noise_free"``: the
        readout ``noise=False`` gives (same exposure, gain and ADC), from the same optical image.
        """
        b, h, w = scene.batch_size, scene.height, scene.width
        if h < 2 or w < 2:
            raise ValueError(f"scene: expected at least 2 x 2 samples (one pixel per sample, a whole mosaic cell's "
                             f"neighbourhood for the network), got {h} x {w}")
        sensor = self.sensor
        sensor.rows, sensor.cols = h, w
        oi = self.optics(scene)
        # the white card: a perfect white under the scene's light, through the same optics and mosaic; once for a
        # batch whose items share their light and geometry (every batch DesignCamera.scene makes), then the same
        # reading for each item
        ill, hfov, dist = scene.illuminant_photons, scene.hfov_deg, scene.distance_m
        shared = b > 1 and all(bool((v == v[:1]).all()) for v in (ill, torch.as_tensor(hfov).reshape(-1),
                                                                    torch.as_tensor(dist).reshape(-1)))
        n = 1 if shared else b
        white_scene = Scene.from_factors(torch.ones(n, 1, h, w, dtype=scene.dtype, device=scene.device),
                                         ill[:n, None, :].to(scene.dtype), scene.wavelengths_nm,
                                         hfov_deg=hfov[:n] if torch.is_tensor(hfov) and hfov.dim() else hfov,
                                         distance_m=dist[:n] if torch.is_tensor(dist) and dist.dim() else dist,
                                         validate=False)
        white_rates, _ = sensor.channel_rates(self.optics(white_scene))
        white_mosaic = sensor.cfa.mosaic(white_rates).expand(b, -1, -1, -1)
        rule = self.config["exposure"]
        # by default detached: the rule is a decision taken from the current design, not a path for gradients
        # (module docstring; the shipped designs were trained so); the sensor's auto-exposure itself is
        # differentiable, which config.exposure.differentiable keeps
        # (up to the longest exposure the rule can use, max exposure x max gain: auto-exposure's own 10 s cap held a
        # config allowing 60 s at 10 s, gain 1, the white card at 0.16 of full scale for 0.9)
        t_max, g_max = float(rule["max_exposure_s"]), float(rule["max_analog_gain"])
        t_white = sensor.exposure_for(None, white_mosaic, 1.0, max_exposure_s=t_max * g_max)
        if not rule.get("differentiable", False):
            t_white = t_white.detach()
        t = t_white.clamp(max=t_max)
        gain = (t_white / t).clamp(max=g_max)
        # Sensor.forward with the exposure given: its electron rate, then the capture (kept apart so that the
        # noise-free readout can reuse the rate)
        rate = sensor.electron_rate(oi)
        raw = sensor.capture(rate, exposure_s=t, analog_gain=gain, generator=generator, noise=noise)
        white = sensor.capture(white_mosaic, exposure_s=t, analog_gain=gain, noise=False).noise_free
        black, _ = raw.levels()  # the zero level: [B, 1, 1, 1] per item with an analog offset and per-item gains
        span = (white - black).detach()
        if not bool(torch.isfinite(span).all()) or bool((span <= 0).any()):
            dark = [k for k in range(white_rates.shape[1]) if not bool((white_rates[:, k] > 0).any())]
            raise ValueError(f"design: the white card reads no signal at {int((span <= 0).sum())} pixels (filters "
                             f"{dark} of the bank pass no light of config.scene.illuminant, or the light is below "
                             f"the sensor's range); every filter must transmit some light")
        x = (raw.data - black) / (white - black)
        if not bool(torch.isfinite(x).all()):
            raise ValueError("lux: the white card's signal is too small to normalise the capture by (non-finite "
                             "input at this light level); expected a brighter scene")
        weights = sensor.cfa.weights(h, w, dtype=x.dtype, device=x.device)
        out = {"input": x, "weights": weights, "raw": raw, "exposure_s": t, "analog_gain": gain}
        if with_noise_free:
            clean = raw if not noise else sensor.capture(rate, exposure_s=t, analog_gain=gain, noise=False)
            out["input_noise_free"] = (clean.data - black) / (white - black)
        return out

    def reconstruct(self, cap: dict, lux: float, *, key: str = "input") -> torch.Tensor:
        """Linear sRGB ``[B, 3, H, W]`` (white = 1): the network of ``lux`` applied to ``cap[key]`` of a
        :meth:`capture` (``"input"``, or ``"input_noise_free"``), in the network's dtype (float32 as shipped: a
        float64 capture is rounded to it; ``camera.double()`` reconstructs in float64)."""
        if key not in ("input", "input_noise_free") or key not in cap:
            raise ValueError(f"key: expected 'input' or 'input_noise_free' (a capture made with with_noise_free=True), "
                             f"got {key!r}; the capture holds {sorted(k for k in cap if k.startswith('input'))}")
        net = self.network(lux)
        p = next(net.parameters())
        return net(cap[key].to(p.dtype), cap["weights"].to(p.dtype))

    def forward(self, scene: Scene, lux: float, *, generator: torch.Generator | None = None,
                noise: bool = True) -> torch.Tensor:
        """Linear sRGB ``[B, 3, H, W]`` (white = 1) reconstructed by the network of ``lux`` (``noise=False``: from
        the sensor's noise-free readout, to measure the error that remains without noise)."""
        return self.reconstruct(self.capture(scene, generator=generator, noise=noise), lux)


# ------------------------------------------------------------------------------------------------ noise bound

def patch_signals(camera: DesignCamera, reflectance, lux: float, *, size: int | None = None) -> dict:
    """What a design's camera records of flat patches: the noise-free capture of each reflectance ``[n, L]`` (on
    :attr:`DesignCamera.wavelengths_nm`) as a uniform ``size`` x ``size`` scene at ``lux`` under the exposure rule,
    differentiable in the filters. ``reflectance`` may be a mapping of named sets ``{name: [n_i, L]}``: they are
    captured together (one exposure, set by the light) and the result is ``{name: signals}``. The pixels 4 or more
    from the border are read; their window must hold whole mosaic cells (``size - 8`` a multiple of the cell's
    height and width; default: the smallest such window of at least 8 x 8, 16 pixels for a 2 x 2 or 4 x 4 cell).

    Returns ``{"rho": [n, C]`` mean photo-electrons of each channel the (hard) mosaic uses, over the pixels 4 or
    more from the border, ``"var": [n, C]`` one pixel's noise variance in electrons (Poisson shot noise ``rho``, if
    the sensor has shot noise, and the capture's dark floor, :meth:`~isettorch.sensor.Sensor.poisson_gaussian`: the
    read noise squared, the dark signal, the other terms the sensor has, and the ADC step squared over 12 at the
    capture's gain),
    ``"frac": [C]`` each channel's share of the mosaic cell, ``"target": [n, 3]`` the patches' linear sRGB (white = 1,
    :func:`linear_srgb_of_reflectance`), ``"names"``, ``"exposure_s"``, ``"gain"`` (floats)}``.
    """
    if isinstance(reflectance, dict):
        names = list(reflectance)
        sets = [torch.as_tensor(reflectance[k], dtype=torch.float64) for k in names]
        if any(r.dim() != 2 for r in sets):
            raise ValueError("reflectance: expected each named set as [n, L]")
        sig = patch_signals(camera, torch.cat(sets), lux, size=size)
        out, start = {}, 0
        for name, r in zip(names, sets):
            rows = slice(start, start + r.shape[0])
            out[name] = {k: v[rows] if k in ("rho", "var", "target") else v for k, v in sig.items()}
            start += r.shape[0]
        return out
    cell = camera.mosaic.index_map
    period = math.lcm(*cell.shape)
    if size is None:
        size = 8 + period * -(-8 // period)
    if not (isinstance(size, int) and size > 8 and (size - 8) % period == 0):
        raise ValueError(f"size: expected 8 plus a positive multiple of the mosaic cell's {tuple(cell.shape)} "
                         f"period ({period}), got {size!r}")
    wl = camera.wavelengths_nm
    refl = torch.as_tensor(reflectance, dtype=torch.float64)
    if refl.dim() != 2 or refl.shape[1] != wl.numel():
        raise ValueError(f"reflectance: expected [n, {wl.numel()}] on the design's grid, got {tuple(refl.shape)}")
    n = refl.shape[0]
    maps = torch.ones(n, 1, size, size, dtype=torch.float64)
    cap = camera.capture(camera.scene(maps, refl[:, None, :], lux), noise=False)
    e = cap["raw"].electrons[:, 0]
    tiled = cell.repeat(size // cell.shape[0] + 1, size // cell.shape[1] + 1)[:size, :size]
    inner, e_inner = tiled[4:-4, 4:-4], e[:, 4:-4, 4:-4]
    used = [c for c in range(camera.bank.num_channels) if bool((cell == c).any())]
    rho = torch.stack([e_inner[:, inner == c].mean(1) for c in used], 1)
    frac = torch.tensor([float((cell == c).double().mean()) for c in used], dtype=torch.float64)
    gain, t = float(cap["analog_gain"][0]), float(cap["exposure_s"][0])
    # the capture's own noise model (Sensor.poisson_gaussian, in DN: a the shot noise's DN per electron, 0 without
    # shot noise; b the dark floor): in electrons the signal's shot noise plus b / k^2, k the DN per electron (read
    # noise, dark signal, CDS, DSNU and the others as the sensor has them, and the ADC step squared over 12)
    s = camera.sensor
    a, b = (float(v[0]) for v in s.poisson_gaussian(exposure_s=t, analog_gain=gain))
    k = float(s.gain_per_electron(gain)[0])
    floor = b / k**2
    if s.output_units == "dn" and records_grad(cap["analog_gain"]):
        # the ADC's rounding, 1/12 DN^2 in b, is 1 / (12 k^2) electrons, k following the gain the rule chose
        # (config.exposure.differentiable): kept in the graph (as a number, 1.2e-3 of the loss's gradient at 100 lux
        # was lost)
        from .metrics.emva import S2_QUANTIZATION_DN2

        k_t = s.gain_per_electron(cap["analog_gain"][:1])[0]
        floor = floor + S2_QUANTIZATION_DN2 * (1 / k_t**2 - 1 / k**2)
    var = (rho if a > 0 else torch.zeros_like(rho)) + floor
    return {"rho": rho, "var": var, "frac": frac, "target": linear_srgb_of_reflectance(refl, wl),
            "names": [camera.bank.channel_names[c] for c in used], "exposure_s": t, "gain": gain}


def bound_patches(wavelengths_nm: torch.Tensor, fit_patches: int = 256, test_colours: int = 64, seed: int = 5
                  ) -> dict:
    """Materials to judge a design's colour by (reflectances ``[n, L]`` on ``wavelengths_nm``): ``fit``, the scene
    generator's reflectance model (:func:`isettorch.data.spectra.random_reflectances`, the training scenes'
    materials), on which a colour correction is learned, and two test sets it is applied to: ``macbeth`` (ISETCam's
    measured Macbeth reflectances, :func:`isettorch.scene.macbeth.macbeth_reflectances`) and ``photo`` (random
    linear sRGB colours ``u^2.2``, ``u`` uniform, lifted as :func:`isettorch.data.photos.lift_srgb` lifts a
    photograph: Mallett & Yuksel's basis). A function of its arguments only."""
    from .data.spectra import random_reflectances, srgb_basis_spectra
    from .scene.macbeth import macbeth_reflectances

    for name, v in (("fit_patches", fit_patches), ("test_colours", test_colours)):
        if not (isinstance(v, int) and v > 0):
            raise ValueError(f"{name}: expected a positive integer, got {v!r}")
    wl = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
    g = torch.Generator().manual_seed(check_seed(seed))  # (int() took 1.5, -1 and "3")
    fit = random_reflectances(fit_patches, wl.float(), g).to(torch.float64)
    colours = torch.rand(test_colours, 3, generator=g, dtype=torch.float64) ** 2.2
    return {"fit": fit, "macbeth": macbeth_reflectances(wl, dtype=torch.float64),
            "photo": colours @ srgb_basis_spectra(wl).to(torch.float64)}


def colour_estimate_mse(fit: dict, window: int, test: dict | None = None) -> torch.Tensor:
    """Mean squared error (per linear-sRGB channel, over the patches) of the best linear colour estimate of a flat
    patch from its channels' means over a window of ``window`` pixels.

    ``fit`` and ``test`` are :func:`patch_signals` of the same design. A window holding a share ``f_c`` of channel
    ``c`` measures its mean with variance ``var / (f_c window)``; the Wiener (linear MMSE) map from those means to
    linear sRGB over ``fit``'s patches is ``M = T' P (P' P + n S)^-1`` (Kay, Fundamentals of Statistical Signal
    Processing I, 1993, 12.6), and its error on ``test``'s patches (default: ``fit``'s) is the colour bias of that
    map plus the noise it passes, ``mean((P M' - T)^2) + trace(M S M') / 3``. With ``test`` another set of spectra
    it is the error of a colour correction learned on one set of materials and applied to another (a network
    trained on the generator's reflectances and scored on photographs lifted to spectra). Differentiable.
    """
    if isinstance(window, bool) or not (isinstance(window, int) and window > 0):
        raise ValueError(f"window: expected a positive number of pixels, got {window!r}")
    test = fit if test is None else test
    for name, sig in (("fit", fit), ("test", test)):
        missing = [k for k in ("rho", "var", "frac", "target") if not isinstance(sig, dict) or k not in sig]
        if missing:
            raise ValueError(f"{name}: expected patch_signals' mapping with 'rho', 'var', 'frac' and 'target', "
                             f"missing {missing}")
        if sig["rho"].dim() != 2 or sig["rho"].shape[0] == 0 or sig["rho"].shape[1] != fit["rho"].shape[1]:
            raise ValueError(f"{name}: expected rho [n >= 1, {fit['rho'].shape[1]}] (the design's channels), got "
                             f"{tuple(sig['rho'].shape)}")
        if not all(bool(torch.isfinite(sig[k].detach()).all()) for k in ("rho", "var", "frac", "target")):
            raise ValueError(f"{name}: expected finite signals, variances, fractions and targets")
        if bool((sig["frac"] <= 0).any()):
            raise ValueError(f"{name}: expected every channel in the mosaic cell (frac > 0), got "
                             f"{sig['frac'].detach().tolist()}")
    rho, target = fit["rho"], fit["target"]
    n = rho.shape[0]
    s = (fit["var"] / (fit["frac"] * window)).mean(0)
    try:
        m = torch.linalg.solve(rho.T @ rho / n + torch.diag(s), rho.T @ target / n).T  # [3, C]
    except torch.linalg.LinAlgError as err:
        raise ValueError("fit: the Wiener system is singular (channels with neither an independent signal over the "
                         "patches nor noise)") from err
    s_test = (test["var"] / (test["frac"] * window)).mean(0)
    return ((test["rho"] @ m.T - test["target"]) ** 2).mean() + (m**2 @ s_test).mean()


def colour_bound_loss(camera: DesignCamera, patches: dict, levels, window: int = 16) -> torch.Tensor:
    """The design criterion of :func:`predesign_filters`: the mean over the light ``levels`` and the two test sets
    of ``patches`` (:func:`bound_patches`: ``macbeth`` and ``photo``) of ``log`` of the colour estimate's error
    (:func:`colour_estimate_mse`: a Wiener colour correction fitted on ``patches["fit"]``, applied to each test set,
    with the photon, read, dark and ADC noise of the design's own capture at that level, averaged over ``window``
    pixels). Differentiable in the filters."""
    levels = [float(v) for v in levels]
    if not levels:
        raise ValueError("levels: expected at least one light level")
    total = 0.0
    for lux in levels:
        sig = patch_signals(camera, {k: patches[k] for k in ("fit", "macbeth", "photo")}, lux)
        for key in ("macbeth", "photo"):
            total = total + torch.log(colour_estimate_mse(sig["fit"], window, sig[key]))
    return total / (2 * len(levels))


def predesign_filters(camera: DesignCamera, levels, *, steps: int = 200, lr: float = 0.05, window: int = 16,
                      fit_patches: int = 256, test_colours: int = 64, seed: int = 5,
                      progress=None) -> dict:
    """Design a camera's learned filters on the noise-limited colour estimate, before (or instead of) training a
    reconstruction: ``steps`` Adam steps on :func:`colour_bound_loss` over the filters' parameters, the mosaic as
    it is (read hard). A colour-filter design criterion of the kind of Vora & Trussell ("Mathematical methods for
    the design of color scanning filters", IEEE Trans. Image Processing 6(2), 1997) and Parmar & Reeves
    ("Optimization of color filter sensitivity functions for color filter array based image acquisition", IS&T
    Color Imaging Conf. 14, 2006), here through the library's own capture: the exposure rule, photon and read noise,
    dark signal and ADC. ``progress(step, loss)`` is called every step if given.

    Returns ``{"steps", "window", "lux", "loss": [start, end], "gain_db": {lux: dB over bayer_rgb}}``: the
    criterion before the first and after the last step, and at each level its gain over Bayer's filters in the
    same camera (``10 log10`` of the ratio of the two errors' geometric means).
    """
    bank = camera.bank
    if not bank.num_learned:
        raise ValueError("camera: only a design with learned filters can be predesigned")
    if not (isinstance(steps, int) and steps >= 0):
        raise ValueError(f"steps: expected a non-negative integer, got {steps!r}")
    levels = [float(v) for v in levels]
    patches = bound_patches(camera.wavelengths_nm, fit_patches, test_colours, seed)
    params = [bank.raw_amplitudes, bank.raw_offsets]
    was = camera.training
    camera.eval()  # the hard mosaic
    opt = torch.optim.Adam(params, lr=float(lr))
    losses = []
    for step in range(steps):
        loss = colour_bound_loss(camera, patches, levels, window)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        if progress is not None:
            progress(step, losses[-1])
    for q in params:
        q.grad = None
    config = {k: v for k, v in camera.config.items() if k in DESIGN_DEFAULTS}
    ref = make_design("bayer_rgb", config).eval()
    with torch.no_grad():  # after the last step, on the hard mosaic
        end = {lux: float(colour_bound_loss(camera, patches, [lux], window)) for lux in levels}
        gain = {f"{lux:g}": round(10 / math.log(10) * (float(colour_bound_loss(ref, patches, [lux], window))
                                                        - end[lux]), 3) for lux in levels}
    camera.train(was)
    return {"steps": steps, "window": window, "lux": levels,
            "loss": [losses[0], sum(end.values()) / len(end)] if losses else [], "gain_db": gain}


# ------------------------------------------------------------------------------------------------ design files

def _plain(value):
    """Config values as plain Python (a design file holds no pickled objects)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, torch.Tensor):
        return value.tolist()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ValueError(f"config: {value!r} ({type(value).__name__}) cannot be stored in a design file")


def design_card(camera: DesignCamera, results: dict | None = None) -> str:
    """A markdown card: the design, its camera, the exposure rule, the levels and (optionally) results
    ``{"<lux>": {"cpsnr": dB, "de2000": value}}``."""
    bank, mosaic, cfg = camera.bank, camera.mosaic, camera.config
    cell = "\n".join("    " + " ".join(f"{x:>3s}" for x in row) for row in mosaic.cell)
    frac = ", ".join(f"{k} {v:.0%}" for k, v in mosaic.fraction().items())
    lines = [f"# Camera design `{camera.name or 'unnamed'}`", "",
             f"Filters ({bank.num_channels}): "
             + ", ".join(f"{n} ({s})" for n, s in zip(bank.channel_names, bank.spec)),
             f"Fixed filters: the library's, scaled {cfg['filters']['fixed_scale']!r}.",
             "", f"Mosaic {mosaic.shape[0]}x{mosaic.shape[1]} ({frac}):", "", cell, "",
             f"Optics: diffraction-limited, f/{cfg['optics']['f_number']:g}, focal length "
             f"{cfg['optics']['focal_length_m'] * 1e3:g} mm.",
             "Sensor: " + ", ".join(f"{k} {v}" for k, v in cfg["sensor"].items()) + ".",
             f"Exposure: incident-light rule, a white card to {cfg['exposure']['target']:g} of full scale, at most "
             f"{cfg['exposure']['max_exposure_s']:.4g} s, then analog gain up to "
             f"{cfg['exposure']['max_analog_gain']:g}.",
             f"Scenes: reflectance under {cfg['scene']['illuminant']} at the trained light levels "
             f"{', '.join(f'{v:g}' for v in camera.lux_levels)} lux; network {cfg['network']}.",
             "Manufacturable: transmittances in [0, 1], slopes within 0.05 / nm (checked on save and load); one filter "
             "per pixel."]
    if cfg.get("training"):
        lines += ["", "Training: " + ", ".join(f"{k} {v}" for k, v in cfg["training"].items()) + "."]
    if results:
        lines += ["", "| lux | CPSNR (dB) | mean dE2000 |", "|---|---|---|"]
        lines += [f"| {k} | {v['cpsnr']:.2f} | {v['de2000']:.2f} |" for k, v in results.items()]
    return "\n".join(lines) + "\n"


def save_design(camera: DesignCamera, path, *, card: str | None = None) -> Path:
    """Write ``camera`` as a design file (module docstring): filters sampled on the bank's grid, the hard mosaic,
    every level's network weights, the config and a card (``card``; default the camera's own, a loaded design's
    training record, else :func:`design_card`'s). ValueError when a filter is not manufacturable."""
    bank, mosaic = camera.bank, camera.mosaic
    filters = bank.filters.detach().to(torch.float64).cpu().clone()
    check_manufacturable(filters, bank.wavelengths_nm, "filters")
    levels = []
    for lux in camera.lux_levels:
        net = camera.network(lux)
        kwargs = getattr(net, "kwargs", None)
        if not isinstance(net, MosaicReconstructionNet) or kwargs is None:
            raise ValueError(f"networks: expected MosaicReconstructionNet modules, got {type(net).__name__}")
        levels.append({"lux": float(lux), "network": {"kwargs": dict(kwargs), "state_dict": {
            k: v.detach().cpu().clone() for k, v in net.state_dict().items()}}})
    payload = {"format": DESIGN_FORMAT, "version": DESIGN_VERSION, "name": camera.name,
               "config": _plain(camera.config), "wavelengths_nm": bank.wavelengths_nm.detach().cpu().clone(),
               "filter_names": list(bank.channel_names), "filter_spec": list(bank.spec), "filters": filters,
               "pixel_qe": bank.extra.detach().cpu().clone(), "mosaic": mosaic.index_map.clone(), "levels": levels,
               # a loaded design's card (its training record) is kept when it is saved again; a new one is written
               "card": card if card is not None else getattr(camera, "card", None) or design_card(camera)}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(payload, path)
    return path


def design_path(design) -> Path:
    """A design file's path: a shipped name (:data:`SHIPPED_DESIGNS`) in the package's assets, else an existing
    path as given (a file named like a shipped design is given as a path, ``./ycmy``: the shipped names come first,
    so a stray file in the working folder cannot shadow them). FileNotFoundError when a shipped design is not in
    this installation yet."""
    name = str(design)
    p = Path(design)
    if name not in SHIPPED_DESIGNS and p.is_file():
        return p
    if name in SHIPPED_DESIGNS:
        asset = Path(__file__).parent / "assets" / f"design_{name}.pt"
        if asset.is_file():
            return asset
        raise FileNotFoundError(
            f"design: the shipped design {name!r} is not in this installation yet ({asset} is missing): the shipped "
            f"designs are produced by training/codesign.py (configs/train/codesign_*.yaml); pass a design file's path "
            f"instead")
    raise FileNotFoundError(f"design: {name!r} is neither a design file nor a shipped design "
                            f"({', '.join(SHIPPED_DESIGNS)})")


def load_design(design, *, device=None) -> DesignCamera:
    """A :class:`DesignCamera` (in eval mode: hard mosaic) from a design file or a shipped name, read with
    ``torch.load(weights_only=True)``."""
    path = design_path(design)
    check_zip_crc(path, "design")  # (torch.load read a file with 64 zeroed bytes: a weight off by 0.098)
    try:
        d = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unreadable file is the same error for the user
        # (torch's message goes on to suggest weights_only=False, an unsafe load of an untrusted file: its first
        # line only)
        detail = first_line(err)
        detail = ("not a torch file of tensors" if "weights_only" in detail or len(detail) < 8
                  else detail)  # (a bare '101' for a text file)
        raise ValueError(f"design: {str(path)!r} is not a readable design file ({type(err).__name__}: {detail})"
                         ) from err
    if not isinstance(d, dict) or d.get("format") != DESIGN_FORMAT:
        raise ValueError(f"design: {str(path)!r} is not an {DESIGN_FORMAT} file")
    if d.get("version") != DESIGN_VERSION:
        raise ValueError(f"design: {str(path)!r} has format version {d.get('version')!r}; this isettorch reads "
                         f"version {DESIGN_VERSION}")
    missing = [k for k in ("filter_names", "filters", "wavelengths_nm", "pixel_qe", "mosaic", "config", "levels")
               if k not in d]
    if missing:
        raise ValueError(f"design: {str(path)!r} lacks {missing}; not a complete design file")
    if not isinstance(d["config"], dict):
        raise ValueError(f"design: {str(path)!r} holds a config of type {type(d['config']).__name__}; expected a "
                         f"mapping (not a valid design file)")
    try:
        names = list(d["filter_names"])
        bank = FilterBank.from_table(d["filters"], d["wavelengths_nm"], names, pixel_qe=d["pixel_qe"])
        bank.spec = list(d.get("filter_spec", bank.spec))
        index = torch.as_tensor(d["mosaic"])
        if index.is_floating_point() or index.is_complex() or index.dtype == torch.bool:  # (0.5 was cast to 0;
            # True / False read as filters 1 / 0)
            raise ValueError(f"mosaic: expected integer filter indices, got {index.dtype}")
        index = index.long()
        mosaic = LearnedMosaic(names, pattern=index, learnable=False)
        camera = DesignCamera(bank, mosaic, d["config"], name=str(d.get("name", path.stem)))
        luxes = [lux_key(float(level["lux"])) for level in d["levels"]]
        if len(set(luxes)) != len(luxes):  # (add_level kept the last network of a repeated level)
            raise ValueError(f"levels: more than one network at one light level, "
                             f"{[float(v['lux']) for v in d['levels']]} lux")
        for level in d["levels"]:
            with torch.random.fork_rng(devices=[]):  # the initial weights, replaced by the file's, drew from the
                net = MosaicReconstructionNet(**level["network"]["kwargs"])  # global generator
            net.load_state_dict(level["network"]["state_dict"])
            bad = [k for k, v in net.state_dict().items() if v.is_floating_point() and not bool(v.isfinite().all())]
            if bad:  # (reported at the first image as "image: expected finite values")
                raise ValueError(f"the network at {float(level['lux']):g} lux has non-finite weights ({bad[0]})")
            camera.add_level(float(level["lux"]), net)
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as err:
        raise ValueError(f"design: {str(path)!r} is not a valid design file ({type(err).__name__}: {err})") from err
    camera.card = str(d.get("card", ""))
    return camera.to(device=device).eval() if device is not None else camera.eval()


def make_design(spec, config: dict | None = None, lux=(), *, seed: int = 0, name: str | None = None) -> DesignCamera:
    """A :class:`DesignCamera` from a design spec: a fixed design's name (``'bayer_rgb'``, ``'ycmy'``, ``'rgbw'``)
    or a mapping ``{"filters": [...], "mosaic_shape": [P, Q], "relax": ..., "mosaic_init_scale": ...,
    "mosaic_init": [[name, ...], ...], "mosaic_init_margin": m}`` for a learned design. ``mosaic_init`` starts the
    learnable mosaic from a hard pattern of the bank's channel names (``F<i>`` for the i-th learned filter, the
    letters of fixed ones; logits one-hot with margin ``mosaic_init_margin``, default 4) instead of random logits,
    e.g. Kodak's CFA 2.0 layout with learned colours. ``{"from_design": DESIGN}`` takes the filters and hard mosaic
    of a design file or shipped name as a fixed design (new networks): a designed sensor's networks trained again
    with a fixed design's budget."""
    scale = _design_config(config)["filters"]["fixed_scale"]
    seed = check_seed(seed)  # (1.5 and True were seed 1; 2^64 - 1 overflowed the mosaic's seed + 1, unnamed)
    if isinstance(spec, str):
        bank, mosaic = fixed_design(spec, fixed_scale=scale)
        return DesignCamera(bank, mosaic, config, lux, name=name or spec)
    if not isinstance(spec, dict):
        raise ValueError(f"design: expected a fixed design name or a mapping, got {spec!r}")
    if "from_design" in spec:
        if len(spec) != 1:
            raise ValueError(f"design.from_design: takes no other keys, got {sorted(spec)}")
        source = load_design(spec["from_design"])
        camera = DesignCamera(source.bank, source.mosaic, config, lux, name=name or source.name)
        # the design's own training record (its predesign and design schedule) stays with the filters
        camera.config["designed_by"] = {"design": str(spec["from_design"]),
                                        "training": source.config.get("training")}
        return camera
    keys = ("filters", "mosaic_shape", "relax", "band_width_nm", "max_log_odds", "mosaic_init_scale", "mosaic_init",
            "mosaic_init_margin")
    unknown = [k for k in spec if k not in keys]
    if unknown:
        raise ValueError(f"design.{unknown[0]}: unknown key; expected one of {keys}")
    bank_kwargs = {k: float(spec[k]) for k in ("band_width_nm", "max_log_odds") if k in spec}
    bank_kwargs["fixed_scale"] = scale
    mosaic_kwargs = {"init_scale": float(spec["mosaic_init_scale"])} if "mosaic_init_scale" in spec else {}
    filters = tuple(spec.get("filters", ("learned", "learned", "learned", "W")))
    shape = tuple(spec.get("mosaic_shape", (4, 4)))
    if "mosaic_init_margin" in spec and "mosaic_init" not in spec:
        raise ValueError("design.mosaic_init_margin: only with design.mosaic_init (the pattern it weighs)")
    if "mosaic_init" in spec:
        names = FilterBank(filters, learnable=False).channel_names
        rows = spec["mosaic_init"]
        if (not isinstance(rows, (list, tuple)) or not rows or any(not isinstance(r, (list, tuple)) for r in rows)
                or any(len(r) != len(rows[0]) for r in rows)):
            raise ValueError(f"design.mosaic_init: expected rows of filter names, got {rows!r}")
        bad = [x for r in rows for x in r if x not in names]
        if bad:
            raise ValueError(f"design.mosaic_init: {bad[0]!r} is not a filter of the bank {names}")
        if "mosaic_shape" in spec and [len(rows), len(rows[0])] != [int(v) for v in shape]:
            raise ValueError(f"design.mosaic_init: a {len(rows)} x {len(rows[0])} pattern, but mosaic_shape is "
                             f"{list(shape)}")
        mosaic_kwargs["pattern"] = torch.tensor([[names.index(x) for x in r] for r in rows], dtype=torch.long)
        if "mosaic_init_margin" in spec:
            mosaic_kwargs["pattern_margin"] = float(spec["mosaic_init_margin"])
        shape = (len(rows), len(rows[0]))
    bank, mosaic = learned_design(filters, shape, seed=seed,
                                  relax=spec.get("relax", "softmax"), bank_kwargs=bank_kwargs,
                                  mosaic_kwargs=mosaic_kwargs or None)
    return DesignCamera(bank, mosaic, config, lux, name=name or "learned")


# ------------------------------------------------------------------------------------------------ evaluation

def evaluate_design(design, images, lux=None, *, seed: int = 0, crop: int = 10, device="cpu",
                    dtype: torch.dtype = torch.float32, noise_free: bool = False, progress: bool = False) -> dict:
    """Score a design on 8-bit RGB photographs: each is lifted to spectra (:func:`isettorch.data.photos.lift_srgb`:
    the photograph as reflectance, Mallett & Yuksel's sRGB basis) under ``config.scene.illuminant`` (D65) at each
    light level, rendered through the design's camera with the noise of generator ``seed_for(seed, image index,
    stream=round(1000 lux))`` (the same generator for every design: repeatable, but not common random numbers, since
    Poisson shot noise takes a number of draws that depends on the signal, so two designs' later draws differ),
    reconstructed by the level's network and compared
    with the photograph in sRGB (output clipped to [0, 1] and encoded, IEC 61966-2-1): CPSNR (MSE over the
    channels, a ``crop``-pixel border excluded: :func:`isettorch.isp.evaluation.cpsnr`) and the mean CIEDE2000
    (CIELAB D65) over the same pixels.

    Args:
        design: a :class:`DesignCamera`, a design file or a shipped name.
        images: a folder of .png/.tif/.jpg images (:func:`isettorch.io.images.read_rgb8`) or an iterable of
            ``(name, uint8 [H, W, 3])``.
        lux: light levels (default: every level the design holds a network for).
        noise_free: also score the same network on the sensor's noise-free readout (no photon, read or
            fixed-pattern noise and no dark signal; the same exposure, gain and ADC): ``cpsnr_noise_free`` per image
            and ``mean_cpsnr_noise_free``.
            The difference to ``cpsnr`` is the part of a design's error that its noise causes; the rest (colour,
            detail, the network's smoothing at that level) is there without noise.

    Returns:
        ``{"design", "lux": [...], "seed", "crop", "mean_cpsnr": {"<lux>": dB}, "mean_de2000": {"<lux>": value},
        "images": [{"name", "corner_light", "cpsnr": {"<lux>": dB}, "de2000": {"<lux>": value}}]}`` (and the
        noise-free scores); ``corner_light``: the irradiance at the photograph's corner relative to its centre
        (:meth:`DesignCamera.corner_light`: a photograph sets the sensor's size, so a large one is a wide-angle
        capture with dark, noisy corners).
    """
    from .isp.evaluation import check_device

    check_float_dtype(dtype)
    check_bool(noise_free, "noise_free")
    seed = check_seed(seed)  # (2^64 ran as seed 0 and was reported as 2^64; 1.5 ran as 1)
    camera = design if isinstance(design, DesignCamera) else load_design(design)
    if lux is not None and (isinstance(lux, (str, bytes)) or not hasattr(lux, "__iter__")):
        raise ValueError(f"lux: expected a list of light levels (lux) or None, got {lux!r}")
    levels = camera.lux_levels if lux is None else [_check_lux(v) for v in lux]  # (True ran as 1 lux)
    if not levels:
        raise ValueError(f"lux: the design {camera.name!r} holds no network; give a design trained for a light level")
    # a level is its network's and its report's key (6 significant digits, lux_key): two levels given with one key
    # would be rendered twice and reported once, so they are refused (the keys stay as they were)
    keys = [f"{v:g}" for v in levels]
    for j, (key, v) in enumerate(zip(keys, levels)):
        if key in keys[:j]:
            other = levels[keys.index(key)]
            raise ValueError(f"lux: {v:g} is given twice; expected distinct light levels" if other == v else
                             f"lux: {other!r} and {v!r} are the same level to 6 significant digits ({key} lux: one "
                             f"network and one report key); expected distinct light levels")
    for v in levels:
        camera.network(v)  # ValueError naming the levels it has
    device = check_device(device)
    was_training = camera.training  # a caller's camera is left in the mode it came in (eval: the hard mosaic)
    camera = camera.to(device).eval()
    try:
        return _evaluate(camera, images, levels, keys, seed, crop, dtype, device, noise_free, progress)
    finally:
        camera.train(was_training)


def _evaluate(camera, images, levels, keys, seed, crop, dtype, device, noise_free, progress) -> dict:
    """:func:`evaluate_design`'s renders and scores, its arguments checked."""
    import numpy as np

    from ._progress import progress as progress_bar
    from .data.config import seed_for
    from .data.photos import lift_srgb
    from .image import srgb_encode
    from .io.images import rgb8_to_tensor
    from .isp.evaluation import check_photos, cpsnr, load_images
    from .metrics.color import srgb_to_xyz, xyz_to_lab
    from .metrics.difference import delta_e_2000

    items = load_images(images)
    if not items:
        raise ValueError("images: expected at least one photograph, got none")
    check_photos(items, crop)  # every input checked before the first render (and the progress bar)
    per_image = []
    bar = progress_bar(total=len(items) * len(levels), unit="render", desc=f"design-eval {camera.name}",
                       quiet=not progress)
    with bar, torch.no_grad():
        for i, (name, array) in enumerate(items):
            lifted = lift_srgb(array, camera.wavelengths_nm)
            truth = rgb8_to_tensor(array)
            hh, ww = truth.shape[-2:]
            lab_truth = xyz_to_lab(srgb_to_xyz(truth[..., crop:hh - crop, crop:ww - crop]))  # (the scored pixels)
            row = ({"name": name, "corner_light": camera.corner_light(*array.shape[:2]), "cpsnr": {}, "de2000": {}}
                   | ({"cpsnr_noise_free": {}} if noise_free else {}))
            for key, v in zip(keys, levels):
                g = torch.Generator(device=device).manual_seed(seed_for(seed, i, stream=round(1000 * v)))
                scene = camera.scene(lifted["maps"][None].to(device), lifted["reflectance"].to(device), v,
                                     dtype=dtype)
                cap = camera.capture(scene, generator=g, with_noise_free=noise_free)
                out = camera.reconstruct(cap, v).to("cpu", torch.float64)
                clean = (camera.reconstruct(cap, v, key="input_noise_free").to("cpu", torch.float64) if noise_free
                         else None)
                del cap, scene  # not needed for the scores (a large photograph's capture holds gigabytes)
                srgb = srgb_encode(out.clamp(0, 1))
                row["cpsnr"][key] = float(cpsnr(srgb, truth, crop)[0])
                lab = xyz_to_lab(srgb_to_xyz(srgb[..., crop:hh - crop, crop:ww - crop]))
                # the mean CIEDE2000 a band of rows at a time (its formula holds about 30 temporaries per pixel)
                de_sum = sum(float(delta_e_2000(lab[..., r:r + 256, :], lab_truth[..., r:r + 256, :]).sum())
                             for r in range(0, lab.shape[-2], 256))
                row["de2000"][key] = de_sum / (lab.shape[-2] * lab.shape[-1])
                if noise_free:
                    row["cpsnr_noise_free"][key] = float(cpsnr(srgb_encode(clean.clamp(0, 1)), truth, crop)[0])
                bar.update(1)
            per_image.append(row)
    out = {"design": camera.name, "lux": levels, "seed": int(seed), "crop": crop,
           "mean_cpsnr": {k: float(np.mean([r["cpsnr"][k] for r in per_image])) for k in keys},
           "mean_de2000": {k: float(np.mean([r["de2000"][k] for r in per_image])) for k in keys}}
    if noise_free:
        out["mean_cpsnr_noise_free"] = {k: float(np.mean([r["cpsnr_noise_free"][k] for r in per_image])) for k in keys}
    return out | {"images": per_image}
