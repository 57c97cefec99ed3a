"""The sweep YAML schema: validation messages, --set, path resolution, shipped sweeps (no Ray, no MLflow)."""

from __future__ import annotations

import json

from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from services import optuna_search
from services.sweep_cli import main as sweep_main
from services.sweep import make_plan, validate_train_configs
from services.paths import resolve_db_url, resolve_storage, resolve_tracking_uri, runs_dir
from services.sweep_schema import SweepError, apply_sets, load_sweep, parse_sweep, sweep_to_yaml

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "sweeps").glob("*.yaml"))


def minimal(**extra) -> dict:
    return {"name": "t", "robots": ["turtlebot2"], "algorithms": ["fastdsac"], "seeds": 2, **extra}


def error_of(data: dict) -> str:
    with pytest.raises(SweepError) as info:
        parse_sweep(data, "s.yaml")
    return str(info.value)


def test_minimal_sweep_defaults():
    sweep = parse_sweep(minimal())
    assert sweep.seed_list == [0, 1]
    assert sweep.experiment == "t"
    assert sweep.retry.max_failures == 1 and sweep.resources.gpu == 0
    config = sweep.train_config("turtlebot2", "fastdsac", 1, "cpu", {"algo.batch_size": 256})
    assert config["seed"] == 1 and config["device"] == "cpu" and config["overrides"] == {"algo.batch_size": 256}
    assert config["budget"]["max_train_seconds"] == 600.0


def test_unknown_top_level_key_names_path_and_allowed():
    message = error_of(minimal(budjet={"max_train_seconds": 5}))
    assert "s.yaml" in message
    assert "budjet: unknown key; allowed: " in message
    assert "budget" in message and "resources" in message


def test_nested_unknown_keys_all_reported_with_paths():
    message = error_of(minimal(budget={"max_train_second": 5}, resources={"gpus": 1}, tracking={"uri": "x"}))
    assert "3 problems" in message
    assert "budget.max_train_second: unknown key; allowed: max_env_steps, max_train_seconds, stop_at_success" in message
    assert "resources.gpus: unknown key; allowed: cpu, gpu" in message
    assert "tracking.uri: unknown key; allowed: experiment, tracking_uri" in message


def test_base_rejects_fields_the_sweep_sets():
    assert "base.seed: set by the sweep's seeds" in error_of(minimal(base={"seed": 3}))
    assert "base.device: set by the sweep's resources.gpu" in error_of(minimal(base={"device": "cuda"}))
    message = error_of(minimal(base={"recipee": "cpu"}))
    assert "base.recipee: unknown key; allowed:" in message and "recipe" in message


def test_names_of_robots_algorithms_objective():
    assert "unknown robot 'turtlebot3'; allowed: turtlebot2, go2" in error_of(minimal(robots=["turtlebot3"]))
    assert "unknown algorithm 'sac'; allowed: fastdsac, fastsac, fasttd3" in error_of(minimal(algorithms=["sac"]))
    search = {"n_trials": 2, "objective": "time_to_80", "parameters": {"algo.batch_size": {"choice": [1]}}}
    assert "search.objective: unknown objective 'time_to_80'; allowed: time_to_90" in error_of(minimal(search=search))


def test_distribution_messages_bracket_dotted_keys():
    search = {"n_trials": 2, "parameters": {"algo.batch_size": {"choise": [256]}, "algo.updates_per_step": {"int": [16, 2]},
                                            "algo.temperature": {"loguniform": [0, 4]}}}
    message = error_of(minimal(search=search))
    assert "search.parameters[algo.batch_size].choise: unknown key; allowed: choice, int, logint, loguniform, uniform" in message
    assert "search.parameters[algo.updates_per_step]: int bounds must be [low, high] with low < high" in message
    assert "search.parameters[algo.temperature]: loguniform bounds must be > 0" in message
    two = {"n_trials": 2, "parameters": {"algo.x": {"int": [1, 2], "uniform": [0, 1]}}}
    assert "give exactly one distribution" in error_of(minimal(search=two))


def test_search_consistency_checks():
    space = {"algo.batch_size": {"choice": [256, 512]}}
    assert "exceeds the 2 seeds" in error_of(minimal(search={"n_trials": 2, "seeds_per_trial": 3, "parameters": space}))
    assert "no parameters for algorithm 'fastdsac'" in error_of(minimal(search={"n_trials": 2}))
    clash = minimal(overrides={"algo.batch_size": 256}, search={"n_trials": 2, "parameters": space})
    assert "algo.batch_size: both searched and fixed" in error_of(clash)
    per_algo = {"n_trials": 2, "algorithm_parameters": {"ppo": space}}
    assert "search.algorithm_parameters: unknown algorithm 'ppo'" in error_of(minimal(search=per_algo))


def test_start_points_must_lie_in_the_search_space():
    space = {"algo.batch_size": {"choice": [256, 512]}, "algo.updates_per_step": {"int": [2, 16]},
             "algo.temperature": {"loguniform": [0.5, 4.0]}}

    def search(*points):
        return minimal(search={"n_trials": 2, "parameters": space, "start_points": list(points)})

    ok = parse_sweep(search({"algo.batch_size": 256, "algo.updates_per_step": 16, "algo.temperature": 0.5}))
    assert ok.search.start_points[0]["algo.updates_per_step"] == 16  # bounds inclusive
    assert "start_points[0]: 'algo.lr' is not a searched parameter" in error_of(search({"algo.lr": 1e-3}))
    assert "start_points[1]: algo.batch_size=1024 lies outside its distribution {choice: [256, 512]}" in error_of(
        search({"algo.batch_size": 256}, {"algo.batch_size": 1024}))
    assert "algo.updates_per_step=2.5 lies outside" in error_of(search({"algo.updates_per_step": 2.5}))
    assert "algo.temperature=8.0 lies outside" in error_of(search({"algo.temperature": 8.0}))


def test_start_points_are_named_as_optuna_names_them():
    sweep = load_sweep(ROOT / "sweeps/tb2_cpu_optuna.yaml")
    (point,) = optuna_search.start_points(sweep, "fastdsac")
    assert set(point) == {f"params/{path}" for path in sweep.search.parameters}


def test_seeds_forms():
    assert parse_sweep(minimal(seeds=[3, 5])).seed_list == [3, 5]
    assert "seeds repeat" in error_of(minimal(seeds=[1, 1]))
    assert "need at least one seed" in error_of(minimal(seeds=0))
    assert "seeds must be >= 0, got [-3]" in error_of(minimal(seeds=[0, -3]))  # failed only in its own trial
    for loose in (True, "2", 2.0, [0, "1"], [True]):  # once coerced: `seeds: true` ran one seed, "2" two
        assert "seeds" in error_of(minimal(seeds=loose)), loose


def test_storage_and_sampler_values_are_checked_before_ray_starts():
    """An empty Ray storage once resolved to the project root; a bad Optuna URL or sampler seed failed only in
    Optuna, the URL with a traceback even in a dry run."""
    assert "storage: String should have at least 1 character" in error_of(minimal(storage=""))
    space = {"algo.batch_size": {"choice": [256, 512]}}
    for search, said in (({"storage": "notaurl"}, "search.storage: 'notaurl' is not a database URL"),
                         ({"sampler_seed": -1}, "search.sampler_seed: Input should be greater than or equal to 0"),
                         ({"sampler_seed": 2**32}, "search.sampler_seed: Input should be less than or equal to")):
        assert said in error_of(minimal(search={"n_trials": 2, "parameters": space, **search}))
    unused = minimal(algorithm_overrides={"fasttd3": {"algo.tau": 0.1}})
    assert "algorithm_overrides for fasttd3, which the sweep does not run (algorithms: fastdsac)" in error_of(unused)
    ok = parse_sweep(minimal(search={"n_trials": 2, "parameters": space, "sampler_seed": 2**32 - 1,
                                     "storage": "sqlite:///runs/optuna.db"}))
    assert ok.search.sampler_seed == 2**32 - 1


def test_a_union_value_error_says_only_its_reason():
    """`base: {maps: family:room}` printed three problems, one per member of the maps union."""
    message = error_of(minimal(base={"maps": "family:room"}))
    assert "(1 problem)" in message and "base.maps.family: unknown map family 'room' (did you mean 'rooms'?)" in message
    assert "maps.str" not in message and "list[str]" not in message


def test_apply_sets_dotted_override_keys():
    data = minimal()
    apply_sets(data, ["budget.max_train_seconds=5", "overrides.algo.batch_size=512", "seeds=[0, 1, 2]",
                      "search.algorithm_parameters.fastsac.algo.alpha_init={loguniform: [0.001, 0.1]}"])
    assert data["budget"] == {"max_train_seconds": 5}
    assert data["overrides"] == {"algo.batch_size": 512}
    assert data["seeds"] == [0, 1, 2]
    assert data["search"]["algorithm_parameters"]["fastsac"] == {"algo.alpha_init": {"loguniform": [0.001, 0.1]}}
    with pytest.raises(SweepError, match="is not key=value"):
        apply_sets({}, ["budget.max_train_seconds"])


def test_a_problem_in_a_set_value_names_the_set(tmp_path):
    """The error named only the sweep file, which holds a good value: the bad one came from the command line."""
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(minimal(budget={"max_train_seconds": 5})))
    with pytest.raises(SweepError) as info:
        load_sweep(path, ["seeds=-3", "budget.max_train_seconds=x", "search.parameters.algo.tau={uniform: [1]}"])
    lines = str(info.value).splitlines()[1:]
    assert lines[0] == "  seeds: need at least one seed (from --set seeds=-3)"
    assert lines[1].startswith("  budget.max_train_seconds: Input should be a valid number")
    assert lines[1].endswith("(from --set budget.max_train_seconds=x)")
    assert any(line.startswith("  search.parameters[algo.tau]") and line.endswith(
        "(from --set search.parameters.algo.tau={uniform: [1]})") for line in lines), lines
    with pytest.raises(SweepError) as info:  # a key set twice: the last --set is the one in force, and named
        load_sweep(path, ["seeds=-3", "budget.max_train_seconds=y", "seeds=-4"])
    assert "  seeds: need at least one seed (from --set seeds=-4)" in str(info.value).splitlines()
    with pytest.raises(SweepError) as info:  # a problem reported on the section that holds the --set's key
        load_sweep(path, ["search.n_trials=3", "search.algorithm_parameters.nosuch.algo.lr={uniform: [0.1, 0.2]}"])
    assert str(info.value).splitlines()[1:] == [
        "  search.algorithm_parameters: unknown algorithm 'nosuch'; allowed: fastdsac, fastsac, fasttd3 "
        "(the section of --set search.algorithm_parameters.nosuch.algo.lr={uniform: [0.1, 0.2]})"], str(info.value)
    with pytest.raises(SweepError) as info:  # which of two --sets under the section is at fault is not known: both
        load_sweep(path, ["algorithm_overrides.bogus.algo.x=1", "algorithm_overrides.fastdsac.algo.y=2"])
    assert ("(the section of --set algorithm_overrides.bogus.algo.x=1, --set algorithm_overrides.fastdsac.algo.y=2)"
            in str(info.value)), str(info.value)
    path.write_text(yaml.safe_dump(minimal(seeds=0)))
    with pytest.raises(SweepError) as info:  # a problem in the file itself: no --set named
        load_sweep(path, ["budget.max_train_seconds=7"])
    assert "seeds: need at least one seed" in str(info.value) and "--set" not in str(info.value)


def test_load_sweep_file_errors(tmp_path):
    with pytest.raises(SweepError, match="no such sweep file"):
        load_sweep(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(SweepError, match="not valid YAML"):
        load_sweep(bad)
    bad.write_text("- a list\n")
    with pytest.raises(SweepError, match="a mapping of keys"):
        load_sweep(bad)


def test_duplicate_keys_are_refused(tmp_path):
    # plain safe_load keeps the last `seeds:` silently: a 10-seed sweep would run one seed
    path = tmp_path / "dup.yaml"
    path.write_text("name: t\nrobots: [turtlebot2]\nalgorithms: [fastdsac]\nseeds: 10\nseeds: 1\n")
    with pytest.raises(SweepError, match=r"dup\.yaml: not valid YAML: duplicate key 'seeds' at line 5 \(first at line 4\)"):
        load_sweep(path)
    path.write_text("name: t\nrobots: [turtlebot2]\nalgorithms: [fastdsac]\nseeds: 2\n"
                    "overrides:\n  algo.batch_size: 256\n  algo.batch_size: 512\n")
    with pytest.raises(SweepError, match="duplicate key 'algo.batch_size' at line 7"):
        load_sweep(path)
    with pytest.raises(SweepError, match=r"--set 'overrides=\{a: 1, a: 2\}'.*duplicate key 'a'"):
        apply_sets({}, ["overrides={a: 1, a: 2}"])


def test_yaml_round_trip():
    sweep = parse_sweep(minimal(budget={"max_train_seconds": 5}, overrides={"algo.batch_size": 512},
                                search={"n_trials": 3, "parameters": {"algo.updates_per_step": {"int": [2, 16]}}}))
    again = parse_sweep(yaml.safe_load(sweep_to_yaml(sweep)))
    assert again == sweep


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_sweeps_validate(path):
    sweep = load_sweep(path)
    assert sweep.name == path.stem
    assert sweep.base.recipe in ("paper", "cpu", "paper-mirror", "generalist")
    # every (robot, algorithm) trial resolves through the library's resolver, as `sweep run` checks first
    validate_train_configs(SimpleNamespace(sweep=sweep, source=str(path)))
    # and each trial reads the sweep back from the dump the driver sends it (services.sweep._trainable)
    assert parse_sweep(sweep.model_dump(mode="json")) == sweep


def test_a_recipe_setup_is_the_trials_robots_not_a_base_key():
    """A recipe with a training setup (setups.yaml `generalist`): base stays as written, the dump a trial
    validates again holds no `overrides` or `budget` in base (the first run of tb2_generalist_optuna.yaml
    failed every trial on that), and each trial gets its own robot's setup under the sweep's values."""
    sweep = parse_sweep(minimal(robots=["turtlebot2", "go2"], base={"recipe": "generalist", "threads": 1},
                                budget={"max_env_steps": 4096}, overrides={"algo.batch_size": 256}))
    assert sweep.base.model_fields_set == {"recipe", "threads"}
    dumped = sweep.model_dump(mode="json")["base"]
    assert dumped == {"recipe": "generalist", "threads": 1}
    assert parse_sweep(sweep.model_dump(mode="json")) == sweep
    from flashnav.spec import config_from_data, resolve
    tb2, go2 = (resolve(config_from_data(sweep.train_config(robot, "fastdsac", 0, "cpu", {"algo.n_step": 3}), robot))
                for robot in ("turtlebot2", "go2"))
    assert tb2.robot.episode.hard_share == 0.5 and tb2.robot.motion.w_bounds[1] > 1.5   # the TurtleBot2 setup's
    assert go2.robot.episode.hard_share == 0.0 and go2.robot.motion.w_bounds[1] < 1.0   # Go2's own
    for run in (tb2, go2):
        assert run.robot.episode.goal_sampling == "geodesic" and run.config.maps is not None
        assert run.config.budget.max_env_steps == 4096 and run.hparams.n_step == 3 and run.hparams.batch_size == 256


def test_shipped_sweeps_content():
    names = {p.stem for p in SHIPPED}
    assert {"tb2_10seed", "go2_10seed", "tb2_optuna", "quickstart"} <= names
    tb2 = load_sweep(ROOT / "sweeps/tb2_10seed.yaml")
    assert tb2.algorithms == ["fastdsac", "fastsac", "fasttd3"] and len(tb2.seed_list) == 10
    assert tb2.base.recipe == "paper" and tb2.resources.gpu == 1
    quick = load_sweep(ROOT / "sweeps/quickstart.yaml")
    assert quick.algorithms == ["fastdsac"] and len(quick.seed_list) == 2 and quick.base.recipe == "cpu"
    assert quick.budget.max_train_seconds <= 30 and quick.base.eval.episodes <= 64 and quick.resources.gpu == 0
    optuna = load_sweep(ROOT / "sweeps/tb2_optuna.yaml")
    assert set(optuna.search.space_for("fastdsac")) == {"algo.updates_per_step", "algo.batch_size", "algo.temperature"}
    assert set(optuna.search.space_for("fastsac")) == {"algo.updates_per_step", "algo.batch_size", "algo.alpha_init"}


def test_paths_resolve_absolute(tmp_path, monkeypatch):
    monkeypatch.delenv("FLASHNAV_RUNS_DIR", raising=False)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.delenv("RAY_JOB_CONFIG_JSON_ENV_VAR", raising=False)
    monkeypatch.setenv("FLASHNAV_PROJECT_DIR", str(tmp_path))
    assert runs_dir() == tmp_path / "runs"
    assert resolve_tracking_uri(None) == f"sqlite:///{tmp_path}/runs/mlflow.db"
    assert resolve_tracking_uri("sqlite:///store/m.db") == f"sqlite:///{tmp_path}/store/m.db"
    assert resolve_tracking_uri("sqlite:////abs/m.db") == "sqlite:////abs/m.db"
    assert resolve_db_url(None, "optuna.db") == f"sqlite:///{tmp_path}/runs/optuna.db"
    assert resolve_storage(None) == f"{tmp_path}/runs/ray"
    assert resolve_storage("rel/ray") == f"{tmp_path}/rel/ray"
    assert resolve_storage("s3://bucket/ray") == "s3://bucket/ray"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://127.0.0.1:5000")
    assert resolve_tracking_uri(None) == "http://127.0.0.1:5000"  # the env beats the embedded default
    assert resolve_tracking_uri("sqlite:////x.db") == "sqlite:////x.db"  # an explicit sweep value beats the env
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "elsewhere"))
    assert runs_dir() == tmp_path / "elsewhere"


def test_a_file_store_is_refused_before_ray_starts_unless_allowed(tmp_path, monkeypatch, capsys):
    """MLflow refuses to write to a file store (maintenance mode) - once Ray was up and the parent run was
    being made, as a traceback. The dry run names it now, with the ways out."""
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE", raising=False)
    monkeypatch.setenv("FLASHNAV_PROJECT_DIR", str(tmp_path))
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    for uri in ("mlruns", "file:///tmp/mlruns"):
        with pytest.raises(ValueError, match="file store.*sqlite:///.*MLFLOW_ALLOW_FILE_STORE=true"):
            resolve_tracking_uri(uri)
    rc = sweep_main(["run", str(ROOT / "sweeps/quickstart.yaml"), "--dry-run", "--set", "tracking.tracking_uri=mlruns"])
    assert rc == 2 and "tracking.tracking_uri 'mlruns' is an MLflow file store" in capsys.readouterr().err
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "./mlruns")
    with pytest.raises(ValueError, match=r"\$MLFLOW_TRACKING_URI './mlruns'"):
        resolve_tracking_uri(None)
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")  # MLflow's own opt-out: then the folder, made absolute
    assert resolve_tracking_uri("mlruns") == f"file://{tmp_path}/mlruns"
    assert resolve_tracking_uri("file:///tmp/mlruns") == "file:///tmp/mlruns"


def test_ray_job_without_runs_dir_never_uses_its_temporary_cwd(tmp_path, monkeypatch):
    monkeypatch.delenv("FLASHNAV_RUNS_DIR", raising=False)
    monkeypatch.delenv("FLASHNAV_PROJECT_DIR", raising=False)
    monkeypatch.setenv("RAY_JOB_CONFIG_JSON_ENV_VAR", "{}")
    monkeypatch.chdir(tmp_path)
    assert runs_dir() == Path.home().resolve() / "flashnav-runs"


def test_plan_paths_and_study_names(tmp_path, monkeypatch):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    sweep = load_sweep(ROOT / "sweeps/tb2_optuna.yaml")
    plan = make_plan(sweep, "tb2_optuna.yaml")
    assert plan.tracking_uri == f"sqlite:///{tmp_path}/mlflow.db"
    assert plan.optuna_url == f"sqlite:///{tmp_path}/optuna.db"
    assert plan.ray_storage == f"{tmp_path}/ray/tb2_optuna/{plan.stamp}"
    assert [t.name for t in plan.targets] == ["turtlebot2-fastdsac", "turtlebot2-fastsac"]
    studies = [t.study for t in plan.targets]
    assert len(set(studies)) == 2 and all(plan.stamp in s for s in studies)  # unique per invocation
    assert plan.n_trials == 60
    with pytest.raises(SweepError, match="nothing to resume"):
        make_plan(sweep, "tb2_optuna.yaml", resume=True)


def test_resume_takes_the_newest_invocation_or_the_one_named_by_its_stamp(tmp_path, monkeypatch):
    """--resume could only continue the newest invocation: once a new run had started (by mistake, or after the
    note that the last one did not finish), the older one's unfinished trials were out of reach."""
    import argparse

    from services.sweep_state import STATE_FILE, stamp_arg

    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    sweep = load_sweep(ROOT / "sweeps/tb2_optuna.yaml")
    for stamp in ("20261201-100000", "20261202-100000"):
        plan = make_plan(sweep, "tb2_optuna.yaml")
        plan.state |= {"stamp": stamp, "studies": {t.name: f"study-{stamp}" for t in plan.targets}}
        folder = tmp_path / "sweeps" / sweep.name / stamp
        folder.mkdir(parents=True)
        (folder / STATE_FILE).write_text(json.dumps(plan.state))
    assert make_plan(sweep, "tb2_optuna.yaml", resume=True).stamp == "20261202-100000"
    older = make_plan(sweep, "tb2_optuna.yaml", resume="20261201-100000")
    assert older.stamp == "20261201-100000" and older.out_dir.name == "20261201-100000"
    assert [t.study for t in older.targets] == ["study-20261201-100000"] * 2
    with pytest.raises(SweepError, match=r"no invocation 20261130-100000 .* \(the newest: 20261201-100000, "
                                         r"20261202-100000\)"):
        make_plan(sweep, "tb2_optuna.yaml", resume="20261130-100000")
    assert stamp_arg("20261201-100000") == "20261201-100000"
    for bad in ("sweeps/tb2_optuna.yaml", "2026123-1745"):  # (strptime alone took the second)
        with pytest.raises(argparse.ArgumentTypeError, match="give the sweep file before --resume"):
            stamp_arg(bad)


def test_search_space_to_tune_domains():
    sweep = load_sweep(ROOT / "sweeps/tb2_optuna.yaml")
    space = optuna_search.search_space(sweep, "fastdsac")
    ups = space["algo.updates_per_step"]
    assert (ups.lower, ups.upper) == (2, 17)  # inclusive [2, 16] in the sweep, exclusive upper in Tune
    assert space["algo.batch_size"].categories == [256, 512, 1024]
    assert space["algo.temperature"].lower == 0.5


def test_best_sweep_is_a_ten_seed_grid():
    sweep = load_sweep(ROOT / "sweeps/tb2_optuna.yaml")
    best = optuna_search.best_sweep(sweep, "turtlebot2", "fastdsac",
                                    {"algo.updates_per_step": 8, "algo.batch_size": 512, "algo.temperature": 1.5})
    assert best.search is None and best.seed_list == list(range(10)) and best.algorithms == ["fastdsac"]
    assert best.overrides == {"algo.updates_per_step": 8, "algo.batch_size": 512, "algo.temperature": 1.5}
    assert best.budget.stop_at_success == 1.0
    assert parse_sweep(yaml.safe_load(sweep_to_yaml(best))) == best


def test_cli_dry_run_prints_plan_and_touches_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    rc = sweep_main(["run", str(ROOT / "sweeps/quickstart.yaml"), "--dry-run", "--set", "budget.max_train_seconds=3"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "sweep quickstart: 2 trials" in out and "budget 3 s" in out and str(tmp_path / "runs") in out
    assert not (tmp_path / "runs").exists()


def test_cli_reports_schema_errors(capsys):
    rc = sweep_main(["run", str(ROOT / "sweeps/quickstart.yaml"), "--dry-run", "--set", "budget.max_train_second=3"])
    assert rc == 2
    assert "budget.max_train_second: unknown key" in capsys.readouterr().err


def test_misspelt_hyperparameter_is_refused_before_anything_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    rc = sweep_main(["run", str(ROOT / "sweeps/tb2_optuna.yaml"), "--dry-run",
                     "--set", "search.algorithm_parameters.fastsac={algo.temprature: {loguniform: [0.5, 4]}}"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "turtlebot2/fastsac" in err and "temprature" in err
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("space, named", [
    ("{algo.batch_size: {choice: [256, big]}}", "algo.batch_size='big' (a choice)"),
    ("{algo.tau: {uniform: [0.05, 5.0]}}", "algo.tau=5.0 (the end of its range)"),
    ("{algo.batch_size: {choice: [256, -4]}}", "algo.batch_size=-4 (a choice)"),
])
def test_every_searched_value_is_checked_not_only_the_first(space, named, tmp_path, monkeypatch, capsys):
    """A choice or range end that no trial could train with fails the dry run, naming it (it once passed, as
    only the first choice and the lower bound were checked, and failed in the trial that drew it)."""
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    rc = sweep_main(["run", str(ROOT / "sweeps/tb2_optuna.yaml"), "--dry-run",
                     "--set", f"search.algorithm_parameters.fastdsac={space}"])
    assert rc == 2
    err = capsys.readouterr().err
    assert f"turtlebot2/fastdsac with the searched {named}" in err, err


def test_optuna_dry_run_creates_no_database(tmp_path, monkeypatch):
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    assert sweep_main(["run", str(ROOT / "sweeps/tb2_optuna.yaml"), "--dry-run"]) == 0
    assert not (tmp_path / "runs").exists()


def test_startup_trials_reach_the_tpe_sampler():
    """search.startup_trials is TPE's n_startup_trials (a 10-trial study at Optuna's default 10 is a seeded random
    search: sessions 47-48 drew the same points in two studies); unset keeps Optuna's default; 0 is refused."""
    from services.optuna_search import make_searcher

    def sampler(**search):
        sweep = parse_sweep(minimal(search={"n_trials": 4, "parameters": {"algo.batch_size": {"choice": [256, 512]}},
                                            **search}))
        return make_searcher(sweep, "sqlite:///:memory:", "unit", "fastdsac").searcher._sampler

    assert sampler(startup_trials=3)._n_startup_trials == 3
    assert sampler()._n_startup_trials == 10
    with pytest.raises(ValueError, match="startup_trials"):
        parse_sweep(minimal(search={"n_trials": 4, "startup_trials": 0,
                                    "parameters": {"algo.batch_size": {"choice": [256, 512]}}}))


@pytest.mark.parametrize("key", ["robots", "algorithms"])
def test_a_robot_or_algorithm_named_twice_is_refused(tmp_path, key):
    """algorithms: [fastdsac, fastdsac] trained every seed twice, and the report pooled them as separate seeds."""
    value = {"robots": "[turtlebot2, turtlebot2]", "algorithms": "[fastdsac, fastdsac]"}[key]
    path = tmp_path / "dup.yaml"
    path.write_text(f"name: dup\n{key}: {value}\nseeds: 1\n")
    with pytest.raises(SweepError, match=f"{key}.*repeat: (turtlebot2|fastdsac)"):
        load_sweep(path)


def test_a_uniform_range_for_an_integer_key_fails_before_ray():
    """`updates_per_step: {uniform: [2, 16]}` passed the dry run at both ends (2.0 and 16.0) and failed every
    trial in Ray on 9.1007...: a value inside a uniform range is checked too."""
    sweep = parse_sweep(minimal(search={"n_trials": 2, "parameters": {"algo.updates_per_step": {"uniform": [2, 16]}}}))
    with pytest.raises(SweepError, match=r"updates_per_step=7\.3\d* \(a value inside its range\)"):
        validate_train_configs(SimpleNamespace(sweep=sweep, source="s.yaml"))


def test_tracking_and_optuna_stores_are_checked_before_ray(tmp_path, monkeypatch):
    """A YAML file as the MLflow or Optuna store, a store under a file, an Optuna driver not installed: all
    passed the dry run and failed once Ray was up, in SQLAlchemy's or Optuna's words (or hung, for a server)."""
    monkeypatch.setenv("FLASHNAV_RUNS_DIR", str(tmp_path / "runs"))
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    not_db = tmp_path / "sweep.yaml"
    not_db.write_text("name: x\n")
    for uri, said in ((f"sqlite:///{not_db}", "is not an SQLite database"),
                      (f"sqlite:///{not_db}/mlflow.db", "is a file, so"),
                      (f"sqlite:///{tmp_path}", "is a folder"),
                      ("http://127.0.0.1:9/", "no MLflow server answers")):
        with pytest.raises(SweepError, match=f"s.yaml: tracking URI .*{said}"):
            make_plan(parse_sweep(minimal(tracking={"tracking_uri": uri})), "s.yaml")
    space = {"algo.batch_size": {"choice": [256]}}
    with pytest.raises(SweepError, match="search.storage .* is not an SQLite database"):
        make_plan(parse_sweep(minimal(search={"n_trials": 2, "parameters": space, "storage": f"sqlite:///{not_db}"})),
                  "s.yaml")
    with pytest.raises(SweepError, match=r"search.storage postgresql://\*\*\*@127.0.0.1:9/db: Optuna cannot open it"):
        optuna_search.storage("postgresql://u:secret@127.0.0.1:9/db")


def test_an_interrupted_sweep_names_the_invocation_to_resume(monkeypatch, capsys):
    """The Ctrl-C line said a bare --resume, which takes the newest invocation: one interrupted before its state was
    on disk (Ray starting) sent the user to an older unfinished one."""
    from services import sweep_cli
    from services.sweep import SweepInterrupted

    def interrupted(stamp):
        def run(*_a, **_k):
            raise SweepInterrupted("stopped", stamp)
        return run

    quickstart = str(ROOT / "sweeps/quickstart.yaml")
    monkeypatch.setattr(sweep_cli, "run_sweep", interrupted("20261203-101010"))
    assert sweep_main(["run", quickstart, "--set", "seeds=3"]) == 130
    assert f"continue it with: flashnav sweep run {quickstart} --resume 20261203-101010 --set seeds=3" in \
        capsys.readouterr().err
    monkeypatch.setattr(sweep_cli, "run_sweep", interrupted(None))
    assert sweep_main(["run", quickstart]) == 130
    assert "interrupted before anything was recorded: nothing to resume" in capsys.readouterr().err

    def twice(*_a, **_k):  # a second Ctrl-C while the sweep stopped (Ray shutting down) replaced the sweep's own
        try:
            raise SweepInterrupted("stopped", "20261203-101010")
        finally:
            raise KeyboardInterrupt  # noqa: B012

    monkeypatch.setattr(sweep_cli, "run_sweep", twice)
    assert sweep_main(["run", quickstart]) == 130
    assert "--resume 20261203-101010" in capsys.readouterr().err
