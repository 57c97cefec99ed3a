#!/usr/bin/env bash
# The GPU checklist of shared/notes/gpu.md in one script (about 9 minutes on an H100): CUDA tests, the simulator's
# profile and schedules beside the version in BASELINE_REV, bench sim, the paper recipe with and without the CUDA
# graph and the overlap, and a small study. Writes under OUT (default runs/gpu). Each step has its own time limit,
# so a slow step costs its limit, not the rest. Usage: OUT=/tmp/gpu BASELINE_REV=6ac69d2 bash scripts/gpu_checklist.sh
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
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
python3 -c "import torch;print(torch.__version__, torch.cuda.get_device_name())" | tee -a "$OUT/gpu.txt"
echo "== tests $(el)"
timeout 75 python3 -m pytest -q -p no:cacheprovider tests/test_raycast.py tests/test_device_paths.py tests/test_cuda_graph.py \
    -k "cuda or chunking" 2>&1 | tail -4 | tee "$OUT/tests.txt"
echo "== profile $(el)"
BASE=()
if [ -n "${BASELINE_REV:-}" ] && git show "$BASELINE_REV:flashnav/sim/raycast_torch.py" > "$OUT/raycast_torch_base.py" 2>/dev/null; then
  BASE=(--baseline "$OUT/raycast_torch_base.py")
fi
timeout 110 python3 scripts/profile_sim.py --device cuda --robot turtlebot2 --num-envs 1024,4096 --seconds 0.5 "${BASE[@]}" \
    --out "$OUT/prof" 2>&1 | grep -v USDT | tail -36
echo "== bench sim $(el)"
timeout 60 $FN bench sim --device cuda --robots turtlebot2,go2 --raycasters exact-torch,march --num-envs 1024,4096,16384 \
    --seconds 0.5 --no-irsim --json "$OUT/sim.json" 2>&1 | tail -18
echo "== paper recipe, FastDSAC seed 0, CUDA graph $(el)"
timeout 110 $FN train --device cuda --recipe paper --seed 0 raycaster=march eval.episodes=1024 --out "$OUT/t_on" 2>&1 | tail -3
echo "== sequential (overlap=false) $(el)"
timeout 60 $FN train --device cuda --recipe paper --seed 0 raycaster=march overlap=false budget.max_train_seconds=8 \
    eval.episodes=16 --out "$OUT/t_seq" 2>&1 | tail -1
echo "== eager (cuda_graph=off) $(el)"
timeout 60 $FN train --device cuda --recipe paper --seed 0 raycaster=march cuda_graph=off budget.max_train_seconds=8 \
    eval.episodes=16 --out "$OUT/t_off" 2>&1 | tail -1
for d in t_on t_seq t_off; do
  python3 -c "import json;d=json.load(open('$OUT/$d/metrics.json'));print('$d',{k:d.get(k) for k in ('cycle','env_steps','train_seconds','env_steps_to_threshold','time_to_threshold','best_success_rate')})" 2>&1 | tail -1
done
echo "== study $(el)"
timeout $(( 560 - ($(date +%s) - T0) )) $FN bench train --device cuda --recipe paper --robots turtlebot2 \
    --algos fastdsac,fastsac,fasttd3 --seeds 3 raycaster=march eval.episodes=1024 --json "$OUT/train_cuda_paper.json" 2>&1 | tail -25
echo "== end $(el)"
