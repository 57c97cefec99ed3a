"""``flashnav bench train``: statistics over seeds (fixed data) and the command on a tiny budget."""

from __future__ import annotations

import json

import pytest

from flashnav.bench.train import summarise
from flashnav.cli import main as cli_main


def _run(t90, t95, t100, s90=None, cycle=(10.0, 20.0, 21.0), s100=None):
    return {"time_to_threshold": {"0.9": t90, "0.95": t95, "1.0": t100},
            "env_steps_to_threshold": {"0.9": s90, "0.95": None, "1.0": s100},
            "cycle": dict(zip(("collector_ms", "learner_ms", "effective_ms"), cycle))}


def test_summarise_counts_only_seeds_that_reached():
    runs = [_run(10.0, 20.0, None, 1000), _run(30.0, None, None, 3000, cycle=(12.0, 22.0, 23.0)),
            _run(None, None, None)]
    s = summarise(runs)
    assert s["runs"] == 3 and s["budget"] is None
    assert s["0.9"] == {"reached": 2, "best_s": 10.0, "mean_s": 20.0, "best_env_steps": 1000.0,
                        "mean_env_steps": 2000.0, "within_budget": 0}
    assert s["0.95"] == {"reached": 1, "best_s": 20.0, "mean_s": 20.0, "best_env_steps": None,
                         "mean_env_steps": None, "within_budget": 0}
    assert s["1.0"] == {"reached": 0, "best_s": None, "mean_s": None, "best_env_steps": None,
                        "mean_env_steps": None, "within_budget": 0}
    assert s["collector_ms"] == pytest.approx(32.0 / 3) and s["effective_ms"] == pytest.approx(65.0 / 3)


def test_summarise_counts_seeds_within_the_paper_budget():
    runs = [_run(5.0, 6.0, 7.0, 1000, s100=150_000), _run(5.0, 6.0, 9.0, 1000, s100=250_000),
            _run(None, None, None)]
    s = summarise(runs, budget=200_704)
    assert s["budget"] == 200_704 and s["1.0"]["reached"] == 2 and s["1.0"]["within_budget"] == 1
    assert s["0.9"]["within_budget"] == 2


def test_summarise_reads_100_percent_on_the_training_episodes_too():
    runs = [{**_run(5.0, 6.0, None, 1000), "training_episodes_to_threshold": {"env_steps": {"1.0": 90_000}}},
            {**_run(5.0, 6.0, None, 1000), "training_episodes_to_threshold": {"env_steps": {"1.0": 210_000}}},
            _run(None, None, None)]  # an older run without the reading
    s = summarise(runs, budget=200_704)
    assert s["training_episodes"] == {"reached": 2, "best_env_steps": 90_000.0, "mean_env_steps": 150_000.0,
                                      "within_budget": 1}
    assert s["1.0"]["reached"] == 0  # the evaluation's own count is untouched


def test_summarise_lists_the_learner_thread_counts():
    runs = [{**_run(10.0, None, None), "threads": 2}, {**_run(None, None, None), "threads": 1},
            {**_run(None, None, None), "threads": 2}]
    assert summarise(runs)["threads"] == [1, 2]                  # shown beside the machine, not inside it
    assert summarise([_run(None, None, None)])["threads"] == []  # GPU runs (and older JSON) have none


def test_bench_train_command_writes_every_run(tmp_path, capsys):
    out = tmp_path / "bench.json"
    code = cli_main(["bench", "train", "--seeds", "2", "--recipe", "cpu", "--device", "cpu", "--budget-seconds", "1",
                     "--json", str(out), "--plot", str(tmp_path / "curves.png"), "algo.num_envs=32", "algo.learning_start=64", "algo.updates_per_step=2",
                     "algo.batch_size=64", "algo.eval_every=2", "eval.episodes=8", "budget.max_env_steps=256"])
    assert code == 0
    data = json.loads(out.read_text())
    assert [r["seed"] for r in data["runs"]] == [0, 1]
    assert all(r["robot"] == "turtlebot2" and r["algorithm"] == "fastdsac" and r["recipe"] == "cpu" for r in data["runs"])
    (robot, algo, recipe, device, summary), = data["groups"]
    assert (robot, algo, recipe) == ("turtlebot2", "fastdsac", "cpu") and summary["runs"] == 2
    printed = capsys.readouterr().out
    assert "turtlebot2 fastdsac seed 1: 90% at" in printed
    assert summary["budget"] == 200_704
    assert (tmp_path / "curves.png").stat().st_size > 0


def _curve_run(seed, rates, t90=None):
    return {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": seed,
            "time_to_threshold": {"0.9": t90, "0.95": None, "1.0": None},
            "curve": [{"train_seconds": 10.0 * i, "env_steps": 5120 * (i + 1), "success_rate": r}
                      for i, r in enumerate(rates)]}


def test_bench_plot_redraws_a_saved_json(tmp_path):
    src = tmp_path / "bench.json"
    src.write_text(json.dumps({"date": "2026-11-23 10:00",
                               "runs": [_curve_run(0, [0.0, 0.5, 0.95], t90=20.0), _curve_run(1, [0.0, 0.2, 0.4])]}))
    png = tmp_path / "fig" / "curves.png"
    assert cli_main(["bench", "plot", str(src), "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def test_bench_plot_draws_run_folders_and_bench_files_together(tmp_path, capsys):
    run = tmp_path / "agents-k3"
    run.mkdir()
    r = _curve_run(0, [0.0, 0.5, 0.95], t90=20.0)
    (run / "metrics.json").write_text(json.dumps({
        "config": {"robot": "turtlebot2", "algorithm": "fastdsac", "seed": 4}, "curve": r["curve"],
        "time_to_threshold": {"0.9": 20.0}, "env_steps_to_threshold": {"0.9": 10240}}))
    src = tmp_path / "bench.json"
    src.write_text(json.dumps({"date": "2026-11-23 10:00", "runs": [_curve_run(1, [0.0, 0.2, 0.4])]}))
    for axis in ("env-steps", "seconds"):
        png = tmp_path / f"{axis}.png"
        assert cli_main(["bench", "plot", str(run), str(src), "--x", axis, "--out", str(png)]) == 0
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from flashnav.bench.train import load_curves
    (loaded,), _ = load_curves(run)
    assert loaded["label"] == "agents-k3" and loaded["seed"] == 4 and loaded["env_steps_to_threshold"]["0.9"] == 10240
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main(["bench", "plot", str(empty), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "empty is not a `flashnav bench train --json` file or a `flashnav train` run folder" in err


def test_bench_plot_names_a_bad_file(tmp_path, capsys):
    bad = tmp_path / "sim.json"
    bad.write_text(json.dumps({"rows": []}))
    assert cli_main(["bench", "plot", str(bad), "--out", str(tmp_path / "x.png")]) == 2
    assert "sim.json is not a `flashnav bench train --json` file" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
    old = tmp_path / "old.json"  # curves without env steps: drawable against seconds only
    run = _curve_run(0, [0.0, 0.5])
    for point in run["curve"]:
        del point["env_steps"]
    old.write_text(json.dumps({"runs": [run]}))
    assert cli_main(["bench", "plot", str(old), "--out", str(tmp_path / "y.png")]) == 2
    assert "old.json: its curves have no env_steps; use --x seconds" in capsys.readouterr().err
    assert cli_main(["bench", "plot", str(old), "--x", "seconds", "--out", str(tmp_path / "y.png")]) == 0


def test_bench_plot_draws_arms_one_colour_each(tmp_path, capsys, monkeypatch):
    runs = []
    for i, rates in enumerate(([0.0, 0.97, 1.0], [0.0, 0.5, 0.98], [0.9, 1.0])):
        d = tmp_path / f"run{i}"
        d.mkdir()
        r = _curve_run(i, rates)
        (d / "metrics.json").write_text(json.dumps({"config": {"robot": "turtlebot2", "algorithm": "fastdsac",
                                                               "seed": i}, "curve": r["curve"]}))
        runs.append(str(d))
    import flashnav.viz as viz

    seen = {}
    real = viz.plot_training_runs

    def spy(runs_, out, title="", **kw):
        seen.update(arms=[r.get("arm") for r in runs_], **kw)
        return real(runs_, out, title, **kw)

    monkeypatch.setattr(viz, "plot_training_runs", spy)
    import matplotlib.axes

    labels, plot = [], matplotlib.axes.Axes.plot

    def plot_and_keep_label(self, *a, **k):
        labels.append(k.get("label"))
        return plot(self, *a, **k)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", plot_and_keep_label)
    png = tmp_path / "arms.png"
    assert cli_main(["bench", "plot", "--arm", "scratch", runs[0], runs[1], "--arm", "fine-tuned", runs[2],
                     "--ymin", "90", "--out", str(png)]) == 0
    assert seen["arms"] == ["scratch", "scratch", "fine-tuned"] and seen["ymin"] == 90.0
    assert {"scratch (2 runs)", "fine-tuned (1 run)"} <= set(labels)  # one legend entry per arm, counted
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert cli_main(["bench", "plot", "--arm", "lonely", "--out", str(png)]) == 2
    assert "--arm lonely names no run" in capsys.readouterr().err
    assert cli_main(["bench", "plot", "--out", str(png)]) == 2
    assert "give run folders or bench files" in capsys.readouterr().err
