#!/usr/bin/env bash
# Ran in full on 2026-11-28 (docs/benchmarks.md "GPU: FastTD3 with the four departures, ten seeds ..."); the GPU
# generalist it pointed to next is scripts/gpu_generalist.sh (run 2026-11-28: "GPU: a first generalist on an H200").
# What this script measures (shared/notes/gpu.md; docs/benchmarks.md's GPU sections say what is done),
# in one script of about 9 minutes on an H100: the CUDA tests, `bench sim` with the exact CUDA kernel for both robots,
# the generalist's cycle on CUDA now that the exact raycaster is one kernel, and the four departures of `paper-mirror`
# on FastTD3 (seeds 0-9 in three lanes, as many as the time allows) to the end of their budgets (nine at once ran out of GPU
# memory and slowed each run 3.5x: "GPU: eight trainings at once"). The default raycaster (`exact`) is the numba.cuda
# kernel on CUDA, the CPU's ranges, so these runs play the CPU's task. Each step has its own time limit, so a slow step
# costs its limit, not the rest. Writes under OUT (default runs/gpu).
# Usage: OUT=/tmp/gpu bash scripts/gpu_checklist.sh
# Without flashnav's dependencies installed (a bare device image), put wheels of gymnasium, farama-notifications,
# pydantic, pydantic-core, annotated-types and typing-inspection in WHEELS (a folder) and they are installed first.
set -o pipefail
OUT=${OUT:-runs/gpu}; mkdir -p "$OUT"
if [ -n "${WHEELS:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$WHEELS"/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
export PYTHONUNBUFFERED=1
FN="python3 -m flashnav.cli"
T0=$(date +%s); el() { echo "[+$(( $(date +%s) - T0 )) s]"; }
left() { echo $(( ${END:-540} - ($(date +%s) - T0) )); }
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
python3 -c "import torch;print(torch.__version__, torch.cuda.get_device_name())" | tee -a "$OUT/gpu.txt"
echo "== tests $(el)"
timeout 90 python3 -m pytest -q -p no:cacheprovider tests/test_raycast_cuda.py tests/test_device_paths.py \
    tests/test_cuda_graph.py tests/test_shield.py -k "gpu or cuda" 2>&1 | tail -4 | tee "$OUT/tests.txt"
echo "== bench sim (Go2; TurtleBot2's rows are in docs) $(el)"
timeout 45 $FN bench sim --device cuda --robots go2 --raycasters exact-cuda,march --num-envs 1024,4096,16384 \
    --seconds 0.5 --no-irsim --json "$OUT/sim.json" 2>&1 | tail -8
echo "== the people shield's cost on CUDA (bench shield; docs: 7.7x the step alone on the CPU) $(el)"
timeout 90 $FN bench shield tests/fixtures/deploy_policy/policy.onnx --device cuda --episodes 512 --repeats 1 \
    --json "$OUT/shield.json" 2>&1 | tail -5
echo "== generalist cycle on CUDA, 1,024 envs $(el)"
timeout -s TERM -k 20 60 $FN train --device cuda --recipe generalist --seed 0 algo.num_envs=1024 budget.max_train_seconds=15 \
    eval.every=100000 --out "$OUT/gen" 2>&1 | tail -1
python3 -c "import json;d=json.load(open('$OUT/gen/metrics.json'));print('generalist', d['env_steps'], round(d['train_seconds'],1), {k:round(v,1) for k,v in d['cycle'].items()})" 2>&1 | tail -1
C="--device cuda eval.episodes=1024 budget.max_train_seconds=100000 threads=1"
echo "== FastTD3 with the four departures, three lanes of seeds, $(left) s $(el)"
lane() { for S in "$@"; do [ "$(left)" -gt 60 ] || break
  timeout -s TERM -k 20 "$(left)" $FN train --algo fasttd3 --recipe paper-mirror --seed "$S" $C --out "$OUT/td3-s$S" \
      > "$OUT/td3-s$S.log" 2>&1; done; }
lane 0 3 6 9 & lane 1 4 7 & lane 2 5 8 &
wait
$FN bench runs "$OUT"/td3-s*/ 2>&1 | tail -14
echo "== end $(el)"
