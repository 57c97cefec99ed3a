"""The replay's wall-map columns as uint8 against float32: memory and sampling time, side by side in one run.

    .venv/bin/python scripts/replay_bits_timing.py [--repeats 20] [--wall-map 24] \
        [--before OLD/flashnav/learn/replay.py]

Two buffers of the generalist recipe's shape (num_envs, buffer_size, batch_size, updates_per_step, n_step, with
``robot.observation.wall_map`` C) are filled with the same random transitions whose last 2 C^2 observation columns
are 0 / 1: one keeps every column as float32 (``binary_columns=0``), the other the wall map's squares as uint8 (what
``flashnav train`` builds). Each then draws a cycle's batches (``sample(batch_size, updates_per_step)``), the two
alternating A B B A, and the script prints each buffer's bytes, the median milliseconds per draw and their ratio,
and checks that the two buffers drew the same batches. ``--before``: also time the replay module of another
checkout (e.g. a ``git worktree`` of an older commit; all float32, its own gather) as a third buffer, in the same
rotation, with the same check.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time

import torch

from flashnav.learn.replay import Replay
from flashnav.machine import machine_name
from flashnav.spec import config_from_cli, resolve


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20, help="draws per buffer (alternating A B B A)")
    ap.add_argument("--wall-map", type=int, default=24, help="robot.observation.wall_map: squares a side")
    ap.add_argument("--before", default=None, metavar="REPLAY_PY", help="another checkout's flashnav/learn/replay.py")
    args = ap.parse_args()
    spec = resolve(config_from_cli(None, {"recipe": "generalist", "device": "cpu"},
                                   [f"robot.observation.wall_map={args.wall_map}"]))
    hp, robot = spec.hparams, spec.robot
    bits = robot.obs_dim - robot.memory_end
    g = torch.Generator().manual_seed(0)
    buffers = {name: Replay(hp.num_envs, robot.obs_dim, 2, hp.buffer_size, seed=1, n_step=hp.n_step, gamma=hp.gamma,
                            binary_columns=b) for name, b in (("float32", 0), ("uint8", bits))}
    if args.before:
        spec_file = importlib.util.spec_from_file_location("replay_before", args.before)
        before = importlib.util.module_from_spec(spec_file)
        spec_file.loader.exec_module(before)
        buffers["before"] = before.Replay(hp.num_envs, robot.obs_dim, 2, hp.buffer_size, seed=1, n_step=hp.n_step,
                                          gamma=hp.gamma)
    for _ in range(buffers["uint8"].rows_per_env):
        obs = torch.cat((torch.rand(hp.num_envs, robot.obs_dim - bits, generator=g),
                         (torch.rand(hp.num_envs, bits, generator=g) < 0.2).float()), dim=-1)
        step = (obs, torch.rand(hp.num_envs, 2, generator=g), torch.randn(hp.num_envs, generator=g),
                torch.rand(hp.num_envs, generator=g) < 0.02, obs.roll(1, 0),
                torch.rand(hp.num_envs, generator=g) < 0.05)
        for replay in buffers.values():
            replay.add(*step)
    times: dict[str, list[float]] = {name: [] for name in buffers}
    names = list(buffers)
    order = [name for i in range(args.repeats) for name in (names if i % 2 == 0 else names[::-1])]
    drawn: dict[str, list] = {name: [] for name in buffers}
    for name in order:
        start = time.perf_counter()
        batch = buffers[name].sample(hp.batch_size, hp.updates_per_step)
        times[name].append(time.perf_counter() - start)
        drawn[name].append(batch)
    same = all(torch.equal(x, y) for name in names[1:] for a, b in zip(drawn["float32"], drawn[name])
               for x, y in zip(a, b))
    print(f"{machine_name()}, torch threads {torch.get_num_threads()}; {hp.num_envs} envs, buffer {hp.buffer_size:,}, "
          f"{hp.updates_per_step} x {hp.batch_size} rows a draw, {hp.n_step}-step; obs {robot.obs_dim} columns, "
          f"{bits} of them the wall map")
    for name, replay in buffers.items():
        fields = ("obs", "obs_bits", "action", "reward", "terminated", "next_obs", "next_obs_bits", "ended")
        nbytes = sum(t.nbytes for t in (getattr(replay, f, None) for f in fields) if t is not None)
        print(f"  {name:8s} {nbytes / 1e9:6.2f} GB   {1e3 * statistics.median(times[name]):7.2f} ms a draw (median of "
              f"{len(times[name])})")
    for name in names[1:]:
        ratio = statistics.median(times["float32"]) / statistics.median(times[name])
        print(f"{name} draws at {ratio:.2f}x the float32 buffer's speed")
    print(f"the same batches from every buffer: {same}")


if __name__ == "__main__":
    main()
