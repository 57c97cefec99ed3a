"""Which device a Tune trial trains on, and how the platform is named in tables (flashnav.machine).

Since Ray 2.5x a trial that asked for ``gpu: 0`` no longer gets ``CUDA_VISIBLE_DEVICES=""``: it sees every
GPU of its node, and ``device="auto"`` would silently put it on a GPU that another trial was given. The
device is therefore chosen from the resources Ray *assigned* (``ray.get_gpu_ids()``), never probed.
Nothing here initialises CUDA in the driver: only :func:`device_name` touches ``torch.cuda`` and only
trials call it.
"""

from __future__ import annotations

import socket


def trial_device() -> str:
    """``"cuda"`` when Ray assigned this trial at least one GPU, else ``"cpu"``.

    Ray restricts CUDA_VISIBLE_DEVICES of a GPU trial to its assigned GPUs, so ``cuda`` (= ``cuda:0``)
    is the trial's own GPU. Must be called inside a Ray worker.
    """
    import ray

    return "cuda" if ray.get_gpu_ids() else "cpu"


def device_kind(device: str) -> str:
    """``cuda`` or ``cpu`` (the ``device_kind`` tag) from a torch device string."""
    return "cuda" if str(device).startswith("cuda") else "cpu"


def device_name(device: str) -> str:
    """The machine, ``NVIDIA H100 80GB HBM3`` or ``AMD EPYC 7B13 (2 cores)`` (flashnav.machine's name),
    without the thread count (the ``threads`` tag): the fallback when training gave none."""
    from flashnav.machine import machine_name

    return machine_name(device)


def host_name() -> str:
    return socket.gethostname()


def check_cluster_fits(cpu: float, gpu: float) -> None:
    """Raise ValueError when no node of the connected Ray cluster can ever run one trial.

    Tune would otherwise leave the trials PENDING forever (e.g. a ``gpu: 1`` sweep on a CPU machine).
    """
    import ray

    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    if any(n.get("CPU", 0) >= cpu and n.get("GPU", 0) >= gpu for n in nodes):
        return
    have = ", ".join(f"{n.get('CPU', 0):g} CPU / {n.get('GPU', 0):g} GPU" for n in nodes) or "no nodes"
    hint = " (--set resources.gpu=0 trains on CPU)" if gpu > 0 else ""
    raise ValueError(f"a trial asks for {cpu:g} CPU / {gpu:g} GPU but the cluster's nodes have {have}{hint}")
