"""``granlab info RUNFILE [--json]``: what a run file holds."""

from __future__ import annotations

import json


def _info(args) -> dict:
    from granlab.engine.io.h5md import summary

    return summary(args.runfile)


def _print_info(result: dict) -> None:
    print(f"{result['run_file']}: H5MD {'.'.join(map(str, result.get('h5md_version') or ['?']))} "
          f"by {result.get('creator', '?')}")
    print(f"  {result.get('particles', '?')} disks, {result['frames']} complete frames"
          + (f", t = {result['first_time']:.6g} .. {result['last_time']:.6g} (step {result['last_step']})"
             if result["frames"] else ""))
    if "cycles" in result:
        print(f"  {result['cycles']} cycle records")
    print(f"  checkpoint: {'step ' + str(result['checkpoint_step']) if result['checkpoint_step'] is not None else 'none'}")
    if "energy_last" in result:
        e = result["energy_last"]
        print(f"  last energies: kinetic {e['kinetic']:.6g}, stored {e['stored']:.6g}, balance {e['balance']:.6g}")
    for note in result.get("notes", []):
        print(f"  note: {note}")
    if result.get("protocol"):
        from granlab.engine.io.jsonsafe import jsonable

        print(f"  protocol: {json.dumps(jsonable(result['protocol']))}")


def add(commands) -> None:
    info = commands.add_parser("info", help="summarise a run file")
    info.add_argument("runfile")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(handler=_info, printer=_print_info)
