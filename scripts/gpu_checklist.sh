#!/usr/bin/env bash
# What is left of the GPU checklist (shared/notes/gpu.md; issue 16 item 6 was measured in full by session 49, 2026-11-30,
# and FastDSAC `paper-mirror` on ten TurtleBot2 seeds by session 50: docs/benchmarks.md, the "GPU: ..." sections), most
# wanted first, in one script of about 9 minutes on an H200:
#   1. the CUDA tests (session 50: all 44 passed in 87 s; session 54 added the wall map's device test), a regression
#      check of the GPU paths;
#   2. the wall map's update cost on the GPU (`flashnav bench update --wall-map 24`, eager and cuda-graph, each beside
#      the same update without the map; on the 2-core CPU it costs ~11x the update since session 55's shared
#      encoder; session 71 on an H200: 2.3x with the CUDA graph), and the env step with the map and its plan at
#      penalty 2 beside the step without them (`flashnav bench sim --wall-map 24 --plan --plan-penalty 2`: the plan
#      runs on the CPU, a host sync a step on a GPU);
#   3. issue 15 DM2's best recipe, `generalist-map` (the TurtleBot2 generalist with the wall map, its plan at penalty 2,
#      the plan's carrot at 0.5 m and DrQ's shift; three seeds on the CPU to its 163,840 env steps: held-out
#      99.1-99.5 %, real 98.3-99.1 %, nav2_tb3_sandbox 93.8-98.4 %, docs/benchmarks.md "Stalls, counted; seed 3; the
#      carrot at 0.5 m"), seeds 0 and 1 at once to the generalist's 409,600 env steps (does more data lift the
#      sandbox and mazes_900002?), then each on the held-out suite (128 episodes
#      a map, as on the CPU; the plan runs on the host); their validation curves, with the 163,840 point, are
#      `flashnav bench runs OUT/gen-*/`;
#   4. with what time is left, FastDSAC's `paper-mirror` on Go2 (issue 16 DM1's Go2 bar; since session 76 with the
#      plan's carrot, 10/10 on the CPU, its plan on the host at every step) for seeds 2-7 to the whole budget of
#      401,408 env steps (session 50 ran seeds 0-1 of the recipe before the carrot to it: 1/2), three lanes.
# Read every seconds figure as shared-GPU seconds (lanes run at once).
# Each step has its own time limit, so a slow step costs its limit, not the rest; END (default 540 s) bounds the whole.
# Writes under OUT (default runs/gpu).
# Usage: OUT=/tmp/gpu bash scripts/gpu_checklist.sh
#        DRY=1 OUT=/tmp/gpu-dry bash scripts/gpu_checklist.sh    # every step on the CPU with tiny budgets (checks the
#                                                                 # script itself, a few minutes on 2 cores; no figure)
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
  DEV=cpu; EPISODES=16; HELDOUT=4; BENCH_S=0.2; SIM_ENVS=32
  TINY="algo.num_envs=32 algo.updates_per_step=2 algo.batch_size=64 algo.learning_start=64 budget.max_env_steps=1024"
  TINY="$TINY eval.every=8"; GEN_TINY="$TINY eval.episodes=24 maps.count=2"
else
  DEV=cuda; EPISODES=1024; HELDOUT=128; BENCH_S=5; SIM_ENVS=128,1024; TINY=""; GEN_TINY=""
fi
T0=$(date +%s); el() { echo "[+$(( $(date +%s) - T0 )) s]"; }
left() { echo $(( ${END:-540} - ($(date +%s) - T0) )); }
if [ -z "${DRY:-}" ]; then nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"; fi
$PY -c "import torch;print(torch.__version__, torch.cuda.get_device_name() if torch.cuda.is_available() else 'no CUDA')" \
    | tee -a "$OUT/gpu.txt"

echo "== 1. CUDA tests $(el)"
timeout 240 $PY -m pytest -q -p no:cacheprovider tests/test_raycast_cuda.py tests/test_device_paths.py \
    tests/test_cuda_graph.py tests/test_shield.py -k "gpu or cuda" > "$OUT/tests.txt" 2>&1
echo "pytest exit $? (124: cut by the step's limit)" >> "$OUT/tests.txt"; tail -4 "$OUT/tests.txt"

echo "== 2. the wall map's update cost $(el)"
timeout 120 $FN bench update --device $DEV --ways eager,cuda-graph --seconds $BENCH_S --warmup 8 --wall-map 24 \
    --json "$OUT/update-wallmap.json" > "$OUT/update-wallmap.txt" 2>&1; echo "exit $?"; tail -12 "$OUT/update-wallmap.txt"

echo "== 2b. the env step with the wall map and its plan $(el)"
timeout 120 $FN bench sim --device $DEV --robots turtlebot2 --num-envs $SIM_ENVS --raycasters exact-torch \
    --seconds 2 --no-irsim --wall-map 24 --plan --plan-penalty 2 --json "$OUT/sim-plan.json" \
    > "$OUT/sim-plan.txt" 2>&1; echo "exit $?"
tail -12 "$OUT/sim-plan.txt"

echo "== 3. generalist-map, seeds 0 and 1 to 409,600 env steps, $(left) s left $(el)"
gen() { S=$1; shift
  timeout -s TERM -k 20 "$(( $(left) - 170 ))" $FN train --algo fastdsac --robot turtlebot2 --recipe generalist-map \
      --seed "$S" --device $DEV threads=1 budget.max_env_steps=409600 "$@" $GEN_TINY --out "$OUT/gen-map-s$S" \
      --overwrite > "$OUT/gen-map-s$S.log" 2>&1
  echo "train seed $S exit $?"
  [ -f "$OUT/gen-map-s$S/policy.pt" ] && timeout 140 $FN eval "$OUT/gen-map-s$S/policy.pt" --maps heldout \
      --episodes $HELDOUT --device $DEV --label "map/s$S" --json "$OUT/heldout-map-s$S.json" \
      > "$OUT/heldout-map-s$S.txt" 2>&1; }
gen 0 & gen 1 &
wait
$FN bench runs "$OUT"/gen-*/ --json "$OUT/gen.json" > "$OUT/gen.txt" 2>&1; tail -12 "$OUT/gen.txt"
tail -n 3 "$OUT"/heldout-*.txt

echo "== 4. paper-mirror, FastDSAC, Go2, seeds 2-7, three at once, $(left) s left $(el)"
lane() { for S in "$@"; do [ "$(left)" -gt 90 ] || break
  timeout -s TERM -k 20 "$(( $(left) - 30 ))" $FN train --algo fastdsac --robot go2 --recipe paper-mirror --seed "$S" \
      --device $DEV eval.episodes=$EPISODES budget.max_train_seconds=100000 threads=1 $TINY --out "$OUT/mirror-go2-s$S" \
      --overwrite > "$OUT/mirror-go2-s$S.log" 2>&1; done; }
lane 2 5 & lane 3 6 & lane 4 7 &
wait
$FN bench runs "$OUT"/mirror-*/ --json "$OUT/mirror.json" > "$OUT/mirror.txt" 2>&1; tail -24 "$OUT/mirror.txt"
echo "== end $(el)"
