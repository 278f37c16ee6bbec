"""What several commands share: option types whose errors are one line, and the progress lines of long work."""

from __future__ import annotations

import argparse
import sys


def number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (inf is allowed)") from None


def progress_line(line: str) -> None:
    """A preparation's progress, once a second, on standard error: standard output keeps the result."""
    print(line, file=sys.stderr, flush=True)


ROLLING_DAMPING_HELP = ("damping ratio of a viscous rolling moment with --rolling (default 0.8; 0 is Gilabert's "
                        "undamped rolling spring, with which a disk held by one contact never stops swinging)")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: a whole number > 0")
    return value
