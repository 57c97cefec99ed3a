"""``flashnav bench ...`` subcommands: speed claims live here, measured as ratios in one run."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from flashnav.names import DEFAULT_ROBOT, RAYCASTERS, ROBOTS, parse_names

#: `bench sim`'s defaults for the flags that --quick replaces (None on the parser: given or not is told apart).
SIM_DEFAULTS = {"robots": ",".join(ROBOTS), "num_envs": "1,64,1024", "seconds": 2.0}


def register_cli(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="benchmarks (simulator, evaluation, training)")
    bsub = bench.add_subparsers(dest="bench_command", metavar="BENCH")
    p = bsub.add_parser("sim", help="simulator env-steps/s per raycaster x num_envs x robot, vs the paper's march and ir-sim")
    p.add_argument("--robots", default=None, help=f"comma-separated presets (default {SIM_DEFAULTS['robots']})")
    p.add_argument("--raycasters", default="exact,exact-torch,march", help="comma-separated raycasters")
    p.add_argument("--num-envs", default=None, help=f"comma-separated batch sizes (default {SIM_DEFAULTS['num_envs']})")
    p.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N")
    p.add_argument("--seconds", type=float, default=None,
                   help=f"minimum timed seconds per row (default {SIM_DEFAULTS['seconds']:g})")
    p.add_argument("--max-steps", type=int, default=2000, help="maximum timed steps per row")
    p.add_argument("--no-irsim", action="store_true", help="skip the ir-sim peer")
    p.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    p.add_argument("--quick", action="store_true", help="a fast smoke run: turtlebot2, 64 envs, 0.5 s rows")
    p.add_argument("--maps", metavar="K|DIR|GLOB",
                   help="also time every row on many maps, right after the bundled map: K generated maps like "
                        "the robot's own (seeds 1000...), or a directory / glob of ROS map YAML files")
    p.add_argument("--agents", type=int, default=0, metavar="K",
                   help="also time every row with K moving agents per environment (e.g. 8), interleaved with "
                        "the static rows; the table gives the ratio to the static step ('x static')")
    p.add_argument("--tracks", type=int, default=0, metavar="M",
                   help="with --agents: also time every row with those agents and M agent tracks in the "
                        "observation (observation.agent_tracks), interleaved with the others")
    p.add_argument("--memory", type=int, default=0, metavar="F",
                   help="also time every row with the memory scan of F stored scans (observation.memory_frames, "
                        "one stored every step), interleaved with the static rows ('x static')")
    p.add_argument("--wall-map", type=int, default=0, metavar="C",
                   help="also time every row with the wall map of C x C squares (observation.wall_map, the other "
                        "wall-map keys at their defaults), interleaved with the static rows ('x static')")
    p.add_argument("--visited", action="store_true",
                   help="with --wall-map: also time every row with that wall map and its visited channel "
                        "(observation.wall_map_visited), shown as 'C+v'")
    p.add_argument("--plan", action="store_true",
                   help="with --wall-map: also time every row with that wall map and its plan channel "
                        "(observation.wall_map_plan), shown as 'C+p'")
    p.add_argument("--plan-penalty", type=float, default=0.0, metavar="X",
                   help="with --plan: one more row whose plan is the cheapest way at that penalty "
                        "(observation.wall_map_plan_penalty), shown as 'C+pX'")
    p.set_defaults(func=run_sim)
    bench.set_defaults(func=lambda args: bench.print_help() or 2)
    from flashnav.bench import evaluation as bench_eval

    bench_eval.register_cli(bsub)
    from flashnav.bench import update as bench_update

    bench_update.register_cli(bsub)
    from flashnav.bench import train as bench_train

    bench_train.register_cli(bsub)
    from flashnav.bench import runs as bench_runs

    bench_runs.register_cli(bsub)
    from flashnav.bench import cycle as bench_cycle

    bench_cycle.register_cli(bsub)
    from flashnav.bench import plan as bench_plan

    bench_plan.register_cli(bsub)
    from flashnav.bench import shield as bench_shield

    bench_shield.register_cli(bsub)


def _csv(text: str, cast=str) -> list:
    return [cast(x) for x in text.split(",") if x.strip()]


def run_sim(args) -> int:
    from flashnav.bench import sim
    from flashnav.bench.irsim_peer import irsim_available, irsim_steps
    from flashnav.outputs import check_output_file
    from flashnav.presets import load_robot

    console = Console()
    if args.quick:  # the smoke run's own robot, size and seconds: say so rather than ignore what was given
        given = [f for f, v in (("--robots", args.robots), ("--num-envs", args.num_envs), ("--seconds", args.seconds))
                 if v is not None]
        if given:
            raise ValueError(f"--quick runs {DEFAULT_ROBOT}, 64 envs and 0.5-s rows: drop {' and '.join(given)} "
                             "(or --quick)")
        args.robots, args.num_envs, args.seconds = DEFAULT_ROBOT, "64", 0.5
    for key, default in SIM_DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, default)
    robots = _csv(args.robots)
    try:
        sizes = _csv(args.num_envs, int)
    except ValueError:
        raise ValueError(f"--num-envs {args.num_envs}: comma-separated whole numbers >= 1, e.g. 1,64,1024") from None
    if not robots or not sizes or min(sizes) < 1:
        raise ValueError(f"--robots {args.robots!r} and --num-envs {args.num_envs!r}: at least one robot and one "
                         "batch size, every size >= 1")
    for robot in robots:  # every preset before the first row: a typo in the last one must not cost the others
        try:
            load_robot(robot)
        except ValueError as exc:
            raise ValueError(f"--robots {robot}: {exc}") from None
    raycasters = parse_names("raycaster", args.raycasters, RAYCASTERS, "--raycasters")
    if not (args.seconds > 0 and args.max_steps >= 1):
        raise ValueError(f"--seconds must be > 0 and --max-steps >= 1, got {args.seconds} and {args.max_steps}")
    if args.json:
        check_output_file(args.json, "--json")
    seconds = args.seconds
    if args.agents < 0 or args.tracks < 0 or args.memory < 0:
        raise ValueError(f"--agents, --tracks and --memory must be >= 0, got {args.agents}, {args.tracks} and "
                         f"{args.memory}")
    if args.wall_map < 0 or args.wall_map == 1:
        raise ValueError(f"--wall-map must be 0 (none) or at least 2 squares a side, got {args.wall_map}")
    for flag, given in (("--visited", args.visited), ("--plan", args.plan)):
        if given and not args.wall_map:
            raise ValueError(f"{flag} times the wall map's {flag[2:]} channel: it needs --wall-map C")
    if args.plan_penalty and not args.plan:
        raise ValueError(f"--plan-penalty {args.plan_penalty:g} prices the plan channel's cells: it needs --plan")
    if args.tracks and not args.agents:
        raise ValueError(f"--tracks {args.tracks} needs --agents K > 0 (the tracks are of those agents)")
    flags = {"agents.count": "--agents", "observation.agent_tracks": "--tracks",
             "observation.memory_frames": "--memory", "observation.wall_map": "--wall-map",
             "observation.wall_map_visited": "--visited", "observation.wall_map_plan": "--plan",
             "observation.wall_map_plan_penalty": "--plan-penalty"}
    for robot in robots:  # every row's preset before the first row (--wall-map 1000 failed after the static rows)
        for overrides in sim.variant_overrides(args.agents, args.tracks, args.memory, args.wall_map, args.visited,
                                               args.plan, args.plan_penalty):
            try:
                load_robot(robot, **overrides)
            except ValueError as exc:
                given = " ".join(f"{flags[k]} {v}" for k, v in overrides.items() if k in flags and v is not False)
                reason = str(exc).splitlines()[-1].split("}: ", 1)[-1]  # (after the overrides, which repeat the flags)
                raise ValueError(f"{given} on {robot}: {reason}") from None
    from flashnav.machine import learner_threads, machine_name

    machine, threads = machine_name(args.device), learner_threads(args.device)
    when = dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    on = f"{machine}, {threads} torch threads" if threads else machine
    console.print(f"[bold]flashnav bench sim[/] {when} on {on}; each row >= {seconds} s of whole env steps")
    rows, accuracy = [], []
    for robot in robots:
        many = _many_maps(robot, args.maps)
        if many is not None:
            console.print(f"  {robot}: {len(many)} maps for the many-map rows")
        for n in sizes:
            for rc in raycasters:
                # march is orders of magnitude slower: a couple of steps give its rate
                max_steps = 3 if rc == "march" and n >= 64 else args.max_steps
                for row in sim.time_steps(robot, rc, n, args.device, seconds, max_steps, maps=many,
                                          agents=args.agents, tracks=args.tracks, memory=args.memory,
                                          wall_map=args.wall_map, visited=args.visited, plan=args.plan,
                                          plan_penalty=args.plan_penalty):
                    rows.append(row.to_dict(1080))
                    console.print(f"  {robot:10s} {rc:12s} N={n:5d} maps={row.maps:3d} agents={row.agents:2d} "
                                  f"tracks={row.tracks:2d} memory={row.memory:2d} "
                                  f"wall_map={_walls(row.wall_map, row.visited, row.plan, row.plan_penalty)}: "
                                  f"{row.env_steps_per_s:12,.0f} env-steps/s")
        for rc in raycasters:
            if rc != "exact":
                accuracy.append(sim.accuracy(robot, rc, args.device))
    peer = []
    if not args.no_irsim:
        if irsim_available():
            for robot in robots:
                peer.append(irsim_steps(robot, seconds))
        else:
            console.print("[yellow]ir-sim not installed (pip install 'flashnav[bench]'): peer rows skipped[/]")
    _print_tables(console, rows, accuracy, peer)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)  # checked creatable before the rows
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"machine": machine, "threads": threads, "date": when, "argv": sys.argv, "rows": rows,
                       "accuracy": accuracy, "irsim": peer}, f, indent=2)
    return 0


def _many_maps(robot: str, spec: str | None):
    """The many-map set of ``--maps`` for ``robot`` (None without it)."""
    if spec is None:
        return None
    from flashnav.bench import sim
    from flashnav.maps.bundled import resolve_maps

    if spec.isdigit():
        return sim.bench_maps(robot, int(spec))
    return resolve_maps(spec, robot)


def _walls(cells: int, visited: bool, plan: bool = False, penalty: float = 0.0) -> str:
    """A row's wall map as the table shows it: its squares a side, '+v' with the visited channel, '+p' with the
    plan's ('+pX' at a plan penalty X)."""
    return f"{cells}" + "+v" * bool(visited) + "+p" * bool(plan) + (f"{penalty:g}" if plan and penalty else "")


def _print_tables(console: Console, rows: list[dict], accuracy: list[dict], peer: list[dict]) -> None:
    key = lambda r: (r["robot"], r["num_envs"], r["maps"], r["agents"], r.get("tracks", 0), r.get("memory", 0),  # noqa: E731
                     r.get("wall_map", 0), r.get("visited", False), r.get("plan", False))
    base = {key(r): r["env_steps_per_s"] for r in rows if r["raycaster"] == "march"}
    # the static single-map row of the same robot, size and raycaster: the reference of both ratios
    one = {(r["robot"], r["num_envs"], r["raycaster"]): r["env_steps_per_s"] for r in rows
           if r["maps"] == 1 and r["agents"] == 0 and r.get("memory", 0) == 0 and r.get("wall_map", 0) == 0}
    many = any(r["maps"] > 1 for r in rows)
    moving = any(r["agents"] > 0 for r in rows)
    remembers = any(r.get("memory", 0) > 0 for r in rows)
    walls = any(r.get("wall_map", 0) > 0 for r in rows)
    vs_static = moving or remembers or walls  # the 'x static' column: rows with agents, the memory scan or the wall map
    tracked = any(r.get("tracks", 0) > 0 for r in rows)
    t = Table(title="whole env step, random actions (full 1,080-beam scans)")
    for col in ("robot", "raycaster", "envs", *(("maps",) if many else ()), *(("agents",) if moving else ()),
                *(("tracks",) if tracked else ()), *(("memory",) if remembers else ()),
                *(("wall map",) if walls else ()), "env-steps/s", "rays/s", "x march", *(("x 1 map",) if many else ()), *(("x static",) if vs_static else ())):
        t.add_column(col, justify="right")
    for r in rows:
        ref = base.get(key(r))
        ratio = f"{r['env_steps_per_s'] / ref:,.0f}x" if ref else "-"
        cells = [r["robot"], r["raycaster"], str(r["num_envs"])] + ([str(r["maps"])] if many else [])
        cells += [str(r["agents"])] if moving else []
        cells += [str(r.get("tracks", 0))] if tracked else []
        cells += [str(r.get("memory", 0))] if remembers else []
        cells += [_walls(r.get("wall_map", 0), r.get("visited", False), r.get("plan", False),
                         r.get("plan_penalty", 0.0))] if walls else []
        cells += [f"{r['env_steps_per_s']:,.0f}", f"{r['rays_per_s']:,.3g}", ratio]
        single = one.get((r["robot"], r["num_envs"], r["raycaster"]))
        if many:
            cells.append(f"{r['env_steps_per_s'] / single:.2f}x" if single and r["maps"] > 1 else "-")
        if vs_static:
            extra = r["agents"] > 0 or r.get("memory", 0) > 0 or r.get("wall_map", 0) > 0
            cells.append(f"{r['env_steps_per_s'] / single:.2f}x" if single and extra else "-")
        t.add_row(*cells)
    for p in peer:
        t.add_row(p["robot"], "ir-sim (peer)", "1", *(("1",) if many else ()), *(("0",) if moving else ()),
                  *(("0",) if tracked else ()), *(("0",) if remembers else ()), *(("0",) if walls else ()),
                  f"{p['env_steps_per_s']:,.1f}", f"{p['env_steps_per_s'] * p['beams']:,.3g}", "-",
                  *(("-",) if many else ()), *(("-",) if vs_static else ()))
    console.print(t)
    if accuracy:
        a = Table(title="range error vs the exact raycaster (random free poses, metres)")
        for col in ("robot", "raycaster", "mean", "p99", "max", "beams > 5 cm"):
            a.add_column(col, justify="right")
        for r in accuracy:
            a.add_row(r["robot"], r["raycaster"], f"{r['mean']:.4f}", f"{r['p99']:.4f}", f"{r['max']:.4f}",
                      f"{r['frac_over_5cm']:.3%}")
        console.print(a)
