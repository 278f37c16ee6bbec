"""``granlab export RUNFILE --format FORMAT --out DIR|FILE``: frames of a run file for ParaView, OVITO and
MDAnalysis (:mod:`granlab.engine.io.export`)."""

from __future__ import annotations

from granlab.engine.io.export import EXPORT_FORMATS, print_summary as print_export_summary

from .render import FrameProgress


def add(commands) -> None:
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


def _export(args) -> dict:
    from granlab.engine.io.export import export_run

    return export_run(args.runfile, args.format, args.out, args.frames, args.force,
                      progress=FrameProgress("exporting"))


def _print_export(result: dict) -> None:
    print_export_summary(result)
