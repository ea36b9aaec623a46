"""A user-defined model from a TOML string, smoothed by the Gaussian closure, the quartic
exponential closure and the unscented Kalman smoother, each with its ±2 sd band.

    pip install ./python matplotlib
    python examples/python/custom_model.py        # writes out/python/custom_model.png

The model syntax is docs/models.md, "Models in a file".
"""

from __future__ import annotations

import os

import onsager

CUBIC = """
name = "cubic"
description = "an asymmetric cubic well driven by noise, measured directly"

[states]
noisy = ["x"]

[parameters]
a = 1.0
b = 1.0
c = 0.3
g = 0.7
sigma_y = 0.3

[dynamics]
drift = ["c + a * x - b * x^3"]
diffusion = "g"

[initial]
x = "normal:0,0.5"

[measurements]
states = ["x"]
names = ["y"]
likelihood = "gaussian:sigma=sigma_y"
every = 0.25

[simulation]
t_end = 10
dt = 0.01
"""

METHODS = [
    ("gaussian-closure", {}),
    ("exp-closure", {"moments": 4}),  # the quartic closure
    ("uks", {}),
]


def main() -> None:
    model = onsager.Model.from_str(CUBIC, name="cubic.toml")
    sim = model.simulate(seed=2)
    estimates = {}
    for method, options in METHODS:
        e = onsager.estimate(model, sim.t, sim.y, method=method, **options)
        estimates[method] = e
        print(f"{method:<17} {e.status:<10} {e.iterations:>3} iterations  {e.solve_seconds:.3f} s")

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install matplotlib): no figure")
        return
    fig, axes = plt.subplots(len(estimates), 1, figsize=(8, 2.4 * len(estimates)), sharex=True, sharey=True)
    for ax, (color, (method, e)) in zip(axes, zip(["C0", "C1", "C2"], estimates.items())):
        ax.plot(sim.truth_t, sim.truth_x[:, 0], color="0.6", lw=0.8, label="truth")
        ax.plot(sim.t, sim.y[:, 0], "k.", ms=3, label="data")
        ax.plot(e.t, e.x[:, 0], color=color, lw=1.2, label=method)
        ax.fill_between(e.t, e.x[:, 0] - 2 * e.sd[:, 0], e.x[:, 0] + 2 * e.sd[:, 0], color=color, alpha=0.25,
                        label="± 2 sd")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("t")
    fig.suptitle("a model from a TOML string: three smoothers with their ± 2 sd bands")
    fig.tight_layout()
    os.makedirs("out/python", exist_ok=True)
    fig.savefig("out/python/custom_model.png", dpi=120)
    print("wrote out/python/custom_model.png")


if __name__ == "__main__":
    main()
