"""``flashnav eval POLICY --maps DIR_OR_GLOB``: one policy on many maps, a table per map (the generalisation
benchmark).

Every map gets the same ``episodes`` fixed episodes: those that a one-map environment on that map draws
with ``reset(seed=seed)`` (:func:`fixed_episodes`), so a map's row does not depend on which other maps
are evaluated beside it, and equals evaluating that map alone. All maps' episodes run together in one
many-map environment (``M x episodes`` slots, slot k on map ``k // episodes``), with the deterministic
policy (:func:`flashnav.evaluate.play_episodes`).

The policy runs on its own robot preset (from its metadata), with the goal band measured by
``goal_sampling`` (``geodesic`` by default here: on maps unlike the training map, the straight-line band
can put goals behind walls farther than the horizon allows; see ``episode.goal_sampling``). The
observation's goal distance is passed to the policy as the environment computes it, as a robot would:
nothing clips it. The policy's input transform was scaled by its training map's diagonal
(``goal_distance_scale``); a map with a larger diagonal is marked, and each row counts the episodes whose
goal-distance input went beyond the scale (inputs the policy never saw in training).

Each map's row also keeps every episode's ending, in the fixed episodes' order (``outcomes``: one letter
per episode, ``s`` success, ``c`` collision, ``t`` timeout), so that an analysis of the same episodes (e.g.
``scripts/greedy_traps.py --outcomes``) can pair its own per-episode reading with the policy's.
"""

from __future__ import annotations

import datetime as dt
import math
import time
from importlib import resources
from pathlib import Path

import torch

from flashnav.evaluate import STALL_M, episode_rates, play_episodes, stalled
from flashnav.guidance import PathGuide
from flashnav.maps.grid import OccupancyMap
from flashnav.maps.validation import spread_episodes
from flashnav.names import BENCHMARK_SUITES
from flashnav.outputs import write_json_report
from flashnav.sim.env import NavVecEnv
from flashnav.sim.goal_fields import evaluation_preset
from flashnav.sim.mapset import sim_frame

#: Version of the ``--json`` layout written by :func:`evaluate_maps` (read by ``flashnav report
#: --generalisation``). Rows written before 2026-11-27 have no ``outcomes``.
EVAL_MAPS_FORMAT = 1
EVAL_MAPS_KIND = "flashnav.eval_maps"
RATES = ("success_rate", "collision_rate", "timeout_rate", "stalled_rate")


def suite_path(maps: str) -> str:
    """``maps`` as given, or the folder of the committed benchmark suite it names (``heldout``, ``real``)
    when no file or folder of that name exists here."""
    if maps in BENCHMARK_SUITES and not Path(maps).exists():
        return str(resources.files("flashnav") / "maps" / "data" / "benchmark" / maps)
    return maps


#: how ``flashnav eval --maps`` draws its episodes unless told otherwise: goals by path length, solvable on any map
SUITE_GOAL_SAMPLING = "geodesic"


def suite_preset(robot, goal_sampling: str | None = None):
    """``robot`` (a preset, its name or YAML) with the episode draws a map suite is played with: ``goal_sampling``,
    else :data:`SUITE_GOAL_SAMPLING`."""
    from flashnav.presets import load_robot

    return load_robot(robot, **{"episode.goal_sampling": goal_sampling or SUITE_GOAL_SAMPLING})


def suite_maps(maps: str, preset) -> list[OccupancyMap]:
    """The maps ``--maps`` names (a committed benchmark suite, a folder, a glob or one map YAML), loaded as ``preset``'s
    map would be; naming nothing is a ValueError that also lists the committed suites."""
    from flashnav.maps.bundled import MapsNotFound, resolve_maps

    try:
        return resolve_maps(suite_path(maps), preset.map)
    except MapsNotFound as exc:  # naming nothing: `eval --maps` also takes the committed suites
        raise ValueError(f"--maps: {exc}; or a committed benchmark suite: {', '.join(BENCHMARK_SUITES)}") from None


def fixed_episodes(env, m: int, count: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``count`` episodes of map ``m`` of ``env``: exactly those that a one-map env on that map (same
    preset and device) draws with ``reset(seed=seed)``. Returns world ``pose`` [count, 3] and ``goal``
    [count, 2], float64 (x, y m; yaw rad)."""
    gen = torch.Generator(device=env.device)
    gen.manual_seed(int(seed))
    pose, goal = env.samplers[m].sample(count, gen)  # the map's simulator frame, as a one-map reset draws
    ox, oy = sim_frame(env.maps[m])
    pose, goal = pose.double(), goal.double()
    pose[:, 0] += ox
    pose[:, 1] += oy
    return pose, goal + torch.tensor([ox, oy], dtype=torch.float64, device=env.device)


class EvalSet:
    """The fixed evaluation set of a training run on maps other than its training maps (``eval.maps``).

    ``episodes`` slots over the ``M`` maps of ``grids`` (:func:`spread_episodes`): slots are in blocks, map
    0's first; map ``m``'s ``n_m`` episodes are those a one-map env on that map with ``n_m`` slots draws with
    ``reset(seed=seed)`` (:func:`fixed_episodes`), with the preset's goal sampling and the paper's
    reward (:func:`~flashnav.sim.goal_fields.evaluation_preset`), so they do not depend on the other maps.
    Every :meth:`evaluate` plays the same episodes (one per slot, deterministic policy) and returns what
    :func:`flashnav.evaluate.evaluate` returns, over all episodes pooled.
    """

    def __init__(self, preset, grids: tuple[OccupancyMap, ...] | list[OccupancyMap], episodes: int, seed: int, *,
                 device: torch.device | str = "cpu", raycaster: str | None = None):
        counts = spread_episodes(episodes, len(grids))
        self.seed, self.counts = int(seed), counts
        self.env = NavVecEnv(evaluation_preset(preset), episodes,
                             grid=grids[0] if len(grids) == 1 else tuple(grids), device=device,
                             seed=seed, raycaster=raycaster)
        poses, goals = zip(*(fixed_episodes(self.env, m, n, seed) for m, n in enumerate(counts)))
        self.pose, self.goal = torch.cat(poses), torch.cat(goals)  # [E, 3], [E, 2] float64, world
        self.map_index = (torch.arange(len(grids), device=self.env.device)
                          .repeat_interleave(torch.tensor(counts, device=self.env.device)) if len(grids) > 1 else None)

    @torch.no_grad()
    def evaluate(self, policy) -> dict[str, float]:
        """success_rate, collision_rate, timeout_rate, mean_return, mean_steps of ``policy`` (obs [k, D] ->
        action [k, 2]) over the set's episodes."""
        self.env.reset(seed=self.seed)  # reseeds the generator the placement draws from (agents, sensor noise)
        obs = self.env.set_state(self.pose, self.goal, map_index=self.map_index)
        e = play_episodes(policy, self.env, obs)
        return episode_rates(e["success"], e["collision"], e["episode_return"], e["episode_steps"])


def map_labels(grids: list[OccupancyMap]) -> list[str]:
    """One label per map: its name, or its file path where two maps share a name."""
    names = [g.name for g in grids]
    return [str(g.source) if names.count(g.name) > 1 and g.source else g.name for g in grids]


@torch.no_grad()
def evaluate_maps(policy, preset, grids: list[OccupancyMap], episodes: int, seed: int, *,
                  goal_distance_scale: float, device: str = "cpu", guide: float | None = None,
                  guide_from: str = "map", guide_carve: bool = True) -> dict:
    """Evaluate the deterministic ``policy`` (obs [k, D] -> action [k, 2]) on ``episodes`` fixed episodes
    per map of ``grids`` (see the module docstring).

    ``guide``: path guidance (:mod:`flashnav.guidance`) with this lookahead in metres; None = the task
    as it is (the policy gets the goal). ``guide_from``: what the guide plans on, ``map`` (the known map,
    :class:`~flashnav.guidance.PathGuide`) or ``scans`` (only what each episode's scans have shown,
    :class:`~flashnav.guidance.MaplessGuide`; maps are then played one at a time, in blocks of slots whose
    per-slot memories fit ``SCANS_GUIDE_CELLS``; ``guide_carve=False``: its wall marks are never forgotten).

    Returns a dict: ``maps`` (one entry per map, in order: label, source, size, resolution, diagonal,
    ``beyond_scale`` = diagonal > ``goal_distance_scale``, ``episodes_beyond_scale`` = episodes whose goal
    distance input exceeded the scale, the three rates as fractions and ``stalled_rate``, the share of episodes
    that timed out with the robot parked (:func:`flashnav.evaluate.stalled`; part of the timeouts), the success
    rate's 95 % interval (:func:`success_interval`), mean steps and return) and
    ``aggregate`` (``mean`` over maps, ``pooled`` over all episodes, the ``worst`` map by success).
    """
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1 per map, got {episodes}")
    if guide_from not in GUIDE_SOURCES:
        raise ValueError(f"guide_from must be one of {GUIDE_SOURCES}, got {guide_from!r}")
    m = len(grids)
    if guide is not None and guide_from == "scans":
        e = _play_scans_guided(policy, evaluation_preset(preset), grids, episodes, seed, device, guide, guide_carve)
    else:
        env = NavVecEnv(evaluation_preset(preset), m * episodes, grid=grids[0] if m == 1 else grids, device=device,
                        seed=seed)
        poses, goals = zip(*(fixed_episodes(env, k, episodes, seed) for k in range(m)))
        map_index = torch.arange(m, device=env.device).repeat_interleave(episodes)
        obs = env.set_state(torch.cat(poses), torch.cat(goals), map_index=map_index if m > 1 else None)
        e = play_episodes(policy, env, obs, guide=None if guide is None else PathGuide(env, lookahead=guide))
    rows = []
    parked = stalled(e)
    for k, (g, label) in enumerate(zip(grids, map_labels(grids))):
        sl = slice(k * episodes, (k + 1) * episodes)
        success, collision = e["success"][sl], e["collision"][sl]
        rows.append({
            "map": label, "source": str(g.source) if g.source else None,
            "width_m": g.width_m, "height_m": g.height_m, "resolution": g.resolution, "diagonal_m": g.diagonal_m,
            "beyond_scale": bool(g.diagonal_m > goal_distance_scale),
            "episodes_beyond_scale": int((e["max_goal_distance"][sl] > goal_distance_scale).sum()),
            "episodes": episodes,
            "success_rate": success.float().mean().item(),
            "success_interval": success_interval(int(success.sum()), episodes),
            "collision_rate": collision.float().mean().item(),
            "timeout_rate": (~success & ~collision).float().mean().item(),
            "stalled_rate": parked[sl].float().mean().item(),
            "mean_steps": e["episode_steps"][sl].mean().item(),
            "mean_return": e["episode_return"][sl].mean().item(),
            "outcomes": outcome_letters(success, collision),
        })
    return {"maps": rows, "aggregate": aggregate(rows)}


def outcome_letters(success: torch.Tensor, collision: torch.Tensor) -> str:
    """One letter per episode: ``s`` success, ``c`` collision, ``t`` timeout (neither)."""
    codes = torch.where(success, 0, torch.where(collision, 1, 2)).tolist()
    return "".join("sct"[c] for c in codes)


GUIDE_SOURCES = ("map", "scans")
#: cells of wall memory and distance field held at once by the scans guide (~5 bytes each)
SCANS_GUIDE_CELLS = 50_000_000


def _play_scans_guided(policy, preset, grids, episodes: int, seed: int, device, lookahead: float,
                       carve: bool = True) -> dict:
    """:func:`play_episodes` with a :class:`~flashnav.guidance.MaplessGuide`, map by map (its memories are
    per map) and in blocks of slots; the starts and goals are each map's fixed ones, as in the one-env path
    (what an env draws while stepping - moving agents, sensor noise - comes from each block's own generator)."""
    from flashnav.guidance import MaplessGuide

    parts = []
    for g in grids:
        pose, goal = fixed_episodes(NavVecEnv(preset, 1, grid=g, device=device, seed=seed), 0, episodes, seed)
        block = max(1, min(episodes, SCANS_GUIDE_CELLS // (g.shape[0] * g.shape[1])))
        for s in range(0, episodes, block):
            e = min(episodes, s + block)
            sub = NavVecEnv(preset, e - s, grid=g, device=device, seed=seed)
            obs = sub.set_state(pose[s:e], goal[s:e])  # float64: far maps' frames stay exact
            parts.append(play_episodes(policy, sub, obs, guide=MaplessGuide(sub, lookahead=lookahead, carve=carve)))
    return {key: torch.cat([p[key] for p in parts]) for key in parts[0]}


#: issue 15's per-map bar: a policy for buildings it never saw succeeds on at least this share of every map's episodes
MAP_BAR = 0.95


def maps_under(rows: list[dict], bar: float = MAP_BAR) -> list[str]:
    """The labels of the per-map rows (``evaluate_maps``' ``maps``) whose success rate is under ``bar``, in order."""
    return [r["map"] for r in rows if r["success_rate"] < bar]


def success_interval(successes: int, episodes: int, confidence: float = 0.95) -> list[float]:
    """The Wilson score interval ``[low, high]`` of a map's success rate from ``successes`` of ``episodes`` fixed
    episodes (scipy's ``binomtest``): how far another draw of as many episodes could read. At 128 episodes a
    map, 121 successes (94.5 %) give about [89.1 %, 97.3 %]: one draw under 95 % is not a map under 95 %."""
    from scipy.stats import binomtest

    ci = binomtest(successes, episodes).proportion_ci(confidence_level=confidence, method="wilson")
    return [float(ci.low), float(ci.high)]


def maps_surely_under(rows: list[dict], bar: float = MAP_BAR) -> list[str]:
    """The labels of the rows whose whole success interval lies under ``bar`` (rows without one: their rate)."""
    return [r["map"] for r in rows if (r.get("success_interval") or [r["success_rate"]] * 2)[1] < bar]


def aggregate(rows: list[dict]) -> dict:
    """``mean``: each rate averaged over maps; ``pooled``: over all episodes (the two agree when every map
    has as many episodes); ``worst``: the map with the lowest success rate (the first of equals)."""
    total = sum(r["episodes"] for r in rows)
    rates = [k for k in RATES if all(k in r for r in rows)]  # a report written before stalled_rate has none
    mean = {k: sum(r[k] for r in rows) / len(rows) for k in rates}
    pooled = {k: sum(r[k] * r["episodes"] for r in rows) / total for k in rates}
    worst = min(rows, key=lambda r: r["success_rate"])
    return {"maps": len(rows), "episodes": total, "mean": mean, "pooled": pooled,
            "worst": {"map": worst["map"], "success_rate": worst["success_rate"]},
            "maps_beyond_scale": sum(r["beyond_scale"] for r in rows),
            "episodes_beyond_scale": sum(r["episodes_beyond_scale"] for r in rows)}


def policy_goal_scale(meta: dict, preset) -> float:
    """The goal-distance scale a loaded policy reads its goal distance with (its run's ``goal_distance_max``), else,
    for files written before it was recorded, the diagonal of ``preset``'s map."""
    return float(meta.get("goal_distance_max") or math.hypot(*preset.map_size))


def default_label(policy: str | Path) -> str:
    """``<folder>/<file>`` of a policy path (``runs/main/policy.onnx`` -> ``main/policy.onnx``)."""
    p = Path(policy)
    return f"{p.parent.name}/{p.name}" if p.parent.name else p.name


def suite_label(maps: str) -> str:
    """A short name for the ``--maps`` argument: a suite name, a folder's name, or the pattern as given."""
    if maps in BENCHMARK_SUITES:
        return maps
    p = Path(maps)
    return p.name if p.is_dir() else str(maps)


def run_eval_maps(args, policy, meta: dict, robot, device) -> int:
    """``flashnav eval POLICY --maps ...``: parsed arguments and the loaded policy, its metadata, robot and
    device from :mod:`flashnav.policy_cli` (which checks the arguments and the output file first)."""
    from flashnav.machine import machine_name

    sampling = args.goal_sampling or SUITE_GOAL_SAMPLING
    preset = suite_preset(robot, sampling)
    scale = policy_goal_scale(meta, preset)
    grids = suite_maps(args.maps, preset)
    start = time.perf_counter()
    guide = getattr(args, "guide", None)
    guide_from = getattr(args, "guide_from", None) or "map"
    keep_walls = bool(getattr(args, "guide_keep_walls", False))
    result = evaluate_maps(policy, preset, grids, args.episodes, args.seed, goal_distance_scale=scale, device=device,
                           guide=guide, guide_from=guide_from, guide_carve=not keep_walls)
    seconds = time.perf_counter() - start
    report = {
        "kind": EVAL_MAPS_KIND, "format_version": EVAL_MAPS_FORMAT,
        "label": args.label or default_label(args.policy), "policy": str(args.policy),
        "suite": suite_label(args.maps), "maps_arg": str(args.maps), "robot": preset.name,
        "goal_sampling": sampling, "goal_band_m": [preset.episode.min_goal_distance, preset.episode.max_goal_distance],
        "episodes_per_map": args.episodes, "seed": args.seed, "goal_distance_scale": scale,
        "guide_lookahead_m": guide, "guide_from": guide_from if guide is not None else None,
        "guide_keep_walls": keep_walls, "robot_overrides": getattr(args, "robot_overrides", None) or {},
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine_name(str(device)), "seconds": seconds, **result,
    }
    print_report(report)
    if args.json:
        write_json_report(args.json, report)
    return 0


def print_report(report: dict) -> None:
    """The per-map table and the aggregate rows, with the goal-distance scale's caveat."""
    from rich.console import Console
    from rich.table import Table

    pct = lambda x: f"{100 * x:.1f} %"  # noqa: E731
    scale = report["goal_distance_scale"]
    console = Console()
    if not console.is_terminal:  # a log or a pipe: wide enough that no map name is cut
        console = Console(width=max(console.width, 132))
    console.print(f"{report['policy']} ({report['robot']}) on {len(report['maps'])} maps of "
                  f"{report['maps_arg']}: {report['episodes_per_map']} episodes per map, seed {report['seed']}, "
                  f"goal sampling {report['goal_sampling']} ({report['goal_band_m'][0]:g}-"
                  f"{report['goal_band_m'][1]:g} m)"
                  + "".join(f", robot.{k}={v}" for k, v in (report.get("robot_overrides") or {}).items()))
    if report.get("guide_lookahead_m") is not None and report.get("guide_from") == "scans":
        console.print(f"mapless guidance: the policy steers at the point {report['guide_lookahead_m']:g} m along a "
                      "path planned on the walls its own scans have shown (no map)")
    elif report.get("guide_lookahead_m") is not None:
        console.print(f"path guidance: the policy steers at the point {report['guide_lookahead_m']:g} m along the "
                      "shortest path (a global planner on the known map; not the zero-shot task)")
    table = Table(title="flashnav eval --maps")
    table.add_column("map", no_wrap=True)
    for col, justify in ( ("size m", "right"), ("cell m", "right"), ("success", "right"),
                         ("95 % interval", "right"), ("collision", "right"), ("timeout", "right"),
                         ("of them stalled", "right"), ("episodes", "right"), ("beyond scale", "right")):
        table.add_column(col, justify=justify)
    for r in report["maps"]:
        beyond = (f"{r['episodes_beyond_scale']} ep" if r["beyond_scale"] else "-")
        low_high = r.get("success_interval")
        interval = f"{100 * low_high[0]:.1f}-{100 * low_high[1]:.1f}" if low_high else "-"
        table.add_row(r["map"], f"{r['width_m']:.1f} x {r['height_m']:.1f}", f"{r['resolution']:g}",
                      pct(r["success_rate"]), interval, pct(r["collision_rate"]), pct(r["timeout_rate"]),
                      pct(r["stalled_rate"]), str(r["episodes"]), beyond)
    agg = report["aggregate"]
    table.add_section()
    for name in ("mean", "pooled"):
        a = agg[name]
        table.add_row(f"{name} over maps" if name == "mean" else "pooled", "", "",
                      pct(a["success_rate"]), "", pct(a["collision_rate"]), pct(a["timeout_rate"]),
                      pct(a["stalled_rate"]), str(agg["episodes"]), "")
    table.add_row(f"worst map: {agg['worst']['map']}", "", "", pct(agg["worst"]["success_rate"]), "", "", "", "", "",
                  "")
    console.print(table)
    under, surely = maps_under(report["maps"]), maps_surely_under(report["maps"])
    line = f"maps under {100 * MAP_BAR:g} % success: {len(under)} of {agg['maps']}"
    if under:
        line += f" ({', '.join(under)}); with the whole 95 % interval under it: {len(surely)}"
        if surely:
            line += f" ({', '.join(surely)})"
    console.print(line)
    if agg["maps_beyond_scale"]:
        console.print(f"{agg['maps_beyond_scale']} of {agg['maps']} maps have a diagonal beyond the policy's "
                      f"goal-distance scale ({scale:.2f} m, its training map's diagonal): 'beyond scale' counts the "
                      f"episodes whose goal-distance input exceeded it ({agg['episodes_beyond_scale']} in all); "
                      f"the input is passed unclipped, as on a robot.")
    console.print(f"'of them stalled': timeouts whose robot drove under {STALL_M:g} m in the second half of the "
                  "horizon (parked, or turning back and forth on the spot); the other timeouts wandered")
    console.print(f"wall time {report['seconds']:.1f} s on {report['machine']}")
