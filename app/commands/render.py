"""``granlab render RUNFILE --out FILE``: pictures and movies of a run file for slides
(:mod:`granlab.app.media.render`)."""

from __future__ import annotations

import math
import sys
import time


def add(commands) -> None:
    # Every render option is read as text and checked by app.render, so that a wrong value is
    # one line naming the option and what is allowed (argparse would print its usage too).
    render = commands.add_parser("render", help="pictures and movies of a run file for slides (.png, .gif, .mp4)")
    render.add_argument("runfile", help="a GranLab run file")
    render.add_argument("--out", required=True, metavar="FILE",
                        help="FILE.png (one picture; one per frame, FILE_00012.png, for several), FILE.gif or FILE.mp4")
    render.add_argument("--frames", metavar="A:B:S",
                        help="a frame K or a range A:B:S, negative counting from the end; a range starting with "
                             "'-' is written --frames=-10: (default: the last frame for .png; for a movie the last "
                             "10 load cycles, or clock units, of a run that names its cycle, else its last 100 frames)")
    render.add_argument("--size", default="1280x720", metavar="WxH", help="picture size in pixels (default 1280x720)")
    render.add_argument("--color", default="rotation", metavar="FIELD",
                        help="disk colours: rotation, coordination, pressure or sliding (default rotation)")
    render.add_argument("--no-forces", action="store_true", help="leave out the force network")
    render.add_argument("--fps", default="10", metavar="F", help="frames per second of a movie (default 10)")
    render.add_argument("--force", action="store_true", help="write over existing pictures or movies")
    render.add_argument("--json", action="store_true", help="print one JSON object")
    render.set_defaults(handler=_render, printer=_print_render)


def _render(args) -> dict:
    from granlab.app.media.render import render_run

    return render_run(args.runfile, args.out, args.frames, args.size, args.color, not args.no_forces, args.fps,
                      args.force, progress=FrameProgress("rendering"))


class FrameProgress:
    """``rendering frame 12 of 100`` on standard error: on one line a terminal rewrites, else a
    line at most once a second (and at the end)."""

    def __init__(self, verb: str):
        self.verb, self.shown = verb, -math.inf

    def __call__(self, done: int, total: int) -> None:
        if sys.stderr.isatty():
            print(f"\r{self.verb} frame {done} of {total}", end="\n" if done == total else "", file=sys.stderr,
                  flush=True)
        elif done == total or time.monotonic() - self.shown >= 1.0:
            self.shown = time.monotonic()
            print(f"{self.verb} frame {done} of {total}", file=sys.stderr, flush=True)


def _print_render(result: dict) -> None:
    from granlab.app.media.render import print_summary

    print_summary(result)
