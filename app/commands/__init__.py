"""The ``granlab`` command line: one module here per command, each adding its options (``add``), its
handler and its printer; this module builds the parser from them and runs a command.

Errors print one line naming what is wrong and exit with status 2; Ctrl-C exits with 130 and
SIGTERM with 143, each after one line. ``granlab X --help`` imports neither numba nor numpy: a
command's module imports at its top only the registries its options name, and what its work needs
when it runs.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from importlib.metadata import version
from pathlib import Path

from granlab.engine.errors import GranLabError, RegistryError, WriteFailed, one_line

from . import (analyze, bench, compile as compile_command, experiment, export, info, prepare, quasistatic, render,
               reproduce, run, serve, study)

COMMANDS = (run, experiment, bench, prepare, study, reproduce, analyze, quasistatic, info, compile_command, serve,
            render, export)
"""The commands, in the order ``granlab --help`` lists them."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, as every other error of the command: the
    usage block argparse prints first would bury the line that says what is wrong."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="granlab", description="GranLab: 2D granular mechanics lab")
    parser.add_argument("--version", action="version", version=f"%(prog)s {version('granlab')}")
    commands = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    from granlab.engine.stopping import stop_on_signals

    with stop_on_signals():  # a signal from here on asks for a stop (engine/stopping.py)
        args = build_parser().parse_args(argv)
        try:
            if args.command == "serve":
                return serve.serve(args)
            if args.command == "bench":
                bench.choose_handler(args)
        except GranLabError as error:
            print(f"granlab {args.command}: error: {one_line(str(error))}", file=sys.stderr)
            return 2
        return run_args(args)


def run_args(args) -> int:
    """Run a parsed command: print its result (or one JSON object); errors exit with status 2,
    Ctrl-C with 130 and SIGTERM with 143, each after one line on standard error. A signal asks the
    work to stop where what it writes is whole (:mod:`granlab.engine.stopping`, set up by :func:`main`)."""
    from granlab.engine.stopping import Stopped

    try:
        result = _handle(args)
    except KeyboardInterrupt as stop:
        stopped = stop if isinstance(stop, Stopped) else Stopped(signal.SIGINT)
        print(f"granlab {args.command}: stopped by {stopped.by}", file=sys.stderr)
        return stopped.exit_status
    if isinstance(result, GranLabError):
        print(f"granlab {args.command}: error: {one_line(str(result))}", file=sys.stderr)
        return 2
    return _print_result(args, result)


def _handle(args):
    """The command's result, or the GranLabError that tells why there is none."""
    from granlab.engine.compilation import announced

    source = next((getattr(args, name) for name in ("runfile", "resume") if getattr(args, name, None)), None)
    try:
        if source is not None and Path(source).is_file():
            from granlab.engine.io import h5md

            h5md.probe(source)
        with announced():
            return args.handler(args)
    except RegistryError as error:  # the engine does not import: a run file cannot be judged with it
        return error
    except WriteFailed as error:
        print(f"granlab {args.command}: error: {one_line(str(error))}", file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(2)  # see WriteFailed: an exit that closes the file would crash the process
    except Exception as error:
        from granlab.engine.io import h5md

        if isinstance(error, GranLabError) and not (source and isinstance(error, h5md.DamagedRunFile)):
            return error
        if source is None or not h5md.raised_by_damage(error):
            raise
        return h5md.damaged(source, error)


def _print_result(args, result) -> int:
    from granlab.engine.io.jsonsafe import jsonable

    try:
        if args.json:
            print(json.dumps(jsonable(result)))
        else:
            args.printer(result)
        sys.stdout.flush()
    except BrokenPipeError:
        # a reader that stopped early (granlab ... | head) had what it wanted; Python's own flush
        # at exit must not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    return result.get("exit_status", 0) if isinstance(result, dict) else 0
