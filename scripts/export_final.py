"""Export a ``flashnav train`` run's final learner as a policy, to evaluate it beside the run's exported one.

``flashnav train`` exports the policy of its best validation evaluation (``RUN/policy.pt``, ``policy.onnx``,
``policy.json``); ``RUN/checkpoint.pt`` holds the learner at the run's end. The two differ when the best evaluation
was not the last, and the validation suite's few episodes a map rank snapshots loosely (docs/benchmarks.md, "One more
layer in the wall map's CNN": a 40,960-step snapshot best on validation, 2.4 points under the final learner on the
held-out suite). This writes the final learner's policy - what its evaluations play: the trained actor, or its
average with ``algo.policy_averaging`` - as the same three files to ``OUT`` (default ``RUN/final``):

    python scripts/export_final.py RUN_DIR_OR_CHECKPOINT [--out DIR]
    flashnav eval RUN/final/policy.onnx --maps heldout --episodes 128
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from flashnav.export import export_policy
from flashnav.finetune import checkpoint_file, load_init_source, load_learner
from flashnav.learn.loop import run_learner
from flashnav.names import POLICY_ONNX, POLICY_TORCHSCRIPT
from flashnav.outputs import check_output_dir
from flashnav.spec import RunSpec

FINAL_DIR = "final"  # --out's default, inside the run folder


def export_final(source: str | Path, out: str | Path | None = None) -> dict[str, Path]:
    """Write the final learner's policy of ``source`` (a run folder or its checkpoint.pt) to ``out`` (default the
    run folder's ``final/``); refuses an ``out`` that already holds a policy. Returns export_policy's paths."""
    path = checkpoint_file(source, "RUN")
    out = check_output_dir(Path(out) if out is not None else path.parent / FINAL_DIR, "--out")  # before the learner
    taken = [name for name in (POLICY_TORCHSCRIPT, POLICY_ONNX) if (out / name).exists()]
    if taken:
        raise FileExistsError(f"--out {out}: already holds {' and '.join(taken)}; give another folder or remove them")
    init, spec = load_init_source(path, RunSpec.from_dict)
    learner = run_learner(spec, "cpu")
    load_learner(learner, init)
    return export_policy(learner.policy, spec.robot, out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", metavar="RUN_DIR_OR_CHECKPOINT", help="a flashnav train --out folder or its checkpoint.pt")
    p.add_argument("--out", default=None, help=f"the folder for the policy files (default RUN/{FINAL_DIR})")
    args = p.parse_args(argv)
    try:
        files = export_final(args.run, args.out)
    except (FileNotFoundError, FileExistsError, ValueError) as exc:
        print(f"export_final: {exc}", file=sys.stderr)
        return 2
    for kind, file in files.items():
        print(f"{kind}: {file}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
