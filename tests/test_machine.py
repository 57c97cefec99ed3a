"""flashnav/machine.py: the machine name carries no thread count; old names split into both."""

from __future__ import annotations

import pytest

from flashnav.machine import cpu_cores, learner_threads, machine_name, split_device_name


@pytest.mark.parametrize("name, want", [
    ("AMD EPYC 7B13 (2 threads)", ("AMD EPYC 7B13", 2)),        # before the split: both in one string
    ("Fake CPU (1 threads)", ("Fake CPU", 1)),
    ("Intel Xeon (R) Gold (16 threads)", ("Intel Xeon (R) Gold", 16)),
    ("AMD EPYC 7B13 (2 cores)", ("AMD EPYC 7B13 (2 cores)", None)),  # the new spelling: the machine as is
    ("NVIDIA H100 80GB HBM3", ("NVIDIA H100 80GB HBM3", None)),
    ("(2 threads)", ("(2 threads)", None)),                      # no machine left: not the old spelling
    (None, (None, None)),
])
def test_split_device_name(name, want):
    assert split_device_name(name) == want


def test_cpu_machine_name_has_cores_not_threads():
    import torch

    name = machine_name("cpu")
    assert name.endswith(f" ({cpu_cores()} cores)") and "threads" not in name
    assert split_device_name(name) == (name, None)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert learner_threads("cpu") == 1 and machine_name("cpu") == name  # a thread setting renames nothing
    finally:
        torch.set_num_threads(before)
    assert learner_threads("cuda:0") is None


def test_numba_threads_sets_and_restores_for_the_calling_thread():
    import threading

    import numba

    from flashnav.machine import numba_threads

    most = int(numba.config.NUMBA_NUM_THREADS)
    before = numba.get_num_threads()
    with numba_threads(1):
        assert numba.get_num_threads() == 1
        with numba_threads():
            assert numba.get_num_threads() == most
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with pytest.raises(RuntimeError), numba_threads(1):  # restored on the way out of a failure too
        raise RuntimeError("boom")
    assert numba.get_num_threads() == before
    for bad in (0, most + 1):
        with pytest.raises(ValueError, match=rf"numba threads must be in \[1, {most}\].*got {bad}"):
            with numba_threads(bad):
                pass
    seen = []

    def worker():
        with numba_threads(1):
            seen.append(numba.get_num_threads())

    with numba_threads():
        t = threading.Thread(target=worker)
        t.start()
        t.join()
        assert seen == [1] and numba.get_num_threads() == most  # the other thread's block left ours alone


@pytest.mark.parametrize("overlap", [True, "auto"])
def test_training_evaluates_on_every_numba_thread_and_collects_on_one_beside_the_learner(monkeypatch, overlap):
    """Overlapped, the warm-up collects on the main thread (no learner yet) and must not leave it
    single-threaded: the evaluations, on the main thread, scan with every numba thread; the collector
    with one (the learner has the other core). Sequential (auto on a CPU), the collector has every thread."""
    import numba

    from flashnav.learn import loop
    from flashnav.sim.env import NavVecEnv
    from test_train import TINY, tiny_config

    during_eval, during_collect = [], []
    evaluate, step = loop.evaluate, NavVecEnv.step

    def counting_evaluate(*args, **kwargs):
        during_eval.append(numba.get_num_threads())
        return evaluate(*args, **kwargs)

    def counting_step(self, *args, **kwargs):
        during_collect.append(numba.get_num_threads())
        return step(self, *args, **kwargs)

    monkeypatch.setattr(loop, "evaluate", counting_evaluate)
    monkeypatch.setattr(NavVecEnv, "step", counting_step)
    before = numba.get_num_threads()
    loop.train(tiny_config(TINY, 32 * 8, 8, overlap=overlap))
    most = int(numba.config.NUMBA_NUM_THREADS)
    assert during_eval and set(during_eval) == {most}
    assert len(during_collect) == 8 and set(during_collect) == {1 if overlap is True else most}
    assert numba.get_num_threads() == before
