"""``granlab experiment NAME [--model M] [--zeta Z] [--mu MU] [--dt DT] [--json]``: a teaching experiment
(collision, closed-path, block) against its formula."""

from __future__ import annotations


from granlab.engine.params import TANGENTIAL_MODELS

from .options import number


def _experiment(args) -> dict:
    from granlab.engine.compilation import compile_sets, step_sets
    from granlab.engine.protocols.teaching import EXPERIMENTS

    options = {key: getattr(args, key) for key in ("zeta", "mu", "dt") if getattr(args, key) is not None}
    models = TANGENTIAL_MODELS if args.model == "all" else (args.model,)
    compile_sets(step_sets(models))
    results = [dict(EXPERIMENTS[args.name](model=model, **options).as_dict(), experiment=args.name)
               for model in models]
    return {"experiment": args.name, "models": results} if args.model == "all" else results[0]


def _print_experiment(result: dict) -> None:
    for one in result.get("models", [result]):
        _print_one_experiment(one)


def _print_one_experiment(result: dict) -> None:
    name = result["experiment"]
    if name == "collision":
        print(f"collision ({result['model']}, zeta = {result['zeta']}, dt = {result['dt']:.3g})")
        print(f"  restitution {result['restitution']:.6f}  predicted exp(-pi zeta/sqrt(1-zeta^2)) = "
              f"{result['restitution_predicted']:.6f}")
        print(f"  contact duration {result['contact_duration']:.6g}  predicted {result['contact_duration_predicted']:.6g}")
    elif name == "closed-path":
        print(f"closed path of ratcheting Fig. 8 ({result['model']})")
        print(f"  enclosed area a = {result['enclosed_area']:.6g}")
        print(f"  change of D_t = {result['delta_Dt']:.6g}  predicted (Eq. 17) {result['predicted_delta_Dt']:.6g}")
        print(f"  slid: {result['slid']}; the disk came back to within {result['final_position_error']:.2g} of A")
    else:
        print(f"block on a plane (mu = {result['mu']}, normal load {result['normal_load']})")
        print(f"  max |F_t| / (mu F_n) = {result['max_Ft_over_muFn']:.6f} (the Coulomb cone allows at most 1)")
        print(f"  slid from load/mu F_n = {result['slide_start_load_ratio']:.4f} until "
              f"{result['slide_end_load_ratio']:.4f}; stuck again: {result['stuck_again']}")
        print(f"  friction work per slide: {', '.join(f'{w:.4g}' for w in result['friction_work_per_slide'])} "
              f"(positive work: {result['friction_work_positive']})")


def add(commands) -> None:
    experiment = commands.add_parser("experiment", help="a teaching experiment against its formula")
    experiment.add_argument("name", choices=("collision", "closed-path", "block"))
    experiment.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS + ("all",),
                            help="tangential spring model (all: each registered model in turn)")
    experiment.add_argument("--zeta", type=number, help="normal damping ratio zeta in [0, 1)")
    experiment.add_argument("--mu", type=number, help="friction coefficient (inf: no sliding)")
    experiment.add_argument("--dt", type=number, help="time step (default: from the stability bound)")
    experiment.add_argument("--json", action="store_true", help="print one JSON object")
    experiment.set_defaults(handler=_experiment, printer=_print_experiment)
