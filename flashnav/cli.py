"""The ``flashnav`` command.

Library subcommands live here; the experiment service adds its own (``sweep``, ``services``,
``report``) through the ``flashnav.commands`` entry-point group, so the library never imports it.
"""

from __future__ import annotations

import argparse
import sys
from importlib.metadata import entry_points
from pathlib import Path


#: Top-level modules of the optional ``services`` extra: a plugin command whose import fails on one of
#: these is shown as unavailable (with the install hint); any other ImportError is a bug and raises.
_SERVICE_EXTRAS = ("ray", "mlflow", "optuna", "pandas")


def _add_library_commands(sub: argparse._SubParsersAction) -> None:
    from flashnav import demo, policy_cli
    from flashnav.bench import cli as bench_cli
    from flashnav.deploy import cli as deploy_cli
    from flashnav.learn import cli as learn_cli

    demo.register_cli(sub)
    bench_cli.register_cli(sub)
    policy_cli.register_cli(sub)
    learn_cli.register_cli(sub)
    deploy_cli.register_cli(sub)


def _unavailable(sub: argparse._SubParsersAction, name: str, exc: BaseException) -> None:
    p = sub.add_parser(name, help=f"(unavailable: {exc})")

    def fail(args) -> int:
        print(f"flashnav {name}: unavailable: {exc}", file=sys.stderr)
        return 2

    p.set_defaults(func=fail)


def _add_plugin_commands(sub: argparse._SubParsersAction) -> None:
    for ep in entry_points(group="flashnav.commands"):
        try:
            register = ep.load()
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] not in _SERVICE_EXTRAS:
                raise  # the project's own code is broken: say so, never hide it as "unavailable"
            _unavailable(sub, ep.name, f"{exc} (install the extra: pip install 'flashnav[services]')")
            continue
        register(sub)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flashnav",
        description="Train deployable 2D-LiDAR navigation policies in seconds.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="on an error, show the full traceback instead of the one-line message")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_library_commands(sub)
    _add_plugin_commands(sub)
    return parser


#: what a user can cause with a bad input or a bad environment (a wrong value, a missing or unwritable
#: file, a misspelt key): one line on stderr and exit status 2. Anything else is a bug and keeps its
#: traceback.
USER_ERRORS = (ValueError, OSError, KeyError, MemoryError)


def error_line(exc: BaseException) -> str:
    """The error as one line: pydantic's multi-line report becomes ``loc: message; ...``."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        from flashnav.config_base import error_lines

        return f"invalid {exc.title}: " + "; ".join(error_lines(exc))
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    if isinstance(exc, MemoryError):  # numpy's says what it could not allocate
        text = (f"out of memory ({text or 'MemoryError'}): fewer environments, evaluation episodes or replay "
                "transitions, or a machine with more memory")
    return " ".join(text.split()) or type(exc).__name__


def _command_parser(parser: argparse.ArgumentParser, args) -> argparse.ArgumentParser:
    """The parser of the command (and subcommand) ``args`` ran, so that an error shows its usage; else ``parser``
    (argparse keeps a parser's subcommands in its private ``_subparsers`` group; stable since Python 3.2)."""
    for action in parser._subparsers._group_actions if parser._subparsers else ():
        chosen = action.choices.get(getattr(args, action.dest, None) or "")
        if chosen is not None:
            return _command_parser(chosen, args)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    # key=value overrides may come before and after options (`train maps.count=16 --out D eval.episodes=256`):
    # argparse leaves those after an option unparsed; they join the command's overrides, anything else
    # is the usual error
    if extra:
        if not hasattr(args, "overrides") or any(a.startswith("-") or "=" not in a for a in extra):
            hint = ""
            if any(Path(a).exists() for a in extra):  # the shell expanded a --maps / --eval-maps pattern
                hint = " (a glob the shell expanded? quote it: --maps 'DIR/*.yaml')"
            _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}{hint}")
        args.overrides = list(args.overrides or []) + extra
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except USER_ERRORS as exc:
        if args.debug:
            raise
        print(f"flashnav {args.command}: error: {error_line(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
