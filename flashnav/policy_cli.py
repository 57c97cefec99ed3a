"""``flashnav eval`` and ``flashnav render``: run an exported policy (policy.pt / policy.onnx).

Both read the policy file alone (no training code, no checkpoint): what is evaluated here is exactly
what a robot would run. The robot defaults to the one recorded in the policy's metadata.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from flashnav.names import EVAL_EPISODES, EVAL_SEED, GOAL_SAMPLINGS, ROBOTS, seed_arg


def register_cli(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="evaluate an exported policy (policy.pt / policy.onnx) on solvable episodes")
    _common_args(p, episodes=EVAL_EPISODES)
    p.add_argument("--device", default="cpu", help="simulator device (cpu, cuda, cuda:N, auto); ONNX always runs on CPU")
    p.add_argument("--json", default=None, metavar="FILE", help="write the rates to this JSON file")
    p.add_argument("--maps", default=None, metavar="DIR_OR_GLOB",
                   help="evaluate on every map of a folder / glob of ROS map YAML files, or of a committed "
                        "benchmark suite (heldout, real): a table per map, --episodes each")
    p.add_argument("--goal-sampling", default=None, choices=GOAL_SAMPLINGS,
                   help="goal band measured as path length (geodesic; the default with --maps) or straight line")
    p.add_argument("--label", default=None, help="with --maps: the policy's name in the JSON and the report")
    p.add_argument("--guide", type=float, default=None, metavar="LOOKAHEAD_M",
                   help="with --maps or --scenario: path guidance, a global planner on the known map "
                        "(flashnav/guidance.py): the policy steers at the point LOOKAHEAD_M metres along the "
                        "shortest path instead of at the goal (e.g. 0.5); a deployment mode, not the zero-shot task")
    p.add_argument("--guide-from", default=None, choices=("map", "scans"),
                   help="with --guide: what the planner knows, the map (default; not the moving agents) or only "
                        "the walls each episode's own scans have shown, no map (flashnav/mapless.py: the "
                        "optimistic mapless planner; a wall mark is forgotten when a later beam passes through it)")
    p.add_argument("--guide-keep-walls", action="store_true",
                   help="with --guide-from scans: never forget a wall mark (no carving by later beams): an "
                        "ablation - moving agents then leave trails of walls in the planner's memory")
    p.add_argument("--scenario", default=None, metavar="NAME[,NAME]",
                   help="evaluation scenarios with moving agents: static, wander-4, wander-8, crossing, or all "
                        "(success / collision with an agent / with a wall / timeout per scenario); the agents are "
                        "the simulator's defaults whatever the policy trained with, or with --robot PRESET.yaml "
                        "that preset's agent options")
    _shield_arg(p)
    _agents_arg(p)
    p.set_defaults(func=run_eval)

    p = sub.add_parser("render", help="draw an exported policy's trajectories (PNG, optionally an animated GIF)")
    _common_args(p, episodes=16)
    p.add_argument("--out", required=True, help="PNG with the trajectories, coloured by outcome")
    p.add_argument("--gif", action="store_true", help="also write an animated GIF next to --out")
    p.add_argument("--scenario", default=None, metavar="NAME",
                   help="draw the episodes of this scenario (static, wander-4, wander-8, crossing) with its agents")
    _shield_arg(p)
    _agents_arg(p)
    p.set_defaults(func=run_render)


def _shield_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--shield", type=float, default=None, metavar="SECONDS",
                   help="with --scenario: a people shield in front of the policy (flashnav/shield.py): the policy's "
                        "action is held SECONDS ahead against every tracked agent walking straight on, and only a "
                        "predicted contact makes the shield play the nearest action that keeps clear of the agents "
                        "and the scan's walls (e.g. 2); a deployment mode, reported beside the policy alone")


def _input_files(args) -> list[Path]:
    """The files a policy command reads that an output must not overwrite: the policy (a run folder's policy files)
    and, with ``--map`` a ROS YAML, the map's YAML and image."""
    from flashnav.maps.ros import map_files
    from flashnav.names import POLICY_ONNX, POLICY_TORCHSCRIPT

    policy = Path(args.policy)
    files = [policy / POLICY_TORCHSCRIPT, policy / POLICY_ONNX] if policy.is_dir() else [policy]
    if getattr(args, "map", None) is not None and str(args.map).endswith((".yaml", ".yml")):
        files += map_files(args.map)
    return files


def _check_shield(args) -> None:
    """``--shield``'s errors, before any work: it needs ``--scenario`` and a look-ahead > 0."""
    if args.shield is not None and args.scenario is None:
        raise ValueError("--shield guards against moving agents: it goes with --scenario NAME")
    if args.shield is not None:
        from flashnav.shield import check_lookahead

        check_lookahead(args.shield, "--shield")


def _people_shield(args, preset):
    """The :class:`flashnav.shield.PeopleShield` of ``--shield`` for ``preset``, or None without it."""
    if args.shield is None:
        return None
    from flashnav.shield import PeopleShield

    return PeopleShield(preset, lookahead=args.shield)


def _agents_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--agents", action="append", default=None, metavar="KEY=VALUE",
                   help="with --scenario: change one of the scenario's agent options (README \"Moving agents\"), "
                        "e.g. --agents reactive=0.5 (half the agents yield to the robot); repeat for more")


def _common_args(p: argparse.ArgumentParser, episodes: int) -> None:
    p.add_argument("policy", metavar="POLICY", help="policy.pt (TorchScript), policy.onnx, or a run folder (its policy.pt)")
    p.add_argument("--robot", default=None,
                   help=f"{', '.join(ROBOTS)} or a preset YAML (default: the robot recorded in the policy)")
    p.add_argument("--map", default=None, help="ROS map YAML or bundled map name (default: the robot's map)")
    p.add_argument("--episodes", type=int, default=episodes, help=f"episodes, run in parallel (one per env; default {episodes})")
    p.add_argument("--seed", type=seed_arg, default=EVAL_SEED, help=f"start/goal sampling seed (default {EVAL_SEED})")
    p.add_argument("overrides", nargs="*", metavar="robot.KEY=VALUE",
                   help="change the simulated robot the policy is played on, as flashnav train's robot.* "
                        "overrides, e.g. robot.lidar.noise_std=0.03 robot.lidar.dropout=0.05 (a robustness "
                        "check: sensor noise, another range or field of view); not robot.agents.* (--scenario, "
                        "--agents) or robot.reward.* (an evaluation counts outcomes, not reward)")


#: robot-preset sections an evaluation override may not touch, and where to go instead
_NOT_OVERRIDABLE = {"agents": "the agents of an evaluation are a scenario's: --scenario NAME [--agents KEY=VALUE]",
                    "reward": "an evaluation counts success, collision and timeout; the reward does not enter it"}


def robot_overrides(args) -> dict:
    """The ``robot.KEY=VALUE`` arguments of ``eval`` / ``render`` as preset overrides (``{"lidar.noise_std":
    0.03}``; values read as YAML); anything else is a ValueError that names it."""
    from flashnav.yamlio import parse_assignment

    out = {}
    for item in getattr(args, "overrides", None) or []:
        key, value = parse_assignment(item)
        if not key.startswith("robot."):
            raise ValueError(f"override {item!r}: flashnav {args.command} takes robot.KEY=VALUE (the simulated robot "
                             "and its sensors), e.g. robot.lidar.noise_std=0.03")
        key = key.removeprefix("robot.")
        if key.split(".")[0] in _NOT_OVERRIDABLE:
            raise ValueError(f"override {item!r}: {_NOT_OVERRIDABLE[key.split('.')[0]]}")
        out[key] = value
    return out


def overrides_label(args) -> str:
    """``, with robot.lidar.noise_std=0.03`` for titles, or ``""`` without overrides."""
    items = getattr(args, "overrides", None) or []
    return f", with {' '.join(items)}" if items else ""


def load_policy_and_env(args, device: str = "cpu"):
    """(policy, metadata, env) for parsed `eval`-style arguments (policy, robot, map, episodes, seed):
    the policy checked against the robot, one env per episode. Shared with `flashnav bench eval`."""
    from flashnav.sim.env import make_env

    policy, meta, robot, device = load_policy_for(args, device)
    env = make_env(robot, args.episodes, map=args.map, device=device, seed=args.seed)
    return policy, meta, env


def load_policy_for(args, device: str = "cpu"):
    """(policy, metadata, preset, device): the policy of parsed `eval`-style arguments checked against
    ``--robot``, else the robot preset recorded in the policy, with the ``robot.*`` overrides (a RobotPreset, as
    evaluations play it); the device resolved."""
    from flashnav.export import load_policy, recorded_robot
    from flashnav.presets import load_robot
    from flashnav.sim.goal_fields import evaluation_preset
    from flashnav.machine import resolve_device

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    try:
        device = resolve_device(device)
    except ValueError as exc:
        raise ValueError(f"--device: {exc}") from None
    overrides = robot_overrides(args)
    policy, meta = load_policy(args.policy, robot=args.robot)
    if (note := snapshot_note(args.policy)) is not None:
        from rich.console import Console

        Console(stderr=True).print(f"[yellow]note[/]: {note}", soft_wrap=True, markup=True, highlight=False)
    robot = load_robot(args.robot if args.robot is not None else recorded_robot(meta), **overrides)
    if overrides and robot.obs_dim != int(meta["obs_dim"]):
        raise ValueError(f"{' '.join(args.overrides)}: the robot then produces obs_dim {robot.obs_dim}, but the "
                         f"policy expects {meta['obs_dim']} (an override may change what the sensors read, not "
                         "the observation's size)")
    # evaluations play the task with the paper's reward, whatever shaping the policy trained with
    return policy, meta, evaluation_preset(robot), device


def snapshot_note(policy: str | Path) -> str | None:
    """A line when ``policy`` (a run folder or a policy file in one) belongs to a run whose ``metrics.json`` says
    ``stop_reason: running``: a ``--save-every`` snapshot of a run still training (or one that crashed), whose
    best policy may still change - an evaluation of it is not the run's. None otherwise (no metrics.json beside
    it, an unreadable one, or a finished run)."""
    import json

    from flashnav.names import METRICS_FILE, SNAPSHOT_STOP_REASON

    path = Path(policy)
    metrics = (path if path.is_dir() else path.parent) / METRICS_FILE
    try:
        stop = json.loads(metrics.read_text(encoding="utf-8")).get("stop_reason")
    except (OSError, ValueError, AttributeError):
        return None
    if stop != SNAPSHOT_STOP_REASON:
        return None
    return (f"{policy}: its run's {metrics} says stop_reason {stop!r} - a snapshot of a run still training (or "
            "one that stopped without finishing); its best policy may change when the run ends")


def _map_label(args, preset) -> str:
    return str(args.map) if args.map is not None else preset.map


def agent_overrides(args) -> dict:
    """``--agents KEY=VALUE`` items as a mapping (values read as YAML); ``--agents`` without ``--scenario`` is an
    error (the other modes have no agents to change)."""
    from flashnav.yamlio import parse_assignment

    items = getattr(args, "agents", None) or []
    if items and getattr(args, "scenario", None) is None:
        raise ValueError("--agents changes the agents of --scenario; give --scenario NAME too")
    return dict(parse_assignment(item, "--agents") for item in items)


def _scenario_env(args, preset, name: str, device):
    """The env of scenario ``name`` (:mod:`flashnav.scenarios`) for parsed `eval`/`render` arguments: its
    fixed agents, or with ``--robot`` the agent options of the preset named there."""
    from flashnav.scenarios import scenario_preset
    from flashnav.sim.env import make_env

    scenario = scenario_preset(preset, name, own_agents=args.robot is not None, agents=agent_overrides(args))
    return make_env(scenario, args.episodes, map=args.map, device=device, seed=args.seed)


def run_eval(args) -> int:
    from rich.console import Console
    from rich.table import Table

    from flashnav.evaluate import evaluate
    from flashnav.outputs import check_output_file, write_json_report

    if args.map is not None and args.maps is not None:
        raise ValueError("give either --map or --maps, not both")
    if args.json:  # before the evaluation, which may take minutes; never over the policy or the map it reads
        check_output_file(args.json, "--json", inputs=_input_files(args))
    if args.maps is not None and args.scenario is not None:
        raise ValueError("give either --maps or --scenario, not both")
    agent_overrides(args)  # --agents without --scenario: an error before any work
    if args.guide_from is not None and args.guide is None:
        raise ValueError(f"--guide-from {args.guide_from} goes with --guide LOOKAHEAD_M")
    if args.guide is not None and not (math.isfinite(args.guide) and args.guide > 0):  # before the policy loads
        raise ValueError(f"--guide must be > 0 metres, got {args.guide}")
    if args.guide_keep_walls and args.guide_from != "scans":
        raise ValueError("--guide-keep-walls goes with --guide LOOKAHEAD_M --guide-from scans")
    _check_shield(args)
    if args.maps is not None:
        from flashnav.eval_maps import run_eval_maps

        args.robot_overrides = robot_overrides(args)  # for its report (eval_maps does not import this module)
        return run_eval_maps(args, *load_policy_for(args, args.device))
    if args.goal_sampling is not None:
        raise ValueError("--goal-sampling goes with --maps (for one map: --maps FILE.yaml)")
    if args.label is not None:
        raise ValueError(f"--label {args.label} goes with --maps (it names the policy in that JSON and the report)")
    if args.scenario is not None:
        return run_scenarios(args)
    if args.guide is not None:
        raise ValueError("--guide goes with --maps or --scenario (for one map: --maps FILE.yaml)")
    policy, meta, env = load_policy_and_env(args, args.device)
    start = time.perf_counter()
    result = evaluate(policy, env, seed=args.seed)
    seconds = time.perf_counter() - start
    report = {
        "success_rate": result["success_rate"],
        "collision_rate": result["collision_rate"],
        "timeout_rate": result["timeout_rate"],
        "mean_return": result["mean_return"],
        "mean_steps": result["mean_steps"],
        "episodes": env.num_envs,
        "robot": env.preset.name,
        "map": _map_label(args, env.preset),
        "policy": str(args.policy),
        "seed": args.seed,
        "robot_overrides": robot_overrides(args),
        "seconds": seconds,
    }
    console = Console()
    console.print(f"{args.policy} on {report['robot']} / {report['map']}: {report['episodes']} episodes, "
                  f"seed {args.seed}{overrides_label(args)}")
    table = Table(title="flashnav eval")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key in ("success_rate", "collision_rate", "timeout_rate"):
        table.add_row(key.replace("_", " "), f"{100 * report[key]:.1f} %")
    table.add_row("mean return", f"{report['mean_return']:.2f}")
    table.add_row("mean steps", f"{report['mean_steps']:.1f}")
    table.add_row("wall time", f"{seconds:.1f} s")
    console.print(table)
    if args.json:
        write_json_report(args.json, report)
    return 0


def run_scenarios(args) -> int:
    """``flashnav eval --scenario``: one table row per scenario (see :mod:`flashnav.scenarios`)."""
    from rich.console import Console
    from rich.table import Table

    from flashnav.outputs import write_json_report
    from flashnav.scenarios import run_scenario, scenario_names

    names = scenario_names(args.scenario)
    policy, meta, preset, device = load_policy_for(args, args.device)  # no env here: each scenario makes its own
    guide = _scenario_guide(args)
    shield = _people_shield(args, preset)
    how = "" if args.guide is None else f", guided from the {args.guide_from or 'map'} ({args.guide} m)"
    how += "" if shield is None else f", behind a people shield ({args.shield:g} s)"
    table = Table(title=f"flashnav eval --scenario: {args.policy} on {preset.name} / {_map_label(args, preset)}, "
                        f"seed {args.seed}{how}{overrides_label(args)}")
    for col in ("scenario", "scored / drawn", "success", "agent collision", "wall collision", "timeout"):
        table.add_column(col, justify="right")
    if shield is not None:
        table.add_column("shield overruled (steps)", justify="right")
    report = {"robot": preset.name, "map": _map_label(args, preset), "policy": str(args.policy), "seed": args.seed,
              "guide_lookahead_m": args.guide, "guide_from": None if args.guide is None else args.guide_from or "map",
              "guide_keep_walls": bool(args.guide_keep_walls), "agents": agent_overrides(args),
              "shield_s": args.shield, "robot_overrides": robot_overrides(args), "scenarios": {}}
    for name in names:
        r = run_scenario(policy, _scenario_env(args, preset, name, device), args.seed, guide=guide, shield=shield)
        report["scenarios"][name] = r
        table.add_row(name, f"{r['scored']} / {r['episodes']}", *(f"{100 * r[k]:.1f} %" for k in (
            "success_rate", "agent_collision_rate", "wall_collision_rate", "timeout_rate")),
            *(() if shield is None else (f"{100 * r['shield_overruled']:.1f} %",)))
    Console().print(table)
    if args.json:
        write_json_report(args.json, report)
    return 0


def _scenario_guide(args):
    """``--guide`` for ``--scenario``: a callable env -> guide, or None."""
    if args.guide is None:
        return None
    from flashnav.eval_maps import SCANS_GUIDE_CELLS
    from flashnav.guidance import MaplessGuide, PathGuide

    if args.guide_from == "scans":
        def scans(env):
            cells = env.frame_maps[0].shape[0] * env.frame_maps[0].shape[1] * env.num_envs
            if cells > SCANS_GUIDE_CELLS:
                raise ValueError(f"--guide-from scans keeps a memory of the map per episode: {env.num_envs} "
                                 f"episodes x {cells // env.num_envs:,} cells is over {SCANS_GUIDE_CELLS:,}; "
                                 "give fewer --episodes")
            return MaplessGuide(env, lookahead=args.guide, carve=not args.guide_keep_walls)
        return scans
    return lambda env: PathGuide(env, lookahead=args.guide)


def run_render(args) -> int:
    from flashnav.outputs import check_figure_file, check_output_file
    from flashnav.rollout import agent_tracks, rollout, took_over_points, write_gif
    from flashnav.viz import draw_trajectories

    if args.gif and Path(args.out).suffix.lower() == ".gif":
        raise ValueError(f"--out {args.out}: names the trajectories picture, and --gif writes the animation beside "
                         f"it as {Path(args.out).name}: give --out {Path(args.out).with_suffix('.png')}")
    inputs = _input_files(args)  # the policy, and the --map YAML and image: read once for both checks
    out_png = check_figure_file(args.out, "--out", inputs=inputs)  # .png added without a suffix
    agent_overrides(args)  # --agents without --scenario: an error before any work
    _check_shield(args)
    if args.gif:
        check_output_file(out_png.with_suffix(".gif"), "--gif", inputs=inputs)
    if args.scenario is None:
        policy, meta, env = load_policy_and_env(args)
    else:  # only the scenario's env is built
        policy, meta, preset, device = load_policy_for(args)
        env = _scenario_env(args, preset, args.scenario, device)
    shield = _people_shield(args, env.preset)
    result = rollout(policy, env, args.seed, shield=shield)
    poses, length, outcomes = result["poses"], result["length"], result["outcomes"]
    paths = [poses[: length[i], i, :2] for i in range(env.num_envs)]
    tracks = agent_tracks(result)
    counts = {k: outcomes.count(k) for k in ("success", "collision", "timeout")}
    title = (f"{env.preset.name} / {_map_label(args, env.preset)}: {Path(args.policy).name}"
             f"{'' if shield is None else f' behind a {args.shield:g}-s shield'}{overrides_label(args)}, "
             f"{counts['success']}/{env.num_envs} reached, {counts['collision']} collided")
    out = draw_trajectories(env.frame_map, paths, result["goals"], outcomes, out_png, title=title, agents=tracks,
                            shielded=None if shield is None else took_over_points(result))
    print(f"{counts} over {env.num_envs} episodes; trajectories: {out}")
    if args.gif:
        gif = write_gif(env.frame_map, result, env.preset.footprint.circumscribed_radius, out_png.with_suffix(".gif"))
        print(f"animation: {gif}")
    return 0
