"""``granlab serve``: the browser lab (its engine thread, 3D scene and dashboard), on 127.0.0.1 unless told
otherwise; its options are checked before panel, bokeh, viser and numba are imported."""

from __future__ import annotations


def add(commands) -> None:
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
    serve.add_argument("--max-viewers", type=int, metavar="N",
                       help="viewers' pages the lab holds at once; one more is told the class is full (default 60)")
    serve.set_defaults(handler=None, printer=None)


def serve(args) -> int:
    """Check the options, then serve until stopped; the exit status (130 after Ctrl-C, 143 after SIGTERM)."""
    from granlab.app.lab.options import HISTORY_MIB, MAX_VIEWERS, PAUSE_WITHOUT_PAGES, check_serve_options

    limits = {"history_mib": HISTORY_MIB if args.history_mib is None else args.history_mib,
              "pause_without_pages": PAUSE_WITHOUT_PAGES if args.pause_without_pages is None
              else args.pause_without_pages,
              "max_viewers": MAX_VIEWERS if args.max_viewers is None else args.max_viewers}
    check_serve_options(args.host, args.port, args.data_dir, **limits)
    from granlab.app.lab.server import serve as serve_lab

    changes = {key: getattr(args, key) for key in ("particles", "seed") if getattr(args, key) is not None}
    return serve_lab(host=args.host, port=args.port, data_dir=args.data_dir, preset=args.preset, tokens=args.tokens,
                     **limits, **changes)
