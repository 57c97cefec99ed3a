#!/usr/bin/env bash
# Session 28, issue 15: a first GPU generalist (TB2, 1,024 envs, 64 updates per step = the CPU recipe's updates per
# env step), with and without a pose trail, side by side, ~200 s of training each, then zero-shot on the held-out suite
# (docs/benchmarks.md "GPU: a first generalist on an H200"). Works in WORK; the held-out JSONs, the eval tables and a
# tarball of the runs (no .pt) go to OUT (the device tool's $OUT), so do not set OUT to WORK.
# Usage (device tool, carry .whl): WHEELS=.whl bash scripts/gpu_generalist.sh   [TS= training s, TT/TE= time limits, EP= episodes]
set -o pipefail
WORK=${WORK:-/tmp/g28}; OUT=${OUT:-runs/gpu-generalist}; mkdir -p "$WORK" "$OUT"
if [ -n "${WHEELS:-}" ]; then   # a bare device image: flashnav's pure-Python dependencies as wheels, as gpu_checklist.sh
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$WHEELS"/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
export PYTHONUNBUFFERED=1
FN="python3 -m flashnav.cli"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$WORK/gpu.txt"
A="--device cuda --recipe generalist --seed 0 algo.num_envs=1024 algo.updates_per_step=64 eval.every=200 budget.max_train_seconds=${TS:-200} budget.max_env_steps=100000000"
arm() { name=$1; shift
  timeout -s TERM -k 20 ${TT:-330} $FN train $A "$@" --out "$WORK/$name" --overwrite > "$WORK/$name.log" 2>&1
  timeout -s TERM -k 10 ${TE:-120} $FN eval "$WORK/$name/policy.onnx" --maps heldout --episodes ${EP:-128} --label "gpu-$name/s0" \
      --json "$WORK/$name.heldout.json" > "$WORK/$name.eval.txt" 2>&1; }
arm gen &
arm gen-trail robot.observation.pose_trail=10 robot.observation.trail_every=10 &
wait
for n in gen gen-trail; do echo "== $n"; tail -3 "$WORK/$n.log"; tail -6 "$WORK/$n.eval.txt"; done
cp "$WORK"/*.heldout.json "$WORK"/*.eval.txt "$OUT"/
tar czf "$OUT/runs.tgz" --exclude='*.pt' -C "$(dirname "$WORK")" "$(basename "$WORK")"
