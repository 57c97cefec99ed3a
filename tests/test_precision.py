"""``algo.precision``: the learner's updates in float32 (the default) or under bf16 autocast."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from flashnav import machine, train
from flashnav.learn import precision as prec
from flashnav.learn.hparams import load_hparams
from flashnav.learn.learners import Learner
from flashnav.machine import cpu_has_bf16
from flashnav.spec import TrainConfig, resolve

TINY = {"algo.num_envs": 32, "algo.learning_start": 64, "algo.updates_per_step": 2, "algo.batch_size": 64,
        "algo.eval_every": 4}


def _product_dtype() -> torch.dtype:
    return (torch.ones(4, 4) @ torch.ones(4, 4)).dtype


def test_only_the_cpu_recipe_of_fastdsac_on_turtlebot2_asks_for_bf16():
    """Every recipe updates in float32 (the paper's recipes, the generalist as measured) except FastDSAC's
    TurtleBot2 `cpu` recipe: ``auto``, bf16 where the hardware multiplies it natively (docs/benchmarks.md)."""
    pinned = json.loads((Path(__file__).parent / "fixtures" / "preset_values.json").read_text())
    combos = [key.split("/") for key in pinned if not key.startswith("robot/")] + [["fastdsac", "generalist", "turtlebot2"]]
    assert len(combos) >= 8
    for algorithm, recipe, robot in combos:
        expected = "auto" if (algorithm, recipe, robot) == ("fastdsac", "cpu", "turtlebot2") else "float32"
        assert load_hparams(algorithm, robot, recipe).precision == expected, (algorithm, recipe, robot)


def test_a_bad_precision_is_named():
    with pytest.raises(ValueError, match="precision"):
        load_hparams("fastdsac", "turtlebot2", "cpu", {"precision": "fp16"})
    with pytest.raises(ValueError, match="'fp8'"):
        prec.update_precision("fp8", torch.device("cpu"))


def test_the_update_context_multiplies_in_the_asked_precision(monkeypatch):
    monkeypatch.setattr(prec, "cpu_has_bf16", lambda: True)
    with prec.update_precision("float32", torch.device("cpu"))():
        assert _product_dtype() == torch.float32
    with prec.update_precision("bf16", torch.device("cpu"))():
        assert _product_dtype() == torch.bfloat16
    assert _product_dtype() == torch.float32  # only inside


def test_weights_changed_inside_the_context_are_seen_by_the_next_product(monkeypatch):
    """A cycle's updates step the weights in place inside one context: autocast's cast cache would
    serve every later forward the first step's bf16 copy (it did, before the cache was turned off)."""
    monkeypatch.setattr(prec, "cpu_has_bf16", lambda: True)
    torch.manual_seed(0)
    layer, x = torch.nn.Linear(4, 4), torch.ones(1, 4)
    with prec.update_precision("bf16", torch.device("cpu"))():
        before = layer(x)
        with torch.no_grad():
            layer.weight.add_(1.0)
        after = layer(x)
    assert after.dtype == torch.bfloat16  # a stale copy gives 0 here; bf16 rounds ~4 to within 1/32
    assert torch.allclose((after - before).float(), torch.full((1, 4), 4.0), atol=0.1)


def test_bf16_on_a_cpu_without_bf16_products_is_warned_about(monkeypatch):
    monkeypatch.setattr(prec, "cpu_has_bf16", lambda: False)
    with pytest.warns(UserWarning, match="avx512_bf16"):
        prec.update_precision("bf16", torch.device("cpu"))


def test_cpu_has_bf16_reads_the_flags(tmp_path):
    with_bf16, without = tmp_path / "a", tmp_path / "b"
    with_bf16.write_text("processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu avx512f avx512_bf16 avx512_vnni\n")
    without.write_text("processor\t: 0\nmodel name\t: Intel Xeon\nflags\t\t: fpu avx512f avx512_vnni amx_tile\n")
    assert cpu_has_bf16(str(with_bf16)) and not cpu_has_bf16(str(without))
    assert not cpu_has_bf16(str(tmp_path / "absent"))


@pytest.mark.parametrize("precision, dtype", [("float32", torch.float32), ("bf16", torch.bfloat16)])
def test_training_runs_its_updates_in_the_asked_precision(precision, dtype, monkeypatch):
    """Every update of a run sees the asked product dtype; the learner's weights stay float32 and finite,
    and the collector acts in float32 (autocast covers the updates only)."""
    monkeypatch.setattr(prec, "cpu_has_bf16", lambda: True)
    seen_update, seen_act = set(), set()
    update, act = Learner.update, Learner.act

    def recording_update(self, batch):
        seen_update.add(_product_dtype())
        return update(self, batch)

    def recording_act(self, obs):
        seen_act.add(_product_dtype())
        return act(self, obs)

    monkeypatch.setattr(Learner, "update", recording_update)
    monkeypatch.setattr(Learner, "act", recording_act)
    config = TrainConfig(device="cpu", recipe="cpu", overrides={**TINY, "algo.precision": precision},
                         budget={"max_env_steps": 32 * 6, "stop_at_success": None}, eval={"episodes": 8})
    result = train(config)
    assert seen_update == {dtype} and seen_act == {torch.float32}
    assert result.learner.num_updates > 0
    weights = [p for net in (result.learner.state.actor, result.learner.state.critic) for p in net.parameters()]
    assert weights and all(p.dtype == torch.float32 and torch.isfinite(p).all() for p in weights)


@pytest.mark.parametrize("native, expected", [(True, "bf16"), (False, "float32")])
def test_auto_resolves_by_the_hardware_and_the_run_records_what_it_ran(native, expected, monkeypatch):
    monkeypatch.setattr(machine, "cpu_has_bf16", lambda: native)
    spec = resolve(TrainConfig(device="cpu", recipe="cpu", overrides={"algo.precision": "auto"}))
    assert spec.hparams.precision == expected
    assert spec.to_dict()["hparams"]["precision"] == expected
    assert machine.resolve_precision("float32") == "float32" and machine.resolve_precision("bf16") == "bf16"
