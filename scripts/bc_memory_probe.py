"""Can a recurrent policy on the policy's own observation solve fresh mazes? A behaviour-cloning probe (issue 15).

    .venv/bin/python scripts/bc_memory_probe.py EVAL_MAZE_YAML [...] [--train-maps 48] [--episodes 32]
        [--rounds 3] [--epochs 6] [--eval-episodes 64] [--models mlp,gru] [--bins K]
        [--wall-map CELLS [--wall-cell M] [--wall-map-frames F | --wall-map-grid G] [--map-encoder cnn|flat|small]]
        [--json OUT]

Every reactive generalist fails issue 15's held-out mazes the same way (82-87 %, every failure a wrong turn,
"wandered"), where the optimistic mapless planner (`scripts/mapless_planner.py`: it remembers the walls its scans
have hit and plans through the rest) solves 99 % of fresh mazes. Before building a recurrent learner (GRU actor and
critics, sequence replay with burn-in, hidden state in the ONNX export: several sessions of work), this probe asks
the cheaper question whether a recurrent network *can* do what the planner does from the policy's observation alone
(the 30 pooled sectors, the goal's distance and bearing, the velocities: not the planner's raw 1,080 beams):

- the teacher is the mapless planner (it uses only what the robot has sensed, so its choices are learnable in
  principle from the sensed history), on TurtleBot2 with the `generalist` recipe's task (the platform turn rate,
  goals 1-5 m by path length);
- both students, a feed-forward MLP and a GRU of the same width, are trained by DAgger (Ross et al., 2011): round 0
  on the teacher's own episodes, each later round on episodes the student drives itself (mixed with the teacher's
  action with probability ``0.5 ** round`` per step), labelled by the teacher at every state it visits, all rounds'
  data aggregated; training mazes are fresh generated mazes (seeds from ``--train-seed``, below the reserved
  validation and held-out seeds), new ones every round;
- each student is then played, deterministic and alone, on the fixed episodes of the evaluation mazes
  (`flashnav eval --maps`'s episodes: give validation mazes, never the held-out suite).

If the GRU reaches the planner and the MLP stays where the reactive RL policies are, memory through recurrence is
worth the recurrent learner; if both stay there, the observation (pooled sectors) or the imitation is the limit and
the recurrent learner alone would not close the gap. Supervised learning is the easier problem: a recurrent RL
learner can do no better than its architecture's imitation ceiling suggests, and may do worse.

``--wall-map CELLS`` asks the next question, whether a richer input closes the gap where recurrence did not: the
students also see an egocentric map of the walls the robot's scans have hit (:class:`WallMap`: the teacher's own
memory, CELLS x CELLS squares around the robot, turned with it, and the goal's square), read by a small
convolutional (or one dense) encoder. If a student with the map imitates the teacher closely, a wall-map
observation is worth building into the simulator and the learners; if not, the map alone does not carry what the
teacher's planning does.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mapless_planner import MaplessPlanner  # noqa: E402  (the teacher)

from flashnav.config import Observation  # noqa: E402
from flashnav.eval_maps import fixed_episodes  # noqa: E402
from flashnav.guidance import EnvScans  # noqa: E402
from flashnav.learn.features import IPAPRec, ObsLayout  # noqa: E402
from flashnav.maps.families import generate_family  # noqa: E402
from flashnav.maps.ros import load_ros_map  # noqa: E402
from flashnav.names import EVAL_SEED, VALIDATION_SEEDS  # noqa: E402
from flashnav.presets import load_robot  # noqa: E402
from flashnav.sim.env import make_env  # noqa: E402
from flashnav.sim.goal_fields import evaluation_preset  # noqa: E402
from flashnav.sim.memory import WallMemory, points_per_frame  # noqa: E402
from flashnav.sim.wall_grid import WallGrid  # noqa: E402
from flashnav.sim.wall_image import check_wall_image, wall_image  # noqa: E402

GOAL_BOUND_M = 10.0  # the goal-distance divisor of the students' input (goals are 1-5 m by path length)
ENCODERS = ("flat", "cnn", "small")  # how a student reads the wall map (--map-encoder)
MAP_ENCODER = "cnn"  # --map-encoder's default
WALL_CELL_M = 0.5  # --wall-cell's default, metres
MEMORY_EVERY = Observation().memory_every  # --wall-map-every's default: the simulator's memory scan's


@dataclasses.dataclass(frozen=True)
class WallMap:
    """An egocentric map of the walls the robot's scans have hit, as a student's extra input: ``cells`` x
    ``cells`` squares of ``cell`` metres, centred on the robot and turned with its heading (row = left, column =
    forward), two channels: 1 where a remembered wall falls in the square (else 0), and 1 in the goal's square
    (clipped onto the map's edge when farther). Unknown reads as free, as the teacher plans it (optimistic).

    Which walls: ``frames=0`` the teacher's own dense memory (:class:`flashnav.mapless.SeenWalls`: every grid cell
    any beam has hit), ``memory=False`` the walls of the current scan only (a control: an image of the scan, no
    memory); ``frames=F > 0`` the simulator's sparse memory points (:class:`flashnav.sim.memory.WallMemory`: the
    nearest hit of each group of beams, 60 points a scan, one scan stored every ``every`` steps, the last F kept),
    the form a simulator slot and a robot can keep cheaply; ``grid=G > 0`` the simulator's dense memory of hits
    (:class:`flashnav.sim.wall_grid.WallGrid`: every beam's hit of every scan, kept as the cells of a coarse grid of
    G metres over the map, drawn at the marked cells' centres; a hit marked at its return, where the env's
    ``observation.wall_map`` marks it 1 mm past: :data:`flashnav.sim.wall_grid.HIT_BEYOND_M`), the form a wall-map
    observation keeps."""

    cells: int
    cell: float
    memory: bool = True
    frames: int = 0
    every: int = MEMORY_EVERY
    grid: float = 0.0

    def __post_init__(self) -> None:
        check_wall_image(self.cells, self.cell)
        if self.frames < 0 or self.every < 1:
            raise ValueError(f"wall map: frames >= 0 and every >= 1, got {self.frames} and {self.every}")
        if not (math.isfinite(self.grid) and self.grid >= 0):
            raise ValueError(f"wall map: a grid of >= 0 metres (0: none), got {self.grid}")
        if sum((bool(self.frames), bool(self.grid), not self.memory)) > 1:
            raise ValueError("wall map: the current scan's walls (no memory), stored frames of points and a grid "
                             "of hits exclude each other")

    @property
    def size(self) -> int:
        return 2 * self.cells * self.cells

    def _draw(self, xy: np.ndarray, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """[N, 2 cells^2] float32: :func:`flashnav.sim.wall_image.wall_image` of N slots' wall points ``xy``
        [N, Q, 2] (``inf`` = none), poses [N, 3] and goals [N, 2], in float64 (then stored as float32)."""
        img = wall_image(torch.from_numpy(np.asarray(xy, dtype=np.float64)), torch.from_numpy(pose),
                         torch.from_numpy(goal), self.cells, self.cell)
        return img.reshape(len(pose), -1).numpy().astype(np.float32)

    def features(self, known: np.ndarray, grid, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """[N, 2 cells^2] float32 for N slots' remembered walls ``known`` [N, H, W] on ``grid``'s cells (each
        wall cell's centre), poses [N, 3] and goals [N, 2] (the grid's frame)."""
        slot, i, j = np.nonzero(known)
        x, y = grid.cell_centres(i, j)
        count = np.bincount(slot, minlength=len(pose))
        xy = np.full((len(pose), max(1, count.max(initial=0)), 2), np.inf)
        xy[slot, np.arange(len(slot)) - np.repeat(np.cumsum(count) - count, count)] = np.stack([x, y], axis=1)
        return self._draw(xy, pose, goal)

    def point_features(self, points: np.ndarray, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """[N, 2 cells^2] float32 for N slots' stored wall points ``points`` [N, F, 2, P] (x and y rows, ``inf``
        where a group of beams hit nothing: :attr:`flashnav.sim.memory.WallMemory.points`), poses and goals."""
        return self._draw(np.moveaxis(points, 2, -1).reshape(len(points), -1, 2), pose, goal)

    def grid_features(self, hits: WallGrid, pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """[N, 2 cells^2] float32 for N slots' grids of hits ``hits`` (every slot), poses and goals."""
        img = hits.image(slice(None), torch.from_numpy(pose), torch.from_numpy(goal), self.cells, self.cell)
        return img.reshape(len(pose), -1).numpy().astype(np.float32)


def task(sectors: int | None = None):
    """(preset, students' input layout) of the `generalist` recipe's TurtleBot2 task as evaluations play it: the
    platform turn rate, goals by path length; ``sectors`` pooled LiDAR sectors (None: the preset's)."""
    overrides = {"episode.goal_sampling": "geodesic", "motion.w_bounds": [-math.pi / 2, math.pi / 2]}
    if sectors is not None:
        overrides["lidar.sectors"] = sectors
    preset = evaluation_preset(load_robot("turtlebot2", **overrides))
    return preset, dataclasses.replace(ObsLayout.from_robot(preset, GOAL_BOUND_M), goal_sincos=True)


class Student(nn.Module):
    """IPAPRec (the learners' input transform, goal angle as sine and cosine) -> ReLU layer -> a GRU cell or a
    second ReLU layer -> an action head. ``step(obs [N, D], h)`` -> (actions [N, 2], h).

    The head: ``bins=0``, tanh actions fitted by mean squared error (which averages two ways round a junction into
    one between them); ``bins=K``, a categorical over K evenly spaced values in [-1, 1] per action dimension,
    fitted by cross-entropy to two-hot labels (the label's weight split between the two nearest values), and
    played (``decode``) at its mode (the most likely value, refined by the probability-weighted mean with its two
    neighbours: a head that chooses one way round instead of averaging them) or at its mean (the average again,
    but learnt by classification, which often trains better than regression: Farebrother et al., 2024)."""

    def __init__(self, layout: ObsLayout, kind: str, width: int = 256, bins: int = 0, wall_map: WallMap | None = None,
                 encoder: str = MAP_ENCODER):
        super().__init__()
        if bins == 1 or bins < 0:
            raise ValueError(f"bins={bins}: 0 (a mean-squared head) or at least 2")
        if encoder not in ENCODERS:
            raise ValueError(f"map encoder {encoder!r}: one of {', '.join(ENCODERS)}")
        self.kind, self.bins, self.wall_map = kind, bins, wall_map
        self.decode = "mode"  # or "mean" (bins only)
        self.inp = IPAPRec(layout)
        extra = 0
        if wall_map is not None:  # the wall map's own encoder, its features joined to IPAPRec's
            k = wall_map.cells
            if encoder == "flat":
                self.map_enc = nn.Sequential(nn.Flatten(), nn.Linear(wall_map.size, width), nn.ReLU())
            else:
                if encoder == "cnn":  # three 3 x 3 convolutions, the last two with stride 2: each output sees 9 x 9
                    layers = [nn.Conv2d(2, 16, 3, padding=1), nn.ReLU(), nn.Conv2d(16, 32, 3, stride=2, padding=1),
                              nn.ReLU(), nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU()]
                else:  # small: two 3 x 3 convolutions of 8 and 16 channels, both with stride 2 (each output sees
                    # 7 x 7 squares): a quarter of the positions of the cnn's first layer and half its channels, the
                    # kind of encoder reinforcement learning, several passes per update, could afford on a CPU
                    layers = [nn.Conv2d(2, 8, 3, stride=2, padding=1), nn.ReLU(),
                              nn.Conv2d(8, 16, 3, stride=2, padding=1), nn.ReLU()]
                convs = nn.Sequential(*layers, nn.Flatten())
                flat = convs(torch.zeros(1, 2, k, k)).shape[1]  # the features the convolutions leave
                self.map_enc = nn.Sequential(*convs, nn.Linear(flat, width), nn.ReLU())
            extra = width
        self.enc = nn.Sequential(nn.Linear(layout.feature_dim + extra, width), nn.ReLU())
        self.core = nn.GRU(width, width, batch_first=True) if kind == "gru" else nn.Sequential(
            nn.Linear(width, width), nn.ReLU())
        self.head = nn.Linear(width, 2 * bins if bins else 2)
        if bins:
            self.register_buffer("centres", torch.linspace(-1.0, 1.0, bins))

    def outputs(self, obs: torch.Tensor, h: torch.Tensor | None = None):
        """obs [B, T, D (+ the wall map's columns)] -> the head's outputs (tanh actions [B, T, 2], or logits
        [B, T, 2, K]), last hidden state (None for the MLP)."""
        if self.wall_map is None:
            x = self.enc(self.inp(obs))
        else:
            k, m = self.wall_map.cells, self.wall_map.size
            maps = obs[..., -m:].reshape(-1, 2, k, k)
            x = self.enc(torch.cat([self.inp(obs[..., :-m]), self.map_enc(maps).reshape(*obs.shape[:-1], -1)], -1))
        if self.kind == "gru":
            x, h = self.core(x, h)
        else:
            x = self.core(x)
        y = self.head(x)
        return (y.unflatten(-1, (2, self.bins)) if self.bins else torch.tanh(y)), h

    def actions(self, out: torch.Tensor) -> torch.Tensor:
        """The head's outputs -> actions [..., 2]: the tanh actions, or each categorical's refined mode or mean."""
        if not self.bins:
            return out
        prob = out.softmax(-1)
        if self.decode == "mean":
            return (prob * self.centres).sum(-1)
        near = prob.argmax(-1, keepdim=True) + torch.arange(3)  # the mode and its neighbours, in the padded bins
        w = nn.functional.pad(prob, (1, 1)).gather(-1, near)  # no weight beyond an end
        return (w * nn.functional.pad(self.centres, (1, 1))[near]).sum(-1) / w.sum(-1)

    def loss(self, out: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """Per step [B, T]: the squared action error, or the two action dimensions' cross-entropies to two-hot
        labels."""
        if not self.bins:
            return ((out - labels) ** 2).sum(-1)
        pos = (labels.clamp(-1, 1) + 1) / 2 * (self.bins - 1)
        lo = pos.floor().clamp(max=self.bins - 2)
        up = pos - lo
        logp = out.log_softmax(-1)
        lo = lo.long()[..., None]
        ce = -((1 - up) * logp.gather(-1, lo)[..., 0] + up * logp.gather(-1, lo + 1)[..., 0])
        return ce.sum(-1)

    def forward(self, obs: torch.Tensor, h: torch.Tensor | None = None):
        """obs [B, T, D] -> actions [B, T, 2], last hidden state (None for the MLP)."""
        out, h = self.outputs(obs, h)
        return self.actions(out), h

    @torch.no_grad()
    def step(self, obs: torch.Tensor, h):
        a, h = self(obs[:, None], h)
        return a[:, 0], h


def play(preset, grid, episodes: int, seed: int, student: Student | None, mix: float, rng: np.random.Generator,
         fixed: bool, teach: bool = True, wall_map: WallMap | None = None) -> dict:
    """``episodes`` episodes on ``grid`` (one per slot): the teacher labels every step of every slot until its
    episode ends; who drives: the teacher with probability ``mix`` per step, else the student (None: always the
    teacher). ``fixed``: `flashnav eval --maps`'s fixed episodes (seed ``seed``), else the env's draws with
    ``reset(seed=seed)``. ``teach=False`` (an evaluation: the student alone) skips the teacher. Returns the
    sequences (obs [T_i, D], labels [T_i, 2]) and each episode's outcome."""
    env = make_env(preset, episodes, map=grid, seed=seed)
    obs, _ = env.reset(seed=seed)
    if fixed:
        start, goal = fixed_episodes(env, 0, episodes, seed)
        obs = env.set_state(start, goal)
    teacher = MaplessPlanner(env) if teach else None
    if teacher is not None:
        teacher.plan_all()
    walls, goals, points, hits = None, None, None, None
    sparse = wall_map is not None and wall_map.frames > 0
    gridded = wall_map is not None and wall_map.grid > 0
    own = wall_map is not None and not (sparse or gridded) and (teacher is None or not wall_map.memory)
    if wall_map is not None:  # the teacher's memory, or the same kept without planning (or the current scan's)
        source = teacher.source if teacher is not None else EnvScans(env)
        walls = source.walls(memory=wall_map.memory) if own else None if sparse or gridded else teacher.walls
        every = np.arange(episodes)
        goals = source.goals(every)  # one episode per slot: its goal holds until it ends
        if own:
            walls.mark(every, *source.scans(every))
        if sparse:  # the simulator's memory points, kept as an env slot keeps them
            points = WallMemory(episodes, wall_map.frames, wall_map.every, preset.lidar.sectors,
                                preset.lidar.max_range, env.beam_angles.cpu(), points_per_frame(preset),
                                torch.device("cpu"))
            sel = torch.arange(episodes)
            points.start(sel, env.pose.cpu(), env.scan(sel.to(env.device)).cpu())
        if gridded:  # the simulator's dense memory of hits, over the map in the simulator's frame
            hits = WallGrid.covering(env.frame_map, episodes, wall_map.grid, preset.lidar.max_range,
                                     env.beam_angles.cpu(), torch.device("cpu"))
            sel = torch.arange(episodes)
            hits.push(sel, env.pose.cpu(), env.scan(sel.to(env.device)).cpu())

    def observed(obs: torch.Tensor) -> torch.Tensor:
        if wall_map is None:
            return obs
        pose = env.pose.cpu().numpy().astype(np.float64)
        feats = (wall_map.point_features(points.points.numpy(), pose, goals) if sparse
                 else wall_map.grid_features(hits, pose, goals) if gridded
                 else wall_map.features(walls.known, walls.grid, pose, goals))
        return torch.cat([obs, torch.from_numpy(feats)], 1)
    h = None
    done = np.zeros(episodes, dtype=bool)
    success, collision = np.zeros(episodes, dtype=bool), np.zeros(episodes, dtype=bool)
    obs_seq, lab_seq = [], []
    lengths = np.full(episodes, preset.episode.horizon)
    for t in range(preset.episode.horizon):
        label = teacher.act() if teacher is not None else torch.zeros(episodes, 2)
        obs = observed(obs)
        obs_seq.append(obs.clone())
        lab_seq.append(label.clone())
        if student is None:
            act = label
        else:
            act, h = student.step(obs, h)
            if mix > 0:
                take = torch.as_tensor(rng.random(episodes) < mix)
                act = torch.where(take[:, None], label, act)
        obs, _, terminated, truncated, info = env.step(act)
        end = (terminated | truncated).numpy() & ~done
        success[end], collision[end] = info["success"].numpy()[end], info["collision"].numpy()[end]
        lengths[end] = t + 1  # the steps recorded before the episode ended: 0..t
        done |= end
        if done.all():
            break
        running = np.nonzero(~done)[0]
        if teacher is not None:
            teacher.update(running)
        if own:
            walls.mark(running, *source.scans(running))
        if sparse:  # t + 1 steps into every running slot's episode (one episode per slot, all started at 0)
            sel = torch.as_tensor(running)
            points.push(sel, env.pose[sel.to(env.device)].cpu(), env.scan(sel.to(env.device)).cpu(),
                        torch.full((len(running),), t + 1))
        if gridded:
            sel = torch.as_tensor(running)
            hits.push(sel, env.pose[sel.to(env.device)].cpu(), env.scan(sel.to(env.device)).cpu())
    obs_t, lab_t = torch.stack(obs_seq, 1), torch.stack(lab_seq, 1)  # [N, T, D], [N, T, 2]
    seqs = [(obs_t[i, : lengths[i]], lab_t[i, : lengths[i]]) for i in range(episodes)]
    return {"seqs": seqs, "success": success, "collision": collision}


def train(student: Student, data: list[tuple[torch.Tensor, torch.Tensor]], epochs: int, batch: int,
          lr: float, rng: np.random.Generator, tell=None, steps: bool = False) -> float:
    """Supervised epochs over episode sequences (padded; a mask drops the padding): the student's loss (mean
    squared action error, or the categorical head's cross-entropy). ``steps`` (feed-forward students only):
    minibatches of shuffled steps instead, as many steps each as ``batch`` episodes hold on the mean (the same
    loss, without the padding's cost). ``tell(epoch, loss)``, if given, after each epoch."""
    if steps and student.kind != "mlp":
        raise ValueError(f"training on shuffled steps needs a feed-forward student, got {student.kind!r}")
    opt = torch.optim.Adam(student.parameters(), lr=lr)
    if steps:
        all_obs, all_lab = torch.cat([o for o, _ in data]), torch.cat([a for _, a in data])
        size = max(1, round(batch * len(all_obs) / len(data)))
        order = np.arange(len(all_obs))
    else:
        order = np.arange(len(data))
        size = batch
    last = float("nan")
    for epoch in range(epochs):
        rng.shuffle(order)
        losses = []
        for k in range(0, len(order), size):
            if steps:
                take = torch.as_tensor(order[k:k + size])
                obs, lab = all_obs[take][None], all_lab[take][None]
                mask = torch.ones(lab.shape[:2])
            else:
                part = [data[i] for i in order[k:k + size]]
                t_max = max(len(o) for o, _ in part)
                obs = torch.stack([torch.cat([o, o[-1:].expand(t_max - len(o), -1)]) for o, _ in part])
                lab = torch.stack([torch.cat([a, a[-1:].expand(t_max - len(a), -1)]) for _, a in part])
                mask = torch.stack([torch.arange(t_max) < len(o) for o, _ in part]).float()
            out, _ = student.outputs(obs)
            loss = (student.loss(out, lab) * mask).sum() / mask.sum()
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(student.parameters(), 1.0)
            opt.step()
            losses.append(loss.item())
        last = float(np.mean(losses))
        if tell is not None:
            tell(epoch + 1, last)
    return last


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("eval_maps", nargs="+", metavar="EVAL_MAZE_YAML",
                   help="the mazes to evaluate on (validation mazes: never the held-out suite)")
    p.add_argument("--train-maps", type=int, default=48, help="fresh training mazes per round")
    p.add_argument("--train-seed", type=int, default=600_000, help="the first training maze's seed")
    p.add_argument("--episodes", type=int, default=32, help="episodes per training maze")
    p.add_argument("--rounds", type=int, default=3,
                   help="DAgger rounds (round 0: the teacher drives; 0 rounds: the teacher's evaluation alone)")
    p.add_argument("--epochs", type=int, default=6, help="training epochs over the aggregated data after each round")
    p.add_argument("--batch", type=int, default=64, help="episodes per gradient step")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--eval-episodes", type=int, default=64, help="fixed episodes per evaluation maze")
    p.add_argument("--models", default="mlp,gru", help="comma-separated: mlp, gru")
    p.add_argument("--bins", type=int, default=0,
                   help="the students' head: 0, tanh actions by mean squared error; K >= 2, a categorical over K "
                        "values per action dimension (cross-entropy to two-hot labels, played at its mode and at "
                        "its mean)")
    p.add_argument("--sectors", type=int, default=None,
                   help="the students' pooled LiDAR sectors (default: the preset's 30; 1,080 beams must divide by it)")
    p.add_argument("--wall-map", type=int, default=0, metavar="CELLS",
                   help="give the students an egocentric map of the walls their scans have hit (the teacher's own "
                        "memory), CELLS x CELLS squares of --wall-cell metres, and the goal's square (default 0: none)")
    p.add_argument("--wall-cell", type=float, default=None, metavar="M", help=f"the wall map's square, metres (default {WALL_CELL_M:g})")
    p.add_argument("--wall-map-now", action="store_true",
                   help="a control: the wall map shows only the current scan's walls (no memory)")
    p.add_argument("--wall-map-frames", type=int, default=None, metavar="F",
                   help="draw the wall map from the simulator's sparse memory points (flashnav.sim.memory: 60 points "
                        "a scan) of the last F stored scans instead of the teacher's dense memory (default: dense)")
    p.add_argument("--wall-map-every", type=int, default=None, metavar="E",
                   help=f"with --wall-map-frames: control steps between two stored scans (default {MEMORY_EVERY})")
    p.add_argument("--wall-map-grid", type=float, default=None, metavar="G",
                   help="draw the wall map from the simulator's dense memory of hits (flashnav.sim.wall_grid.WallGrid: "
                        "every beam's hit, kept as cells of G metres) instead of the teacher's memory (default: the "
                        "teacher's)")
    p.add_argument("--map-encoder", default=None, choices=ENCODERS,
                   help="how the students read the wall map: flat, one ReLU layer over its squares; cnn, three "
                        "3 x 3 convolutions first (16, 32, 32 channels), the last two with stride 2; small, two 3 x 3 "
                        f"convolutions (8, 16 channels), both with stride 2 (default {MAP_ENCODER})")
    p.add_argument("--step-batches", action="store_true",
                   help="train the MLP on minibatches of shuffled steps (as many as --batch episodes hold on the "
                        "mean) instead of padded episodes: the same loss, faster (default: padded episodes, as the "
                        "GRU needs)")
    p.add_argument("--seed", type=int, default=0, help="seeds the networks, the shuffles and the mixing")
    p.add_argument("--no-teacher-eval", action="store_true",
                   help="skip the teacher's own evaluation on the evaluation mazes (the students' ceiling)")
    p.add_argument("--json", help="write the results here")
    a = p.parse_args()
    kinds = a.models.split(",")
    for k in kinds:
        if k not in ("mlp", "gru"):
            p.error(f"--models: unknown model {k!r} (mlp, gru)")
    for m in a.eval_maps:
        if not Path(m).is_file():
            p.error(f"evaluation map {m}: no such file")
    given = [f for f, v in (("--wall-cell", a.wall_cell), ("--map-encoder", a.map_encoder),
                            ("--wall-map-now", a.wall_map_now or None), ("--wall-map-frames", a.wall_map_frames),
                            ("--wall-map-every", a.wall_map_every), ("--wall-map-grid", a.wall_map_grid))
             if v is not None]
    if given and not a.wall_map:
        p.error(f"{', '.join(given)} without --wall-map CELLS: there is no wall map to shape")
    if a.wall_map_every is not None and a.wall_map_frames is None:
        p.error("--wall-map-every without --wall-map-frames: the dense memory keeps every scan")
    if a.wall_map_frames is not None and a.wall_map_frames < 1:
        p.error(f"--wall-map-frames {a.wall_map_frames}: at least 1 stored scan")
    if a.wall_map_grid is not None and not (math.isfinite(a.wall_map_grid) and a.wall_map_grid > 0):
        p.error(f"--wall-map-grid {a.wall_map_grid}: cells of > 0 metres")
    if a.step_batches and "mlp" not in kinds:
        p.error("--step-batches trains the MLP student only, and --models has none")
    if a.rounds == 0 and a.no_teacher_eval:
        p.error("--rounds 0 with --no-teacher-eval: nothing to do")
    last_seed = a.train_seed + a.rounds * a.train_maps - 1
    if last_seed >= VALIDATION_SEEDS[0]:
        p.error(f"--train-seed {a.train_seed}: the training mazes would reach seed {last_seed}, reserved for "
                f"validation and held-out suites (>= {VALIDATION_SEEDS[0]})")
    from flashnav.maps.validation import check_not_benchmark
    from flashnav.outputs import check_output_file

    try:  # before an hour of work: the JSON's path, and evaluation maps that are not the held-out suites
        if a.json:
            check_output_file(a.json, "--json")
        eval_grids = [load_ros_map(m) for m in a.eval_maps]
        check_not_benchmark(eval_grids, key="EVAL_MAZE_YAML")
    except ValueError as exc:
        p.error(str(exc))
    torch.set_num_threads(1)  # small batches: one thread is faster than two that contend
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    preset, layout = task(a.sectors)
    try:
        wall_map = WallMap(a.wall_map, WALL_CELL_M if a.wall_cell is None else a.wall_cell, not a.wall_map_now,
                           a.wall_map_frames or 0, MEMORY_EVERY if a.wall_map_every is None else a.wall_map_every,
                           a.wall_map_grid or 0.0) if a.wall_map else None
    except ValueError as exc:
        p.error(f"--wall-map / --wall-cell / --wall-map-frames / --wall-map-every / --wall-map-grid: {exc}")
    try:  # Student checks --bins
        students = {k: Student(layout, k, a.width, a.bins, wall_map, a.map_encoder or MAP_ENCODER) for k in kinds}
    except ValueError as exc:
        p.error(f"--bins: {exc}")
    data: dict[str, list] = {k: [] for k in kinds}
    log: dict = {"args": vars(a), "rounds": []}
    t0 = time.perf_counter()

    def save() -> None:  # after each stage: an interrupted probe keeps what it measured
        if a.json:
            Path(a.json).write_text(json.dumps(log, indent=1), encoding="utf-8")

    def evaluate(student: Student | None) -> dict:
        """The student alone (None: the teacher alone) on the evaluation mazes' fixed episodes."""
        per_map = {}
        for m, grid in zip(a.eval_maps, eval_grids):
            r = play(preset, grid, a.eval_episodes, EVAL_SEED, student, 0.0 if student else 1.0, rng, fixed=True,
                     teach=student is None, wall_map=wall_map if student else None)
            per_map[Path(m).stem] = float(r["success"].mean())
        return {"mean": float(np.mean(list(per_map.values()))), "worst": min(per_map.values()), "per_map": per_map}

    if not a.no_teacher_eval:  # the ceiling, on the same episodes
        log["teacher"] = evaluate(None)
        print(f"[{time.perf_counter() - t0:.0f} s] the teacher alone: evaluation mazes mean {log['teacher']['mean']:.1%}, "
              f"worst {log['teacher']['worst']:.1%}", flush=True)
        save()

    for rnd in range(a.rounds):
        mix = 0.5 ** rnd
        seeds = range(a.train_seed + rnd * a.train_maps, a.train_seed + (rnd + 1) * a.train_maps)
        row: dict = {"round": rnd, "mix": mix if rnd else 1.0}
        grids = [(s, generate_family("mazes", s, robot_radius=0.3)) for s in seeds]  # the round's mazes, once
        if rnd == 0:  # the teacher drives: the same data for every student
            shared = [play(preset, grid, a.episodes, s, None, 1.0, rng, fixed=False, wall_map=wall_map)
                      for s, grid in grids]
        for k in kinds:
            runs = shared if rnd == 0 else [play(preset, grid, a.episodes, s, students[k], mix, rng, fixed=False,
                                                 wall_map=wall_map) for s, grid in grids]
            data[k] += [q for r in runs for q in r["seqs"]]
            drove = float(np.mean([r["success"].mean() for r in runs]))
            def tell(epoch: int, loss: float, k: str = k) -> None:  # progress on the long part
                if epoch % 10 == 0 and epoch < a.epochs:
                    print(f"[{time.perf_counter() - t0:.0f} s] round {rnd} {k}: epoch {epoch}/{a.epochs}, loss {loss:.4f}",
                          flush=True)

            loss = train(students[k], data[k], a.epochs, a.batch, a.lr, rng, tell, a.step_batches and k == "mlp")
            ev = evaluate(students[k])
            row[k] = {"collected_success": drove, "episodes": len(data[k]),
                      "steps": int(sum(len(o) for o, _ in data[k])), "loss": loss, "eval": ev}
            said = f"evaluation mazes mean {ev['mean']:.1%}, worst {ev['worst']:.1%}"
            if a.bins:  # the same network played at its mean too ("eval" is the mode)
                students[k].decode = "mean"
                ev = row[k]["eval_mean"] = evaluate(students[k])
                students[k].decode = "mode"
                said = f"{said} at the mode; at the mean {ev['mean']:.1%}, worst {ev['worst']:.1%}"
            print(f"[{time.perf_counter() - t0:.0f} s] round {rnd} {k}: driving {drove:.1%} while collecting, "
                  f"{len(data[k])} episodes, loss {loss:.4f}; {said}", flush=True)
        log["rounds"].append(row)
        save()
    if a.json:
        print(f"json: {a.json}")


if __name__ == "__main__":
    main()
