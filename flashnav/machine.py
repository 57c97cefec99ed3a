"""The platform a run trained on, named in one place: the machine, and apart from it the thread count.

* machine: the GPU's name (``NVIDIA H100 80GB HBM3``), or the CPU model and the cores this process
  may use (``AMD EPYC 7B13 (2 cores)``). This is the ``device_name`` of a run and the report's
  platform: a property of the hardware, so tables group by it.
* threads: the torch CPU threads the learner used (an int on a CPU run; None on a GPU), a tuning
  knob that is recorded beside the machine, never inside its name.

* device: the name a run asks for (``auto``, ``cpu``, ``cuda``, ``cuda:N``), checked and resolved against
  what this machine has (:func:`resolve_device`; the spec and ``flashnav eval`` call it), and the
  switches that follow from it: precision, the CUDA-graph path and the collector/learner overlap
  (:func:`resolve_precision`, :func:`resolve_cuda_graph`, :func:`resolve_overlap`; the spec records them).

Runs written before the split spelled both in one string, ``AMD EPYC 7B13 (2 threads)``;
:func:`split_device_name` reads either spelling. torch is imported lazily (GPU names and thread
counts only), so readers such as the report stay light.
"""

from __future__ import annotations

import os
import platform
import re
from contextlib import contextmanager
from functools import lru_cache

from flashnav.names import CUDA_GRAPH_MODES, check_name

_OLD_SPELLING = re.compile(r"^(?P<machine>.*?)\s*\((?P<threads>\d+) threads?\)$")


@lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's marketing name (``AMD EPYC 7B13``), from /proc/cpuinfo where present."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


@lru_cache(maxsize=1)
def cpu_has_bf16(cpuinfo: str = "/proc/cpuinfo") -> bool:
    """Whether this CPU multiplies in bf16 natively (``cpuinfo``'s flags avx512_bf16 or amx_bf16).
    Without them torch emulates bf16 products: ``precision: bf16`` updates ran 2.6-2.9x slower on an
    Intel Xeon without them and 1.2x faster on an AMD EPYC with AVX-512 BF16 (docs/benchmarks.md)."""
    try:
        with open(cpuinfo, encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("flags"):
                    return bool({"avx512_bf16", "amx_bf16"} & set(line.split(":", 1)[1].split()))
    except OSError:
        pass
    return False


def native_bf16(device: str = "cpu") -> bool:
    """Whether ``device`` multiplies bf16 natively: a GPU that supports bf16, a CPU with AVX-512 BF16 / AMX."""
    if _is_gpu(device):
        import torch

        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    return cpu_has_bf16()


def resolve_precision(precision: str, device: str = "cpu") -> str:
    """``algo.precision`` on a resolved ``device``: ``auto`` -> ``bf16`` where :func:`native_bf16`, else
    ``float32``; ``float32`` and ``bf16`` are kept as asked."""
    if precision == "auto":
        return "bf16" if native_bf16(device) else "float32"
    return precision


def cpu_cores() -> int:
    """Logical CPUs this process may run on (its affinity mask: a container's share, not the host's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _is_gpu(device: str) -> bool:
    return str(device).startswith("cuda")


def machine_name(device: str = "cpu") -> str:
    """``NVIDIA H100 80GB HBM3`` for a CUDA device, else ``<cpu model> (<cores> cores)``."""
    if _is_gpu(device):
        import torch

        if torch.cuda.is_available():
            return torch.cuda.get_device_name(torch.device(device))
    return f"{cpu_model()} ({cpu_cores()} cores)"


def learner_threads(device: str = "cpu") -> int | None:
    """torch's CPU thread count now (call it while the learner's setting holds); None on a GPU."""
    if _is_gpu(device):
        return None
    import torch

    return int(torch.get_num_threads())


@contextmanager
def numba_threads(n: int | None = None):
    """Inside the block, numba kernels called from this thread use ``n`` threads (None: all numba may
    use, ``NUMBA_NUM_THREADS``); after it, the thread's count before. The count is thread-local, so a
    block in one thread leaves the others' alone: the collector and the map stream's worker step on one
    thread while the learner owns the other core, and an evaluation (the learner and collector idle) uses every core. The
    kernels' results do not depend on the count (each environment is one independent loop iteration).
    Nothing where numba is absent; an ``n`` outside [1, NUMBA_NUM_THREADS] is a ValueError."""
    try:
        import numba
    except ImportError:
        yield
        return
    most = int(numba.config.NUMBA_NUM_THREADS)
    n = most if n is None else int(n)
    if not 1 <= n <= most:
        raise ValueError(f"numba threads must be in [1, {most}] (NUMBA_NUM_THREADS), got {n}")
    before = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def split_device_name(name: str | None) -> tuple[str | None, int | None]:
    """``device_name`` of either spelling -> (machine, threads parsed from it, or None).

    ``"AMD EPYC 7B13 (2 threads)"`` (before the split) -> ``("AMD EPYC 7B13", 2)``;
    ``"AMD EPYC 7B13 (2 cores)"`` and GPU names come back unchanged with None; None stays None.
    """
    if name is None:
        return None, None
    match = _OLD_SPELLING.match(str(name))
    if match is None or not match["machine"]:
        return str(name), None
    return match["machine"], int(match["threads"])


# ---- which device a run asks for ------------------------------------------------------------------

_DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")


def check_device_name(device: str) -> None:
    """A ValueError naming ``device`` unless it is auto, cpu, cuda or cuda:N."""
    if not _DEVICE.fullmatch(str(device)):
        raise ValueError(f"device {device!r} is not one of auto, cpu, cuda, cuda:N")


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when a GPU is visible, else ``cpu``; a CUDA device must exist."""
    import torch

    check_device_name(device)
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ValueError(f"device {device!r} requested but CUDA is not available on this machine")
        index = int(device.split(":")[1]) if ":" in device else 0
        if index >= torch.cuda.device_count():
            raise ValueError(f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return device


#: what a run's config records that a machine resolves for itself (``flashnav.spec.run_request`` leaves them out)
MACHINE_KEYS = ("device", "overlap", "cuda_graph", "threads")


def resolve_recipe(recipe: str, device: str) -> str:
    """``auto`` -> ``paper`` on a GPU, ``cpu`` otherwise."""
    if recipe != "auto":
        return recipe
    return "paper" if device.startswith("cuda") else "cpu"


def resolve_cuda_graph(mode: str, device: str, decaying_lr: bool = False) -> bool:
    """``TrainConfig.cuda_graph`` on a resolved ``device``: whether the loop runs a cycle's updates on
    static buffers (:class:`flashnav.learn.cuda_graph.CycleUpdates`; captured as a CUDA graph only on
    a CUDA device). ``auto`` -> on for cuda, off elsewhere (and off where the learning rate decays,
    ``decaying_lr``: a captured optimiser step replays the rate it was recorded with). Measured on an
    H100 (docs/benchmarks.md "GPU: the paper recipe on an H100"): the paper recipe's learner takes
    60.8 ms per cycle captured against 374 ms eager, and a whole FastDSAC run trains to the same
    success levels; on a CPU the static buffers only cost (a few per cent)."""
    check_name("cuda_graph", mode, CUDA_GRAPH_MODES)
    if mode == "auto":
        return str(device).split(":")[0] == "cuda" and not decaying_lr
    return mode == "on"


def resolve_overlap(mode: bool | str, device: str) -> bool:
    """``TrainConfig.overlap`` on a resolved ``device``: whether the collector steps in a second thread
    beside the learner. ``auto`` -> on for cuda (the collector's kernels on a stream of their own), off
    for cpu: both schedules do the same work in the same order, and on a CPU the learner's matrix
    products on every core beat one core each for learner and collector, because collection is a
    small part of the cycle (on a 2-core AMD EPYC without AVX-512, whole training processes 0.85x
    (`cpu` recipe) and 0.84x (`paper`) the wall time: docs/benchmarks.md "Overlap or all cores")."""
    if isinstance(mode, bool):
        return mode
    if mode != "auto":
        raise ValueError(f"overlap: {mode!r} is not one of true, false, auto")
    return str(device).startswith("cuda")


__all__ = ["cpu_model", "cpu_has_bf16", "native_bf16", "resolve_precision", "cpu_cores", "machine_name", "learner_threads", "split_device_name", "check_device_name",
           "resolve_device", "resolve_cuda_graph", "resolve_overlap", "numba_threads"]
