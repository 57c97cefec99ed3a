"""Actor and critic networks; their input transform, IPAPRec (paper eq. 2), and the observation layout it reads
live in :mod:`flashnav.learn.features` (imported here under the same names).

Observation layout (raw physical units, from the simulator), ``obs [N, D] float32``: columns ``0..S-1`` pooled LiDAR
sector minima (metres, ``(0, max_range]``), ``S`` goal distance (metres), ``S+1`` goal angle in the robot frame
(radians, ``[-pi, pi)``), then the velocity state (``(v, w)`` -> D = S + 4, or ``(vx, vy, w)`` -> D = S + 5); with a
scan history of k frames (:mod:`flashnav.sim.history`) k * S more LiDAR columns follow, the previous pooled scans
newest first; with M agent tracks (:mod:`flashnav.sim.tracks`) 6 M columns follow (present, x, y, vx, vy, radius
each); with a pose trail of P breadcrumbs (:mod:`flashnav.sim.trail`) 2 P columns follow (x, y each, metres); with a
memory scan S more LiDAR-like columns; with a wall map of C x C squares (:mod:`flashnav.sim.wall_grid`) 2 C^2 columns
(3 C^2 with the visited squares) of 0 / 1 end it, read by a CNN (:class:`flashnav.learn.wall_map.WallMapEncoder`, one
shared by a learner's actor and critics) whose features join IPAPRec's.
Actions are ``[N, A]`` in ``[-1, 1]``.

Every network owns its input transform: LiDAR readings become ``1 / (l - beta)`` with a trainable
``beta = r_in - margin - softplus(rho)`` that always stays below the inscribed radius ``r_in``; the
other features are divided by their known bounds. Twin critics are one batched network (weights
stacked ``[2, in, out]``, evaluated with ``torch.baddbmm``): one kernel chain instead of two.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from flashnav.learn.features import BETA_INIT, BETA_MARGIN, NORM_EPS, IPAPRec, ObsLayout  # noqa: F401 (re-exported)
from flashnav.learn.wall_map import WallMapEncoder, network_encoder, wall_features

#: std of the actor's output-layer weights at init: actions start near 0, DEM weights near uniform.
ACTOR_OUT_INIT_STD = 0.01


def _uniform_(tensor: torch.Tensor, fan_in: int, generator: torch.Generator | None) -> None:
    """nn.Linear's default init, U(-1/sqrt(fan_in), 1/sqrt(fan_in)), from an explicit generator."""
    bound = 1.0 / math.sqrt(fan_in)
    with torch.no_grad():
        tensor.uniform_(-bound, bound, generator=generator)


class MLP(nn.Module):
    """``[..., in] -> [..., out]``: Linear(/LayerNorm)/LeakyReLU hidden layers, linear output.

    ``layer_norm``: a LayerNorm (learned gain and bias) between each hidden Linear and its activation,
    as in the FastSAC / FastDSAC reference networks; off in the paper recipe (the paper is silent)."""

    def __init__(self, in_dim: int, hidden: Sequence[int], out_dim: int,
                 generator: torch.Generator | None = None, out_init_std: float | None = None,
                 layer_norm: bool = False):
        super().__init__()
        sizes = [in_dim, *hidden, out_dim]
        layers: list[nn.Module] = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            linear = nn.Linear(n_in, n_out)
            _uniform_(linear.weight, n_in, generator)
            _uniform_(linear.bias, n_in, generator)
            layers.append(linear)
            if i < len(sizes) - 2:
                if layer_norm:
                    layers.append(nn.LayerNorm(n_out))
                layers.append(nn.LeakyReLU())
        if out_init_std is not None:
            with torch.no_grad():
                layers[-1].weight.normal_(0.0, out_init_std, generator=generator)
                layers[-1].bias.zero_()
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class Actor(nn.Module):
    """``obs [N, D]`` (raw units) -> raw head outputs ``[N, heads * A]``.

    heads = 1 (FastTD3: mu), 2 (FastSAC: mu, raw log sigma), 3 (FastDSAC DEM: mu, raw log sigma,
    allocation logits). The deterministic action is ``tanh(mu)``, or with an action ``headroom`` k > 1
    ``clamp(k tanh(mu), -1, 1)`` (:func:`with_headroom`); see :class:`DeterministicActor`.
    """

    def __init__(self, layout: ObsLayout, action_dim: int, hidden: Sequence[int], heads: int,
                 generator: torch.Generator | None = None, layer_norm: bool = False, obs_norm: bool = False,
                 out_init_std: float = ACTOR_OUT_INIT_STD, headroom: float = 1.0,
                 walls: WallMapEncoder | None = None):
        super().__init__()
        self.action_dim = action_dim
        self.heads = heads
        self.headroom = float(headroom)
        self.transform = IPAPRec(layout, normalize=obs_norm)
        # out_init_std 0: the output layer keeps the uniform draw of every other layer (PyTorch's default)
        self.mlp = MLP(layout.feature_dim, hidden, heads * action_dim, generator, out_init_std or None, layer_norm)
        # ``walls``: the critics' encoder, shared (the learners'; its parameters are trained by the critic loss); a
        # network built alone draws its own after the MLP's draws (without a wall map the same seed gives the same
        # weights as before it existed)
        self.walls = network_encoder(layout, walls, generator)
        self.vector_end = layout.memory_end

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs [N, D]``: raw observations, or with a wall map, the vector columns followed by the encoder's features
        (:func:`flashnav.learn.wall_map.encode_wall_maps`)."""
        x = self.transform(obs)
        if self.walls is not None:
            x = torch.cat([x, wall_features(self.walls, obs, self.vector_end)], dim=-1)
        return self.mlp(x)


class DeterministicActor(nn.Module):
    """Deployable policy: ``obs [N, D]`` raw units -> ``action [N, A]`` = tanh(mu), in [-1, 1] (with the
    actor's action headroom k > 1: ``clamp(k tanh(mu), -1, 1)``).

    Shares parameters with the wrapped actor (evaluation sees the latest weights); deep-copy it to
    freeze. Plain tensor ops only, so ``torch.export`` / ONNX / TorchScript can trace it.
    """

    def __init__(self, actor: Actor):
        super().__init__()
        self.actor = actor
        self.action_dim = actor.action_dim

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return with_headroom(torch.tanh(self.actor(obs)[..., : self.action_dim]), self.actor.headroom)


def with_headroom(squashed: torch.Tensor, headroom: float) -> torch.Tensor:
    """The robot's action from the actor's tanh output ``squashed [..., A]``: ``clamp(headroom * squashed,
    -1, 1)``. A tanh output reaches the action bounds (top speed, top turn rate) only in the limit, so a
    policy whose best action is a bound sits below it; with headroom k > 1 the bound is reached at
    ``|tanh| = 1 / k`` (docs/learners.md S19). ``headroom`` 1 returns ``squashed`` itself: the paper's action."""
    if headroom == 1.0:
        return squashed
    return (headroom * squashed).clamp(-1.0, 1.0)


class TwinCritic(nn.Module):
    """Two critics as one batched network: ``(obs [B, D], action [B, A]) -> [2, B, out]``.

    Weights are stacked ``[2, in, out]`` (biases ``[2, 1, out]``) and applied with ``baddbmm``;
    each critic keeps its own IPAPRec beta. ``out`` = K logits (C51) or 2 (Gaussian: mean, raw std;
    see :func:`gaussian_head`). ``detach_params=True`` evaluates with detached weights, so the actor
    loss backpropagates into the action only and never writes critic gradients. ``layer_norm``: each
    copy's hidden pre-activations are layer-normalised with their own gain and bias (``[2, 1, out]``),
    the same as :class:`MLP`'s option.
    """

    def __init__(self, layout: ObsLayout, action_dim: int, hidden: Sequence[int], out_dim: int,
                 generator: torch.Generator | None = None, copies: int = 2, layer_norm: bool = False,
                 obs_norm: bool = False, walls: WallMapEncoder | None = None):
        super().__init__()
        self.copies = copies
        self.layer_norm = layer_norm
        self.transform = IPAPRec(layout, copies=copies, normalize=obs_norm)
        sizes = [layout.feature_dim + action_dim, *hidden, out_dim]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for n_in, n_out in zip(sizes[:-1], sizes[1:]):
            w = torch.empty(copies, n_in, n_out)
            b = torch.empty(copies, 1, n_out)
            for k in range(copies):  # same draw order as copies separate nn.Linear layers
                _uniform_(w[k], n_in, generator)
                _uniform_(b[k], n_in, generator)
            self.weights.append(nn.Parameter(w))
            self.biases.append(nn.Parameter(b))
        if layer_norm:  # after the weight draws: the same seed gives the same Linear weights either way
            self.norm_gains = nn.ParameterList(nn.Parameter(torch.ones(copies, 1, n)) for n in hidden)
            self.norm_biases = nn.ParameterList(nn.Parameter(torch.zeros(copies, 1, n)) for n in hidden)
        # one wall-map encoder for both critics (given, or drawn after the layers' draws)
        self.walls = network_encoder(layout, walls, generator)
        self.vector_end = layout.memory_end

    def forward(self, obs: torch.Tensor, action: torch.Tensor, detach_params: bool = False) -> torch.Tensor:
        """``obs [B, D]`` as :meth:`Actor.forward` reads it. ``detach_params`` detaches the wall-map encoder's
        output too: the actor loss writes no critic gradient."""
        x = self.transform(obs, detach_rho=detach_params)
        if self.walls is not None:
            walls = wall_features(self.walls, obs, self.vector_end)
            if detach_params:
                walls = walls.detach()
            x = torch.cat([x, walls.unsqueeze(0).expand(self.copies, -1, -1)], dim=-1)
        x = torch.cat([x, action.unsqueeze(0).expand(self.copies, -1, -1)], dim=-1)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            if detach_params:
                w, b = w.detach(), b.detach()
            x = torch.baddbmm(b, x, w)
            if i < last:
                if self.layer_norm:
                    g, c = self.norm_gains[i], self.norm_biases[i]
                    if detach_params:
                        g, c = g.detach(), c.detach()
                    x = torch.addcmul(c, F.layer_norm(x, x.shape[-1:]), g)
                x = F.leaky_relu(x)
        return x


def gaussian_head(out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``[..., 2]`` critic output -> (mean, std = softplus(raw)), each ``[...]``, reward units."""
    return out[..., 0], F.softplus(out[..., 1])


def bounded_log_std(raw: torch.Tensor, log_std_min: float, log_std_max: float) -> torch.Tensor:
    """``lmin + 0.5 (lmax - lmin)(tanh(raw) + 1)``: smooth map of raw outputs onto [lmin, lmax]."""
    return log_std_min + 0.5 * (log_std_max - log_std_min) * (torch.tanh(raw) + 1.0)


def dem_log_weights(logits: torch.Tensor, temperature: float, scale: torch.Tensor | float = 1.0) -> torch.Tensor:
    """Log of the DEM allocation ``w = A * softmax(scale * clamp(logits / T, -20, 20))``, ``[..., A]``.

    ``scale`` (per-env ``[N, 1]`` during collection, 1 in training) sharpens (> 1) or flattens (< 1)
    the allocation. Returned in log space so that ``log sigma_eff = log w + log sigma`` stays finite
    when one dimension's weight underflows.
    """
    a = logits.shape[-1]
    z = scale * torch.clamp(logits / temperature, -20.0, 20.0)
    return math.log(a) + torch.log_softmax(z, dim=-1)


def squashed_gaussian(mu: torch.Tensor, log_std: torch.Tensor, noise: torch.Tensor,
                      headroom: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised tanh-Gaussian sample and its log-density.

    ``mu, log_std, noise [N, A]`` -> ``action [N, A]`` in (-1, 1), ``log_prob [N]`` (nats), with the
    tanh change-of-variables correction ``log(1 - a^2 + 1e-6)`` summed over action dimensions. With
    ``headroom`` k > 1 the action is :func:`with_headroom` of the tanh sample (in [-1, 1]); ``log_prob``
    stays the density of the tanh sample, before the clamp.
    """
    squashed = torch.tanh(mu + torch.exp(log_std) * noise)
    log_prob = -0.5 * noise.pow(2) - log_std - 0.5 * math.log(2.0 * math.pi)
    log_prob = log_prob - torch.log(1.0 - squashed.pow(2) + 1e-6)
    return with_headroom(squashed, headroom), log_prob.sum(-1)
