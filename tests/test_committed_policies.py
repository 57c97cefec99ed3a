"""The committed policies (docs/policies): each loads in the deploy runtime, its ONNX input is the width its
metadata records, and its recorded request (config.yaml) resolves, with today's recipes, to that observation - or,
for the one docs/policies/README.md says the recipe now resolves differently, to it with the overrides the README
names."""

from __future__ import annotations

from pathlib import Path

import pytest

from flashnav.request import config_from_cli
from flashnav.spec import resolve

pytest.importorskip("onnxruntime")

POLICIES = Path(__file__).resolve().parent.parent / "docs" / "policies"
#: the README's overrides that train the Go2 policy of before session 76 again: no wall map, so no plan or carrot
NO_CARROT = ("robot.observation.wall_map=0", "robot.observation.wall_map_plan=false",
             "robot.observation.wall_map_plan_penalty=0", "robot.observation.wall_map_carrot=0")


def folders() -> list[Path]:
    return sorted(p for p in POLICIES.iterdir() if (p / "policy.onnx").is_file())


def test_the_policies_folder_holds_the_four_the_readme_lists():
    readme = (POLICIES / "README.md").read_text()
    names = [p.name for p in folders()]
    assert len(names) == 4 and all(f"`{n}`" in readme for n in names)


@pytest.mark.parametrize("folder", folders(), ids=lambda p: p.name)
def test_a_committed_policy_loads_and_its_request_resolves_to_its_observation(folder):
    from flashnav.deploy.runtime import PolicyRuntime

    rt = PolicyRuntime.load(folder)
    (width,) = rt.session.get_inputs()[0].shape[1:]
    assert width == rt.obs_dim == rt.meta["obs_dim"]
    spec = resolve(config_from_cli(str(folder / "config.yaml"), {"device": "cpu"}))
    if folder.name == "go2-paper-mirror-s0":  # trained before the recipe took the plan's carrot
        assert spec.robot.obs_dim != rt.obs_dim and spec.robot.observation.wall_map_carrot == 0.5
        spec = resolve(config_from_cli(str(folder / "config.yaml"), {"device": "cpu"}, NO_CARROT))
    assert spec.robot.obs_dim == rt.obs_dim
    assert rt.carrot == spec.robot.observation.wall_map_carrot
    assert rt.wall_map == spec.robot.observation.wall_map


def test_the_go2_carrot_policy_sees_the_recipes_plan_and_carrot():
    """The Go2 `paper-mirror` policy of session 76 reads what the recipe now resolves to by itself: the 2 x 2 wall map
    with the plan (price 2) and the carrot at 0.5 m."""
    from flashnav.deploy.runtime import PolicyRuntime

    rt = PolicyRuntime.load(POLICIES / "go2-paper-mirror-carrot-s0")
    assert (rt.wall_map, rt.carrot, rt.plan_penalty, rt.wall_channel_names) == (2, 0.5, 2.0, ("walls", "goal", "plan"))
    plain = resolve(config_from_cli(None, {"robot": "go2", "recipe": "paper-mirror", "device": "cpu"}))
    assert plain.robot.obs_dim == rt.obs_dim and plain.hparams.wall_map_convs == ((8, 1),)
