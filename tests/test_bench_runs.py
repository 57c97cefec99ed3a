"""``flashnav bench runs``: the finished-runs table (issue 16, item 1) is the runs' own records, read right."""

from __future__ import annotations

import json
import warnings

import pytest

from flashnav.bench.runs import group_rows, load_runs, run_row
from flashnav.cli import main as cli_main


def _metrics(seed: int, success: list[float], to100=None, train100=None, robot="turtlebot2") -> dict:
    steps = [5120 * (i + 1) for i in range(len(success))]
    return {"config": {"robot": robot, "algorithm": "fastdsac", "seed": seed},
            "curve": [{"env_steps": s, "train_seconds": s / 1000, "success_rate": r} for s, r in zip(steps, success)],
            "time_to_threshold": {"0.9": 1.0, "0.95": 2.0, "1.0": None if to100 is None else 3.0},
            "env_steps_to_threshold": {"0.9": 10240, "0.95": 15360, "1.0": to100},
            "training_episodes_to_threshold": {"env_steps": {"1.0": train100}}, "env_steps": steps[-1]}


def _run(tmp_path, name: str, metrics: dict):
    d = tmp_path / name
    d.mkdir()
    (d / "metrics.json").write_text(json.dumps(metrics))
    return d


def test_rows_read_thresholds_best_and_the_last_evaluations(tmp_path):
    a = _run(tmp_path, "a", _metrics(0, [0.2, 0.9, 0.96, 1.0, 0.98, 0.99], to100=20480, train100=15360))
    b = _run(tmp_path, "b", _metrics(1, [0.1, 0.92, 0.97, 0.99, 0.995], to100=None))
    rows = [run_row(r, last=3) for d in (a, b) for r in load_runs(d)]
    assert rows[0]["label"] == "a" and rows[0]["to_1.0"] == 20480 and rows[0]["best"] == 1.0
    assert rows[0]["last_mean"] == pytest.approx((1.0 + 0.98 + 0.99) / 3) and rows[0]["last_min"] == 0.98
    assert rows[0]["train_episodes_100"] == 15360 and rows[0]["env_steps"] == 30720
    assert rows[1]["to_1.0"] is None and rows[1]["last_min"] == 0.97 and rows[1]["train_episodes_100"] is None
    (g,) = group_rows(rows)
    assert g["runs"] == 2 and g["budget"] == 200_704  # the paper's TurtleBot2 FastDSAC budget
    assert g["to_1.0"] == {"reached": 1, "mean": 20480} and g["to_0.9"] == {"reached": 2, "mean": 10240}
    assert g["within_budget"] == 1 and g["best"] == [0.995, 1.0]
    late = run_row(load_runs(_run(tmp_path, "late", _metrics(2, [1.0], to100=250_000)))[0])
    assert group_rows([late])[0]["within_budget"] == 0  # 100 % after the budget does not count
    assert g["cut_short"] == 1  # b ended at 25,600 env steps without 100 %: never had the whole budget
    whole = run_row(load_runs(_run(tmp_path, "whole", _metrics(4, [0.99] * 40)))[0])  # 204,800 env steps
    assert group_rows([whole])[0]["cut_short"] == 0 and group_rows([late])[0]["cut_short"] == 0


def test_the_command_prints_both_tables_and_writes_json(tmp_path, capsys):
    a = _run(tmp_path, "run-a", _metrics(0, [0.5, 1.0], to100=10240))
    bench = tmp_path / "bench.json"
    m = _metrics(3, [0.4, 0.93])
    bench.write_text(json.dumps({"date": "2026-11-26", "runs": [{**m, "robot": "turtlebot2",
                                                                  "algorithm": "fastdsac", "seed": 3}]}))
    out = tmp_path / "t.json"
    assert cli_main(["bench", "runs", str(a), str(bench), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "run-a" in text and "bench seed 3" in text and "1/2 (<= 200,704); 1 cut short" in text
    data = json.loads(out.read_text())
    assert [r["label"] for r in data["runs"]] == ["run-a", "bench seed 3"] and data["groups"][0]["runs"] == 2


def test_bad_sources_and_options_are_named(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli_main(["bench", "runs", str(empty)]) == 2
    assert "empty: not a flashnav train run folder" in capsys.readouterr().err
    sim = tmp_path / "sim.json"
    sim.write_text(json.dumps({"rows": []}))
    assert cli_main(["bench", "runs", str(sim)]) == 2
    assert "sim.json: not a flashnav train run folder" in capsys.readouterr().err
    a = _run(tmp_path, "a", _metrics(0, [1.0], to100=5120))
    assert cli_main(["bench", "runs", str(a), "--last", "0"]) == 2
    assert "--last must be >= 1" in capsys.readouterr().err


def _trial(root, name: str, checkpoints: dict[int, list[dict]]):
    """A Tune trial folder as `flashnav sweep run` leaves it: checkpoint_<i>/seed_<s>/result.json; the latest
    checkpoint holds every seed the trial finished (services/trainable.py)."""
    for i, results in checkpoints.items():
        for r in results:
            d = root / name / f"checkpoint_{i:06d}" / f"seed_{r['config']['seed']}"
            d.mkdir(parents=True)
            (d / "result.json").write_text(json.dumps(r))


def test_a_sweep_output_reads_each_trials_latest_checkpoint(tmp_path, capsys):
    sweep = tmp_path / "ray" / "tb2" / "20261130-100445" / "turtlebot2-fastdsac"
    _trial(sweep, "train_trial_aa_1_algorithm=fastdsac,algo_n_step=3", {
        0: [_metrics(0, [0.5, 0.9])],
        1: [_metrics(0, [0.5, 0.9]), _metrics(1, [0.6, 1.0], to100=10240)]})   # seed 0 again, and seed 1 done
    _trial(sweep, "train_trial_bb_2_algorithm=fastdsac,algo_n_step=1", {0: [_metrics(0, [0.7, 0.95])]})
    (sweep / "experiment_state.json").write_text("{}")
    records = load_runs(tmp_path / "ray")
    assert [r["label"] for r in records] == ["train_trial_aa_1 seed 0", "train_trial_aa_1 seed 1",
                                             "train_trial_bb_2 seed 0"]
    (g,) = group_rows([run_row(r) for r in records])
    assert g["runs"] == 3 and g["to_1.0"]["reached"] == 1 and g["budget"] == 200_704
    assert cli_main(["bench", "runs", str(tmp_path / "ray" / "tb2")]) == 0
    assert "train_trial_bb_2 seed 0" in capsys.readouterr().out


def test_no_paper_budget_for_runs_off_the_papers_task(tmp_path):
    """A generalist (its maps, scored on validation maps) or a fine-tuning on a building is not the task the
    paper's env-step budget is for: the group shows none."""
    on = _metrics(0, [1.0], to100=5120)
    on["config"].update({"map": None, "maps": None, "eval": {"maps": None}})
    assert group_rows([run_row(load_runs(_run(tmp_path, "on", on))[0])])[0]["budget"] == 200_704
    for name, extra in (("gen", {"maps": {"family": ["mazes"], "count": 16}, "eval": {"maps": "validation"}}),
                        ("ft", {"map": "/maps/building.yaml"})):
        m = _metrics(0, [1.0], to100=5120)
        m["config"].update(extra)
        rows = [run_row(load_runs(_run(tmp_path, name, m))[0]), run_row(load_runs(tmp_path / "on")[0])]
        assert group_rows(rows)[0]["budget"] is None and group_rows(rows)[0]["within_budget"] is None, name


def test_bench_plot_reads_a_sweep_output_and_one_trial_folder(tmp_path):
    from flashnav.bench.train import load_curves

    sweep = tmp_path / "ray" / "tb2" / "stamp" / "turtlebot2-fastdsac"
    _trial(sweep, "train_trial_aa_1_algorithm=fastdsac", {0: [_metrics(0, [0.5, 0.9])]})
    _trial(sweep, "train_trial_bb_2_algorithm=fastdsac", {0: [_metrics(0, [0.7, 0.95])]})
    runs, when = load_curves(tmp_path / "ray")
    assert [r["label"] for r in runs] == ["train_trial_aa_1 seed 0", "train_trial_bb_2 seed 0"] and when[:2] == "20"
    one, _ = load_curves(sweep / "train_trial_bb_2_algorithm=fastdsac")
    assert [r["curve"][-1]["success_rate"] for r in one] == [0.95]


@pytest.mark.parametrize("edit, named", [
    (lambda m: m.update(curve=[1, 2, 3]), "evaluation 0 of its curve is 1, not a JSON object"),
    (lambda m: m["curve"][1].update(success_rate="high"), "evaluation 1 of its curve has success_rate 'high'"),
    (lambda m: m["curve"][0].update(success_rate=1.7), "success_rate 1.7, not a number in [0, 1]"),
    (lambda m: m["curve"][0].update(env_steps="many"), "evaluation 0 of its curve has env_steps 'many'"),
    (lambda m: m.pop("curve"), "its curve is None, not a list of evaluations"),
    (lambda m: m["config"].update(seed="2"), "its seed is '2', not an integer"),
    (lambda m: m.update(config=[1]), "its config is [1], not an object"),
    (lambda m: m.update(env_steps_to_threshold=[0.9]), "its env_steps_to_threshold is [0.9], not a JSON object"),
])
def test_a_malformed_record_is_refused_naming_its_folder(tmp_path, capsys, edit, named):
    """A metrics.json edited by hand or cut short: both commands name the folder and what is wrong, no traceback,
    nothing drawn."""
    m = _metrics(0, [0.5, 0.9])
    edit(m)
    bad = _run(tmp_path, "badrun", m)
    assert cli_main(["bench", "runs", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "badrun" in err and named in err, err
    png = tmp_path / "p.png"
    assert cli_main(["bench", "plot", str(bad), "--out", str(png)]) == 2
    err = capsys.readouterr().err
    assert "badrun" in err and named in err and not png.exists(), err


def test_runs_json_is_checked_first_and_never_overwrites_a_source(tmp_path, capsys):
    a = _run(tmp_path, "a", _metrics(0, [1.0], to100=5120))
    before = (a / "metrics.json").read_text()
    assert cli_main(["bench", "runs", str(a), "--json", str(a / "metrics.json")]) == 2
    captured = capsys.readouterr()
    assert "--json" in captured.err and "is one of the command's inputs" in captured.err
    assert (a / "metrics.json").read_text() == before and "finished runs" not in captured.out  # no table first
    assert cli_main(["bench", "runs", str(a), "--json", str(tmp_path)]) == 2
    assert "--json" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.json"))


def test_plot_refuses_an_empty_curve_and_a_bad_ymin(tmp_path, capsys):
    ok = _run(tmp_path, "ok", _metrics(0, [0.5, 1.0], to100=10240))
    empty = _run(tmp_path, "none", {**_metrics(1, [0.5]), "curve": []})
    png = tmp_path / "p.png"
    assert cli_main(["bench", "plot", str(empty), "--out", str(png)]) == 2
    assert "none: 1 of its runs have no evaluations" in capsys.readouterr().err
    for ymin in ("150", "-50", "nan", "100"):
        assert cli_main(["bench", "plot", str(ok), "--ymin", ymin, "--out", str(png)]) == 2
        assert "--ymin is the success (%) the axis starts at, in [0, 100)" in capsys.readouterr().err
    assert not png.exists()
    assert cli_main(["bench", "plot", str(ok), "--ymin", "95", "--out", str(png)]) == 0


def test_a_sweep_folder_with_several_invocations_or_a_damaged_trial_says_so(tmp_path):
    """runs/ray/NAME with three invocations counted seed 0 three times without a word; a trial checkpoint
    without its result was left out silently; a truncated result named only the folder above."""
    for stamp in ("20261203-100000", "20261203-110000"):
        _trial(tmp_path / "ray" / "tb2" / stamp / "grid", "train_trial_aa_1_algorithm=fastdsac",
               {0: [_metrics(0, [0.5, 0.9])]})
    with pytest.warns(RuntimeWarning, match=r"2 sweep invocations pooled \(20261203-100000, 20261203-110000\)"):
        assert len(load_runs(tmp_path / "ray" / "tb2")) == 2
    one = tmp_path / "ray" / "tb2" / "20261203-110000"
    (one / "grid" / "train_trial_bb_2_algorithm=fastdsac" / "checkpoint_000000").mkdir(parents=True)
    with pytest.warns(RuntimeWarning, match=r"1 trial checkpoint\(s\) without a seed_\*/result.json, left out: .*bb_2"):
        assert len(load_runs(one)) == 1
    bad = one / "grid" / "train_trial_aa_1_algorithm=fastdsac" / "checkpoint_000000" / "seed_0" / "result.json"
    bad.write_text(bad.read_text()[:40])
    with pytest.raises(ValueError, match=rf"{bad}: not a trial's result \(JSONDecodeError"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        load_runs(one)


def test_the_outputs_folder_a_sweep_prints_leads_to_its_trials(tmp_path):
    """`bench runs runs/sweeps/NAME/STAMP` (the "outputs:" folder `sweep run` prints) was refused as no sweep."""
    trials = tmp_path / "ray" / "tb2" / "20261203-100000"
    _trial(trials / "grid", "train_trial_aa_1_algorithm=fastdsac", {0: [_metrics(0, [0.5, 0.9])]})
    outputs = tmp_path / "sweeps" / "tb2" / "20261203-100000"
    outputs.mkdir(parents=True)
    (outputs / "sweep_state.json").write_text(json.dumps({"ray_storage": str(trials)}))
    assert [r["label"] for r in load_runs(outputs)] == ["train_trial_aa_1 seed 0"]
