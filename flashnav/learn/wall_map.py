"""The networks' reader of the wall map (``observation.wall_map``, :mod:`flashnav.sim.memory`): a small CNN.

The wall map is the observation's last ``2 C^2`` columns: an egocentric image of C x C squares, channel 0 the walls
the robot's LiDAR hit this episode, channel 1 the goal's square (each 0 or 1, row by row). Issue 15's
behaviour-cloning probe (``scripts/bc_memory_probe.py``, docs/benchmarks.md) found that a student reading the
teacher's memory through this encoder imitates a planner on fresh mazes better than with the usual input alone,
while one dense layer over the same squares, or a smaller CNN, gained little (drawn from a grid of every hit, as
the simulator keeps it, the same student reached less than from the teacher's memory: docs/benchmarks.md, "A dense
grid of every hit"; whether the map pays in reinforcement learning is not measured yet); the encoder here is that probe's
``cnn``: three 3 x 3 convolutions of 16, 32 and 32 channels (the last two with stride 2; each output sees 9 x 9
squares), LeakyReLU after each (the networks' activation), then one layer of :data:`WALL_MAP_FEATURES` units whose
output joins the IPAPRec features ahead of the actor's or critic's MLP.

``copies`` C > 0 (the twin critics) runs C independent encoders as one grouped convolution (weights of copy k
in group k) and one batched matrix product, as :class:`flashnav.learn.networks.TwinCritic` batches its layers.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

#: Output width of the wall-map encoder: the features it adds to the MLP's input.
WALL_MAP_FEATURES = 256
#: (out channels, stride) of the three 3 x 3 convolutions.
WALL_MAP_CONVS = ((16, 1), (32, 2), (32, 2))
#: Channels of the wall map: walls, goal.
WALL_MAP_CHANNELS = 2


def conv_side(cells: int) -> int:
    """Side of the convolutions' output grid for a C x C map (padding 1: a stride-2 layer halves, rounding up)."""
    side = cells
    for _, stride in WALL_MAP_CONVS:
        side = (side - 1) // stride + 1
    return side


class WallMapEncoder(nn.Module):
    """The wall map's columns ``[B, 2 C^2]`` -> features ``[B, F]`` (``copies`` 0) or ``[copies, B, F]``,
    F = :data:`WALL_MAP_FEATURES`. Every weight is drawn from ``generator`` (PyTorch's default uniform bounds),
    copy by copy."""

    def __init__(self, cells: int, copies: int = 0, generator: torch.Generator | None = None):
        super().__init__()
        if cells < 2:
            raise ValueError(f"a wall-map encoder needs at least 2 x 2 squares, got {cells}")
        self.cells, self.copies = cells, copies
        k = max(copies, 1)
        self.conv_weights, self.conv_biases = nn.ParameterList(), nn.ParameterList()
        c_in = WALL_MAP_CHANNELS
        for c_out, _ in WALL_MAP_CONVS:
            w, b = torch.empty(k * c_out, c_in, 3, 3), torch.empty(k * c_out)
            bound = 1.0 / math.sqrt(c_in * 9)
            with torch.no_grad():
                for j in range(k):
                    w[j * c_out:(j + 1) * c_out].uniform_(-bound, bound, generator=generator)
                    b[j * c_out:(j + 1) * c_out].uniform_(-bound, bound, generator=generator)
            self.conv_weights.append(nn.Parameter(w))
            self.conv_biases.append(nn.Parameter(b))
            c_in = c_out
        self.flat = c_in * conv_side(cells) ** 2
        bound = 1.0 / math.sqrt(self.flat)
        w, b = torch.empty(k, self.flat, WALL_MAP_FEATURES), torch.empty(k, 1, WALL_MAP_FEATURES)
        with torch.no_grad():
            for j in range(k):
                w[j].uniform_(-bound, bound, generator=generator)
                b[j].uniform_(-bound, bound, generator=generator)
        self.out_weight, self.out_bias = nn.Parameter(w), nn.Parameter(b)

    def forward(self, image: torch.Tensor, detach_params: bool = False) -> torch.Tensor:
        lead = image.shape[:-1]
        k = max(self.copies, 1)
        x = image.reshape(-1, WALL_MAP_CHANNELS, self.cells, self.cells)
        if k > 1:  # every copy reads the same map: its own group of channels
            x = x.repeat(1, k, 1, 1)
        for w, b, (_, stride) in zip(self.conv_weights, self.conv_biases, WALL_MAP_CONVS):
            if detach_params:
                w, b = w.detach(), b.detach()
            x = F.leaky_relu(F.conv2d(x, w, b, stride=stride, padding=1, groups=k))
        x = x.reshape(x.shape[0], k, self.flat).transpose(0, 1)  # [k, B, flat]: copy j's channels are group j's
        w, b = (self.out_weight, self.out_bias) if not detach_params else (self.out_weight.detach(),
                                                                           self.out_bias.detach())
        x = F.leaky_relu(torch.baddbmm(b, x, w))  # [k, B, F]
        if self.copies:
            return x
        return x[0].reshape(*lead, WALL_MAP_FEATURES)
