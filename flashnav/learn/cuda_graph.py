"""The U learner updates of a cycle on static batch buffers, captured once as a CUDA graph and replayed.

```python
updates = CycleUpdates(learner, obs_dim, action_dim, batch_size=B, updates=U, capture=True)  # capture: CUDA only
replay.sample(B, U, out=updates.batches)   # the replay gathers into the static [U, B, ...] buffers
metrics = updates.run()                    # U x learner.update(updates.batches.at(i)), or one graph replay
```

Every cycle runs exactly the eager update code (:meth:`flashnav.learn.learners.Learner.update` on
``batches.at(i)``, i < U); what changes is *where* its inputs live (static buffers the replay
gathers into) and, on a CUDA device, *how it is launched*: after ``warmup_cycles`` eager cycles (on
a side stream, so that lazy initialisation - optimiser moments, cuBLAS handles - happens outside the
capture), the U updates are captured once into a ``torch.cuda.CUDAGraph`` and every later cycle is
one ``replay()``: one launch instead of thousands of small kernels. On a CPU, or with
``capture=False``, the same code runs eagerly (capture skipped); the CPU tests pin it bit for bit
to the plain eager loop (tests/test_cuda_graph.py).

What makes the update capturable, and where it lives:
- no host reads of device values inside an update (no ``.item()``, no branching on tensors): the
  running std is initialised with ``torch.where``, the temperature is the tensor ``log_alpha``;
- the actor schedule is decided on the host from ``state.num_updates``: a graph captures one
  *phase* (``num_updates % policy_frequency`` at the cycle's start) and is kept per phase, so a U
  that ``policy_frequency`` does not divide still replays the right schedule; ``num_updates`` is
  advanced by U on the host after each replay;
- the optimisers are fused AdamW (:func:`flashnav.learn.common.adamw`): their step counters and
  bias corrections live on the device, so ``capturable`` only has to pass torch's capture check
  (it is set for the capture and restored after; the fused kernel does not read it); learning
  rates and every other hyperparameter are constants of the capture (no schedule exists to freeze);
- random draws come from ``state.update_gen``, registered with the graph, so each replay advances
  it exactly as the eager updates would;
- outputs (metrics) are the graph's static tensors, overwritten by the next replay of that graph;
  the actor metrics that the updates before a cycle's first actor step repeat are carried between
  cycles in tensors of their own (copied in and out inside the cycle).

Why manual capture, not ``torch.compile(mode="reduce-overhead")``: on a CPU reduce-overhead is
inductor without CUDA graphs (different kernels, different rounding, and half the eager speed on
this project's CPU, docs/benchmarks.md), so no CPU test could show that the captured code is the
update the learner runs; manual capture keeps the eager code and only changes how it is launched,
and it captures the optimiser steps, Polyak averaging and temperature step too, not only the networks.
"""

from __future__ import annotations

import contextlib
import dataclasses
from typing import Any, Callable, Iterator

import torch

from flashnav.learn.common import optimizers
from flashnav.learn.replay import Replay, Transition


def check_fused(opts: list[torch.optim.Optimizer]) -> None:
    """A ValueError naming the first optimiser that is not fused: only the fused kernel keeps its
    step counter and bias correction on the device with the numbers of the eager step."""
    for opt in opts:
        if not all(group.get("fused") for group in opt.param_groups):
            raise ValueError(f"CUDA-graph capture needs fused optimisers (flashnav.learn.common.adamw); "
                             f"{type(opt).__name__} over {sum(len(g['params']) for g in opt.param_groups)} "
                             "tensors is not fused")


def has_state(opts: list[torch.optim.Optimizer]) -> bool:
    """True when every optimiser has stepped and holds the moments of every parameter that has a
    gradient: a capture must not create them (their zero fill would be recorded and replayed every
    cycle). A parameter without a gradient is skipped by the step, in the capture as well."""
    return all(opt.state and all(p in opt.state for group in opt.param_groups for p in group["params"]
                                 if p.grad is not None) for opt in opts)


@contextlib.contextmanager
def capturable(opts: list[torch.optim.Optimizer]) -> Iterator[None]:
    """``capturable=True`` on every param group for the duration of a capture, restored after (so a
    checkpoint's optimiser state and later eager steps are those of the eager learner)."""
    saved = [[group["capturable"] for group in opt.param_groups] for opt in opts]
    try:
        for opt in opts:
            for group in opt.param_groups:
                group["capturable"] = True
        yield
    finally:
        for opt, flags in zip(opts, saved):
            for group, flag in zip(opt.param_groups, flags):
                group["capturable"] = flag


def static_batches(updates: int, batch_size: int, obs_dim: int, action_dim: int,
                   device: torch.device | str) -> Transition:
    """Zeroed static ``[U, B, ...]`` float32 buffers in :class:`Transition` layout."""
    f32 = dict(dtype=torch.float32, device=torch.device(device))
    return Transition(obs=torch.zeros(updates, batch_size, obs_dim, **f32),
                      action=torch.zeros(updates, batch_size, action_dim, **f32),
                      reward=torch.zeros(updates, batch_size, **f32),
                      bootstrap=torch.zeros(updates, batch_size, **f32),
                      next_obs=torch.zeros(updates, batch_size, obs_dim, **f32))


class CudaGraphs:
    """How :class:`CycleUpdates` launches on a CUDA device: warm-up cycles on a side stream, captures
    into ``torch.cuda.CUDAGraph`` on that stream. (The CPU tests pass an emulation with the same two
    methods, tests/test_cuda_graph.py, to run the capture-and-replay bookkeeping without a GPU.)"""

    def __init__(self, device: torch.device):
        self.stream = torch.cuda.Stream(device)
        self.device = device

    def warmup(self, updates: Callable[[], list]) -> list:
        """Run ``updates`` eagerly on the side stream (torch's recipe: what a capture must find
        initialised is initialised outside it), ordered after and before the caller's stream."""
        caller = torch.cuda.current_stream(self.device)
        self.stream.wait_stream(caller)
        with torch.cuda.stream(self.stream):
            out = updates()
        caller.wait_stream(self.stream)
        return out

    def capture(self, updates: Callable[[], list], generator: torch.Generator) -> tuple[Any, list]:
        """Record ``updates`` (nothing runs on the device) with ``generator`` registered, so each
        replay draws what the eager calls would; returns the graph and its static outputs."""
        graph = torch.cuda.CUDAGraph()
        graph.register_generator_state(generator)
        with torch.cuda.graph(graph, stream=self.stream):
            outputs = updates()
        return graph, outputs


class CycleUpdates:
    """The U updates of a cycle of ``learner`` on static batch buffers ``batches [U, B, ...]``.

    ``capture``: record them as a CUDA graph after ``warmup_cycles`` eager cycles and replay it
    (the learner must be on a CUDA device; ``graphs`` replaces :class:`CudaGraphs`, for tests);
    ``False`` runs the same updates eagerly every cycle. Once built, every update of the learner
    goes through :meth:`run` (it carries the actor metrics from cycle to cycle).
    """

    def __init__(self, learner, obs_dim: int, action_dim: int, batch_size: int, updates: int,
                 capture: bool, warmup_cycles: int = 1, graphs: Any = None):
        if min(obs_dim, action_dim, batch_size, updates) <= 0 or warmup_cycles < 1:
            raise ValueError(f"CycleUpdates needs obs_dim, action_dim, batch_size, updates > 0 and warmup_cycles "
                             f">= 1, got {obs_dim}, {action_dim}, {batch_size}, {updates}, {warmup_cycles}")
        device = learner.device
        if capture and graphs is None and device.type != "cuda":
            raise ValueError(f"CUDA-graph capture needs a learner on a CUDA device, this one is on {device} "
                             "(capture=False runs the same static-buffer updates eagerly)")
        self.learner, self.updates, self.batch_size = learner, updates, batch_size
        self.capture, self.warmup_cycles = capture, warmup_cycles
        self.batches = static_batches(updates, batch_size, obs_dim, action_dim, device)
        self.cycles = 0                                        # run() calls so far
        self._graphs: dict[int, Any] = {}                      # phase -> captured graph
        self._outputs: dict[int, list[dict[str, torch.Tensor]]] = {}
        self._backend = (graphs or CudaGraphs(device)) if capture else None
        # The actor metrics carried from one cycle into the next (repeated by the updates before the
        # cycle's first actor step), in tensors of their own: a replay must read the last cycle's values
        # from memory it owns, not from whatever tensors the capture happened to see.
        self._carry = {k: v.detach().clone() for k, v in learner.state.last_actor_metrics.items()}

    @property
    def graphs(self) -> int:
        """Graphs captured so far (one per phase of the actor schedule met after the warm-up)."""
        return len(self._graphs)

    def sample(self, replay: Replay) -> Transition:
        """Gather this cycle's U batches from ``replay`` into :attr:`batches` (returned)."""
        return replay.sample(self.batch_size, self.updates, out=self.batches)

    def _phase(self) -> int:
        return self.learner.state.num_updates % self.learner.hp.policy_frequency

    def _ready(self) -> bool:
        return self.cycles >= self.warmup_cycles and has_state(optimizers(self.learner.state))

    @property
    def captures_next(self) -> bool:
        """True when the next :meth:`run` captures a graph: the caller runs that cycle with nothing
        else issuing CUDA work (the loop does not overlap collection with it)."""
        return self.capture and self._ready() and self._phase() not in self._graphs

    def run(self) -> list[dict[str, torch.Tensor]]:
        """The cycle's U updates on :attr:`batches`; returns each update's metrics (on a replayed
        graph, its static outputs: valid until that graph's next replay)."""
        if not self.capture:
            metrics = self._updates()
        elif not self._ready():
            metrics = self._backend.warmup(self._updates)
        else:
            state = self.learner.state
            start, phase = state.num_updates, self._phase()
            if phase not in self._graphs:
                self._capture(phase)
            self._graphs[phase].replay()
            state.num_updates = start + self.updates  # the replay ran no Python: count its updates here
            metrics = self._outputs[phase]
        self.cycles += 1
        return metrics

    def _updates(self) -> list[dict[str, torch.Tensor]]:
        """The update code itself: the same on every device and in every mode (the carried actor
        metrics are copied in and out; their values are those of the plain eager loop)."""
        state = self.learner.state
        state.last_actor_metrics = {k: v.clone() for k, v in self._carry.items()}
        metrics = [self.learner.update(self.batches.at(i)) for i in range(self.updates)]
        for key, carried in self._carry.items():
            carried.copy_(state.last_actor_metrics[key])
        return metrics

    def _capture(self, phase: int) -> None:
        """Record the U updates of ``phase``. Nothing runs on the device; Python's side effect, the
        update count, is rolled back: the first replay does the work."""
        state = self.learner.state
        opts = optimizers(state)
        check_fused(opts)
        start = state.num_updates
        with capturable(opts):
            self._graphs[phase], self._outputs[phase] = self._backend.capture(self._updates, state.update_gen)
        state.num_updates = start
