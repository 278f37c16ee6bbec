"""The ``granlab`` command: the engine's commands (:mod:`granlab.engine.cli`), ``serve`` (the lab),
``render`` (pictures and movies of a run file, :mod:`granlab.app.media.render`), ``export`` (run files for
ParaView, OVITO and MDAnalysis, :mod:`granlab.engine.io.export`) and ``bench --lab`` (the lab's benchmark)."""

from __future__ import annotations

import math
import sys
import time

from granlab.engine import cli as engine_cli
from granlab.engine.errors import GranLabError, one_line
from granlab.engine.io.export import EXPORT_FORMATS, print_summary as print_export_summary


def build_parser():
    parser = engine_cli.build_parser()
    commands = next(action for action in parser._actions if action.dest == "command")
    serve = commands.add_parser("serve", help="start the browser lab (engine thread, 3D scene, dashboard)")
    serve.add_argument("--port", type=int, default=5006, help="dashboard port (default 5006; 0: any free port)")
    serve.add_argument("--host", default="127.0.0.1",
                       help="address to bind (default 127.0.0.1: this machine only; any other serves with tokens)")
    serve.add_argument("--tokens", action="store_true",
                       help="a presenter's and a viewers' address, each with its own token, on this machine too")
    serve.add_argument("--data-dir", default="granlab-data", help="folder for saved runs (default ./granlab-data)")
    serve.add_argument("--preset", default="ratchet", help="preset shown first (default ratchet)")
    serve.add_argument("--particles", type=int, help="number of disks of the first preset (default: the preset's)")
    serve.add_argument("--seed", type=int, help="seed of the first preset (default 0)")
    serve.add_argument("--history-mib", type=float, metavar="MIB",
                       help="memory for the frames kept for saves and movies (default 64 MiB; the oldest go first)")
    serve.add_argument("--pause-without-pages", type=float, metavar="SECONDS",
                       help="pause a run left with no page open after SECONDS; it goes on when a page opens "
                            "(default 60; 0: never)")
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
    export = commands.add_parser("export", help=f"frames of a run file for other tools ({', '.join(EXPORT_FORMATS)})")
    export.add_argument("runfile", help="a GranLab run file")
    export.add_argument("--format", required=True, choices=EXPORT_FORMATS, metavar="FORMAT",
                        help="; ".join(f"{fmt.name} ({fmt.title})" for fmt in EXPORT_FORMATS.values()))
    export.add_argument("--out", required=True, metavar="DIR|FILE",
                        help="; ".join(f"{f'FILE{fmt.suffix}' if fmt.suffix else 'a folder'} for {fmt.name}"
                                       for fmt in EXPORT_FORMATS.values()))
    export.add_argument("--frames", metavar="A:B:S",
                        help="a frame K or a range A:B:S, negative counting from the end (default: every frame)")
    export.add_argument("--force", action="store_true", help="write over existing files")
    export.add_argument("--json", action="store_true", help="print one JSON object")
    export.set_defaults(handler=_export, printer=_print_export)
    bench = commands.choices["bench"]
    bench.add_argument("--lab", action="store_true",
                       help="benchmark the lab instead: a served preset streaming to a headless Chromium tab")
    bench.add_argument("--seconds", type=float, default=20.0, help="length of each lab measurement (default 20 s)")
    bench.add_argument("--tabs", type=int, default=100,
                       help="tabs opened and closed by the lab benchmark (default 100)")
    bench.add_argument("--viewers", type=int, metavar="N",
                       help="with --lab: a classroom instead, one presenter and N viewers as light clients (nothing "
                            "drawn) on the lab served with tokens, at 256 and 5600 disks (or --particles)")
    return parser


def _render(args) -> dict:
    from .media.render import render_run

    return render_run(args.runfile, args.out, args.frames, args.size, args.color, not args.no_forces, args.fps,
                      args.force, progress=_FrameProgress("rendering"))


class _FrameProgress:
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
    from .media.render import print_summary

    print_summary(result)


def _export(args) -> dict:
    from granlab.engine.io.export import export_run

    return export_run(args.runfile, args.format, args.out, args.frames, args.force,
                      progress=_FrameProgress("exporting"))


def _print_export(result: dict) -> None:
    print_export_summary(result)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "serve":
            from .lab.options import HISTORY_MIB, PAUSE_WITHOUT_PAGES, check_serve_options

            limits = {"history_mib": HISTORY_MIB if args.history_mib is None else args.history_mib,
                      "pause_without_pages": PAUSE_WITHOUT_PAGES if args.pause_without_pages is None
                      else args.pause_without_pages}
            check_serve_options(args.host, args.port, args.data_dir, **limits)
            from .lab.server import serve

            changes = {key: getattr(args, key) for key in ("particles", "seed") if getattr(args, key) is not None}
            serve(host=args.host, port=args.port, data_dir=args.data_dir, preset=args.preset, tokens=args.tokens,
                  **limits, **changes)
            return 0
        if args.command == "bench" and args.viewers is not None and not args.lab:
            raise GranLabError("--viewers goes with --lab: granlab bench --lab --viewers N")
        if args.command == "bench" and args.lab:
            from .lab import bench

            args.handler, args.printer = bench.handler, bench.print_result
    except GranLabError as error:
        print(f"granlab {args.command}: error: {one_line(str(error))}", file=sys.stderr)
        return 2
    return engine_cli.run_args(args)


if __name__ == "__main__":
    sys.exit(main())
