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


def test_single_threaded_numba_holds_for_the_calling_thread_only():
    import threading

    import numba

    from flashnav.machine import single_threaded_numba

    before, seen = numba.get_num_threads(), []

    def worker():
        single_threaded_numba()
        seen.append(numba.get_num_threads())

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [1] and numba.get_num_threads() == before
