"""Sensor presets from published EMVA 1288 measurements (merged into ``isettorch.sensor.sensor.PRESETS``).

Each preset encodes the datasheet's saturation capacity as the photodiode's clip (``full_well_e``), its temporal dark
noise as ``read_noise_v``, its pixel pitch and bit depth, and its quoted peak quantum efficiency (at 525 nm) as a
QE flat over 400-700 nm (``pixel_qe``: the presets' electrons were 1.3-1.4x too many at 1 QE; a real monochrome
sensor's QE also falls towards 400 and 700 nm, which a flat QE overestimates). Values are rounded; quantities a
datasheet gives only as plots (QE curves, DSNU/PRNU, dark current) are left at the sensor defaults. The numbers were
transcribed from the documents named below from memory, without the documents at hand: check them against the
current datasheet before quantitative use.
"""

from __future__ import annotations

from typing import Any

__all__ = ["EMVA_PRESETS", "emva_preset"]


def emva_preset(*, pixel_size_m: float, saturation_e: float, dark_noise_e: float, adc_bits: int, rows: int,
                cols: int, qe_peak: float, cfa: str = "mono", black_level_dn: float = 64.0) -> dict[str, Any]:
    """Sensor arguments for a datasheet's (saturation capacity, temporal dark noise): the photodiode clips at the
    saturation capacity (``full_well_e``, EMVA 1288 4.0 section 6.5), which a 1 V swing places at 95 % of the ADC
    range; a black level (pedestal) keeps the dark noise unclipped; ``qe_peak`` is the QE on the default
    400:10:700 nm grid (flat)."""
    if not 0 < qe_peak <= 1:
        raise ValueError(f"qe_peak: expected a quantum efficiency in (0, 1], got {qe_peak!r}")
    cg = 0.95 / saturation_e
    return dict(pixel_size_m=pixel_size_m, fill_factor=1.0, conversion_gain_v_per_e=cg, voltage_swing_v=1.0,
                read_noise_v=dark_noise_e * cg, adc_bits=adc_bits, black_level_dn=black_level_dn,
                full_well_e=saturation_e, cfa=cfa, rows=rows, cols=cols, pixel_qe=[float(qe_peak)] * 31)


EMVA_PRESETS: dict[str, dict[str, Any]] = {
    # Sony IMX174 (Pregius, 5.86 um global shutter, 1936 x 1216), 12-bit: saturation capacity ~32 000 e-, temporal
    # dark noise ~6.9 e- (QE ~76 % at 525 nm). Source: Point Grey (FLIR) White Paper "Sony Pregius Global Shutter
    # CMOS Imaging Performance" (2015) and FLIR's EMVA 1288 imaging-performance tables for IMX174 cameras.
    "imx174_emva": emva_preset(pixel_size_m=5.86e-6, saturation_e=32000.0, dark_noise_e=6.9, adc_bits=12, rows=1216,
                               cols=1936, qe_peak=0.76),
    # Sony IMX250 (Pregius 2nd generation, 3.45 um, 2448 x 2048), 12-bit: saturation capacity ~10 500 e-, temporal
    # dark noise ~2.4 e- (QE ~70 % at 525 nm). Source: FLIR (Teledyne), "How to Evaluate Camera Sensitivity"
    # (white paper comparing Pregius generations with EMVA 1288 data) and FLIR Blackfly S BFS-U3-51S5M EMVA data.
    "imx250_emva": emva_preset(pixel_size_m=3.45e-6, saturation_e=10500.0, dark_noise_e=2.4, adc_bits=12, rows=2048,
                               cols=2448, qe_peak=0.70),
}
