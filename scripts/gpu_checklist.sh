#!/usr/bin/env bash
# What is left of the GPU checklist (shared/notes/gpu.md; issue 16 item 6 was measured in full by session 49, 2026-11-30,
# and FastDSAC `paper-mirror` on ten TurtleBot2 seeds by session 50: docs/benchmarks.md, the "GPU: ..." sections), most
# wanted first, in one script of about 9 minutes on an H200:
#   1. the CUDA tests (session 50: all 44 passed in 87 s; session 54 added the wall map's device test), a regression
#      check of the GPU paths;
#   2. the wall map's update cost on the GPU (`flashnav bench update --wall-map 24`, eager and cuda-graph, each beside
#      the same update without the map; on the 2-core CPU it costs ~11x the update since session 55's shared
#      encoder: docs/benchmarks.md);
#   3. issue 15 DM2's reinforcement-learning run with the wall map to the whole budget (observation.wall_map; session
#      55 ran seed 0 on the CPU to 171,264 env steps: a faster climb, no higher plateau; session 56 added DrQ's
#      random shift of the map, algo.wall_shift=1, to 162,944: the best policy yet, docs/benchmarks.md): the
#      TurtleBot2 `generalist` recipe, FastDSAC seed 0, with a 24 x 24 wall map shifted by up to one square and,
#      beside it, without the map (the recipe itself), both to the recipe's 409,600 env steps, then each on the
#      held-out suite (256 episodes a map);
#      the runs' validation curves are `flashnav bench runs OUT/gen-*/`;
#   4. with what time is left, FastDSAC's `paper-mirror` on Go2 (issue 16 DM1's Go2 bar, 20/30 on the CPU) for seeds
#      2-7 to the whole budget of 401,408 env steps (session 50 ran seeds 0-1 to it: 1/2), three lanes.
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
  DEV=cpu; EPISODES=16; HELDOUT=4; BENCH_S=0.2; TINY="algo.num_envs=32 algo.updates_per_step=2 algo.batch_size=64 \
algo.learning_start=64 budget.max_env_steps=1024 eval.every=8"; GEN_TINY="$TINY eval.episodes=24 maps.count=2"
else
  DEV=cuda; EPISODES=1024; HELDOUT=256; BENCH_S=5; TINY=""; GEN_TINY=""
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

echo "== 3. generalist with and without the wall map, seed 0, $(left) s left $(el)"
gen() { NAME=$1; shift
  timeout -s TERM -k 20 "$(( $(left) - 60 ))" $FN train --algo fastdsac --robot turtlebot2 --recipe generalist --seed 0 \
      --device $DEV threads=1 "$@" $GEN_TINY --out "$OUT/gen-$NAME-s0" --overwrite > "$OUT/gen-$NAME-s0.log" 2>&1
  echo "train $NAME exit $?"
  [ -f "$OUT/gen-$NAME-s0/policy.pt" ] && timeout 50 $FN eval "$OUT/gen-$NAME-s0/policy.pt" --maps heldout \
      --episodes $HELDOUT --device $DEV --label "$NAME/s0" --json "$OUT/heldout-$NAME-s0.json" \
      > "$OUT/heldout-$NAME-s0.txt" 2>&1; }
gen wallmap robot.observation.wall_map=24 algo.wall_shift=1 & gen plain &
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
