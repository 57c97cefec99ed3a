"""The machine a run or a benchmark ran on, as reports show it (a neutral leaf module: both the
training loop and the benchmarks import it, and neither imports the other)."""

from __future__ import annotations

import platform

import torch


def machine_description(device: str = "cpu") -> str:
    """The GPU's name for a CUDA ``device`` (when CUDA is available), else the CPU model and the
    number of torch threads, e.g. ``"AMD EPYC 7B13 (2 threads)"``."""
    if device.startswith("cuda") and torch.cuda.is_available():
        return torch.cuda.get_device_name(torch.device(device))
    return f"{cpu_model()} ({torch.get_num_threads()} threads)"


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo, else what the platform module reports."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
