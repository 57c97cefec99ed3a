"""The arithmetic of the learner's updates (``algo.precision``): float32, or bf16 autocast.

``bf16`` runs each update under ``torch.autocast(bfloat16)``: the matrix products in bf16, the
weights, optimiser state, running statistics and targets float32 (the learners cast what must stay
float32 themselves). It pays only where the hardware multiplies bf16 natively - CPUs with AVX-512 BF16
or AMX, GPUs; elsewhere torch emulates the products and it is slower (docs/benchmarks.md, "Learner
update: bf16 autocast").

Autocast's weight-cast cache is off: the cycle's updates change the weights in place inside one
context (optimiser steps, the actor update after the critic's), and a cached bf16 copy of a weight
would go stale after its first step - every later forward of the cycle would run on the old weights.
"""

from __future__ import annotations

import contextlib
import warnings
from typing import Callable

import torch

from flashnav.machine import cpu_has_bf16, resolve_precision
from flashnav.names import PRECISIONS


def update_precision(precision: str, device: torch.device | str) -> Callable[[], contextlib.AbstractContextManager]:
    """A factory of the context the learner's updates run in: nothing for ``float32``; for ``bf16``,
    ``torch.autocast(bfloat16)`` without its weight-cast cache; ``auto`` is either, by the device
    (:func:`flashnav.machine.resolve_precision`; a run's spec has resolved it already). A CPU without native bf16 products is
    warned about (there bf16 is slower); a name outside :data:`PRECISIONS` is a ValueError."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    precision = resolve_precision(precision, str(device))
    if precision == "float32":
        return contextlib.nullcontext
    kind = torch.device(device).type
    if kind == "cpu" and not cpu_has_bf16():
        warnings.warn("precision bf16 on a CPU without AVX-512 BF16 or AMX (no avx512_bf16 / amx_bf16 in "
                      "/proc/cpuinfo): torch emulates the bf16 products, so updates run slower, not faster "
                      "(2.6-2.9x on an Intel Xeon, docs/benchmarks.md); precision float32 is faster here",
                      stacklevel=2)
    return lambda: torch.autocast(kind, dtype=torch.bfloat16, cache_enabled=False)


__all__ = ["PRECISIONS", "update_precision"]
