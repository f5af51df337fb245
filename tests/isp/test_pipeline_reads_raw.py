"""The image processor fits its colour matrix from the raw's own sensor QE (no separate fit(sensor) per frame)."""

import torch

from isettorch.isp import ImageProcessor
from isettorch.optics.optical_image import OpticalImage
from isettorch.sensor import Sensor


def test_processor_fitted_from_the_raw_equals_one_fitted_from_the_sensor():
    g = torch.Generator().manual_seed(0)
    oi = OpticalImage(torch.rand(1, 31, 16, 16, generator=g, dtype=torch.float64) * 1e17,
                      torch.arange(400.0, 701.0, 10.0, dtype=torch.float64), sample_spacing_m=2.8e-6)
    sensor = Sensor(rows=16, cols=16, cfa="RGGB", adc_bits=10, filters="isetcam_rgb")
    raw = sensor(oi, exposure_s=1e-3, noise=False)
    assert raw.spectral_qe is sensor.spectral_qe
    from_raw = ImageProcessor()(raw)
    fitted = ImageProcessor().fit(sensor)
    ref = fitted(raw.replace(spectral_qe=None))
    assert torch.equal(from_raw.sensor_to_xyz, ref.sensor_to_xyz)
    assert torch.allclose(from_raw.image, ref.image, rtol=0, atol=0)
    # a processor with a fixed matrix keeps it
    fixed = ImageProcessor(sensor_to_xyz=torch.eye(3))
    assert torch.equal(fixed(raw).sensor_to_xyz, torch.eye(3, dtype=fixed(raw).sensor_to_xyz.dtype))
