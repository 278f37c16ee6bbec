"""``granlab analyze RUNFILE {stiffness,status,rigidity,packing,fractal} [--frame K] [--json]``: quasi-static
and structural analysis of one frame (:mod:`granlab.engine.analysis.report`)."""

from __future__ import annotations

import sys

from granlab.engine.analysis import ANALYSES, LOADS

from .options import number


LAW_OPTIONS = {"friction": ("--mu", "mu"), "normal_stiffness": ("--kn", "K_n"),
               "tangential_stiffness": ("--kt", "K_t")}
"""The contact law's values ``analyze`` takes from its options when a file carries none: option, symbol."""


def _analyze(args) -> dict:
    from granlab.engine.analysis.plausibility import implausible
    from granlab.engine.analysis.report import analyze
    from granlab.engine.analysis.states import read_state

    given = {key: getattr(args, option[2:]) for key, (option, _) in LAW_OPTIONS.items()
             if getattr(args, option[2:]) is not None}
    columns = tuple(args.contact_columns.replace(",", " ").split()) if args.contact_columns else None
    state = read_state(args.runfile, args.frame, law=given, contacts=args.contacts, contact_columns=columns)
    warnings = implausible(state)
    for warning in warnings:  # before the work: a wrong reading is told at once
        print(f"granlab analyze: warning: {warning}", file=sys.stderr, flush=True)
    result = analyze(state, args.analysis, load=args.load, seed=args.seed).as_dict()
    result.update(run_file=args.runfile, source=state.source, particles=state.disks, forces_known=state.forces_known,
                  law={"friction": state.law.friction, "normal_stiffness": state.law.normal_stiffness,
                       "tangential_stiffness": state.law.tangential_stiffness,
                       "assumed": [] if state.law_given else [key for key in LAW_OPTIONS if key not in given]},
                  warnings=warnings)
    return result


def _print_analysis(result) -> None:
    """The rows of the report (:meth:`granlab.engine.analysis.report.AnalysisReport.rows`) that ``result``
    (a :class:`granlab.engine.analysis.report.ReportDict`) keeps: "label: text  (note)", the texts aligned."""
    print(f"{result['analysis']} of {result['source']} ({result['particles']} disks"
          + ("" if result["forces_known"] else "; contacts from the geometry, no forces") + ")")
    law = result["law"]
    if law["assumed"]:
        values = {key: f"{LAW_OPTIONS[key][1]} = {law[key]:g}" for key in LAW_OPTIONS}
        given = [values[key] for key in LAW_OPTIONS if key not in law["assumed"]]
        print("  contact law assumed, the file carries none: "
              + ", ".join(f"{values[key]} ({LAW_OPTIONS[key][0]})" for key in law["assumed"])
              + (f"; given: {', '.join(given)}" if given else ""))
    rows = result.report.rows()
    width = max((len(row.label) for row in rows), default=0) + 1
    for row in rows:
        print(f"  {row.label + ':':<{width}} {row.text}" + (f"  ({row.note})" if row.note else ""))
    print("  time: " + ", ".join(f"{k} {v:.3g} s" for k, v in result["timings_s"].items()))


def add(commands) -> None:
    analyze = commands.add_parser("analyze", help="quasi-static and structural analysis of one frame of a run file, "
                                                  "an H5MD file, a LAMMPS dump or an extended XYZ file")
    analyze.add_argument("runfile", metavar="FILE",
                         help="a GranLab run file, an H5MD file with positions, radii and a 2D box, a LAMMPS dump "
                              "custom (id x y radius|diameter) or an extended XYZ file (radius, Lattice, pbc)")
    analyze.add_argument("analysis", choices=ANALYSES,
                         help="; ".join(f"{name}: {analysis.title}" for name, analysis in ANALYSES.items()))
    analyze.add_argument("--frame", type=int, default=-1, help="frame index (negative counts from the end; default -1)")
    analyze.add_argument("--load", choices=LOADS, default="auto",
                         help="load increment of stiffness and status (default auto: the walls' loads, else random; "
                              "cell: the target stress of a cell under stress control)")
    analyze.add_argument("--seed", type=int, default=0, help="seed of the random load increment")
    analyze.add_argument("--mu", type=number,
                         help="friction coefficient to assume (default: the run's; other codes' files: 0.5)")
    analyze.add_argument("--kn", type=number, help="normal stiffness K_n to assume (default: the run's; else 1000)")
    analyze.add_argument("--kt", type=number, help="tangential stiffness K_t to assume (default: the run's; else 1000)")
    analyze.add_argument("--contacts", metavar="FILE",
                         help="a LAMMPS dump local of the contacts (compute pair/local) at the dump's timesteps")
    analyze.add_argument("--contact-columns", metavar="NAMES",
                         help="what each column of --contacts holds, in order: id1 id2 fx fy [ftx fty], - for a "
                              "column to leave out (default: the names in its header)")
    analyze.add_argument("--json", action="store_true", help="print one JSON object")
    analyze.set_defaults(handler=_analyze, printer=_print_analysis)
