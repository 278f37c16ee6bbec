"""``granlab bench [--steps S] [--json]``: particle-steps per second on the LAMMPS reference system
(``--scaling``, ``--profile``; ``--analysis PACKING.h5``: the wall time of every analysis instead; ``--lab``:
the lab's benchmark, :mod:`granlab.app.lab.bench`)."""

from __future__ import annotations


from granlab.engine.errors import GranLabError
from granlab.engine.params import BACKENDS, TANGENTIAL_MODELS

from .options import positive_int


def _bench(args) -> dict:
    import numba

    from granlab.engine import bench

    if args.beside_engine and not args.analysis:
        raise GranLabError("--beside-engine times the analyses of --analysis PACKING.h5: give that too")
    if args.analysis:
        if args.beside_engine:
            return bench.analysis_beside_engine(args.analysis, args.particles or bench.ANALYSIS_PARTICLES)
        return bench.analysis(args.analysis, args.particles or bench.ANALYSIS_PARTICLES)
    steps = args.steps or (bench.SCALING_STEPS if args.scaling else bench.TIMED_STEPS)
    if steps < 1 or not 2 <= args.side <= 1000:
        raise GranLabError(f"bench takes --steps >= 1 and 2 <= --side <= 1000, not {steps} and {args.side}")
    if args.check is not None and args.backend != "cuda":
        raise GranLabError("--check compares a run on the device with the CPU engine: give --backend cuda too")
    if args.batch is not None:
        return bench.batch_study(args.batch, args.backend)
    if args.backend == "cuda":
        from granlab.engine.cuda import check_backend

        check_backend("cuda")
        if args.check is not None:
            return bench.device_check(args.check, args.side, args.model)
        return bench.device(steps, args.side, args.model)
    if args.scaling:
        return bench.scaling(steps=steps)
    if args.profile:
        return bench.profile(args.side, args.steps or 1000)
    from granlab.engine.compilation import compile_sets, step_sets

    compile_sets(step_sets([args.model]) + step_sets([args.model], threads=numba.config.NUMBA_NUM_THREADS > 1))
    return bench.run(steps, args.side, args.model)


def _print_bench(result: dict) -> None:
    if "batch_s" in result:
        print(result["system"])
        print(f"  side by side in one batch: {result['batch_s']:.2f} s, {1e3 * result['batch_per_sample_s']:.1f} ms a sample")
        print(f"  one after another, one thread: {result['alone_s']:.2f} s for {result['alone_samples']} samples, "
              f"{1e3 * result['alone_per_sample_s']:.1f} ms a sample ({result['speedup_per_sample']:.2f}x the batch's)")
        return
    if "check" in result:
        check = result["check"]
        worst = max(check["differences"], key=check["differences"].get)
        print(result["system"])
        print(f"  after {check['steps']} steps on the device and on the CPU: largest relative difference "
              f"{check['worst']:.2e} ({worst}), allowed {check['tolerance']:.0e}: "
              + ("agree" if result["exit_status"] == 0 else "DIFFER"))
        if not check["same_contacts"]:
            print("  the two contact tables differ (rows or status): their springs are not compared")
        return
    if result.get("backend") == "cuda":
        print(result["system"])
        print(f"  {result['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s")
        return
    if "contact_pass_ns_per_row" in result:
        step = result["ns_per_particle_step"]
        print(result["system"])
        print(f"  a particle-step: {step:.1f} ns ({1e3 / step:.1f} M particle-steps/s)")
        print(f"  contact pass:    {result['contact_pass_ns_per_disk']:.1f} ns per disk "
              f"({result['rows_per_disk']:.2f} rows per disk, {result['contact_pass_ns_per_row']:.1f} ns per row), "
              f"{100 * result['contact_pass_ns_per_disk'] / step:.0f} %; every row directly: "
              f"{result['direct_contact_pass_ns_per_row']:.1f} ns per row")
        print(f"  particle pass:   {result['particle_pass_ns_per_disk']:.1f} ns per disk, "
              f"{100 * result['particle_pass_ns_per_disk'] / step:.0f} %")
        if result["other_ns_per_disk"] > 0:
            print(f"  the rest:        {result['other_ns_per_disk']:.1f} ns per disk (walls, cell, tallies, checks), "
                  f"{100 * result['other_ns_per_disk'] / step:.0f} %")
        else:
            print("  the rest:        below the noise (the two passes timed apart take longer than in a step)")
        print(f"  one rebuild of the contact table: {result['rebuild_in_steps']:.1f} steps")
        return
    if "sizes" in result:
        print(result["system"])
        print(f"  {'disks':>9} {'steps':>6} {'M particle-steps/s':>19} {'ns/particle-step':>17} {'bytes/disk':>11} "
              f"{'a rebuild, in steps':>20} {'rebuilds':>9} {'rebuild share':>14}")
        for row in result["sizes"]:
            print(f"  {row['particles']:>9} {row['steps']:>6} {row['particle_steps_per_s'] / 1e6:>19.2f} "
                  f"{row['ns_per_particle_step']:>17.1f} {row['bytes_per_disk']:>11.0f} {row['rebuild_in_steps']:>20.1f} "
                  f"{row['rebuilds']:>9} {100 * row['rebuild_share']:>13.1f}%")
        print(f"  slowest size over fastest, per particle-step: {result['worst_over_best']:.2f}")
        return
    if "beside_engine" in result:
        print(f"analyses of {result['packing']} ({result['particles']} disks) beside a simulation of it on one "
              f"thread ({result['engine_steps_per_s_alone']:.0f} steps/s alone; {result['cores']} cores, "
              f"{result['free_threads']} free)")
        print(f"  {'analysis':<10}{'alone':>9}{'beside, every core':>26}{'beside, free cores':>26}")
        for kind, row in result["beside_engine"].items():
            print(f"  {kind:<10}{row['alone_s']:>8.3f}s"
                  + "".join(f"{row[name + '_s']:>12.3f}s, engine "
                          + ("    -" if row[name + "_engine_share"] is None else f"{row[name + '_engine_share']:>5.2f}")
                          for name in ("every_core", "free_cores")))
        return
    if "fractal_s" in result:
        print(f"analysis of {result['packing']}: {result['particles']} disks, {result['contacts']} contacts"
              + (f" (prepared in {result['preparation_s']:.0f} s)" if result["preparation_s"] else ""))
        for kind, values in result["values"].items():
            if "error" in values:
                print(f"  {kind}: error: {values['error']}")
                continue
            timing = result["timings_s"][kind]
            stages = ", ".join(f"{k} {v:.3f}" for k, v in timing.items() if k != "total")
            print(f"  {kind}: {timing['total']:.3f} s ({stages})")
        return
    print(result["system"])
    print(f"  1 thread:  {result['particle_steps_per_s_1thread'] / 1e6:.2f} M particle-steps/s")
    print(f"  {result['threads_all']} threads: {result['particle_steps_per_s_all'] / 1e6:.2f} M particle-steps/s "
          f"(speed-up {result['speedup']:.2f})")


def add(commands) -> None:
    bench = commands.add_parser("bench", help="particle-steps per second on the LAMMPS reference system")
    bench.add_argument("--steps", type=int, help="timed steps (default 5000; with --scaling 1000 at each size)")
    bench.add_argument("--scaling", action="store_true",
                       help="the reference system at 10^3, 10^4, 10^5 and 10^6 disks on one thread: particle-steps "
                            "per second, bytes per disk and the share of rebuilds at each size (a minute or two)")
    bench.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS,
                       help="tangential model (lammps: integrated as LAMMPS does it)")
    bench.add_argument("--profile", action="store_true",
                       help="where a particle-step goes on one thread: contact pass per row, pass over the disks, "
                            "the rest, a rebuild")
    bench.add_argument("--side", type=int, default=100, help="disks per side of the lattice (default 100: 10 000)")
    bench.add_argument("--backend", choices=BACKENDS, default="cpu",
                       help="where the steps run: the CPU's threads (default), or an NVIDIA GPU (numba.cuda)")
    bench.add_argument("--batch", type=positive_int, metavar="SAMPLES",
                       help="a ratchet study's cycles, SAMPLES boxes of 16 disks side by side in one batch against "
                            "10 of them one after another (on --backend)")
    bench.add_argument("--check", type=positive_int, metavar="N",
                       help="with --backend cuda: run N steps on the device and on the CPU and compare them; exit 1 "
                            "when they differ by more than 1e-12 (relative)")
    bench.add_argument("--analysis", metavar="PACKING.h5",
                       help="time every analysis of 'granlab analyze' on this packing instead (prepared there by "
                            "method 1 if missing)")
    bench.add_argument("--beside-engine", action="store_true",
                       help="with --analysis: run each analysis beside a simulation of the packing on one thread, "
                            "with every core and with the cores it leaves free, as in the lab")
    bench.add_argument("--particles", type=positive_int, help="disks of a prepared packing or of the lab (default 5600)")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.add_argument("--lab", action="store_true",
                       help="benchmark the lab instead: a served preset streaming to a headless Chromium tab")
    bench.add_argument("--seconds", type=float, default=20.0, help="length of each lab measurement (default 20 s)")
    bench.add_argument("--tabs", type=int, default=100,
                       help="tabs opened and closed by the lab benchmark (default 100)")
    bench.add_argument("--viewers", type=int, metavar="N",
                       help="with --lab: a classroom instead, one presenter and N viewers as light clients (nothing "
                            "drawn) on the lab served with tokens, at 256 and 5600 disks (or --particles)")
    bench.add_argument("--storm", action="store_true",
                       help="with --lab --viewers N: N viewers joining and leaving at once for --seconds, and 6 that "
                            "never read; /status's latency and the server's memory throughout and after")
    bench.add_argument("--soak", action="store_true",
                       help="with --lab: one presenter and --viewers N (10) viewers' pages open for --seconds (3600 "
                            "for an hour); the server's memory over that time and what the lab holds")
    bench.set_defaults(handler=_bench, printer=_print_bench)


def choose_handler(args) -> None:
    """``--lab`` benchmarks the lab instead (:mod:`granlab.app.lab.bench`); ``--viewers`` goes with it."""
    if args.viewers is not None and not args.lab:
        raise GranLabError("--viewers goes with --lab: granlab bench --lab --viewers N")
    if args.storm and not args.lab:
        raise GranLabError("--storm goes with --lab: granlab bench --lab --storm --viewers N")
    if args.soak and not args.lab:
        raise GranLabError("--soak goes with --lab: granlab bench --lab --soak --seconds 3600")
    if args.lab:
        from granlab.app.lab import bench as lab_bench

        args.handler, args.printer = lab_bench.handler, lab_bench.print_result
