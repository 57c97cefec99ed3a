"""Counter-based draws and sample orders of the moving agents (:mod:`flashnav.sim.agents`), pure torch;
the numba kernel :func:`flashnav.sim.agent_numba.hash_uniform` computes the same bits."""

from __future__ import annotations

import torch


def _lsr(x: torch.Tensor, s: int) -> torch.Tensor:
    """Logical right shift of int64 ``x`` by ``s`` bits (torch's >> is arithmetic)."""
    return (x >> s) & ((1 << (64 - s)) - 1)


def hash_uniform(key, step, agent, lane) -> torch.Tensor:
    """float32 uniforms in [0, 1) (24 bits), a splitmix64 hash of the broadcast int64 tensors
    (wrapping int64 arithmetic): counter-based draws, independent of any generator's position."""
    x = key * -7046029254386353131 + step * 1442695040888963407 + agent * 6364136223846793005 + lane
    x = (x ^ _lsr(x, 30)) * -4658895280553007687
    x = (x ^ _lsr(x, 27)) * -7723592293110705685
    x = x ^ _lsr(x, 31)
    return _lsr(x, 40).float() * (1.0 / (1 << 24))


def coarse_first(count: int) -> torch.Tensor:
    """[count] float64: the fractions 0, 1/(count-1), ..., 1, ordered end points first and then by
    halving (1, 0, 1/2, 1/4, 3/4, ...): a blocked segment is usually found blocked after a few samples."""
    order, seen, step = [count - 1, 0], {0, count - 1}, count - 1
    while len(order) < count:
        step = max(step // 2, 1)
        for i in range(0, count, step):
            if i not in seen:
                seen.add(i)
                order.append(i)
    return torch.tensor(order, dtype=torch.float64) / (count - 1)
