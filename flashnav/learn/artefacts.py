"""A training run's folder: what ``flashnav train --out`` writes, from the library (:func:`save_run`)."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from flashnav.names import CHECKPOINT_FILE, CONFIG_FILE, METRICS_FILE, REPLAY_FILE, RUN_FILES
from flashnav.yamlio import dump_yaml

__all__ = ["RUN_FILES", "save_run"]


def save_run(result, out: str | Path, replay: bool = False) -> Path:
    """Write a :class:`~flashnav.learn.loop.TrainResult` as a run folder, what ``flashnav train --out`` writes
    (:data:`RUN_FILES`; ``flashnav eval``, ``--init-from`` and ``deploy`` read it). Each file is replaced whole:
    they are written to a folder of their own beside them and renamed into ``out``, so a crash while writing
    leaves the previous set (a snapshot) readable. ``replay`` (``--save-replay``): the run's replay buffer too,
    as :data:`REPLAY_FILE` (``--init-from OUT --init-replay`` reads it); without it a ``replay.pt`` left in ``out``
    by an earlier run is removed, so the folder never pairs this run's learner with another run's buffer.
    Returns ``out``."""
    import tempfile

    from flashnav.checkpoint import save_checkpoint, save_replay
    from flashnav.export import export_policy

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    metrics = result.to_dict()  # once: every snapshot writes it (its "config" is the spec's to_dict)
    config = metrics["config"]
    with tempfile.TemporaryDirectory(prefix=".saving-", dir=out) as tmp:
        tmp = Path(tmp)
        dump_yaml(config, tmp / CONFIG_FILE)
        with open(tmp / METRICS_FILE, "w", encoding="utf-8") as f:
            json.dump(metrics, f, indent=2)
        save_checkpoint(tmp / CHECKPOINT_FILE, result.learner.state_dict(), config,
                        {"metrics": {k: v for k, v in metrics.items() if k != "config"},
                         "saved_at": dt.datetime.now().isoformat(timespec="seconds")})
        export_policy(result.policy, result.spec.robot, tmp)  # the best evaluated policy
        if replay:
            if result.replay is None:
                raise ValueError(f"save_run(..., replay=True) into {out}: the result carries no replay buffer "
                                 "(train it with train(..., keep_replay=True))")
            save_replay(tmp / REPLAY_FILE, result.replay.state_dict())
        else:
            (out / REPLAY_FILE).unlink(missing_ok=True)
        for path in sorted(tmp.iterdir()):  # files only (export_policy writes no folder)
            path.replace(out / path.name)
    return out
