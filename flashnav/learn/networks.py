"""Actor and critic networks with the IPAPRec input transform (paper eq. 2).

Observation layout (raw physical units, from the simulator), ``obs [N, D] float32``:
columns ``0..S-1`` pooled LiDAR sector minima (metres, ``(0, max_range]``), ``S`` goal distance
(metres), ``S+1`` goal angle in the robot frame (radians, ``[-pi, pi)``), then the velocity state
(``(v, w)`` -> D = S + 4, or ``(vx, vy, w)`` -> D = S + 5); with a scan history of k frames
(:mod:`flashnav.sim.history`) k * S more LiDAR columns follow, the previous pooled scans newest first;
with M agent tracks (:mod:`flashnav.sim.tracks`) 6 M columns follow (present, x, y, vx, vy, radius each);
with a pose trail of P breadcrumbs (:mod:`flashnav.sim.trail`) 2 P columns end it (x, y each, metres).
Actions are ``[N, A]`` in ``[-1, 1]``.

Every network owns its input transform: LiDAR readings become ``1 / (l - beta)`` with a trainable
``beta = r_in - margin - softplus(rho)`` that always stays below the inscribed radius ``r_in``; the
other features are divided by their known bounds. Twin critics are one batched network (weights
stacked ``[2, in, out]``, evaluated with ``torch.baddbmm``): one kernel chain instead of two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from flashnav.sim.tracks import track_scales
from flashnav.sim.trail import trail_bound

#: Floor on ``r_in - beta`` (metres). softplus(rho) underflows to exactly 0 in float32 for rho below
#: about -104, which would put beta on the inscribed radius and the feature at infinity; the margin
#: caps the LiDAR feature at 1 / margin = 100 whatever the optimiser does to rho.
BETA_MARGIN = 0.01
#: beta at initialisation (metres): the plain reciprocal 1 / l.
BETA_INIT = 0.0
#: std of the actor's output-layer weights at init: actions start near 0, DEM weights near uniform.
ACTOR_OUT_INIT_STD = 0.01
#: added to the running variance before the square root of the optional feature normalisation.
NORM_EPS = 1e-8


@dataclass(frozen=True)
class ObsLayout:
    """Where each feature sits in the observation and the bounds used to scale it.

    ``sectors``: number of pooled LiDAR sectors S (columns 0..S-1).
    ``inscribed_radius``: smallest reading a collision-free robot can see, metres.
    ``max_range``: LiDAR maximum range, metres.
    ``goal_scale``: ``(distance, angle)`` divisors, metres and radians (a float = distance, angle pi).
    ``velocity_scales``: one divisor per velocity column (m/s or rad/s), e.g. ``(0.5, pi/4)``.
    ``scan_history``: previous pooled scans k after those columns (k * S more LiDAR columns; 0 = none).
    ``agent_tracks``: tracked agents M after the history (M * len(track_scales) columns; 0 = none).
    ``track_scales``: the divisors of one track's columns (:func:`flashnav.sim.tracks.track_scales`).
    ``pose_trail``: breadcrumbs P after the tracks (2 P columns, x and y; 0 = none).
    ``trail_scale``: the divisor of every breadcrumb column, metres (:func:`flashnav.sim.trail.trail_bound`).
    ``goal_sincos``: the networks see the goal angle as (sin, cos) instead of angle / pi (one feature more than
    the observation's columns: :attr:`feature_dim`); the observation itself is unchanged.
    """

    sectors: int
    inscribed_radius: float
    max_range: float
    goal_scale: tuple[float, float]
    velocity_scales: tuple[float, ...]
    scan_history: int = 0
    agent_tracks: int = 0
    track_scales: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    pose_trail: int = 0
    trail_scale: float = 1.0
    goal_sincos: bool = False

    def __post_init__(self) -> None:
        goal = self.goal_scale
        if isinstance(goal, (int, float)):
            object.__setattr__(self, "goal_scale", (float(goal), math.pi))
        object.__setattr__(self, "velocity_scales", tuple(float(v) for v in self.velocity_scales))
        object.__setattr__(self, "track_scales", tuple(float(v) for v in self.track_scales))
        if self.sectors <= 0:
            raise ValueError(f"ObsLayout.sectors must be > 0, got {self.sectors}")
        if not 0 < self.inscribed_radius < self.max_range:
            raise ValueError("ObsLayout needs 0 < inscribed_radius < max_range (metres), got "
                             f"{self.inscribed_radius} and {self.max_range}")
        if BETA_INIT >= self.inscribed_radius - BETA_MARGIN:
            raise ValueError(f"inscribed_radius {self.inscribed_radius} m is too small for beta init {BETA_INIT}")
        if min(self.goal_scale) <= 0 or any(v <= 0 for v in (*self.velocity_scales, *self.track_scales,
                                                              self.trail_scale)):
            raise ValueError("ObsLayout scales must all be > 0")
        if not isinstance(self.scan_history, int) or self.scan_history < 0:
            raise ValueError(f"ObsLayout.scan_history must be an integer >= 0, got {self.scan_history!r}")
        if not isinstance(self.agent_tracks, int) or self.agent_tracks < 0:
            raise ValueError(f"ObsLayout.agent_tracks must be an integer >= 0, got {self.agent_tracks!r}")
        if not isinstance(self.pose_trail, int) or self.pose_trail < 0:
            raise ValueError(f"ObsLayout.pose_trail must be an integer >= 0, got {self.pose_trail!r}")

    @property
    def base_dim(self) -> int:
        """B = sectors + 2 goal features + velocity features: the paper's observation."""
        return self.sectors + 2 + len(self.velocity_scales)

    @property
    def history_end(self) -> int:
        """B + scan_history * sectors: the end of the LiDAR history, where the agent tracks start."""
        return self.base_dim + self.scan_history * self.sectors

    @property
    def obs_dim(self) -> int:
        """D = B + scan_history * sectors + agent_tracks * len(track_scales) + 2 * pose_trail."""
        return self.history_end + self.agent_tracks * len(self.track_scales) + 2 * self.pose_trail

    @property
    def feature_dim(self) -> int:
        """The networks' input width: D, or D + 1 with ``goal_sincos`` (the angle's sine and cosine)."""
        return self.obs_dim + int(self.goal_sincos)

    def feature_scales(self) -> torch.Tensor:
        """Divisors for the scaled columns: goal distance, angle, velocities, then the agent tracks' and
        the pose trail's."""
        return torch.tensor((*self.goal_scale, *self.velocity_scales, *self.track_scales * self.agent_tracks,
                             *(self.trail_scale,) * (2 * self.pose_trail)), dtype=torch.float32)

    @classmethod
    def from_robot(cls, preset, goal_distance_max: float) -> "ObsLayout":
        """Layout for a :class:`flashnav.config.RobotPreset` on a map whose diagonal is
        ``goal_distance_max`` metres (``OccupancyMap.diagonal_m``, the environment's observation bound;
        ``RunSpec.goal_distance_max`` in training).

        The goal distance is scaled by that bound; velocities by the action bounds (the velocity state
        follows the commanded velocity); ``vy`` (always 0 on Go2) reuses the v bound.
        """
        v_max = max(abs(b) for b in preset.motion.v_bounds)
        w_max = max(abs(b) for b in preset.motion.w_bounds)
        velocity = (v_max, w_max) if preset.motion.velocity_state_dims == 2 else (v_max, v_max, w_max)
        return cls(sectors=preset.lidar.sectors, inscribed_radius=preset.footprint.inscribed_radius,
                   max_range=preset.lidar.max_range, goal_scale=(float(goal_distance_max), math.pi),
                   velocity_scales=velocity, scan_history=preset.observation.scan_history,
                   agent_tracks=preset.observation.agent_tracks, track_scales=track_scales(preset),
                   pose_trail=preset.observation.pose_trail, trail_scale=trail_bound(preset))


class IPAPRec(nn.Module):
    """``obs [..., D]`` -> features ``[..., D]``: LiDAR ``1 / (l - beta)``, other columns / bounds.

    ``copies=0``: one transform (scalar rho), any leading shape. ``copies=C``: C independent
    transforms (rho ``[C]``) for a batched ensemble; input ``[B, D]``, output ``[C, B, D]``.
    Readings are clamped to ``[inscribed_radius, max_range]`` first: a post-collision final
    observation can read inside the footprint, and must not reach the pole of the reciprocal.
    ``normalize``: the features are then centred and scaled by running statistics (buffers, updated
    only by :meth:`update_stats`), like the reference code's empirical observation normaliser.
    History frames (columns from ``layout.base_dim`` on) get the same ``1 / (l - beta)`` with the same
    beta: one reading means the same distance whenever it was taken, and sharing keeps one parameter
    per transform; agent tracks (the last columns) are divided by their bounds like the goal and
    velocity columns, and so are the pose trail's breadcrumbs after them. The output keeps the input's
    column order; with ``layout.goal_sincos`` the goal angle's column holds sin(angle) and cos(angle) follows it
    (``layout.feature_dim`` columns: sin and cos are continuous where the angle jumps from pi to -pi, the goal
    straight behind; docs/learners.md S18).
    """

    def __init__(self, layout: ObsLayout, copies: int = 0, normalize: bool = False):
        super().__init__()
        self.sectors = layout.sectors
        self.r_in = float(layout.inscribed_radius)
        self.max_range = float(layout.max_range)
        self.copies = copies
        self.base_dim, self.history_end = layout.base_dim, layout.history_end
        # Python bools: tracing records one path
        self.history = layout.history_end > layout.base_dim
        self.tracks = layout.obs_dim > layout.history_end  # agent tracks and / or the pose trail
        self.scaled_base = layout.base_dim - layout.sectors  # goal and velocity columns
        self.goal_sincos = bool(layout.goal_sincos)
        # softplus(rho0) = r_in - margin - BETA_INIT puts beta at BETA_INIT
        gap = self.r_in - BETA_MARGIN - BETA_INIT
        rho0 = gap + math.log(-math.expm1(-gap))
        self.rho = nn.Parameter(torch.full((copies,) if copies else (), rho0))
        self.register_buffer("inv_scale", 1.0 / layout.feature_scales())
        self.normalize = normalize
        if normalize:  # running statistics of the transformed features (identity until the first update)
            shape = (copies, 1, layout.feature_dim) if copies else (layout.feature_dim,)
            self.register_buffer("feat_mean", torch.zeros(shape))
            self.register_buffer("feat_var", torch.ones(shape))
            self.register_buffer("feat_count", torch.zeros((), dtype=torch.float64))

    def beta(self, detach: bool = False) -> torch.Tensor:
        """Pole position, metres: ``[]`` or ``[C]``, always <= r_in - margin."""
        rho = self.rho.detach() if detach else self.rho
        return self.r_in - BETA_MARGIN - F.softplus(rho)

    def forward(self, obs: torch.Tensor, detach_rho: bool = False) -> torch.Tensor:
        x = self.features(obs, detach_rho)
        if self.normalize:
            x = (x - self.feat_mean) * torch.rsqrt(self.feat_var + NORM_EPS)
        return x

    @torch.no_grad()
    def update_stats(self, obs: torch.Tensor) -> None:
        """Merge the batch ``obs [B, D]``'s transformed features into the running mean and variance
        (Chan et al.'s parallel update; per copy for a batched transform). Only with ``normalize``."""
        x = self.features(obs, detach_rho=True)
        n = x.shape[-2]
        keep = self.copies > 0
        mean, var = x.mean(-2, keepdim=keep), x.var(-2, unbiased=False, keepdim=keep)
        count = self.feat_count
        total = count + n
        delta = mean - self.feat_mean
        m2 = self.feat_var * count + var * n + delta.square() * (count * n / total)
        self.feat_mean.add_(delta * (n / total))
        self.feat_var.copy_(m2 / total)
        self.feat_count.copy_(total)

    def features(self, obs: torch.Tensor, detach_rho: bool = False) -> torch.Tensor:
        """The transform before any normalisation: LiDAR ``1 / (l - beta)``, the rest / bounds (the goal
        angle as its sine and cosine with ``goal_sincos``)."""
        x = self._features(obs, detach_rho)
        if not self.goal_sincos:
            return x
        angle = obs[..., self.sectors + 1: self.sectors + 2]
        if self.copies > 0:
            angle = angle.unsqueeze(0).expand(self.copies, -1, -1)
        return torch.cat([x[..., : self.sectors + 1], torch.sin(angle), torch.cos(angle),
                          x[..., self.sectors + 2:]], dim=-1)

    def _features(self, obs: torch.Tensor, detach_rho: bool) -> torch.Tensor:
        beta = self.beta(detach_rho)
        if self.copies > 0:
            beta = beta.view(-1, 1, 1)
        if not self.history and not self.tracks:
            return torch.cat([self._reciprocal(obs[..., : self.sectors], beta),
                              self._scaled(obs[..., self.sectors:])], dim=-1)
        parts = [self._reciprocal(obs[..., : self.sectors], beta)]
        parts.append(self._scaled(obs[..., self.sectors: self.base_dim], 0, self.scaled_base))
        if self.history:
            parts.append(self._reciprocal(obs[..., self.base_dim: self.history_end], beta))
        if self.tracks:
            parts.append(self._scaled(obs[..., self.history_end:], self.scaled_base, None))
        return torch.cat(parts, dim=-1)

    def _reciprocal(self, lidar: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
        """LiDAR columns ``[B, L]`` -> ``1 / (clamp(l) - beta)``, ``[B, L]`` or ``[C, B, L]``."""
        lidar = lidar.clamp(min=self.r_in, max=self.max_range)
        return torch.reciprocal((lidar.unsqueeze(0) if self.copies > 0 else lidar) - beta)

    def _scaled(self, rest: torch.Tensor, start: int = 0, stop: int | None = None) -> torch.Tensor:
        """Goal and velocity columns (and agent tracks) divided by their bounds ``inv_scale[start:stop]``,
        expanded over copies."""
        rest = rest * (self.inv_scale if start == 0 and stop is None else self.inv_scale[start:stop])
        return rest.unsqueeze(0).expand(self.copies, -1, -1) if self.copies > 0 else rest


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
    allocation logits). The deterministic action is always ``tanh(mu)``; see :class:`DeterministicActor`.
    """

    def __init__(self, layout: ObsLayout, action_dim: int, hidden: Sequence[int], heads: int,
                 generator: torch.Generator | None = None, layer_norm: bool = False, obs_norm: bool = False,
                 out_init_std: float = ACTOR_OUT_INIT_STD):
        super().__init__()
        self.action_dim = action_dim
        self.heads = heads
        self.transform = IPAPRec(layout, normalize=obs_norm)
        # out_init_std 0: the output layer keeps the uniform draw of every other layer (PyTorch's default)
        self.mlp = MLP(layout.feature_dim, hidden, heads * action_dim, generator, out_init_std or None, layer_norm)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.mlp(self.transform(obs))


class DeterministicActor(nn.Module):
    """Deployable policy: ``obs [N, D]`` raw units -> ``action [N, A]`` = tanh(mu), in [-1, 1].

    Shares parameters with the wrapped actor (evaluation sees the latest weights); deep-copy it to
    freeze. Plain tensor ops only, so ``torch.export`` / ONNX / TorchScript can trace it.
    """

    def __init__(self, actor: Actor):
        super().__init__()
        self.actor = actor
        self.action_dim = actor.action_dim

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.actor(obs)[..., : self.action_dim])


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
                 obs_norm: bool = False):
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

    def forward(self, obs: torch.Tensor, action: torch.Tensor, detach_params: bool = False) -> torch.Tensor:
        x = self.transform(obs, detach_rho=detach_params)
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


def squashed_gaussian(mu: torch.Tensor, log_std: torch.Tensor,
                      noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparameterised tanh-Gaussian sample and its log-density.

    ``mu, log_std, noise [N, A]`` -> ``action [N, A]`` in (-1, 1), ``log_prob [N]`` (nats), with the
    tanh change-of-variables correction ``log(1 - a^2 + 1e-6)`` summed over action dimensions.
    """
    action = torch.tanh(mu + torch.exp(log_std) * noise)
    log_prob = -0.5 * noise.pow(2) - log_std - 0.5 * math.log(2.0 * math.pi)
    log_prob = log_prob - torch.log(1.0 - action.pow(2) + 1e-6)
    return action, log_prob.sum(-1)
