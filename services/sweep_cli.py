"""The sweep command line, and ``flashnav sweep submit`` (the Ray Jobs API).

    flashnav sweep run SWEEP.yaml [--address ADDR] [--resume [STAMP]] [--dry-run] [--set KEY=VALUE ...]
    flashnav sweep submit SWEEP.yaml [--address http://HEAD:8265] [--no-wait] [--resume [STAMP]] [--set ...]
    python -m services.sweep_cli run|submit ...        (where the console script is missing)
    ray job submit --address http://HEAD:8265 --working-dir . -- flashnav sweep run sweeps/tb2_10seed.yaml

``run`` calls services.sweep.run_sweep (the driver); ``submit`` uploads the working dir and runs that
same command on the cluster as a Ray job, following its logs.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path
from typing import Any, Callable

from services.sweep import SweepInterrupted, git_commit, run_sweep
from services.sweep_schema import SweepError, load_sweep, set_flags
from services.sweep_state import stamp_arg

HELP = "Ray Tune sweeps (seed grids, Optuna searches) tracked in MLflow"


# ---------------------------------------------------------------- submit (Ray Jobs API)


def submit_sweep(path: str | Path, *, address: str | None = None, resume: bool | str = False,
                 sets: list[str] | None = None,
                 env: list[str] | None = None, wait: bool = True, module: bool = False,
                 echo: Callable[[str], Any] = print) -> int:
    """Submit ``flashnav sweep run PATH`` as a Ray job (working_dir ".") and follow its logs."""
    import asyncio

    from ray.job_submission import JobStatus, JobSubmissionClient

    from services import stack

    load_sweep(path, sets)  # fail here, not on the cluster
    try:
        relative = Path(path).resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        raise SweepError(f"{path} is outside the working dir {Path.cwd()}: only that is uploaded") from None
    address = address or os.environ.get("RAY_API_SERVER_ADDRESS") or stack.jobs_address()
    stack.align_client_auth()
    command = (["python", "-m", "services.sweep_cli"] if module else ["flashnav", "sweep"]) + ["run", relative.as_posix()]
    command += (["--resume"] + ([resume] if isinstance(resume, str) else [])) if resume else []
    for assignment in sets or []:
        command += ["--set", assignment]
    env_vars = {"FLASHNAV_GIT_COMMIT": git_commit(Path.cwd())}
    for item in env or []:
        key, _, value = item.partition("=")
        env_vars[key] = value
    client = JobSubmissionClient(address)
    job_id = client.submit_job(entrypoint=shlex.join(command), runtime_env={"working_dir": ".", "env_vars": env_vars})
    echo(f"submitted job {job_id} to {address}: {shlex.join(command)}")
    if not wait:
        return 0

    async def follow() -> None:
        async for lines in client.tail_job_logs(job_id):
            print(lines, end="", flush=True)

    try:
        asyncio.run(follow())
    except KeyboardInterrupt:
        echo(f"\nstopped following; the job keeps running (ray job stop --address {address} {job_id})")
        return 130
    status = client.get_job_status(job_id)
    echo(f"job {job_id}: {status}")
    return 0 if status == JobStatus.SUCCEEDED else 1


# ---------------------------------------------------------------- CLI


def _add_commands(sub) -> None:
    run = sub.add_parser("run", help="run a sweep (in-process Ray here, or the cluster at --address / RAY_ADDRESS)")
    run.add_argument("sweep", help="sweep YAML (see sweeps/)")
    run.add_argument("--address", help="Ray cluster address (HOST:6379, auto); default $RAY_ADDRESS, else in-process")
    run.add_argument("--resume", nargs="?", const=True, default=False, type=stamp_arg, metavar="STAMP",
                     help="continue the newest invocation of this sweep (or the one of STAMP, its folder's name under "
                          "<runs>/sweeps/NAME/): its finished trials are kept, the rest run")
    run.add_argument("--dry-run", action="store_true", help="validate and print the plan; run nothing")
    run.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                     help="override a sweep key, e.g. --set budget.max_train_seconds=5 (repeatable)")
    run.set_defaults(func=_cmd_run)
    submit = sub.add_parser("submit", help="submit `flashnav sweep run` as a Ray job and follow its logs")
    submit.add_argument("sweep", help="sweep YAML inside the current directory (uploaded as working_dir)")
    submit.add_argument("--address", help="jobs API, e.g. http://HEAD:8265; default $RAY_API_SERVER_ADDRESS, "
                                          "else the local stack's")
    submit.add_argument("--resume", nargs="?", const=True, default=False, type=stamp_arg, metavar="STAMP")
    submit.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    submit.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="environment variable for the job driver (e.g. MLFLOW_TRACKING_URI=http://HEAD:5000)")
    submit.add_argument("--no-wait", action="store_true", help="return once submitted")
    submit.add_argument("--module", action="store_true", help="entrypoint `python -m services.sweep_cli` (no console script)")
    submit.set_defaults(func=_cmd_submit)


def _guard(fn: Callable[[], int], resume_hint: Callable[[KeyboardInterrupt], str | None] | None = None) -> int:
    try:
        return fn()
    except SweepError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        hint = resume_hint(exc) if resume_hint else None
        print("interrupted before anything was recorded: nothing to resume" if hint == "" else
              f"interrupted: finished trials are kept{f'; continue it with: {hint}' if hint else ''}", file=sys.stderr)
        return 130


def _interrupted(exc: BaseException | None) -> SweepInterrupted | None:
    """The sweep's own interrupt, also under a second Ctrl-C that came while it stopped (Python chains it as the
    context of the second)."""
    while exc is not None and not isinstance(exc, SweepInterrupted):
        exc = exc.__context__
    return exc


def _cmd_run(args: argparse.Namespace) -> int:
    sets = set_flags(args.sets)

    def hint(exc: KeyboardInterrupt) -> str:
        """The command that continues the interrupted invocation ("": none was recorded)."""
        recorded = _interrupted(exc)
        stamp = (recorded.stamp if recorded else None) or (args.resume if isinstance(args.resume, str) else None)
        if stamp is None and not args.resume:
            return ""
        return f"flashnav sweep run {shlex.quote(args.sweep)} --resume{f' {stamp}' if stamp else ''}{sets}"

    return _guard(lambda: run_sweep(args.sweep, address=args.address, resume=args.resume,
                                    dry_run=args.dry_run, sets=args.sets), hint)


def _cmd_submit(args: argparse.Namespace) -> int:
    return _guard(lambda: submit_sweep(args.sweep, address=args.address, resume=args.resume, sets=args.sets,
                                       env=args.env, wait=not args.no_wait, module=args.module))


def register_cli(subparsers) -> None:
    """Entry point ``flashnav.commands: sweep``: adds ``flashnav sweep run|submit``."""
    parser = subparsers.add_parser("sweep", help=HELP, description=HELP)
    _add_commands(parser.add_subparsers(dest="sweep_command", metavar="{run,submit}", required=True))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.sweep_cli", description=HELP)
    _add_commands(parser.add_subparsers(dest="sweep_command", metavar="{run,submit}", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    # Ray pickles only what services.sweep defines, imported above as a package module, never `__main__`
    sys.exit(main())
