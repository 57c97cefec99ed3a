"""scripts/bc_memory_probe.py: DAgger students (MLP and GRU) of the mapless planner on mazes (issue 15)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import bc_memory_probe  # noqa: E402
import mapless_planner  # noqa: E402

from flashnav.maps import save_ros_map  # noqa: E402
from flashnav.maps.families import generate_family  # noqa: E402
from flashnav.names import EVAL_SEED  # noqa: E402

PRESET, LAYOUT = bc_memory_probe.task()


@pytest.fixture(scope="module")
def maze(tmp_path_factory):
    grid = generate_family("mazes", 7, size=(6.0, 6.0), resolution=0.05)
    return save_ros_map(grid, tmp_path_factory.mktemp("maze") / "maze.yaml")


def test_the_teacher_alone_plays_the_planner_scripts_episodes(maze):
    """With no student, ``play`` is scripts/mapless_planner.py's planner on `flashnav eval --maps`'s fixed episodes:
    the same outcome episode by episode, and each recorded sequence ends with its episode."""
    from flashnav.maps.ros import load_ros_map

    ref = mapless_planner.run_map(PRESET, str(maze), 8, EVAL_SEED)["mapless"]["per_episode"]
    run = bc_memory_probe.play(PRESET, load_ros_map(maze), 8, EVAL_SEED, None, 1.0, np.random.default_rng(0), fixed=True)
    assert run["success"].tolist() == [e["success"] for e in ref]
    assert run["collision"].tolist() == [e["collision"] for e in ref]
    assert [len(o) for o, _ in run["seqs"]] == [e["steps"] for e in ref]
    for obs, labels in run["seqs"]:
        assert obs.shape[1] == 30 + 2 + 2 and labels.shape[1] == 2 and labels.abs().max() <= 1


@pytest.mark.parametrize("kind,bins", [("mlp", 0), ("gru", 0), ("mlp", 11), ("gru", 11)])
def test_a_student_steps_as_it_reads_sequences_and_learns_its_labels(kind, bins):
    """Step by step with its hidden state is the same network as over a whole sequence (what training sees), and a
    few epochs on one sequence bring the loss down."""
    torch.manual_seed(0)
    student = bc_memory_probe.Student(LAYOUT, kind, width=32, bins=bins)
    obs = torch.rand(3, 12, LAYOUT.obs_dim) * 4 + 0.5
    whole, _ = student(obs)
    h, steps = None, []
    for t in range(12):
        a, h = student.step(obs[:, t], h)
        steps.append(a)
    torch.testing.assert_close(torch.stack(steps, 1), whole.detach())
    labels = torch.tanh(obs[..., :2] - 2)
    data = [(obs[i], labels[i]) for i in range(3)]
    rng = np.random.default_rng(0)
    first = bc_memory_probe.train(student, data, 1, 3, 1e-3, rng)
    last = bc_memory_probe.train(student, data, 150, 3, 3e-3, rng)
    assert last < 0.5 * first
    if kind == "gru":
        with pytest.raises(ValueError, match="feed-forward student"):
            bc_memory_probe.train(student, data, 1, 3, 1e-3, rng, steps=True)


def test_step_batches_train_the_loss_over_real_steps_only():
    """Shuffled-step minibatches fit the same loss as padded episodes: on one full batch (every step at once) the
    first gradient step is the same whichever way the steps are laid out; episodes of different lengths keep
    their padding out of the loss."""
    torch.manual_seed(0)
    obs = torch.rand(3, 12, LAYOUT.obs_dim) * 4 + 0.5
    labels = torch.tanh(obs[..., :2] - 2)
    data = [(obs[0], labels[0]), (obs[1, :5], labels[1, :5]), (obs[2, :9], labels[2, :9])]
    nets = []
    for steps in (False, True):
        torch.manual_seed(1)
        student = bc_memory_probe.Student(LAYOUT, "mlp", width=16)
        seen = []
        bc_memory_probe.train(student, data, 1, 3, 1e-2, np.random.default_rng(0), lambda e, loss: seen.append(loss),
                              steps=steps)
        nets.append((student, seen[0]))
    assert nets[0][1] == pytest.approx(nets[1][1], rel=1e-5)  # the loss before the step: the mean over 26 steps
    for a, b in zip(nets[0][0].parameters(), nets[1][0].parameters()):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_the_categorical_head_chooses_a_way_round_where_squared_error_averages():
    """Half the labels turn left (-0.8), half right (+0.8) on the same input: the mean-squared head learns the
    average (straight on, into the wall); the categorical head plays one of the two; two-hot labels between two
    values decode back to the label."""
    torch.manual_seed(0)
    obs = torch.ones(2, 1, LAYOUT.obs_dim)
    labels = torch.tensor([[[0.5, -0.8]], [[0.5, 0.8]]])
    data = [(obs[i], labels[i]) for i in range(2)]
    played = {}
    for bins in (0, 21):
        student = bc_memory_probe.Student(LAYOUT, "mlp", width=32, bins=bins)
        bc_memory_probe.train(student, data, 300, 2, 3e-3, np.random.default_rng(0))
        played[bins] = student.step(obs[:1, 0], None)[0][0]
    assert abs(played[0][1]) < 0.2 and abs(played[21][1]) > 0.6
    assert abs(played[0][0] - 0.5) < 0.05 and abs(played[21][0] - 0.5) < 0.05
    student.decode = "mean"  # the categorical's mean: the average again
    assert abs(student.step(obs[:1, 0], None)[0][0, 1]) < 0.2
    student = bc_memory_probe.Student(LAYOUT, "mlp", width=8, bins=5)
    for y in (-1.0, -0.7, 0.0, 0.3, 1.0):  # logits of the two-hot label itself: its mode decodes to y
        target = torch.tensor([y, y])
        pos = (target + 1) / 2 * 4
        lo = pos.floor().clamp(max=3).long()
        prob = torch.zeros(2, 5)
        prob[torch.arange(2), lo] = 1 - (pos - lo)
        prob[torch.arange(2), lo + 1] += pos - lo
        torch.testing.assert_close(student.actions(prob.clamp_min(1e-9).log()), target, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="bins=1"):
        bc_memory_probe.Student(LAYOUT, "mlp", bins=1)


def test_the_wall_map_against_a_cell_by_cell_reference():
    """Every remembered wall cell's centre, turned into the robot frame one at a time, lands in the square the
    vectorised map marks (and nothing else is marked); the goal's square is marked, clipped onto the edge when
    farther; a pose turned by 90 degrees turns the map with it."""
    from flashnav.maps.grid import OccupancyMap

    rng = np.random.default_rng(3)
    grid = OccupancyMap(occupied=np.zeros((40, 60), dtype=bool), resolution=0.1, origin=(-1.0, 0.5))
    known = rng.random((3, 40, 60)) < 0.05
    pose = np.array([[1.0, 2.0, 0.3], [2.5, 1.5, -2.0], [0.0, 4.0, math.pi / 2]])
    goal = np.array([[1.5, 2.5], [2.5 + 30 * math.cos(-2.0), 1.5 + 30 * math.sin(-2.0)], [0.1, 4.6]])
    wm = bc_memory_probe.WallMap(8, 0.35)
    got = wm.features(known, grid, pose, goal).reshape(3, 2, 8, 8)
    want = np.zeros_like(got)
    half = 8 * 0.35 / 2
    for n in range(3):
        c, s = math.cos(pose[n, 2]), math.sin(pose[n, 2])
        for i, j in zip(*np.nonzero(known[n])):
            x, y = -1.0 + (j + 0.5) * 0.1 - pose[n, 0], 0.5 + (i + 0.5) * 0.1 - pose[n, 1]
            fwd, left = c * x + s * y, -s * x + c * y
            r, q = math.floor((left + half) / 0.35), math.floor((fwd + half) / 0.35)
            if 0 <= r < 8 and 0 <= q < 8:
                want[n, 0, r, q] = 1.0
        x, y = goal[n] - pose[n, :2]
        fwd, left = c * x + s * y, -s * x + c * y
        want[n, 1, min(max(math.floor((left + half) / 0.35), 0), 7), min(max(math.floor((fwd + half) / 0.35), 0), 7)] = 1
    np.testing.assert_array_equal(got, want)
    assert want[:, 0].sum() > 10 and want[1, 1, 4, 7] == 1  # walls in view; the far goal clipped straight ahead
    assert want[2, 1, 3, 5] == 1  # 0.6 m ahead and 0.1 m right of a robot facing +y
    one = np.zeros((1, 40, 60), dtype=bool)
    one[0, 25, 30] = True  # a wall cell centred 0.5 m east, 0.05 m south of the robot: ahead facing east, right facing north
    east = wm.features(one, grid, np.array([[1.55, 3.1, 0.0]]), np.array([[1.55, 3.1]])).reshape(2, 8, 8)
    north = wm.features(one, grid, np.array([[1.55, 3.1, math.pi / 2]]), np.array([[1.55, 3.1]])).reshape(2, 8, 8)
    assert np.argwhere(east[0]).tolist() == [[3, 5]] and np.argwhere(north[0]).tolist() == [[2, 3]]
    with pytest.raises(ValueError, match="at least 2 cells"):
        bc_memory_probe.WallMap(1, 0.5)


def test_a_student_with_a_wall_map_reads_it_and_the_teacher_fills_it(maze):
    """The wall map's columns follow the observation's; a student of either encoder steps as it reads sequences;
    the teacher's episodes carry maps whose walls grow as the robot sees more (the memory)."""
    from flashnav.maps.ros import load_ros_map

    wm = bc_memory_probe.WallMap(6, 0.5)
    run = bc_memory_probe.play(PRESET, load_ros_map(maze), 4, EVAL_SEED, None, 1.0, np.random.default_rng(0),
                               fixed=True, wall_map=wm)
    obs, _ = run["seqs"][0]
    assert obs.shape[1] == LAYOUT.obs_dim + wm.size
    maps = obs[:, LAYOUT.obs_dim:].reshape(-1, 2, 6, 6)
    assert maps[:, 1].sum((1, 2)).eq(1).all() and maps[0, 0].sum() > 0  # one goal square; walls from the first scan
    now = bc_memory_probe.play(PRESET, load_ros_map(maze), 4, EVAL_SEED, None, 1.0, np.random.default_rng(0),
                               fixed=True, wall_map=dataclasses.replace(wm, memory=False))
    for (o_mem, _), (o_now, _) in zip(run["seqs"], now["seqs"]):  # the teacher drives both the same way
        torch.testing.assert_close(o_now[:, :LAYOUT.obs_dim], o_mem[:, :LAYOUT.obs_dim])
        walls_mem, walls_now = (o[:, LAYOUT.obs_dim:].reshape(-1, 2, 6, 6)[:, 0] for o in (o_mem, o_now))
        assert torch.equal(walls_now[0], walls_mem[0]) and (walls_now <= walls_mem).all()  # the scan's walls remembered
    forgot = [int((o[:, LAYOUT.obs_dim:] < m[:, LAYOUT.obs_dim:]).sum()) for (m, _), (o, _) in zip(run["seqs"], now["seqs"])]
    assert sum(forgot) > 0  # the memory keeps walls the current scan no longer shows
    for encoder in ("flat", "cnn", "small"):
        torch.manual_seed(0)
        student = bc_memory_probe.Student(LAYOUT, "gru", width=16, wall_map=wm, encoder=encoder)
        whole, _ = student(obs[None])
        h, steps = None, []
        for t in range(len(obs)):
            a, h = student.step(obs[None, t], h)
            steps.append(a)
        torch.testing.assert_close(torch.stack(steps, 1), whole.detach())
        moved = obs.clone()
        moved[:, LAYOUT.obs_dim:] = 0
        assert not torch.allclose(student(moved[None])[0], whole)  # the map is read
    with pytest.raises(ValueError, match="map encoder"):
        bc_memory_probe.Student(LAYOUT, "mlp", wall_map=wm, encoder="rnn")


def test_the_sparse_wall_map_draws_the_points_as_the_dense_one_draws_cell_centres():
    """Stored points at wall-cell centres (``inf`` where a group hit nothing) give the dense map of those cells."""
    from flashnav.maps.grid import OccupancyMap

    rng = np.random.default_rng(5)
    grid = OccupancyMap(occupied=np.zeros((30, 50), dtype=bool), resolution=0.1, origin=(-0.5, 0.2))
    known = rng.random((2, 30, 50)) < 0.04
    pose = np.array([[1.2, 1.6, 0.7], [3.0, 2.2, -2.6]])
    goal = np.array([[2.0, 2.0], [0.0, 0.5]])
    frames, per = 3, 40
    points = np.full((2, frames, 2, per), np.inf, dtype=np.float32)
    for n in range(2):
        i, j = np.nonzero(known[n])
        x, y = grid.cell_centres(i, j)
        slots = rng.permutation(frames * per)[: len(i)]  # scattered over frames and groups, the rest unhit
        points[n, slots // per, 0, slots % per], points[n, slots // per, 1, slots % per] = x, y
    wm = bc_memory_probe.WallMap(10, 0.3, frames=frames)
    got = wm.point_features(points, pose, goal)
    np.testing.assert_array_equal(got, wm.features(known, grid, pose, goal))
    assert got.reshape(2, 2, 10, 10)[:, 0].sum() > 10
    for bad, said in ((dict(frames=-1), "frames >= 0"), (dict(every=0), "every >= 1"),
                      (dict(frames=2, memory=False), "exclude each other")):
        with pytest.raises(ValueError, match=said):
            bc_memory_probe.WallMap(10, 0.3, **bad)


def test_the_sparse_wall_map_keeps_the_simulators_own_memory_points(maze, monkeypatch):
    """Played with ``frames``/``every`` (the teacher driving), the probe keeps exactly the points that an env slot
    with ``observation.memory_frames``/``memory_every`` keeps in its first episode, step by step."""
    from flashnav.maps.ros import load_ros_map

    frames, every = 4, 3
    preset = PRESET.model_copy(update={"observation": PRESET.observation.model_copy(
        update={"memory_frames": frames, "memory_every": every})})
    envs, compared = [], []
    make = bc_memory_probe.make_env
    monkeypatch.setattr(bc_memory_probe, "make_env", lambda *a, **k: envs.append(make(*a, **k)) or envs[-1])
    draw = bc_memory_probe.WallMap.point_features

    def check(self, points, pose, goal):
        env = envs[-1]
        t = len(compared)
        first = (env.steps == t).numpy()  # slots still in their first episode (the env restarts the others)
        np.testing.assert_array_equal(points[first], env.extras.memory.points.numpy()[first])
        compared.append(int(first.sum()))
        return draw(self, points, pose, goal)

    monkeypatch.setattr(bc_memory_probe.WallMap, "point_features", check)
    wm = bc_memory_probe.WallMap(6, 0.5, frames=frames, every=every)
    run = bc_memory_probe.play(preset, load_ros_map(maze), 4, EVAL_SEED, None, 1.0, np.random.default_rng(0),
                               fixed=True, wall_map=wm)
    assert len(compared) > 2 * frames * every and sum(compared) > 4 * frames * every  # the ring went round
    maps = run["seqs"][0][0][:, -wm.size:].reshape(-1, 2, 6, 6)
    assert maps[0, 0].sum() > 0 and maps[:, 1].sum((1, 2)).eq(1).all()


def test_the_grid_wall_map_draws_the_hits_the_teachers_memory_draws(maze, monkeypatch):
    """Played with ``grid`` at the map's resolution (the teacher driving: the same episodes), the simulator's dense
    memory of hits draws the teacher's own map, up to hits on a cell's edge (float32 against float64), once both
    mark a hit where the teacher does (half a map cell past it) and remember every wall (the teacher's carving
    off for this check); a coarser grid draws a map of its own cells."""
    from flashnav.guidance import EnvScans
    from flashnav.maps.ros import load_ros_map
    from flashnav.sim.wall_grid import WallGrid

    grid = load_ros_map(maze)
    walls_of = EnvScans.walls
    monkeypatch.setattr(EnvScans, "walls", lambda self, *a, **k: walls_of(self, *a, **{**k, "carve": False}))
    covering = WallGrid.covering.__func__
    beyond = {"m": grid.resolution / 2}
    monkeypatch.setattr(bc_memory_probe.WallGrid, "covering",
                        classmethod(lambda cls, *a: covering(cls, *a, beyond=beyond["m"])))
    wm = bc_memory_probe.WallMap(8, 0.5)

    def walls(**grid_of):
        run = bc_memory_probe.play(PRESET, grid, 4, EVAL_SEED, None, 1.0, np.random.default_rng(0), fixed=True,
                                   wall_map=dataclasses.replace(wm, **grid_of))
        obs = torch.cat([o for o, _ in run["seqs"]])
        return obs[:, :LAYOUT.obs_dim], obs[:, LAYOUT.obs_dim:].reshape(-1, 2, 8, 8)

    base, dense = walls()
    same, hits = walls(grid=grid.resolution)
    torch.testing.assert_close(same, base)  # the same episodes
    assert torch.equal(hits[:, 1], dense[:, 1])  # the same goal squares
    wall = dense[:, 0].sum()
    assert wall > 1000 and (hits[:, 0] != dense[:, 0]).sum() < 0.01 * wall
    beyond["m"] = 0.0  # as the probe plays it: the hit itself, on cells of 0.25 m
    same, coarse = walls(grid=0.25)
    torch.testing.assert_close(same, base)
    assert 0.5 * wall < coarse[:, 0].sum() < 1.5 * wall and not torch.equal(coarse[:, 0], dense[:, 0])
    with pytest.raises(ValueError, match="exclude each other"):
        bc_memory_probe.WallMap(8, 0.5, frames=2, grid=0.1)
    with pytest.raises(ValueError, match="grid of >= 0 metres"):
        bc_memory_probe.WallMap(8, 0.5, grid=-0.1)


def test_the_probe_end_to_end_and_its_seed_check(maze, tmp_path, monkeypatch, capsys):
    out = tmp_path / "probe.json"
    monkeypatch.setattr(sys, "argv", ["bc_memory_probe.py", str(maze), "--train-maps", "1", "--episodes", "4",
                                      "--rounds", "2", "--epochs", "1", "--eval-episodes", "4", "--width", "16", "--bins", "5",
                                      "--json", str(out)])
    bc_memory_probe.main()
    doc = json.loads(out.read_text())
    assert [r["round"] for r in doc["rounds"]] == [0, 1] and doc["rounds"][1]["mix"] == 0.5
    assert set(doc["teacher"]["per_map"]) == {"maze"} and 0 <= doc["teacher"]["mean"] <= 1
    for k in ("mlp", "gru"):
        assert doc["rounds"][0][k]["episodes"] == 4 and doc["rounds"][1][k]["episodes"] == 8
        assert set(doc["rounds"][1][k]["eval"]["per_map"]) == set(doc["rounds"][1][k]["eval_mean"]["per_map"]) == {"maze"}
    monkeypatch.setattr(sys, "argv", ["bc_memory_probe.py", str(maze), "--train-seed", "799999"])
    with pytest.raises(SystemExit):
        bc_memory_probe.main()
    assert "reserved for validation and held-out suites" in capsys.readouterr().err
    for argv, said in ((["--wall-cell", "0.25"], "--wall-cell without --wall-map"),
                       (["--map-encoder", "flat", "--wall-map-now"], "--map-encoder, --wall-map-now without --wall-map"),
                       (["--wall-map", "12", "--wall-cell", "-1"], "at least 2 cells a side of > 0 metres"),
                       (["--step-batches", "--models", "gru"], "--step-batches trains the MLP student only"),
                       (["--wall-map-frames", "4"], "--wall-map-frames without --wall-map"),
                       (["--wall-map", "12", "--wall-map-every", "5"], "--wall-map-every without --wall-map-frames"),
                       (["--wall-map", "12", "--wall-map-frames", "0"], "at least 1 stored scan"),
                       (["--wall-map", "12", "--wall-map-frames", "3", "--wall-map-now"], "exclude each other"),
                       (["--wall-map-grid", "0.1"], "--wall-map-grid without --wall-map"),
                       (["--wall-map", "12", "--wall-map-grid", "0"], "--wall-map-grid 0.0: cells of > 0 metres"),
                       (["--wall-map", "12", "--wall-map-grid", "0.1", "--wall-map-frames", "2"], "exclude each other")):
        monkeypatch.setattr(sys, "argv", ["bc_memory_probe.py", str(maze), *argv])
        with pytest.raises(SystemExit):
            bc_memory_probe.main()
        assert said in capsys.readouterr().err
    from flashnav.maps.validation import benchmark_dir

    heldout = sorted((benchmark_dir() / "heldout").glob("mazes_*.yaml"))[0]
    monkeypatch.setattr(sys, "argv", ["bc_memory_probe.py", str(heldout)])
    with pytest.raises(SystemExit):
        bc_memory_probe.main()
    assert "is a map of the 'heldout' benchmark suite" in capsys.readouterr().err
