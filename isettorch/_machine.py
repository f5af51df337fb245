"""Where a number was measured: the one record of the machine that benchmarks and training runs write beside their
results."""

from __future__ import annotations

import os
import platform
import sys

import torch


def machine_info(device="cpu") -> dict:
    """The CPU (its model name from ``/proc/cpuinfo`` where there is one), the vector instructions torch's CPU kernels
    use (``torch.backends.cpu.get_cpu_capability()``: ``AVX512``, ``AVX2``, ...; CPU timings of convolutions differ
    about 2x between them), core count, torch threads, versions, the load average now and, on CUDA, the GPU.

    Example:
        >>> sorted(machine_info())[:3]
        ['cpu_capability', 'cpu_count', 'device']
    """
    info = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_capability": torch.backends.cpu.get_cpu_capability(), "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "torch": torch.__version__,
            "python": sys.version.split()[0], "device": str(device)}
    try:
        with open("/proc/cpuinfo") as fh:
            names = [ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")]
        if names:
            info["processor"] = names[0]
    except OSError:
        pass
    if hasattr(os, "getloadavg"):
        info["load_average_start"] = [round(x, 2) for x in os.getloadavg()]
    if torch.device(device).type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info
