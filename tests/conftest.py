"""Shared test set-up."""

from __future__ import annotations

import shutil
import tempfile


def start_local_ray(ray, num_cpus: int = 2) -> str:
    """Start a private local Ray cluster for the tests, in a temp dir of its own.

    Ray keeps `session_latest` (how a driver finds the cluster it just started) under its temp dir,
    /tmp/ray by default: with another local cluster running on the machine (a user's sweep, say) the
    two race on that link and the test's driver can end up talking to the other cluster's GCS
    ("InvalidAuthToken" when that one uses token auth). A short path of our own avoids it (Ray's
    socket paths must stay under ~107 characters). Returns the dir; remove it after shutdown."""
    temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")
    ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, _temp_dir=temp_dir)
    return temp_dir


def stop_local_ray(ray, temp_dir: str) -> None:
    ray.shutdown()
    shutil.rmtree(temp_dir, ignore_errors=True)
