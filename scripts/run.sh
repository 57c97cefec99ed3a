#!/usr/bin/env bash
# The main job on the embedded defaults: set everything up, then run `flashnav` with the given
# arguments (default: the simulator demo and the simulator benchmark).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
if [ "$#" -gt 0 ]; then
  exec .venv/bin/flashnav "$@"
fi
.venv/bin/flashnav demo
exec .venv/bin/flashnav bench sim --robots turtlebot2 --num-envs 64,1024
