"""Deploy exported policies on a robot.

``flashnav.deploy.runtime`` / ``scan`` / ``controller``: numpy + onnxruntime only (no torch, no ROS):
load policy.onnx, turn raw scans and odometry into the observation, commands back, the safety states.
``ros1``: the thin ROS 1 node over them; ``sim_robot``: the simulator behind ROS topics (the
closed-loop harness); ``replay``: a policy over a recorded bag. ``flashnav deploy --help``.
"""

from flashnav.deploy.controller import Command, Controller
from flashnav.deploy.runtime import Decision, PolicyRuntime
from flashnav.deploy.scan import Mount, ScanAdapter, SectorLayout

__all__ = ["Command", "Controller", "Decision", "Mount", "PolicyRuntime", "ScanAdapter", "SectorLayout"]
