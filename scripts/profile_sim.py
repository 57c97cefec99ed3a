"""Where a simulator step's time goes on a device, and what the torch raycasters' schedules cost.

1. Raycaster alone, side by side in one run: each torch raycaster (``exact-torch``, ``march``) at
   its defaults and with other batch / chunk settings, optionally beside the same class from another
   version of ``raycast_torch.py`` (``--baseline FILE``, e.g. ``git show REV:flashnav/sim/raycast_torch.py``),
   on the robot's bundled map at the poses of a stepped environment: ms per call and rays/s, and
   whether the ranges equal the default's.
2. Whole ``env.step`` per raycaster, and one step under ``torch.profiler``: the top ops by device
   time and the host-side synchronisations (``aten::nonzero`` and friends), written as text.

    python scripts/profile_sim.py --device cuda --robot turtlebot2 --num-envs 1024,4096 --out /tmp/prof
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import torch

from flashnav.sim.env import make_env
from flashnav.sim.raycast_torch import MarchRaycaster, TorchExactRaycaster


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn, device: torch.device, seconds: float) -> tuple[float, int]:
    """Mean seconds per call of ``fn`` over at least ``seconds`` (and 3 calls) after 2 warm-up calls."""
    for _ in range(2):
        fn()
    _sync(device)
    calls, start = 0, time.perf_counter()
    while calls < 3 or time.perf_counter() - start < seconds:
        fn()
        calls += 1
        _sync(device)
    return (time.perf_counter() - start) / calls, calls


def variants(env, baseline) -> list[tuple[str, object]]:
    """(label, raycaster) pairs on the env's map and beams."""
    grid, angles, rmax, dev = env.frame_maps[0], env.beam_angles, env.preset.lidar.max_range, env.device
    step = env.preset.lidar.march_step
    out = [("exact-torch default", TorchExactRaycaster(grid, angles, rmax, dev)),
           ("exact-torch batch 2^18", TorchExactRaycaster(grid, angles, rmax, dev, max_batch_rays=1 << 18)),
           ("exact-torch lines 8 jumps 4", TorchExactRaycaster(grid, angles, rmax, dev, chunk_lines=8, jumps_per_round=4)),
           ("exact-torch lines 16 jumps 6", TorchExactRaycaster(grid, angles, rmax, dev, chunk_lines=16, jumps_per_round=6)),
           ("march default", MarchRaycaster(grid, angles, rmax, dev, step=step)),
           ("march batch 2^18", MarchRaycaster(grid, angles, rmax, dev, step=step, max_batch_rays=1 << 18)),
           ("march growth 1", MarchRaycaster(grid, angles, rmax, dev, step=step, chunk_growth=1)),
           ("march growth 2", MarchRaycaster(grid, angles, rmax, dev, step=step, chunk_growth=2)),
           ("march chunk 64", MarchRaycaster(grid, angles, rmax, dev, step=step, chunk_steps=64)),
           ("march chunk 128", MarchRaycaster(grid, angles, rmax, dev, step=step, chunk_steps=128))]
    if baseline is not None:
        out += [("exact-torch BASELINE", baseline.TorchExactRaycaster(grid, angles, rmax, dev)),
                ("march BASELINE", baseline.MarchRaycaster(grid, angles, rmax, dev, step=step))]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--robot", default="turtlebot2")
    ap.add_argument("--num-envs", default="1024,4096", help="comma-separated")
    ap.add_argument("--seconds", type=float, default=1.0, help="per timed row")
    ap.add_argument("--baseline", type=Path, help="another raycast_torch.py to time beside this one")
    ap.add_argument("--no-profile", action="store_true", help="skip the torch.profiler step")
    ap.add_argument("--out", type=Path, required=True, help="folder for profile_sim.json and the profiler tables")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    baseline = None
    if args.baseline is not None:
        spec = importlib.util.spec_from_file_location("raycast_torch_baseline", args.baseline)
        baseline = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(baseline)
    rows: list[dict] = []
    for n in (int(v) for v in args.num_envs.split(",")):
        env = make_env(args.robot, n, device=args.device, seed=0, raycaster="march")
        dev = env.device
        env.reset(seed=0)
        gen = torch.Generator(device=dev).manual_seed(0)
        for _ in range(5):  # poses spread over the map, as in training
            env.step(torch.rand(n, 2, generator=gen, device=dev) * 2 - 1)
        pose = env.pose.clone()
        defaults: dict[str, torch.Tensor] = {}
        for label, rc in variants(env, baseline):
            family = label.split()[0]
            ranges = rc(pose)
            same = None if label.endswith("default") else bool(torch.equal(ranges, defaults[family]))
            defaults.setdefault(family, ranges)
            sec, calls = timed(lambda: rc(pose), dev, args.seconds)
            row = {"kind": "raycast", "num_envs": n, "label": label, "ms": sec * 1e3, "calls": calls,
                   "rays_per_s": pose.shape[0] * env.beam_angles.numel() / sec, "equal_to_default": same}
            rows.append(row)
            print(f"{n:6d} envs  {label:32s} {sec * 1e3:9.2f} ms  {row['rays_per_s'] / 1e6:8.1f} M rays/s  "
                  f"same={same}", flush=True)
        del env
        for rc_name in ("exact-torch", "march"):
            env = make_env(args.robot, n, device=args.device, seed=0, raycaster=rc_name)
            env.reset(seed=0)
            acts = [torch.rand(n, 2, generator=gen, device=dev) * 2 - 1 for _ in range(8)]
            k = [0]

            def step():
                env.step(acts[k[0] % 8])
                k[0] += 1
            sec, calls = timed(step, dev, args.seconds)
            rows.append({"kind": "env.step", "num_envs": n, "label": rc_name, "ms": sec * 1e3, "calls": calls,
                         "env_steps_per_s": n / sec})
            print(f"{n:6d} envs  env.step {rc_name:23s} {sec * 1e3:9.2f} ms  {n / sec:10.0f} env-steps/s", flush=True)
            if not args.no_profile:
                from torch.profiler import ProfilerActivity, profile
                acts_ = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.type == "cuda" else [])
                with profile(activities=acts_) as prof:
                    for _ in range(3):
                        step()
                    _sync(dev)
                key = "cuda_time_total" if dev.type == "cuda" else "cpu_time_total"
                text = prof.key_averages().table(sort_by=key, row_limit=25)
                counts = {e.key: e.count for e in prof.key_averages()
                          if e.key in ("aten::nonzero", "aten::item", "aten::_local_scalar_dense", "cudaStreamSynchronize",
                                       "cudaMemcpyAsync", "aten::index", "aten::index_put_", "cudaLaunchKernel")}
                (args.out / f"profile_{args.robot}_{rc_name}_{n}.txt").write_text(
                    f"3 env.step calls, {n} envs, {rc_name}, {dev}\ncounts: {counts}\n\n{text}\n")
                print(f"        3 steps: {counts}", flush=True)
            del env
    (args.out / "profile_sim.json").write_text(json.dumps(
        {"device": torch.cuda.get_device_name() if torch.device(args.device).type == "cuda" else args.device,
         "torch": torch.__version__, "robot": args.robot, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
