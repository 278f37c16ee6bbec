"""``granlab prepare --method {compress,1,2} [options] [--json]``: a packing in equilibrium."""

from __future__ import annotations


from granlab.engine import costs
from granlab.engine.errors import ParameterError
from granlab.engine.params import BACKENDS, GILABERT_DT_SAFETY

from .options import ROLLING_DAMPING_HELP, number, positive_int, progress_line


def _prepare(args) -> dict:
    import numba

    from granlab.engine.analysis.packing import packing_stats
    from granlab.engine.compilation import compile_sets, step_sets
    from granlab.engine.cuda import check_backend
    from granlab.engine.io.h5md import RunWriter
    from granlab.engine.io.outputs import check_output
    from granlab.engine.protocols import prepare
    from granlab.engine.simulation import PARALLEL_MIN_DISKS

    check_backend(args.backend)
    if args.out:
        check_output(args.out, force=args.force)
    costs.check_memory(args.particles, "--particles")
    if args.method == "compress" and args.dt_safety is not None:
        raise ParameterError("--dt-safety", args.dt_safety, "an option of --method 1 and 2 only")
    threaded = numba.get_num_threads() > 1 and args.particles >= PARALLEL_MIN_DISKS
    compile_sets(step_sets(["cundall-strack"], threaded) + ["state", "packing"])
    if args.method == "compress":
        prepared = prepare.compress(args.particles, seed=args.seed, pressure=args.pressure,
                                    friction=0.2 if args.mu is None else args.mu, max_time=args.max_time or 400.0,
                                    progress=progress_line, backend=args.backend)
    else:
        law = prepare.gilabert_law(friction=0.15 if args.mu is None else args.mu, kappa=args.kappa,
                                   cohesion=args.method == "2" or args.cohesive, rolling=args.rolling,
                                   pressure=args.pressure, rolling_damping_ratio=args.rolling_damping)
        args.dt_safety = GILABERT_DT_SAFETY if args.dt_safety is None else args.dt_safety  # the run file keeps it
        common = dict(count=args.particles, solid_fraction=args.solid_fraction, pressure=args.pressure, law=law,
                      seed=args.seed, progress=progress_line, dt_safety=args.dt_safety, backend=args.backend)
        if args.method == "1":
            prepared = prepare.method1(max_time=args.max_time or 2000.0, **common)
        else:
            prepared = prepare.method2(speed=args.speed, accelerated=args.accelerated,
                                       max_time=args.max_time or 4000.0, **common)
    sim = prepared.sim
    stats = packing_stats(sim.snapshot(), prepared.report.force_scale)
    run_file = args.out
    if run_file:
        with RunWriter(run_file, sim, protocol={"command": "prepare", **{k: v for k, v in vars(args).items()
                                                                          if k not in ("handler", "printer")}},
                       overwrite=args.force) as w:
            w.write_frame(sim)
            w.write_checkpoint(sim)
    return {"method": args.method, "particles": sim.particles.count, "phi": stats.phi, "z": stats.z,
            "z_star": stats.z_star, "rattlers": stats.rattlers, "equilibrated": prepared.equilibrated,
            "sim_time": prepared.sim_time, "wall_time_s": prepared.wall_time_s, "run_file": run_file,
            "pressure": prepared.pressure, "measured_pressure": prepared.report.measured_pressure,
            "equilibrium": prepared.report.as_dict()}


def _print_prepare(result: dict) -> None:
    state = "in equilibrium" if result["equilibrated"] else "NOT in equilibrium (time limit reached)"
    print(f"method {result['method']}: {result['particles']} disks {state} after t = {result['sim_time']:.4g} "
          f"({result['wall_time_s']:.2f} s)")
    print(f"  solid fraction {result['phi']:.4f}, coordination z = {result['z']:.3f} (z* = {result['z_star']:.3f}), "
          f"{result['rattlers']} rattlers; pressure {result['measured_pressure']:.6g} (imposed {result['pressure']:.6g})")
    if result["run_file"]:
        print(f"  run file: {result['run_file']}")


def add(commands) -> None:
    prepare = commands.add_parser("prepare", help="prepare a packing in equilibrium")
    prepare.add_argument("--method", required=True, choices=("compress", "1", "2"),
                         help="compress: ratcheting biaxial box; 1, 2: Gilabert's methods")
    prepare.add_argument("--particles", type=positive_int, default=None, help="number of disks")
    prepare.add_argument("--seed", type=int, default=0)
    prepare.add_argument("--pressure", type=number, default=None,
                         help="P (compress: P0 = 1 in paper units; Gilabert: P* a F0 or P with kappa = K_N/P)")
    prepare.add_argument("--mu", type=number, help="friction (compress: switched on after compression, 0.2)")
    prepare.add_argument("--solid-fraction", type=number, default=0.36, help="initial gas fraction Phi_I (1, 2)")
    prepare.add_argument("--kappa", type=number, default=1e5, help="stiffness parameter kappa (1, 2)")
    prepare.add_argument("--cohesive", action="store_true", help="method 1 with cohesion (method 2 always is)")
    prepare.add_argument("--rolling", action="store_true", help="rolling resistance (Gilabert Table I)")
    prepare.add_argument("--rolling-damping", type=number, default=0.8, metavar="ZETA_R",
                         help=ROLLING_DAMPING_HELP)
    prepare.add_argument("--speed", type=number, help="V0 of method 2 (default V* = sqrt(F0 D0))")
    prepare.add_argument("--accelerated", action="store_true", help="method 2 series B: soft, then stiffened")
    prepare.add_argument("--max-time", type=number, help="simulated-time limit of each stage")
    prepare.add_argument("--dt-safety", type=number, metavar="F",
                         help=f"methods 1 and 2: the time step as a fraction F of the stability bound, in (0, 1] "
                              f"(default {GILABERT_DT_SAFETY}; 0.3 until 27 Nov 2026)")
    prepare.add_argument("--backend", choices=BACKENDS, default="cpu",
                         help="where the steps run: the CPU's threads (default), or an NVIDIA GPU (numba.cuda)")
    prepare.add_argument("--out", help="write the packing to a run file")
    prepare.add_argument("--force", action="store_true", help="write over an existing --out file")
    prepare.add_argument("--json", action="store_true", help="print one JSON object")
    prepare.set_defaults(handler=_prepare_with_defaults, printer=_print_prepare)


def _prepare_with_defaults(args) -> dict:
    defaults = {"compress": (16, 1.0), "1": (200, 1e-2), "2": (200, 1e-2)}[args.method]
    if args.particles is None:
        args.particles = defaults[0]
    if args.pressure is None:
        args.pressure = defaults[1]
    return _prepare(args)
