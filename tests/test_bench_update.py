"""``flashnav bench update``: eager vs torch.compile learner updates, timed side by side."""

from __future__ import annotations

import json

import pytest
import torch

from flashnav.bench.update import compile_networks, parse_ways, random_batches, run_spec, time_steps, time_updates
from flashnav.cli import main as cli_main
from flashnav.learn.hparams import load_hparams
from flashnav.learn.learners import make_learner
from flashnav.learn.networks import ObsLayout
from flashnav.presets import load_robot


def test_ways_name_the_bad_one():
    assert parse_ways("eager, default") == ["eager", "default"]
    with pytest.raises(ValueError, match="--ways: unknown way 'fast'"):
        parse_ways("eager,fast")


def test_time_updates_counts_whole_updates():
    spec = run_spec("fastsac", "turtlebot2", "cpu", "cpu", ["batch_size=32"])
    row = time_updates(spec, "eager", seconds=0.2, warmup=2)
    assert row["way"] == "eager" and row["batch_size"] == 32
    assert row["updates"] >= 8 and row["updates"] % 8 == 0 and row["ms_per_update"] > 0


def test_time_steps_warms_up_apart_then_times_whole_steps_until_the_budget():
    # A fake clock that only the steps advance: warm-up steps take 5 s each, timed steps 0.3 s.
    now, calls = [0.0], []

    def warm(i):
        calls.append(("warm", i))
        now[0] += 5.0

    def step():
        calls.append("step")
        now[0] += 0.3

    row = time_steps(warm, 3, step, 4, seconds=1.0, device="cpu", clock=lambda: now[0])
    assert calls == [("warm", 0), ("warm", 1), ("warm", 2)] + ["step"] * 4  # 4 x 0.3 s is the first >= 1 s
    assert row == {"warmup_s": 15.0, "updates": 16, "ms_per_update": pytest.approx(1000.0 * 1.2 / 16)}


def _learner(way):
    hp = load_hparams("fastdsac", "turtlebot2", "cpu", {"batch_size": 64})
    layout = ObsLayout.from_robot(load_robot("turtlebot2"), 10.0 * 2 ** 0.5)
    learner = make_learner("fastdsac", hp, layout, 2, hp.num_envs, "cpu", seed=3)
    compile_networks(learner, way)
    return learner, random_batches(layout.obs_dim, 64, "cpu", seed=5, n=4)


def test_compiled_networks_update_like_eager_ones():
    # The compiled way is only worth timing if it computes the same update: same seed, same batches,
    # same losses and weights (to float rounding) after a few updates, the actor's included.
    (eager, batches), (compiled, _) = _learner("eager"), _learner("default")
    assert compiled.state.critic._compiled_call_impl is not None and eager.state.critic._compiled_call_impl is None
    for batch in batches:
        a, b = eager.update(batch), compiled.update(batch)
        for key in ("critic_loss", "actor_loss", "alpha"):
            assert float(b[key]) == pytest.approx(float(a[key]), rel=1e-4, abs=1e-5), key
    for p, q in zip(eager.state.critic.parameters(), compiled.state.critic.parameters()):
        torch.testing.assert_close(q, p, rtol=1e-4, atol=1e-5)
    assert compiled.state.critic.state_dict().keys() == eager.state.critic.state_dict().keys()


def test_bench_update_command_writes_rows(tmp_path, capsys):
    out = tmp_path / "update.json"
    code = cli_main(["bench", "update", "--ways", "eager", "--seconds", "0.2", "--warmup", "2", "--device", "cpu",
                     "--json", str(out), "algo.batch_size=32"])
    assert code == 0
    data = json.loads(out.read_text())
    assert data["recipe"] == "cpu" and [r["way"] for r in data["rows"]] == ["eager"]
    assert "1.00x" in capsys.readouterr().out


def test_bench_update_rejects_a_bad_way(capsys):
    assert cli_main(["bench", "update", "--ways", "eager,turbo", "--device", "cpu"]) == 2
    assert "--ways: unknown way 'turbo'" in capsys.readouterr().err


@pytest.mark.parametrize("algo", ["fastdsac", "fastsac", "fasttd3"])
def test_bf16_autocast_way_times_updates_of_every_learner(algo):
    # The way changes the arithmetic, not the code: every learner's update runs under bf16 autocast
    # (its float32 state - running std, C51 targets - stays float32).
    import torch

    spec = run_spec(algo, "turtlebot2", "cpu", "cpu", ["batch_size=32"])
    row = time_updates(spec, "bf16-autocast", seconds=0.1, warmup=2)
    assert row["way"] == "bf16-autocast" and row["updates"] >= 8 and row["ms_per_update"] > 0
    assert "bf16-autocast" in parse_ways("eager,bf16-autocast")
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert torch.ones(2, 2).matmul(torch.ones(2, 2)).dtype == torch.bfloat16  # autocast really applies



@pytest.mark.parametrize("algo", ["fastdsac", "fasttd3"])
def test_cuda_graph_way_times_whole_cycles(algo):
    # On a CPU the way runs a cycle's updates on static buffers with the capture skipped: whole
    # cycles of U updates are timed, and the row says no graph was captured.
    spec = run_spec(algo, "turtlebot2", "cpu", "cpu", ["batch_size=32", "updates_per_step=3"])
    row = time_updates(spec, "cuda-graph", seconds=0.1, warmup=2)
    assert row["way"] == "cuda-graph" and row["captured"] is False
    assert row["updates"] >= 3 and row["updates"] % 3 == 0 and row["ms_per_update"] > 0
    assert "cuda-graph" in parse_ways("eager,cuda-graph")


def test_bench_update_shows_the_cuda_graph_way_beside_eager(tmp_path, capsys):
    out = tmp_path / "update.json"
    code = cli_main(["bench", "update", "--ways", "eager,cuda-graph", "--seconds", "0.2", "--warmup", "2",
                     "--device", "cpu", "--json", str(out), "algo.batch_size=32", "algo.updates_per_step=2"])
    assert code == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["way"] for r in rows] == ["eager", "cuda-graph"] and rows[1]["captured"] is False
    assert "capture skipped" in " ".join(capsys.readouterr().out.split())  # rich wraps at 80 columns
