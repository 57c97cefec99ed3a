"""The names users choose from, defined once.

Command-line choices, schema validation (``TrainConfig``, sweep files), the presets' loaders, the
metrics and the report tables all import these tuples; nothing else spells the lists out.
"""

from __future__ import annotations

#: Robot presets shipped in ``flashnav/presets/<name>.yaml`` (a preset YAML path works too).
ROBOTS = ("turtlebot2", "go2")
#: The robot of every command and constructor that is not told one.
DEFAULT_ROBOT = ROBOTS[0]
#: Display names of the robots (tables, figures), in the paper's order.
ROBOT_LABELS = {"turtlebot2": "TurtleBot2", "go2": "Go2"}
#: Learners, each a module of functions in ``flashnav/learn/<name>.py``.
ALGORITHMS = ("fastdsac", "fastsac", "fasttd3")
#: Display names of the learners (tables, figures).
ALGORITHM_LABELS = {"fastdsac": "FastDSAC", "fastsac": "FastSAC", "fasttd3": "FastTD3"}
#: Hyperparameter recipes in ``flashnav/presets/<algorithm>.yaml``: ``paper`` is appendix A (GPU),
#: ``cpu`` the departures measured for a 2-core CPU, ``paper-mirror`` (FastDSAC; FastSAC and FastTD3 on
#: TurtleBot2) the paper recipe with 5-step returns, gamma 0.99, mirrored replay and (TurtleBot2) the goal angle as
#: sine and cosine (the departures with which TurtleBot2 reaches 100 % within the paper's budget in 8 of 10 seeds),
#: ``generalist`` (FastDSAC, TurtleBot2 and Go2) training for unseen buildings, with its training setup (maps,
#: evaluation, task) in ``presets/setups.yaml``.
#: ``generalist-map`` (FastDSAC, TurtleBot2) the generalist that also sees a map of the walls its scans hit with its
#: own plan drawn in (``observation.wall_map``, ``wall_map_plan``, ``wall_map_plan_penalty``; setup in
#: ``presets/setups.yaml``).
#: ``crowd`` (FastDSAC, TurtleBot2) training among moving people, with its setup (agents, their tracks, the turn rate
#: and reverse of the platform, a 360-deg LiDAR) in ``presets/setups.yaml``.
RECIPES = ("paper", "cpu", "paper-mirror", "generalist", "generalist-map", "crowd")
#: What a user may ask for: a recipe, or ``auto`` (``paper`` on a GPU, ``cpu`` otherwise).
RECIPE_CHOICES = ("auto", *RECIPES)
#: What ``--robot`` takes, for help texts.
ROBOT_HELP = f"{', '.join(ROBOTS)} or a preset YAML (default {DEFAULT_ROBOT})"
#: What a ``--device`` that defaults to ``auto`` takes, for help texts.
DEVICE_HELP = "auto (default), cpu, cuda, cuda:N"
#: The choices in one line, for help texts (``--recipe``, ``TrainConfig.recipe``).
RECIPE_HELP = ("paper (appendix A, GPU), cpu (2 CPU cores), auto (by device), paper-mirror (FastDSAC, and "
               "FastSAC and FastTD3 on TurtleBot2: paper + 5-step returns, gamma 0.99, mirrored replay, goal angle as "
               "sin/cos; FastTD3 and Go2: pink forward-speed noise; Go2: more long detours and geodesic progress in "
               "training, the plan's carrot over the walls it has seen: presets/setups.yaml), generalist (FastDSAC on "
               "many maps, TurtleBot2 or Go2; also sets its maps, "
               "evaluation and task: presets/setups.yaml), generalist-map (FastDSAC, the TurtleBot2 generalist with a "
               "map of the walls it has scanned and its plan to the goal drawn in), crowd (FastDSAC, TurtleBot2, "
               "among moving people: paper-mirror without the sin/cos, 8 agents and 4 tracks, the platform's turn "
               "rate and reverse, a 360-deg LiDAR)")
#: LiDAR raycasters (:func:`flashnav.sim.raycast.make_raycaster`); the first is the default.
RAYCASTERS = ("exact", "exact-torch", "march", "exact-cuda")
DEFAULT_RAYCASTER = RAYCASTERS[0]
#: How the episode sampler picks goals (``episode.goal_sampling``; :mod:`flashnav.sim.sampling`):
#: ``euclidean`` (the default, the paper task) by straight-line distance, ``geodesic`` by path length.
GOAL_SAMPLINGS = ("euclidean", "geodesic")
#: The distance of the reward's shaping term (``reward.progress_metric``; :mod:`flashnav.sim.goal_fields`):
#: ``euclidean`` (the default, the paper's) or ``geodesic`` (path length; training only).
PROGRESS_METRICS = ("euclidean", "geodesic")
#: Families of generated maps (:mod:`flashnav.maps.families`).
MAP_FAMILIES = ("rooms", "offices", "halls", "warehouses", "mazes", "clutter")
#: Map suites of the generalisation benchmark, committed in ``flashnav/maps/data/benchmark/<name>/``
#: (``flashnav eval POLICY --maps heldout``): generated maps no training may use, and real ROS maps
#: of buildings from public packages (their README lists sources and licences).
BENCHMARK_SUITES = ("heldout", "real")
#: Generator seeds reserved for the held-out suite (this and above) and for a validation suite (tuning);
#: training maps take seeds below ``VALIDATION_SEEDS[0]``.
HELDOUT_SEEDS_FROM = 900_000
VALIDATION_SEEDS = (800_000, 899_999)
#: ``TrainConfig.cuda_graph``: a cycle's updates on static buffers captured as a CUDA graph (``on``;
#: eager with capture skipped on a CPU), the plain eager loop (``off``), or ``auto`` (on for cuda only).
CUDA_GRAPH_MODES = ("auto", "on", "off")
#: ``algo.precision``: the arithmetic of the learner's updates (flashnav/learn/precision.py); ``auto`` is
#: bf16 where the device multiplies bf16 natively, else float32, resolved when a run is set up.
PRECISIONS = ("float32", "bf16", "auto")
#: Behaviours of the moving agents (:mod:`flashnav.sim.agents`): ``waypoints`` walks between random
#: free points, ``bounce`` keeps a constant velocity and turns away from walls, ``crossing`` appears
#: at a chosen moment and walks across the robot's route (evaluation scenarios).
AGENT_BEHAVIOURS = ("waypoints", "bounce", "crossing")
#: Evaluation scenarios (:mod:`flashnav.scenarios`, ``flashnav eval --scenario NAME``): no agents, 4
#: or 8 wandering agents, one agent crossing the robot's route.
SCENARIOS = ("static", "wander-4", "wander-8", "crossing")
#: The fixed evaluation set: the start/goal seed and the episode count every evaluation plays by default
#: (``eval.seed`` / ``eval.episodes`` in training, ``flashnav eval``, ``bench eval``, ``deploy sim-robot``).
EVAL_SEED, EVAL_EPISODES = 12345, 1024
#: the largest seed (training, evaluation, an environment's): a torch generator takes a signed 64-bit integer
MAX_SEED = 2**63 - 1
#: The files of a run folder (``flashnav train --out``; :func:`flashnav.learn.artefacts.save_run`): the run's config,
#: its curve and outcome, the learner state, the best policy (TorchScript, ONNX) and a readable copy of its metadata.
CONFIG_FILE, METRICS_FILE, CHECKPOINT_FILE = "config.yaml", "metrics.json", "checkpoint.pt"
POLICY_TORCHSCRIPT, POLICY_ONNX, POLICY_METADATA = "policy.pt", "policy.onnx", "policy.json"
RUN_FILES = (CONFIG_FILE, METRICS_FILE, CHECKPOINT_FILE, POLICY_TORCHSCRIPT, POLICY_ONNX, POLICY_METADATA)
#: The replay buffer a run folder holds only with ``flashnav train --save-replay`` (``--init-replay`` reads it).
REPLAY_FILE = "replay.pt"
#: A sweep trial's checkpoint (services/trainable.py writes it; services/tracking.py and ``flashnav bench runs`` read
#: it): one folder per finished seed with the run's config, curve, best policy and its result (a run folder's metrics).
TRIAL_SEED_DIR, TRIAL_RESULT_FILE = "seed_{seed}", "result.json"
#: a sweep invocation's state in its outputs folder (runs/sweeps/NAME/STAMP): ``ray_storage`` is where its trials are
SWEEP_STATE_FILE = "sweep_state.json"
#: ``stop_reason`` of a run folder written while its run goes on (a ``--save-every`` snapshot): ``flashnav train``
#: writes it, ``flashnav eval`` names a policy of such a run.
SNAPSHOT_STOP_REASON = "running"
#: Success-rate thresholds of time-to-threshold (the paper's 90 / 95 / 100 %), and their tags in
#: metric names (``time_to_90``).
THRESHOLDS = (0.9, 0.95, 1.0)
THRESHOLD_TAGS = ("90", "95", "100")


def seed_arg(text: str) -> int:
    """The argparse type of every ``--seed``: a whole number >= 0 (numpy's generators refuse a negative one,
    which failed deep in a run with "expected non-negative integer")."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    if value > MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be <= 2**63 - 1, got {value}")
    return value


def check_name(kind: str, value: str, allowed: tuple[str, ...]) -> str:
    """``value`` if it is one of ``allowed``, else a ValueError naming ``kind`` and the choices."""
    if value not in allowed:
        import difflib

        close = difflib.get_close_matches(str(value), allowed, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown {kind} {value!r}{hint}; use one of {', '.join(allowed)}")
    return value


def check_robot(value: str) -> str:
    """``value`` if it names a bundled robot preset or a preset YAML path, else a ValueError."""
    if value not in ROBOTS and not str(value).endswith((".yaml", ".yml")):
        from pathlib import Path

        if Path(value).is_dir():
            inside = sorted(str(q) for q in Path(value).glob("*.y*ml"))[:5]
            raise ValueError(f"{value!r} is a folder: give a robot preset YAML file"
                             + (f" (here: {', '.join(inside)})" if inside else " (it holds no .yaml file)")
                             + f", or one of {', '.join(ROBOTS)}")
        raise ValueError(f"unknown robot {value!r}; allowed: {', '.join(ROBOTS)} or a preset YAML path")
    return value


def parse_names(kind: str, text: str | list[str], allowed: tuple[str, ...], option: str | None = None,
                unique: bool = False) -> list[str]:
    """A comma list of ``kind`` names (``"wander-8, crossing"``; or a list of names, as YAML gives)
    or ``all`` -> the names, each checked against ``allowed``; ``all`` -> every allowed name, in their
    order. Blank items are skipped. A ValueError names ``option`` (the flag or key, when given) and
    the bad name, with the choices; with ``unique``, a name given twice too (where a repeat means nothing; a map
    family named twice is drawn twice as often)."""
    where = f"{option}: " if option else ""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [n.strip() if isinstance(n, str) else n for n in items]
    names = [n for n in names if n != ""]
    if names == ["all"]:
        return list(allowed)
    if not names:
        raise ValueError(f"{where}no {kind} named in {text!r}; use one of {', '.join(allowed)}, or all")
    for name in names:
        try:
            check_name(kind, name, allowed)
        except ValueError as exc:
            raise ValueError(f"{where}{exc}") from None
    twice = sorted({n for n in names if names.count(n) > 1}) if unique else []
    if twice:  # `--scenario static,static` ran twice and kept one result
        raise ValueError(f"{where}{kind} {', '.join(map(str, twice))} named more than once in {text!r}")
    return names
