"""Checks of what a caller hands the environment (poses, goals, actions): exact shapes and finite
values, with errors that name the input and the offending row."""

from __future__ import annotations

import torch


def as_batch(device: torch.device, value, name: str, shape: tuple[int, int], layout: str,
             dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``value`` as ``dtype`` on ``device``, exactly ``shape``: no reshape, so [2, N] or a flat [2N] is an
    error rather than a silent scramble of the rows."""
    t = torch.as_tensor(value, device=device, dtype=dtype)
    if tuple(t.shape) != shape:
        raise ValueError(f"{name} must have shape [{layout}] = {list(shape)}, got {list(t.shape)}")
    return t


def check_finite(value: torch.Tensor, name: str) -> None:
    """ValueError naming ``name`` and the first row holding a NaN or an infinity (if any)."""
    rows = (~torch.isfinite(value)).any(dim=1).nonzero()
    if rows.numel():
        row = int(rows[0, 0])
        raise ValueError(f"{name}[{row}] = {value[row].tolist()} is not finite (NaN or inf)")
