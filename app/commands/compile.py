"""``granlab compile [--only SET...]``: compile the kernels before their first use (:mod:`granlab.engine.compilation`)."""

from __future__ import annotations

import time


from .options import positive_int


def add(commands) -> None:
    from granlab.engine.compilation import KERNEL_SETS

    compile_ = commands.add_parser("compile", help="compile every kernel now (a first run then starts at once): the "
                                                   "night before a class, or after an upgrade")
    compile_.add_argument("--only", nargs="+", choices=tuple(KERNEL_SETS), metavar="SET",
                          help="these kernel sets only: " + ", ".join(KERNEL_SETS))
    compile_.add_argument("--workers", type=positive_int, help="processes compiling side by side (default: one a "
                                                                "core)")
    compile_.add_argument("--json", action="store_true", help="print one JSON object")
    compile_.set_defaults(handler=_compile, printer=_print_compile)


def _compile(args) -> dict:
    import numba

    from granlab.engine.compilation import KERNEL_SETS, compile_sets, missing, not_kept
    from granlab.engine.errors import GranLabError
    from granlab.engine.kernels.cache import cache_root

    start = time.perf_counter()
    names = args.only or tuple(KERNEL_SETS)
    if numba.config.NUMBA_NUM_THREADS < 2:  # one core: nothing runs the several-thread code
        names = [name for name in names if not name.endswith("-threads")]
    compiled = compile_sets(names, workers=args.workers)
    unkept = missing(names, loaded=False)
    if unkept:
        raise GranLabError(f"{len(unkept)} of {len(names)} kernel sets are not in the kernel cache after compiling "
                           f"them ({', '.join(kernel_set.name for kernel_set in unkept)}): {not_kept()}; the next run "
                           "compiles them again")
    return {"compiled": compiled, "already": [name for name in names if name not in compiled],
            "seconds": time.perf_counter() - start, "cache": str(cache_root())}


def _print_compile(result: dict) -> None:
    if result["compiled"]:
        print(f"compiled {len(result['compiled'])} kernel sets in {result['seconds']:.0f} s "
              f"({len(result['already'])} were compiled before), kept in {result['cache']}")
    else:
        print(f"every kernel set was compiled before ({len(result['already'])}), kept in {result['cache']}")
