#!/usr/bin/env bash
# The main job on the embedded defaults: set everything up, train a TurtleBot2 policy with FastDSAC
# (the recipe for this machine: `cpu` without a GPU, the paper's with one), then score the exported
# policy on 1,024 fresh solvable episodes. With arguments, runs `flashnav ARGS...` instead.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
if [ "$#" -gt 0 ]; then
  exec .venv/bin/flashnav "$@"
fi
out=runs/main
.venv/bin/flashnav train --out "$out"
exec .venv/bin/flashnav eval "$out/policy.pt" --episodes 1024 --seed 2026 --json "$out/eval.json"
