"""scripts/bc_memory_probe.py: DAgger students (MLP and GRU) of the mapless planner on mazes (issue 15)."""

from __future__ import annotations

import json
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
    from flashnav.maps.validation import benchmark_dir

    heldout = sorted((benchmark_dir() / "heldout").glob("mazes_*.yaml"))[0]
    monkeypatch.setattr(sys, "argv", ["bc_memory_probe.py", str(heldout)])
    with pytest.raises(SystemExit):
        bc_memory_probe.main()
    assert "is a map of the 'heldout' benchmark suite" in capsys.readouterr().err
