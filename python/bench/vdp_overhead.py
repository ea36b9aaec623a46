"""Overhead of the Python package over the CLI: the Van der Pol JME benchmark (Student-t
likelihood nu=4, scale=0.5; Hermite-Simpson with step 0.005 on [0, 16], seed-1 data; as in
benches/path.rs) timed from Python (the whole `onsager.estimate` call: array conversion, the
solve, the result arrays) against the CLI's `solve_seconds` on the same data, in one run.

    pip install ./python
    cargo build --release
    python python/bench/vdp_overhead.py [--cli target/release/onsager] [--repeats 5]

Prints the medians and their ratio (Python / CLI).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import onsager

LIKELIHOOD = "student-t:nu=4,scale=0.5"
OPTIONS = {"step": 0.005}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cli", default=str(Path(__file__).resolve().parents[2] / "target/release/onsager"))
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    model = onsager.Model.builtin("van-der-pol").with_likelihood(LIKELIHOOD)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data.csv"
        subprocess.run([args.cli, "simulate", "--model", "van-der-pol", "--likelihood", LIKELIHOOD,
                        "--seed", "1", "--out", str(data)], check=True, capture_output=True)
        table = np.genfromtxt(data, delimiter=",", names=True)
        t = table["t"]
        y = np.column_stack([table[name] for name in model.outputs])
        cli, py = [], []
        for _ in range(args.repeats):
            report = Path(tmp) / "report.json"
            cmd = [args.cli, "estimate", "--model", "van-der-pol", "--likelihood", LIKELIHOOD, "--data", str(data),
                   "--method", "jme", "--out", str(Path(tmp) / "path.csv"), "--report", str(report)]
            for k, v in OPTIONS.items():
                cmd += ["--option", f"{k}={v}"]
            subprocess.run(cmd, check=True, capture_output=True)
            cli.append(json.loads(report.read_text())["solve_seconds"])
            start = time.perf_counter()
            est = onsager.estimate(model, t, y, method="jme", **OPTIONS)
            py.append(time.perf_counter() - start)
            assert est.success, est.status
    c, p = statistics.median(cli), statistics.median(py)
    print(f"van der pol jme ({len(t)} measurements, {est.x.shape[0]} path points), {args.repeats} runs each")
    print(f"  CLI solve_seconds (median): {c:.4f} s")
    print(f"  Python estimate() wall time (median): {p:.4f} s")
    print(f"  ratio Python / CLI: {p / c:.3f}")


if __name__ == "__main__":
    main()
