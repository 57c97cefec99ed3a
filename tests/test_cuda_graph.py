"""The CUDA-graph fast path (flashnav.learn.cuda_graph): the static-buffer updates are the eager ones.

On a CPU the path runs with the capture skipped; these tests pin it bit for bit to the plain eager
loop (``replay.sample`` then ``learner.update(batches.at(i))``, what ``flashnav train`` runs with
``cuda_graph=off``) for every learner: parameters, target critics, optimiser moments and steps, the
temperature and running std, RNG states and every update's metrics. The tests marked ``cuda`` run
the capture itself where a GPU is visible.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from flashnav.learn.common import adamw
from flashnav.learn.cuda_graph import CycleUpdates, capturable, check_fused, has_state, optimizers
from flashnav.learn.hparams import load_hparams
from flashnav.learn.learners import make_learner
from flashnav.learn.networks import ObsLayout
from flashnav.learn.replay import Replay
from flashnav.presets import load_robot
from flashnav.machine import resolve_cuda_graph
from flashnav.spec import RunSpec, TrainConfig, config_from_cli, resolve

ALGOS = ("fastdsac", "fastsac", "fasttd3")
N, B = 16, 64
CUDA = pytest.mark.skipif(not torch.cuda.is_available(),
                          reason="CUDA-graph capture needs a CUDA GPU (none visible): the CPU tests above run "
                                 "the same update code with the capture skipped")


def build(algo: str, device: str = "cpu", updates: int = 4, seed: int = 7, **overrides):
    """A learner (``updates`` per cycle) and a replay filled with 24 vector steps of random data,
    the same for the same arguments."""
    robot = load_robot("turtlebot2")
    small = {"actor_hidden": [64, 64], "critic_hidden": [64, 64]}  # the update code, not the width, is under test
    hp = load_hparams(algo, "turtlebot2", "cpu", {"batch_size": B, "updates_per_step": updates, **small, **overrides})
    layout = ObsLayout.from_robot(robot, 10.0)
    learner = make_learner(algo, hp, layout, 2, N, device, seed)
    replay = Replay(N, layout.obs_dim, 2, capacity=N * 32, device=device, seed=seed)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(24):
        obs = torch.rand(N, layout.obs_dim, generator=gen) * 3.0 + 0.3
        replay.add(obs.to(device), (torch.rand(N, 2, generator=gen) * 2.4 - 1.2).to(device),
                   torch.randn(N, generator=gen).to(device), (torch.rand(N, generator=gen) < 0.1).to(device),
                   (obs + 0.05 * torch.randn(N, layout.obs_dim, generator=gen)).to(device))
    return learner, replay, layout


def eager_cycle(learner, replay) -> list[dict]:
    """The reference: today's eager loop body."""
    hp = learner.hp
    batches = replay.sample(hp.batch_size, hp.updates_per_step)
    return [learner.update(batches.at(i)) for i in range(hp.updates_per_step)]


def assert_same(a, b, path="state", exact=True):
    """Recursive equality of state dicts / metrics: tensors bit for bit (``exact``) or to float32
    rounding, everything else ==."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same(a[key], b[key], f"{path}[{key!r}]", exact)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]", exact)
    elif isinstance(a, torch.Tensor):
        if exact or not a.is_floating_point():
            assert a.dtype == b.dtype and torch.equal(a.cpu(), b.cpu()), path
        else:
            torch.testing.assert_close(b.cpu(), a.cpu(), rtol=1e-4, atol=1e-5, msg=path)
    else:
        assert a == b, path


@pytest.mark.parametrize("updates", [4, 3])  # 3: the actor schedule (every 2nd) changes phase between cycles
@pytest.mark.parametrize("algo", ALGOS)
def test_static_buffer_path_is_the_eager_update_bit_for_bit(algo, updates):
    (eager, replay_a, layout), (static, replay_b, _) = build(algo, updates=updates), build(algo, updates=updates)
    cycles = CycleUpdates(static, layout.obs_dim, 2, B, updates, capture=False)
    for _ in range(-(-20 // updates)):                     # ~20 updates
        want = eager_cycle(eager, replay_a)
        assert cycles.sample(replay_b) is cycles.batches
        got = cycles.run()
        assert_same(want, got, "metrics")
    assert static.num_updates == eager.num_updates == updates * cycles.cycles and cycles.graphs == 0
    state_a, state_b = eager.state_dict(), static.state_dict()
    assert_same(state_a, state_b)
    assert state_b["critic_opt"]["state"] and state_b["actor_opt"]["state"]  # moments compared, not empty
    assert torch.equal(replay_a.generator.get_state(), replay_b.generator.get_state())
    # the actor and critic have actually moved (the comparison is not between two untrained nets)
    fresh = build(algo, updates=updates)[0]
    assert not torch.equal(fresh.state.critic_params[0], static.state.critic_params[0])
    assert not torch.equal(fresh.state.actor_params[0], static.state.actor_params[0])


class EmulatedGraphs:
    """:class:`~flashnav.learn.cuda_graph.CudaGraphs` on a CPU, with a CUDA graph's semantics: a
    capture executes nothing (the updates run, then the learner and the carried metrics are rolled
    back), a replay runs the recorded updates and leaves its results in the capture's output tensors
    (a graph's static outputs). Records what it was asked to do."""

    def __init__(self):
        self.cycles = None  # the CycleUpdates, set once built
        self.warmups, self.captured_phases, self.flags = 0, [], []

    def warmup(self, updates):
        self.warmups += 1
        return updates()

    def capture(self, updates, generator):
        learner = self.cycles.learner
        assert generator is learner.state.update_gen
        self.flags.append([g["capturable"] for o in optimizers(learner.state) for g in o.param_groups])
        self.captured_phases.append(learner.state.num_updates % learner.hp.policy_frequency)
        saved, carry = learner.state_dict(), {k: v.clone() for k, v in self.cycles._carry.items()}
        outputs = updates()
        learner.load_state_dict(saved)
        for key, value in carry.items():
            self.cycles._carry[key].copy_(value)
        return self.Graph(updates, outputs), outputs

    class Graph:
        def __init__(self, updates, outputs):
            self.updates, self.outputs = updates, outputs

        def replay(self):
            for old, new in zip(self.outputs, self.updates()):
                for key in old:
                    old[key].copy_(new[key])


#: the optional parts of an update (running feature statistics, layer norm, the averaged policy)
NORMS = {"obs_norm": True, "layer_norm": True, "policy_averaging": 0.1}


@pytest.mark.parametrize("norms", [{}, NORMS], ids=["plain", "norms"])
@pytest.mark.parametrize("updates", [4, 3])
@pytest.mark.parametrize("algo", ALGOS)
def test_capture_and_replay_bookkeeping_matches_eager(algo, updates, norms):
    # The capture path's own logic - warm-up cycles, one graph per phase of the actor schedule,
    # the update count rolled back after a capture and advanced after a replay, capturable flags
    # only during a capture, static outputs - run against an emulated graph: bit for bit the eager loop.
    (eager, replay_a, layout), (static, replay_b, _) = (build(algo, updates=updates, **norms),
                                                        build(algo, updates=updates, **norms))
    emulated = EmulatedGraphs()
    cycles = CycleUpdates(static, layout.obs_dim, 2, B, updates, capture=True, warmup_cycles=2, graphs=emulated)
    emulated.cycles = cycles
    captures = []
    for _ in range(-(-20 // updates)):
        captures.append(cycles.captures_next)
        want = eager_cycle(eager, replay_a)
        cycles.sample(replay_b)
        assert_same(want, cycles.run(), "metrics")
        assert static.num_updates == eager.num_updates
    phases = 1 if updates % static.hp.policy_frequency == 0 else static.hp.policy_frequency
    assert emulated.warmups == 2 and cycles.graphs == phases
    assert captures[:2] == [False, False] and sum(captures) == phases
    assert sorted(emulated.captured_phases) == list(range(phases))
    assert all(all(flags) for flags in emulated.flags)
    assert not any(g["capturable"] for o in optimizers(static.state) for g in o.param_groups)
    assert_same(eager.state_dict(), static.state_dict())


def test_warm_up_lasts_until_every_optimiser_has_its_moments():
    p, q = torch.zeros(3, requires_grad=True), torch.zeros(3, requires_grad=True)
    opt = adamw([p, q], 1e-3, (0.9, 0.95), 0.0)
    assert not has_state([opt])
    p.sum().backward()
    opt.step()
    assert has_state([opt])  # q never had a gradient: the step skips it, and so would a capture
    q.grad = torch.ones(3)
    assert not has_state([opt])


HOST_READS = ("item", "tolist", "numpy", "cpu", "__bool__", "__float__", "__int__", "__index__")


@pytest.mark.parametrize("norms", [{}, NORMS], ids=["plain", "norms"])
@pytest.mark.parametrize("algo", ALGOS)
def test_a_cycle_never_reads_a_device_value_on_the_host(algo, monkeypatch, norms):
    # What a CUDA graph cannot replay: a host read (a sync, and a value frozen at capture). Run a
    # warm cycle (optimiser state created) and then one with every host-read method of Tensor raising.
    learner, replay, layout = build(algo, updates=3, **norms)
    cycles = CycleUpdates(learner, layout.obs_dim, 2, B, 3, capture=False)
    cycles.sample(replay)
    cycles.run()

    def refuse(name):
        def method(self, *args, **kwargs):
            raise AssertionError(f"Tensor.{name} called inside a cycle's updates")
        return method

    for name in HOST_READS:
        monkeypatch.setattr(torch.Tensor, name, refuse(name))
    with pytest.raises(AssertionError, match="Tensor.item"):
        torch.ones(()).item()  # the guard is live
    cycles.run()
    cycles.run()


def test_optimizers_capture_flags_and_errors():
    learner, _, layout = build("fastdsac")
    opts = optimizers(learner.state)
    assert len(opts) == 3 and learner.state.algo.temperature.opt in opts  # actor, critic, temperature
    check_fused(opts)  # common.adamw is fused on this torch
    assert not has_state(opts)
    with capturable(opts):
        assert all(g["capturable"] for o in opts for g in o.param_groups)
    assert not any(g["capturable"] for o in opts for g in o.param_groups)
    plain = torch.optim.AdamW([torch.zeros(3, requires_grad=True)], foreach=True)
    with pytest.raises(ValueError, match="not fused"):
        check_fused([plain])
    with pytest.raises(ValueError, match="CUDA device.*cpu"):
        CycleUpdates(learner, layout.obs_dim, 2, B, 4, capture=True)
    with pytest.raises(ValueError, match="updates > 0"):
        CycleUpdates(learner, layout.obs_dim, 2, B, 0, capture=False)
    assert adamw([torch.zeros(2, requires_grad=True)], 1e-3, (0.9, 0.95), 0.0).defaults["fused"]


def test_cuda_graph_option_resolves_by_device():
    assert [resolve_cuda_graph(m, "cpu") for m in ("auto", "on", "off")] == [False, True, False]
    # auto: on for cuda (measured on an H100), unless the learning rate decays (a capture replays its rate)
    assert [resolve_cuda_graph(m, "cuda:0") for m in ("auto", "on", "off")] == [True, True, False]
    assert [resolve_cuda_graph(m, "cuda", decaying_lr=True) for m in ("auto", "on", "off")] == [False, True, False]
    with pytest.raises(ValueError, match="cuda_graph 'fast'"):
        resolve_cuda_graph("fast", "cpu")
    with pytest.raises(ValueError, match="cuda_graph"):
        TrainConfig(cuda_graph="fast")
    # the command line and YAML read a bare on / off as booleans
    assert [config_from_cli(None, {}, [f"cuda_graph={v}"]).cuda_graph for v in ("on", "off", "auto")] == \
        ["on", "off", "auto"]
    spec = resolve(TrainConfig(device="cpu"))
    assert spec.cuda_graph is False and spec.to_dict()["cuda_graph"] == "off"
    on = resolve(TrainConfig(device="cpu", cuda_graph="on"))
    assert on.cuda_graph is True and RunSpec.from_dict(on.to_dict()).cuda_graph is True
    assert RunSpec.from_dict(spec.to_dict()).cuda_graph is False


def gap(a, b) -> float:
    """Largest ``|a - b| / (1 + |a|)`` over the float tensors of two nested states / metrics; every
    other value (integers, RNG states, step counts kept as ints) must be equal."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        return max([gap(a[k], b[k]) for k in a], default=0.0)
    if isinstance(a, (list, tuple)):
        return max([gap(x, y) for x, y in zip(a, b)], default=0.0)
    if isinstance(a, torch.Tensor) and a.is_floating_point():
        a, b = a.detach().double().cpu(), b.detach().double().cpu()
        return float(((a - b).abs() / (1 + a.abs())).max()) if a.numel() else 0.0
    if isinstance(a, torch.Tensor):
        assert torch.equal(a.cpu(), b.cpu())
    else:
        assert a == b
    return 0.0


@CUDA
@pytest.mark.parametrize("algo", ALGOS)
def test_graph_replay_matches_eager_updates_on_cuda(algo):
    # Same seed, same batches, ~20 updates: the captured graph replayed against the eager loop. The
    # GPU itself need not be bitwise reproducible (atomics in the C51 projection's scatter_add and in
    # index backward, cuBLAS kernel choice), so the graph's distance from eager is held to that of
    # a second eager run (times 10, plus float32 rounding); a missed, repeated or stale update is
    # orders of magnitude larger. RNG states and update counts must match exactly.
    (eager, replay_a, layout), (again, replay_c, _) = build(algo, "cuda"), build(algo, "cuda")
    static, replay_b, _ = build(algo, "cuda")
    cycles = CycleUpdates(static, layout.obs_dim, 2, B, 4, capture=True)
    metric_gaps = []
    for _ in range(5):
        want, other = eager_cycle(eager, replay_a), eager_cycle(again, replay_c)
        cycles.sample(replay_b)
        got = cycles.run()
        metric_gaps.append((gap(want, other), gap(want, got)))
    torch.cuda.synchronize()
    assert cycles.graphs == 1 and cycles.cycles == 5 and static.num_updates == eager.num_updates == 20
    noise, graph = gap(eager.state_dict(), again.state_dict()), gap(eager.state_dict(), static.state_dict())
    assert graph <= 10 * noise + 1e-5, (graph, noise)
    for noise, graph in metric_gaps:
        assert graph <= 10 * noise + 1e-5, (graph, noise)


@CUDA
@pytest.mark.parametrize("late", [{}, {"algo.late_batch_size": 256, "algo.late_from": 0.5}])
def test_train_runs_with_the_cuda_graph_and_collector_stream(late):
    # with a late batch the run captures a second set of graphs, for the larger batch, half way through
    from flashnav import train

    overrides = {"algo.num_envs": 64, "algo.learning_start": 128, "algo.updates_per_step": 4,
                 "algo.batch_size": 128, "algo.eval_every": 4, **late}
    config = TrainConfig(device="cuda", recipe="cpu", cuda_graph="on", overrides=overrides,
                         budget={"max_env_steps": 64 * 12, "stop_at_success": None}, eval={"episodes": 32})
    result = train(config)
    assert result.spec.cuda_graph and len(result.curve) == 3
    assert all(torch.isfinite(p).all() for p in result.learner.state.critic_params)


@pytest.mark.parametrize("late", [{}, {"algo.late_batch_size": 96, "algo.late_from": 0.5}])
def test_loop_with_static_buffers_trains_exactly_like_without(late):
    # TrainConfig.cuda_graph=on on a CPU: the loop's static-buffer path, overlapped and sequential,
    # gives the run of cuda_graph=off (the CPU default) to the bit - also where the batch grows late
    # (a second set of static buffers from half way on).
    from flashnav import train

    def run(**kw):
        config = TrainConfig.model_validate(dict(
            device="cpu", recipe="cpu", seed=3, budget={"max_env_steps": 32 * 6, "stop_at_success": None},
            eval={"episodes": 16}, overrides={"algo.num_envs": 32, "algo.learning_start": 64,
                                              "algo.updates_per_step": 3, "algo.batch_size": 64,
                                              "algo.eval_every": 3, **late}, **kw))
        result = train(config)
        curve = [(c["success_rate"], c["mean_return"]) for c in result.curve]
        return curve, result.learner.state_dict(), result.spec.cuda_graph

    for overlap in (True, False):
        (curve_a, state_a, flag_a), (curve_b, state_b, flag_b) = run(overlap=overlap), run(overlap=overlap,
                                                                                         cuda_graph="on")
        assert (flag_a, flag_b) == (False, True)
        assert curve_a == curve_b
        assert_same(state_a, state_b)


def test_module_dataclass_walk_finds_nested_optimizers():
    @dataclasses.dataclass
    class Inner:
        opt: torch.optim.Optimizer

    @dataclasses.dataclass
    class Outer:
        a: torch.optim.Optimizer
        inner: Inner
        n: int = 0

    p = torch.zeros(2, requires_grad=True)
    a, b = torch.optim.SGD([p], lr=0.1), torch.optim.SGD([p], lr=0.2)
    assert optimizers(Outer(a, Inner(b))) == [a, b]
