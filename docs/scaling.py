"""The scaling curve of docs/performance.md: ``granlab bench --scaling`` drawn as cost per particle-step
and bytes per disk against the number of disks.

    python docs/scaling.py [--out docs/images/scaling.png] [--steps 1000]

Runs the reference system at 10³, 10⁴, 10⁵ and 10⁶ disks on one thread (a minute or two; the
10⁶-disk system takes about 1.4 GB), prints the table and writes the picture.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from granlab.engine import bench


def draw(result: dict, out: Path) -> None:
    rows = result["sizes"]
    disks = [row["particles"] for row in rows]
    figure = Figure(figsize=(8, 3.6), dpi=100)
    FigureCanvasAgg(figure)
    cost, memory = figure.subplots(1, 2)
    cost.plot(disks, [row["ns_per_particle_step"] for row in rows], "o-", color="#1f77b4")
    best = min(row["ns_per_particle_step"] for row in rows)
    cost.axhline(1.5 * best, color="#d62728", linestyle="--", label="1.5 × the best size")
    cost.set(xscale="log", xlabel="disks N", ylabel="ns per particle-step (1 thread)", ylim=(0, 2.0 * best),
             title="Cost per particle-step")
    cost.legend(loc="lower right", fontsize=9)
    memory.plot(disks, [row["bytes_per_disk"] for row in rows], "o-", color="#2ca02c")
    memory.set(xscale="log", xlabel="disks N", ylabel="bytes of state per disk", title="Memory per disk",
               ylim=(0, 1.3 * max(row["bytes_per_disk"] for row in rows)))
    for axes in (cost, memory):
        axes.grid(True, alpha=0.3)
    figure.tight_layout()
    figure.savefig(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "images" / "scaling.png"))
    parser.add_argument("--steps", type=int, default=bench.SCALING_STEPS)
    args = parser.parse_args()
    result = bench.scaling(steps=args.steps)
    for row in result["sizes"]:
        print(f"{row['particles']:>8} disks: {row['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s, "
              f"{row['ns_per_particle_step']:.1f} ns each, {row['bytes_per_disk']:.0f} bytes/disk, a rebuild "
              f"{row['rebuild_in_steps']:.1f} steps, {row['rebuilds']} rebuilds ({100 * row['rebuild_share']:.1f} %)")
    print(f"slowest over fastest: {result['worst_over_best']:.2f}")
    draw(result, Path(args.out))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
