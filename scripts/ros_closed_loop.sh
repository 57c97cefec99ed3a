#!/usr/bin/env bash
# A policy in closed loop over a private ROS 1 master on simulated time: roscore, `flashnav deploy ros POLICY
# [NODE_ARGS...]` and `flashnav deploy sim-robot` playing N episodes of `flashnav eval --maps MAP --episodes N`
# (goals by path length, seed 12345); the outcomes in OUT (JSON), the logs beside it (OUT.node.log, OUT.sim.log).
#   bash scripts/ros_closed_loop.sh policy.onnx building.yaml 32 out.json --guide 0.5
# Needs ROS 1 (scripts/bootstrap.sh installs it where apt is available).
set -u
[ $# -ge 4 ] || { echo "usage: $0 POLICY MAP EPISODES OUT.json [NODE_ARGS...]" >&2; exit 2; }
for f in /opt/ros/*/setup.bash; do [ -f "$f" ] && source "$f"; done
POLICY=$1; MAP=$2; N=$3; OUT=$4; shift 4
PORT=$((12000 + RANDOM % 2000)); D=$(mktemp -d)
export ROS_MASTER_URI=http://127.0.0.1:$PORT ROS_IP=127.0.0.1 ROS_HOME=$D ROS_LOG_DIR=$D/log PYTHONUNBUFFERED=1
unset ROS_HOSTNAME
setsid roscore -p $PORT > $D/roscore.log 2>&1 & RC=$!
for i in $(seq 50); do rosparam list >/dev/null 2>&1 && break; sleep 0.2; done
rosparam set /use_sim_time true
setsid ${PYTHON:-.venv/bin/python} -m flashnav.cli deploy ros "$POLICY" "$@" > $OUT.node.log 2>&1 & NODE=$!
${PYTHON:-.venv/bin/python} -m flashnav.cli deploy sim-robot --map "$MAP" --episodes $N --seed 12345 --goal-sampling geodesic --results $OUT > $OUT.sim.log 2>&1
echo "sim-robot rc=$?"
kill -INT -- -$NODE 2>/dev/null; sleep 1; kill -INT -- -$RC 2>/dev/null; sleep 1; kill -9 -- -$NODE -$RC 2>/dev/null
