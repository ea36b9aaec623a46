"""Python and the CLI agree: the same data and options give the same path, to round-off, for
every method (`onsager estimate` writes the path CSV with 17 significant digits)."""

from __future__ import annotations

import csv
import json
import subprocess

import numpy as np
import pytest

import onsager


def write_data(path, t, y, names):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", *names])
        for ti, row in zip(t, y):
            w.writerow([repr(float(ti)), *["" if np.isnan(v) else repr(float(v)) for v in row]])


def read_path(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    header, body = rows[0], np.array([[float(v) if v else np.nan for v in r] for r in rows[1:]])
    return header, body


# (method, options as Python keywords, the same as --option pairs, parameters to estimate)
CASES = [
    (m, {}, ["D"] if m == "pem" else [])
    for m in onsager.methods()
] + [
    ("exp-closure", {"moments": 6}, []),
    ("jme", {"transcription": "trapezoidal"}, ["D"]),
    ("ksp", {"grid": "lo=-2.5,hi=2.5,cells=300"}, []),
]


@pytest.mark.parametrize("method,options,estimate", CASES, ids=lambda c: str(c))
def test_python_and_cli_give_the_same_estimate(tmp_path, cli, model, record, method, options, estimate):
    y = record.y.copy()
    y[4, 0] = np.nan  # a missing measurement travels as NaN both ways
    data = tmp_path / "data.csv"
    write_data(data, record.t, y, model.outputs)
    out, report = tmp_path / "path.csv", tmp_path / "report.json"
    args = [cli, "estimate", "--model", "double-well", "--data", str(data), "--method", method,
            "--out", str(out), "--report", str(report), "--seed", "7"]
    for k, v in options.items():
        args += ["--option", f"{k}={v}"]
    if estimate:
        args += ["--estimate", ",".join(estimate)]
    run = subprocess.run(args, capture_output=True, text=True)
    # A non-converged estimate is written too (exit code 2), and is a result in Python.
    assert run.returncode in (0, 2) and report.exists(), run.stderr + run.stdout

    est = onsager.estimate(model, record.t, y, method=method, estimate=estimate or None, seed=7, **options)
    header, body = read_path(out)
    n = len(est.states)
    assert header[: n + 1] == ["t", *est.states]
    np.testing.assert_allclose(est.t, body[:, 0], rtol=1e-15, atol=0)
    np.testing.assert_allclose(est.x, body[:, 1 : n + 1], rtol=1e-12, atol=1e-13)
    if est.sd is not None:
        np.testing.assert_allclose(est.sd, body[:, n + 1 : 2 * n + 1], rtol=1e-12, atol=1e-13)
    else:  # the CLI writes empty sd columns, or none
        assert np.isnan(body[:, n + 1 :]).all()
    rep = json.loads(report.read_text())
    assert rep["status"] == est.status and rep["iterations"] == est.iterations
    for name, entry in rep["theta"].items():
        assert est.theta[name] == pytest.approx(entry["value"], rel=1e-12)
        if est.theta_sd is not None and name in est.theta_sd:
            assert est.theta_sd[name] == pytest.approx(entry["sd"], rel=1e-12)
    assert est.report["details"] .keys() == rep["details"].keys()


def test_simulation_matches_the_cli(tmp_path, cli, model):
    out, truth = tmp_path / "d.csv", tmp_path / "x.csv"
    run = subprocess.run([cli, "simulate", "--model", "van-der-pol", "--seed", "11", "--t-end", "3",
                          "--out", str(out), "--truth", str(truth)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    sim = onsager.Model.builtin("van-der-pol").simulate(t_end=3.0, seed=11)
    header, body = read_path(out)
    assert header == ["t", *sim.outputs]
    np.testing.assert_array_equal(sim.t, body[:, 0])
    np.testing.assert_allclose(sim.y, body[:, 1:], rtol=1e-15, equal_nan=True)
    header, body = read_path(truth)
    np.testing.assert_allclose(sim.truth_x, body[:, 1 : 1 + len(sim.states)], rtol=1e-15)
