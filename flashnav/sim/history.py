"""The opt-in history of previous pooled scans (``observation.scan_history``, issue 13).

A moving obstacle is invisible to a policy that sees one frame: it cannot tell a pedestrian walking
into its path from one walking away. With ``scan_history = k > 0`` every observation carries the k
pooled scans of the previous control steps (env steps) after the paper's observation::

    [0, B)              the paper's observation (sectors, goal distance, angle, velocity), unchanged
    [B + j S, B + (j+1) S)   the pooled scan of j + 1 steps ago, j = 0 .. k - 1 (newest first, oldest last)

with B = ``preset.base_obs_dim`` and S sectors; the current frame's columns sit where they always do,
so a policy's reading of the paper's layout is unchanged. Each frame is the scan as the policy saw it
(pooled, after the optional noise and dropout). A new episode (a reset, sparse or full, and
``set_state``) fills its slot's history with its first scan: at step 0 the k history frames all equal
the current frame, as a robot that has just started has seen nothing else. The robot side
(:mod:`flashnav.deploy.controller`) keeps the same frames from successive scans at the control rate.

The frames are a shift register ``[N, k, S]`` rather than a ring with a head pointer per slot: for the
small k that help (a few frames) copying k * S floats per stepped slot costs less than the gathers a
per-slot head would need on every observation, and the observation is then a plain view of the rows.
"""

from __future__ import annotations

import torch


class ScanHistory:
    """The last ``frames`` pooled scans [N, frames, sectors] float32 metres of each of N slots."""

    def __init__(self, num_envs: int, frames: int, sectors: int, device: torch.device):
        if frames < 1 or sectors < 1 or num_envs < 1:
            raise ValueError(f"ScanHistory needs num_envs, frames and sectors >= 1, got {num_envs}, {frames}, {sectors}")
        self.sectors = sectors
        self.frames = torch.zeros(num_envs, frames, sectors, device=device, dtype=torch.float32)

    @property
    def columns(self) -> int:
        """Observation columns the history adds: frames * sectors."""
        return self.frames.shape[1] * self.sectors

    def start(self, idx, obs: torch.Tensor) -> torch.Tensor:
        """New episodes in slots ``idx`` (a [k] long index or ``slice(None)``) whose first observation
        (the paper's layout) is ``obs`` [k, B]: every history frame becomes that first scan. Returns
        the full observation [k, B + frames * S]; other slots are untouched."""
        first = obs[:, : self.sectors]
        self.frames[idx] = first[:, None, :].expand(-1, self.frames.shape[1], -1)
        return torch.cat([obs, first.repeat(1, self.frames.shape[1])], dim=1)

    def push(self, idx, obs: torch.Tensor) -> torch.Tensor:
        """One step of slots ``idx`` whose new observation (the paper's layout) is ``obs`` [k, B]: the
        full observation [k, B + frames * S] carries the frames *before* this step; then this step's
        scan becomes the newest frame and the oldest is dropped."""
        past = self.frames[idx]
        full = torch.cat([obs, past.flatten(1)], dim=1)
        self.frames[idx] = torch.cat([obs[:, None, : self.sectors], past[:, :-1]], dim=1)
        return full
