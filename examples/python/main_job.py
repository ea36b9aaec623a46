"""The README's main job from Python: simulate the built-in double well (seed 1), compare the
estimators on its 41 measurements against the true path, print the table and plot the paths.

    pip install ./python matplotlib
    python examples/python/main_job.py            # writes out/python/main_job.png

The table has the numbers of `cargo run --release` (same model, seed and estimators).
"""

from __future__ import annotations

import math
import os

import onsager


def main() -> None:
    model = onsager.Model.builtin("double-well")
    sim = model.simulate(seed=1)
    table = onsager.compare(model, sim.t, sim.y, truth=sim)

    def cell(v: float | None) -> str:
        return "-" if v is None else f"{v:.4f}"

    print(f"{'method':<19} {'status':<10} {'rmse_truth':>10} {'rmse_ksp':>9} {'rmse_m-opt':>11} {'seconds':>8}")
    for r in table:
        print(f"{r['label']:<19} {r['status']:<10} {cell(r['rmse_truth']):>10} {cell(r['rmse_ksp']):>9} "
              f"{cell(r['rmse_mean_optimal']):>11} {r['solve_seconds']:>8.3f}")

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install matplotlib): no figure")
        return
    labels = [label for label, e in table.estimates.items() if e is not None]
    cols = 3
    rows = math.ceil(len(labels) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.6 * rows), sharex=True, sharey=True)
    for ax, label in zip(axes.flat, labels):
        e = table.estimates[label]
        ax.plot(sim.truth_t, sim.truth_x[:, 0], color="0.6", lw=0.8, label="truth")
        ax.plot(sim.t, sim.y[:, 0], "k.", ms=3, label="data")
        ax.plot(e.t, e.x[:, 0], color="C0", lw=1.2, label=label)
        if e.sd is not None:
            ax.fill_between(e.t, e.x[:, 0] - 2 * e.sd[:, 0], e.x[:, 0] + 2 * e.sd[:, 0], color="C0", alpha=0.2)
        ax.set_title(f"{label} ({e.status})", fontsize=9)
    for ax in list(axes.flat)[len(labels):]:
        ax.axis("off")
    fig.suptitle("double well, 41 measurements: estimate ± 2 sd, truth (grey), data (dots)")
    fig.tight_layout()
    os.makedirs("out/python", exist_ok=True)
    fig.savefig("out/python/main_job.png", dpi=120)
    print("wrote out/python/main_job.png")


if __name__ == "__main__":
    main()
