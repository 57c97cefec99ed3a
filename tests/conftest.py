"""Shared test set-up: one private local Ray cluster for the whole session, and a folder of two small
held-out maps (``small_heldout_maps``) for the tests that play a map suite as a user's folder.

The cluster runs in a temp dir of its own and with an explicit ``RAY_AUTH_MODE=disabled`` (it listens on
127.0.0.1 only). Both matter on Ray >= 2.59:

- Ray keeps `session_latest` (how a driver finds the cluster it just started) under its temp dir,
  /tmp/ray by default: with another local cluster running on the machine the two race on that link and
  the test's driver can end up talking to the other cluster's GCS.
- With RAY_AUTH_MODE unset, a new local ``ray.init()`` turns token auth on and writes ~/.ray/auth_token
  (a test must not write the user's home), and with the variable left over as ``token`` by anything
  earlier in the process the GCS starts in token mode without a token and dies ("Token authentication
  is enabled but Ray couldn't find an authentication token", seen in CI as InvalidAuthToken). The
  fixture sets the mode for the session and puts the environment back afterwards.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile

import pytest

AUTH = "RAY_AUTH_MODE"


@pytest.fixture(scope="session")
def ray_session():
    """The private Ray cluster (started on first use, shut down at the end of the session).

    Test modules whose functions run inside Ray workers call ``ship_by_value(__name__)``: workers
    cannot import test modules (tests/ is not a package on their path)."""
    import ray

    started = not ray.is_initialized()
    previous = os.environ.get(AUTH)
    temp_dir = None
    if started:
        os.environ[AUTH] = "disabled"
        temp_dir = tempfile.mkdtemp(prefix="ray-", dir="/tmp")  # short: Ray's socket paths have a length limit
        ray.init(address="local", num_cpus=2, include_dashboard=False, _temp_dir=temp_dir)
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()
            shutil.rmtree(temp_dir, ignore_errors=True)
            if previous is None:
                os.environ.pop(AUTH, None)
            else:
                os.environ[AUTH] = previous


#: the two smallest maps of the committed held-out suite (9 x 10 m, 7 x 12 m at 0.1 m)
SMALL_HELDOUT = ("rooms_900003", "warehouses_900002")


@pytest.fixture
def small_heldout_maps(tmp_path):
    """A folder holding copies of ``SMALL_HELDOUT`` (YAML and image): a user's own map folder for ``--maps``."""
    from pathlib import Path

    from flashnav.eval_maps import suite_path

    maps = tmp_path / "maps"
    maps.mkdir()
    for name in SMALL_HELDOUT:
        for suffix in (".yaml", ".png"):
            (maps / f"{name}{suffix}").write_bytes((Path(suite_path("heldout")) / f"{name}{suffix}").read_bytes())
    return maps


def ship_by_value(module_name: str) -> None:
    """Pickle a test module's functions by value so Ray workers can run them."""
    import ray

    ray.cloudpickle.register_pickle_by_value(sys.modules[module_name])
