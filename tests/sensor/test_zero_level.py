"""The zero level of a sensor with an analog offset (ISETCam ``sensorGet(sensor, 'zero level')``, the response to a
black image, which ``ipCompute`` subtracts): the black level plus the offset after gain. A capture's ``black_level``
is it, so the Poisson-Gaussian model, ``RawImage.normalized``, the training pairs and ``isettorch process`` measure
the signal from there (the offset counted as signal overstated the pairs' noise metadata by ``a`` x offset)."""

from __future__ import annotations

import pytest
import torch

from isettorch.sensor import Sensor

BITS, BLACK, CG, OFFSET = 12, 64.0, 5e-5, 0.02


def _sensor(convention="multiply", gain=2.0, **kw):
    base = dict(rows=64, cols=64, cfa="mono", adc_bits=BITS, black_level_dn=BLACK, conversion_gain_v_per_e=CG,
                read_noise_v=2e-4, analog_gain=gain, analog_offset_v=OFFSET, gain_convention=convention,
                exposure_s=0.01, shot_noise="poisson")
    base.update(kw)
    return Sensor(**base)


@pytest.mark.parametrize("convention, gain, volts", [("multiply", 2.0, OFFSET * 2.0), ("isetcam", 2.0, OFFSET / 2.0),
                                                     ("multiply", 0.5, OFFSET * 0.5)])
def test_zero_level_is_black_plus_offset_after_gain(convention, gain, volts):
    s = _sensor(convention, gain)
    lsb = 1.0 / 2**BITS  # 1 V swing
    assert s.zero_level() == pytest.approx(BLACK + volts / lsb, rel=1e-12)
    # per item: a [B] tensor for tensor gains
    z = s.zero_level(torch.tensor([gain, 2 * gain], dtype=torch.float64))
    other = OFFSET / (2 * gain) if convention == "isetcam" else OFFSET * 2 * gain
    torch.testing.assert_close(z, torch.tensor([BLACK + volts / lsb, BLACK + other / lsb], dtype=torch.float64))
    # volts and electrons readouts: the offset after gain in volts; none in electrons (that chain takes neither)
    v = _sensor(convention, gain, adc_bits=None, black_level_dn=0.0, output_units="volts")
    assert v.zero_level() == pytest.approx(volts, rel=1e-12)
    assert _sensor(convention, gain, output_units="electrons").zero_level() == 0.0
    # no offset: the black level itself, a float, as before
    plain = _sensor(convention, gain, analog_offset_v=0.0)
    assert plain.zero_level() == BLACK and type(plain.zero_level(torch.tensor([1.0, 2.0]))) is float


@pytest.mark.parametrize("convention", ["multiply", "isetcam"])
def test_dark_capture_reads_its_black_level(convention):
    """No light: the noisy frame's mean is the raw's black level (the offset included), normalized() reads 0."""
    s = _sensor(convention)
    dark = s.capture(torch.zeros(4, 1, 64, 64, dtype=torch.float64), generator=torch.Generator().manual_seed(2))
    # read noise 2e-4 V x gain: a few DN per pixel; the mean of 16384 pixels is good to ~0.05 DN
    assert float(dark.data.mean()) == pytest.approx(dark.black_level, abs=0.1)
    assert abs(float(dark.normalized().mean())) < 0.1 / (dark.white_level - dark.black_level)
    # the noise-free chain of a black image is the zero level itself (ISETCam's sensorZerolevel)
    torch.testing.assert_close(dark.noise_free, torch.full_like(dark.noise_free, s.zero_level()))


@pytest.mark.parametrize("convention", ["multiply", "isetcam"])
def test_variance_follows_signal_above_the_zero_level(convention):
    """var(data - noise_free) = a x + b with x = noise_free - raw.black_level (Foi et al. 2008), at two flat levels;
    with the offset counted as signal, a x overstated it by a x offset (gain 2, 0.02 V: 163.84 DN of offset)."""
    s = _sensor(convention)
    for rate in (2e4, 2e5):  # electrons/s: 200 and 2000 electrons at 10 ms
        raw = s.capture(torch.full((8, 1, 64, 64), rate, dtype=torch.float64),
                        generator=torch.Generator().manual_seed(1))
        a, b = s.poisson_gaussian(raw)
        x = float((raw.noise_free - raw.black_level).mean())
        expected = float(a[0]) * x + float(b[0])
        # 32768 samples: the sample variance's standard error is sqrt(2 / n) = 0.8 %
        assert float((raw.data - raw.noise_free).var()) == pytest.approx(expected, rel=0.04)
        # x is the photo-electrons' signal alone
        assert x == pytest.approx(rate * 0.01 * float(s.gain_per_electron()[0]), rel=1e-9)


def test_per_item_gains_give_per_item_black_levels():
    s = _sensor()
    gain = torch.tensor([1.0, 4.0], dtype=torch.float64)
    raw = s.capture(torch.zeros(2, 1, 64, 64, dtype=torch.float64), analog_gain=gain, noise=False)
    assert isinstance(raw.black_level, torch.Tensor) and raw.black_level.shape == (2,)
    black, white = raw.levels()
    torch.testing.assert_close(raw.noise_free - black, torch.zeros_like(raw.data), atol=1e-9, rtol=0)
    # the rounded frame is within half a code of it (0.02 V x 4 = 327.68 DN of offset at gain 4)
    assert float((raw.data - black).abs().max()) <= 0.5
    assert float(raw.normalized().abs().max()) <= float((0.5 / (white - black)).max())


def test_an_offset_that_fills_the_range_is_refused():
    s = _sensor(gain=60.0)  # 0.02 V x 60 = 1.2 V above a 1 V swing
    with pytest.raises(ValueError, match="analog_offset_v"):
        s.capture(torch.zeros(1, 1, 64, 64, dtype=torch.float64))


def test_pair_stream_normalises_by_the_zero_level():
    """PairStream through a camera with an analog offset: the raw is 0 at no light, and its noise metadata describe
    the variance of raw - noise_free_raw (normalised units) over the items' signals."""
    from isettorch.camera import Camera
    from isettorch.data import PairStream

    cfg = {"optics": {"type": "diffraction_limited", "f_number": 2.8, "focal_length_m": 4e-3},
           "sensor": {"rows": 34, "cols": 34, "cfa": "RGGB", "adc_bits": BITS, "black_level_dn": BLACK,
                      "conversion_gain_v_per_e": CG, "read_noise_v": 2e-4, "analog_gain": 2.0,
                      "analog_offset_v": OFFSET, "auto_exposure": "percentile", "ae_percentile": 98.0,
                      "ae_target": 0.5, "fpn_mode": "per_frame"}}
    camera = Camera.from_config(cfg)
    batch = PairStream(8, seed=0, scene={"height": 34, "width": 34}, camera=camera,
                       targets=("noise_free_raw",)).batch(0)
    meta = batch["meta"]
    zero = camera.sensor.zero_level()
    assert meta["black_level_dn"].double().tolist() == pytest.approx([zero] * 8, rel=1e-6)  # float32 metadata
    x = batch["noise_free_raw"].double()
    res = batch["raw"].double() - x
    var_model = meta["noise_gain"].double().reshape(-1, 1, 1, 1) * x + \
        meta["noise_floor_var"].double().reshape(-1, 1, 1, 1)
    # summed over 8 x 34 x 34 pixels: the measured and modelled variance agree to the sample's few percent (the
    # offset counted as signal added a x 163.84 DN / span to every pixel's variance)
    assert float((res**2).sum()) == pytest.approx(float(var_model.sum()), rel=0.05)
    # the noise-free raw is the signal alone: its darkest pixels reach 0, not the offset's 0.04 of the span
    assert float(x.min()) < 0.01


def test_process_levels_use_the_zero_level():
    from isettorch.commands.process import levels, noise_params

    s = _sensor(full_well_e=None)
    black, span = levels(s)
    assert black == pytest.approx(s.zero_level(), rel=1e-12) and span == pytest.approx(s.white_level_dn - black)
    a, _ = noise_params(s)
    assert a == pytest.approx(float(s.gain_per_electron()[0]) / span, rel=1e-12)
    # at another gain: the zero level of that gain
    assert levels(s, 1.0)[0] == pytest.approx(BLACK + OFFSET * 2**BITS, rel=1e-12)


def test_process_refuses_a_gain_without_room_above_the_zero_level():
    """A white level at or below the zero level gave span 0 (ZeroDivisionError, a traceback) or a negative shot gain
    (a message naming internal parameters): refused naming the gain."""
    from isettorch.commands.process import levels, noise_params

    with pytest.raises(ValueError, match=r"analog_gain: the gain 60 .*analog offset of 0.02 V"):
        levels(_sensor(), 60.0)  # 0.02 V x 60 = 1.2 V above the 1 V swing
    full_well = _sensor(analog_offset_v=0.0, full_well_e=3000)
    with pytest.raises(ValueError, match="analog_gain: the gain 1e-06"):
        noise_params(full_well, 1e-6)  # the full well's 0.15 V x 1e-6 is under one code
    # a list gain in the config is named as before (one value expected), offset or not
    with pytest.raises(ValueError, match="analog_gain: expected 1 value"):
        noise_params(_sensor(gain=[1.0, 2.0]))


def test_levels_keep_the_data_dtype():
    """Per-item levels from a float64 gain do not promote float32 data (a list gain made the ISP's input float64)."""
    s = _sensor()
    raw = s.capture(torch.zeros(2, 1, 64, 64), analog_gain=torch.tensor([1.0, 2.0], dtype=torch.float64))
    assert raw.normalized().dtype == torch.float32
    # a list gain's zero levels are the call's [B] gain's, on the data's device and dtype (they were a CPU float64
    # tensor: on a GPU, a device mismatch at the first normalisation)
    raw = s.capture(torch.zeros(2, 1, 64, 64), analog_gain=[1.0, 2.0])
    assert raw.black_level.dtype == torch.float32 and raw.black_level.device == raw.data.device
    torch.testing.assert_close(raw.black_level, torch.tensor([BLACK + OFFSET * 4096, BLACK + 2 * OFFSET * 4096]))


def test_isetcam_monochrome_processing_keeps_the_offset():
    """ISETCam's ipCompute subtracts the zero level for colour sensors only: a monochrome image is the input over
    the voltage swing (ipComputeSingle), the offset included; the library's own processing subtracts it."""
    from isettorch.isp import ImageProcessor

    s = _sensor(adc_bits=None, black_level_dn=0.0, output_units="volts")
    raw = s.capture(torch.full((1, 1, 64, 64), 1e5, dtype=torch.float64), noise=False)
    iset = ImageProcessor(monochrome_divisor="voltage_swing")(raw).display_linear
    torch.testing.assert_close(iset, (raw.data / 1.0).expand(-1, 3, -1, -1))
    assert float(raw.data.mean()) == pytest.approx(1e5 * 0.01 * CG * 2 + OFFSET * 2, rel=1e-12)
    own = ImageProcessor()(raw).input  # white-level scaling: from the zero level
    torch.testing.assert_close(own, (raw.data - OFFSET * 2) / (1.0 - OFFSET * 2))


def test_isetcam_colour_parity_subtracts_the_zero_level():
    """ip_result_from_case on a colour case with an analog offset, against ISETCam's own rules: ipCompute subtracts
    the zero level (the offset / gain) before demosaicking, and displayRender scales the image maximum to max volts /
    voltage swing of the raw volts, the offset included. Everything between is linear, so the offset case is the case
    without it (our output there is ISETCam's to 2e-6, tests/isp/test_pipeline.py) times (max v + z) / max v. The
    volts are halved so that max v + z is not the swing (where any scaling of the offset case looked alike)."""
    import numpy as np
    from shared_paths import PARITY_CASE

    from isettorch.isp.isetcam import ip_result_from_case

    if not PARITY_CASE.exists():
        pytest.skip("ISETCam parity case not available")
    d = np.load(PARITY_CASE, allow_pickle=False)
    case = {k: d[k] for k in d.files}
    swing, gain = float(case["sensor_voltage_swing_v"]), float(case["sensor_analog_gain"])
    volts = case["sensor_volts"].astype(np.float64) / 2
    zero = 0.05 * swing
    plain, _ = ip_result_from_case(dict(case, sensor_analog_offset=np.float64(0.0), sensor_volts=volts))
    ours, _ = ip_result_from_case(dict(case, sensor_analog_offset=np.float64(zero * gain), sensor_volts=volts + zero))
    vmax = float(volts.max())
    np.testing.assert_allclose(ours, plain * (vmax + zero) / vmax, rtol=1e-9, atol=1e-12)


def test_process_normalises_at_the_frames_gain():
    """With a full well under the ADC's range the white level moves with the gain: frames at --analog-gain 0.5 are
    scaled by the white level at 0.5, as the training pairs normalise each capture at its own gain (the config's gain
    gave a span of 1229 DN for 307 at 0.5: those frames came out at a quarter of their level)."""
    from isettorch.commands.process import levels

    s = _sensor(analog_offset_v=0.0, full_well_e=3000)  # 3000 e- x 5e-5 V/e- = 0.15 V at the pixel
    assert levels(s) == (BLACK, 1229.0)  # x 2: 0.3 V = 1228.8 codes, rounded
    assert levels(s, 0.5) == (BLACK, 307.0)  # x 0.5: 0.075 V = 307.2 codes


def test_levels_follow_the_data_device():
    """Per-item levels made on the CPU (a list gain's white level with a full well) are moved to the data's device
    (checked with the 'meta' device: on a GPU they mixed devices at the first normalisation)."""
    from isettorch.sensor.raw import RawImage

    raw = RawImage(torch.zeros(2, 1, 4, 4, device="meta"), "dn", "RGGB", black_level=torch.tensor([64.0, 65.0]),
                   white_level=torch.tensor([1000.0, 2000.0], dtype=torch.float64))
    black, white = raw.levels()
    assert black.device.type == white.device.type == "meta" and white.dtype == torch.float32
    assert raw.normalized().shape == (2, 1, 4, 4)
