#!/usr/bin/env bash
# Create or refresh the project's virtual environment (.venv) so that the README's commands work on a
# fresh machine. Idempotent: re-installs only when pyproject.toml changed since the last run.
# On a machine without an NVIDIA GPU it installs a CPU-only torch build (no multi-GB CUDA wheels).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${FLASHNAV_VENV:-.venv}
stamp="$VENV/.flashnav-installed"
want=$(sha256sum pyproject.toml | cut -c1-16)

# ROS 1 for `flashnav deploy ros|sim-robot|replay` and its closed-loop test: Debian's packages, installed
# once where apt-get is available and we are root (or have sudo); anywhere else the deploy runtime still
# works and the ROS tests skip with a message. FLASHNAV_SKIP_ROS=1 skips this step.
ros_pkgs="ros-core python3-rospy python3-sensor-msgs python3-geometry-msgs python3-nav-msgs python3-rosbag"
if [ "${FLASHNAV_SKIP_ROS:-0}" != 1 ] && ! { command -v roscore >/dev/null 2>&1 \
     && /usr/bin/python3 -c "import rospy, rosbag, sensor_msgs.msg, nav_msgs.msg, geometry_msgs.msg" 2>/dev/null; }; then
  as_root=()
  [ "$(id -u)" = 0 ] || { command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null && as_root=(sudo -n); }
  if command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" = 0 ] || [ "${#as_root[@]}" -gt 0 ]; }; then
    echo "[bootstrap] installing ROS 1 (Debian packages: $ros_pkgs) for flashnav deploy" >&2
    { "${as_root[@]}" apt-get update -qq && "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -qq --no-install-recommends $ros_pkgs >/dev/null; } \
      || echo "[bootstrap] could not install ROS 1: flashnav deploy ros/sim-robot/replay and their tests are unavailable" >&2
  else
    echo "[bootstrap] ROS 1 not installed (needs apt-get as root): flashnav deploy ros/sim-robot/replay and their tests are unavailable" >&2
  fi
fi

if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$VENV/bin/python" -c "import flashnav" 2>/dev/null; then
  exit 0
fi
echo "[bootstrap] setting up $VENV (first run takes a few minutes)" >&2
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
pip() { "$VENV/bin/python" -m pip --disable-pip-version-check "$@"; }

if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
  if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
    echo "[bootstrap] NVIDIA GPU found: installing torch with CUDA" >&2
    pip install -q torch
  else
    echo "[bootstrap] no NVIDIA GPU: installing a CPU-only torch" >&2
    # a CPU build offered by the configured indexes/find-links, else PyTorch's own CPU index
    pip install -q "torch==${FLASHNAV_TORCH_CPU_VERSION:-2.13.0}+cpu" 2>/dev/null \
      || pip install -q --isolated torch --index-url https://download.pytorch.org/whl/cpu
  fi
fi
pip install -q -e ".[dev]"
if pip list 2>/dev/null | grep -qi '^nvidia-' && ! command -v nvidia-smi >/dev/null 2>&1; then
  echo "[bootstrap] warning: CUDA packages were installed on a machine without a GPU" >&2
fi
echo "$want" > "$stamp"
