#!/usr/bin/env bash
# What is left of the GPU checklist (shared/notes/gpu.md; issue 16 item 6), most wanted first, in one script of about
# 8 minutes on an H100 (the earlier parts ran 2026-11-26..28: docs/benchmarks.md, the "GPU: ..." sections):
#   1. the CUDA tests, the people shield's among them (written after the last GPU session: never run on a GPU);
#   2. issue 16 item 6's study: the `paper` recipe on TurtleBot2, 3 seeds per learner, to the paper's budget of 200,704
#      env steps or 100 % of 1,024 fixed evaluation episodes (so far on a GPU: FastDSAC 1 seed, FastSAC 2, FastTD3 1
#      cut short). One lane per learner, three trainings at once (nine at once ran out of GPU memory and slowed each
#      run 3.5x: "GPU: eight trainings at once"), so read its seconds as shared-GPU seconds and its env steps as the
#      study's figures. The default raycaster `exact` is the numba.cuda kernel on CUDA: the CPU's task;
#   3. `flashnav bench shield --device cuda` (the shield's cost on a CUDA simulator; on the CPU 7.7x the step alone).
# Each step has its own time limit, so a slow step costs its limit, not the rest; END (default 540 s) bounds the whole.
# Writes under OUT (default runs/gpu); the table of step 2 is `flashnav bench runs OUT/paper-*/`.
# Usage: OUT=/tmp/gpu bash scripts/gpu_checklist.sh
#        DRY=1 OUT=/tmp/gpu-dry bash scripts/gpu_checklist.sh    # every step on the CPU with tiny budgets (checks the
#                                                                 # script itself, ~3 min on 2 cores; no figure)
# Without flashnav's dependencies installed (a bare device image), put wheels of gymnasium, farama-notifications,
# pydantic, pydantic-core, annotated-types and typing-inspection in WHEELS (a folder) and they are installed first.
set -o pipefail
OUT=${OUT:-runs/gpu}; mkdir -p "$OUT"
if [ -n "${WHEELS:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$WHEELS"/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
export PYTHONUNBUFFERED=1
PY=${PY:-python3}
FN="$PY -m flashnav.cli"
if [ -n "${DRY:-}" ]; then
  DEV=cpu; EPISODES=16; TINY="algo.num_envs=32 algo.updates_per_step=2 algo.batch_size=64 algo.learning_start=64 \
budget.max_env_steps=1024 eval.every=8"
else
  DEV=cuda; EPISODES=1024; TINY=""
fi
T0=$(date +%s); el() { echo "[+$(( $(date +%s) - T0 )) s]"; }
left() { echo $(( ${END:-540} - ($(date +%s) - T0) )); }
if [ -z "${DRY:-}" ]; then nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"; fi
$PY -c "import torch;print(torch.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else 'no CUDA')" \
    | tee -a "$OUT/gpu.txt"

echo "== 1. CUDA tests $(el)"
timeout 100 $PY -m pytest -q -p no:cacheprovider tests/test_raycast_cuda.py tests/test_device_paths.py \
    tests/test_cuda_graph.py tests/test_shield.py -k "gpu or cuda" 2>&1 | tail -4 | tee "$OUT/tests.txt"

echo "== 2. the paper recipe, TurtleBot2, 3 seeds per learner, one lane each, $(left) s left $(el)"
lane() { local algo=$1; shift; for S in "$@"; do [ "$(left)" -gt 90 ] || break
  timeout -s TERM -k 20 "$(( $(left) - 70 ))" $FN train --algo "$algo" --recipe paper --seed "$S" --device $DEV \
      eval.episodes=$EPISODES budget.max_train_seconds=100000 threads=1 $TINY --out "$OUT/paper-$algo-s$S" --overwrite \
      > "$OUT/paper-$algo-s$S.log" 2>&1; done; }
lane fastdsac 0 1 2 & lane fastsac 0 1 2 & lane fasttd3 0 1 2 &
wait
$FN bench runs "$OUT"/paper-*/ 2>&1 | tail -16 | tee "$OUT/paper.txt"

echo "== 3. the people shield's cost on $DEV $(el)"
timeout 60 $FN bench shield tests/fixtures/deploy_policy/policy.onnx --device $DEV --episodes $(( EPISODES / 2 )) \
    --repeats 1 --json "$OUT/shield.json" 2>&1 | tail -5
echo "== end $(el)"
