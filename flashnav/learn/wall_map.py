"""The networks' reader of the wall map (``observation.wall_map``, :mod:`flashnav.sim.wall_grid`): a small CNN, one
per learner, shared by the actor and the critics.

The wall map is the observation's last ``2 C^2`` columns: an egocentric image of C x C squares, channel 0 the walls
the robot's LiDAR hit this episode, channel 1 the goal's square (each 0 or 1, row by row); with
``observation.wall_map_visited`` a third channel (``3 C^2`` columns), the squares the robot has been in. Issue 15's
behaviour-cloning probe (``scripts/bc_memory_probe.py``, docs/benchmarks.md) found that a student reading the
teacher's memory through this encoder imitates a planner on fresh mazes better than with the usual input alone,
while one dense layer over the same squares, or a smaller CNN, gained little (drawn from a grid of every hit, as
the simulator keeps it, the same student reached less than from the teacher's memory: docs/benchmarks.md, "A dense
grid of every hit"); the encoder here is by default that probe's ``cnn``: three 3 x 3 convolutions of 16, 32 and 32
channels (the last two with stride 2; each output sees 9 x 9 squares; the learners' ``wall_map_convs`` sets other
layers), LeakyReLU after each (the networks' activation), then one layer of :data:`WALL_MAP_FEATURES` units whose
output joins the IPAPRec features ahead of the actor's or critic's MLP.

One encoder serves the actor and both critics, as in pixel-based off-policy learners (SAC-AE, DrQ: the critic's
loss trains it, the actor reads its features detached, the target critics read the map through their own Polyak
copy): :func:`encode_wall_maps` runs it once on a replay batch's observations (with gradients, for the critic loss)
and the target copy once on the next observations, and the networks read those features instead of encoding the
squares again (:func:`is_encoded`); the actor step encodes the observations again after the critic's step, without
gradients, as the references do. Collection, evaluation and the exported policy read the squares through the same
encoder. Against one encoder per network (the first build, never trained at length) this runs the CNN forward on
two and a half batches an update and backward on one, instead of about eight and three
(``flashnav bench update --wall-map``; docs/benchmarks.md).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from flashnav.learn.hparams import WALL_MAP_CONVS, bad_conv_layers
from flashnav.policy_meta import wall_map_channel_names

#: Output width of the wall-map encoder: the features it adds to the MLP's input.
WALL_MAP_FEATURES = 256
#: Channels of a wall map without the visited squares (walls, goal): the default of the encoder and the shift.
WALL_MAP_CHANNELS = len(wall_map_channel_names(1))


def conv_side(cells: int, convs=WALL_MAP_CONVS) -> int:
    """Side of the convolutions' output grid for a C x C map (padding 1: a stride-2 layer halves, rounding up)."""
    side = cells
    for _, stride in convs:
        side = (side - 1) // stride + 1
    return side


def receptive_field(convs=WALL_MAP_CONVS) -> int:
    """Squares a side that one output of the convolutions sees (3 x 3 kernels: each layer adds 2 x the product of
    the strides before it)."""
    field, jump = 1, 1
    for _, stride in convs:
        field, jump = field + 2 * jump, jump * stride
    return field


class WallMapEncoder(nn.Module):
    """The wall map's columns ``[..., channels C^2]`` -> features ``[..., F]``, F = :data:`WALL_MAP_FEATURES`. Every
    weight is drawn from ``generator`` (PyTorch's default uniform bounds); ``convs`` the 3 x 3 convolutions,
    ``(out channels, stride)`` each."""

    def __init__(self, cells: int, generator: torch.Generator | None = None, channels: int = WALL_MAP_CHANNELS,
                 convs=WALL_MAP_CONVS):
        super().__init__()
        if cells < 2:
            raise ValueError(f"a wall-map encoder needs at least 2 x 2 squares, got {cells}")
        if channels not in (2, 3, 4):
            raise ValueError(f"a wall-map encoder reads 2 channels (walls, goal), 3 or 4 (and visited and / or plan), "
                             f"got {channels}")
        self.cells, self.channels = cells, channels
        self.convs = tuple((int(c), int(s)) for c, s in convs)
        if not self.convs or bad_conv_layers(self.convs):
            raise ValueError(f"a wall-map encoder's convolutions are (out channels > 0, stride 1 or 2), at least "
                             f"one, got {convs}")
        #: the columns it reads: channels x cells^2
        self.squares = channels * cells * cells
        self.conv_weights, self.conv_biases = nn.ParameterList(), nn.ParameterList()
        c_in = channels
        for c_out, _ in self.convs:
            w, b = torch.empty(c_out, c_in, 3, 3), torch.empty(c_out)
            bound = 1.0 / math.sqrt(c_in * 9)
            with torch.no_grad():
                w.uniform_(-bound, bound, generator=generator)
                b.uniform_(-bound, bound, generator=generator)
            self.conv_weights.append(nn.Parameter(w))
            self.conv_biases.append(nn.Parameter(b))
            c_in = c_out
        self.flat = c_in * conv_side(cells, self.convs) ** 2
        bound = 1.0 / math.sqrt(self.flat)
        w, b = torch.empty(WALL_MAP_FEATURES, self.flat), torch.empty(WALL_MAP_FEATURES)
        with torch.no_grad():
            w.uniform_(-bound, bound, generator=generator)
            b.uniform_(-bound, bound, generator=generator)
        self.out_weight, self.out_bias = nn.Parameter(w), nn.Parameter(b)

    def conv_grid(self, image: torch.Tensor) -> torch.Tensor:
        """The convolutions' output ``[N, channels, side, side]`` of images ``[N, self.channels, C, C]``."""
        x = image
        for w, b, (_, stride) in zip(self.conv_weights, self.conv_biases, self.convs):
            x = F.leaky_relu(F.conv2d(x, w, b, stride=stride, padding=1))
        return x

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        lead = image.shape[:-1]
        x = self.conv_grid(image.reshape(-1, self.channels, self.cells, self.cells))
        x = F.leaky_relu(F.linear(x.reshape(x.shape[0], self.flat), self.out_weight, self.out_bias))
        return x.reshape(*lead, WALL_MAP_FEATURES)


def network_encoder(layout, given: WallMapEncoder | None,
                    generator: torch.Generator | None) -> WallMapEncoder | None:
    """A network's encoder: ``given`` (a learner's one, shared by its networks), else the network's own for the wall
    map of ``layout`` (a :class:`flashnav.learn.features.ObsLayout`) drawn from ``generator`` (None without a map)."""
    if given is None and layout.wall_map:
        return WallMapEncoder(layout.wall_map, generator=generator, channels=layout.wall_channels,
                              convs=layout.wall_convs)
    return given


def is_encoded(obs: torch.Tensor, vector_end: int, encoder: WallMapEncoder) -> bool:
    """Whether ``obs [..., D]`` carries the encoder's features between its first ``vector_end`` columns and the
    squares (D = vector_end + :data:`WALL_MAP_FEATURES` + ``encoder.squares``, :func:`encode_wall_maps`) rather than
    the squares alone (D = vector_end + ``encoder.squares``)."""
    return obs.shape[-1] == vector_end + WALL_MAP_FEATURES + encoder.squares


def wall_features(encoder: WallMapEncoder, obs: torch.Tensor, vector_end: int) -> torch.Tensor:
    """``[..., F]``: the features ``obs`` carries (:func:`is_encoded`), or the encoder's features of its squares."""
    if is_encoded(obs, vector_end, encoder):
        return obs[..., vector_end: vector_end + WALL_MAP_FEATURES]
    return encoder(obs[..., vector_end:])


def with_features(obs: torch.Tensor, encoder: WallMapEncoder, vector_end: int) -> torch.Tensor:
    """``obs [B, vector_end + S]`` (S = ``encoder.squares``; or an encoded one: its squares are read again) ->
    ``[B, vector_end + F + S]`` with ``encoder``'s features of the squares (with gradients where ``encoder`` and grad
    mode give them)."""
    squares = obs[..., obs.shape[-1] - encoder.squares:]
    return torch.cat([obs[..., :vector_end], encoder(squares), squares], dim=-1)


def encode_wall_maps(batch, critic: nn.Module, critic_target: nn.Module):
    """A replay batch with each observation's features computed once for the whole update (:func:`with_features`):
    ``obs``'s by the critics' encoder, with gradients (the critic loss trains it), ``next_obs``'s by the target
    critics' copy, without (the target and the next action read them). The actor step re-reads ``obs``'s squares
    after the critic step, without gradients: :func:`flashnav.learn.common.actor_view`."""
    end = critic.vector_end
    obs = with_features(batch.obs, critic.walls, end)
    with torch.no_grad():
        next_obs = with_features(batch.next_obs, critic_target.walls, end)
    return batch._replace(obs=obs, next_obs=next_obs)
