"""How often does one policy read 100 % on E fixed evaluation episodes? (docs/benchmarks.md, issue 16.)

    .venv/bin/python scripts/eval_sizes.py POLICY [--episodes 64,256,1024] [--seeds 20] [--json OUT]

Evaluates the exported POLICY (policy.pt / policy.onnx) with :func:`flashnav.evaluate.evaluate` on
``--seeds`` freshly seeded sets of each size (the robot and map recorded in the policy) and prints the
mean / min / max success and how many sets read 100 %.
"""

from __future__ import annotations

import argparse
import json

from flashnav.evaluate import evaluate
from flashnav.export import evaluated_robot, load_policy
from flashnav.metrics import reaches
from flashnav.sim.env import make_env


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy")
    p.add_argument("--episodes", default="64,256,1024", help="comma-separated evaluation-set sizes")
    p.add_argument("--seeds", type=int, default=20, help="evaluation seeds 0..S-1 per size")
    p.add_argument("--json", help="write every success rate here")
    args = p.parse_args()
    policy, meta = load_policy(args.policy)
    preset = evaluated_robot(meta)  # the policy's own observation, the paper's reward
    out = {}
    for episodes in (int(e) for e in args.episodes.split(",")):
        rates = [evaluate(policy, make_env(preset, episodes, seed=seed), seed)["success_rate"]
                 for seed in range(args.seeds)]
        out[episodes] = rates
        print(f"{episodes:5d} episodes: success mean {sum(rates) / len(rates):.4f}, min {min(rates):.4f}, "
              f"max {max(rates):.4f}; read 100 % in {sum(reaches(r, 1.0) for r in rates)}/{len(rates)} sets",
              flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
