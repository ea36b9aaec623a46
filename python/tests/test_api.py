"""The Python API: models, simulation, estimates, compare, experiments, numpy input."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_builtin_model_properties():
    m = onsager.Model.builtin("duffing", d=0.3)
    assert m.params["d"] == 0.3 and len(m.states) == 2
    assert m.outputs and isinstance(m.likelihood, str)
    assert set(onsager.builtin_models()) >= {"double-well", "van-der-pol", "duffing"}
    assert "exp-closure" in onsager.methods() and "moments" in onsager.methods()["exp-closure"]["options"]


def test_simulate_shapes_and_determinism(model):
    a = model.simulate(t_end=2.0, seed=5)
    b = model.simulate(t_end=2.0, seed=5)
    assert a.t.dtype == np.float64 and a.y.shape == (len(a.t), 1)
    assert a.truth_x.shape == (len(a.truth_t), 1)
    np.testing.assert_array_equal(a.y, b.y)
    c = model.simulate(t_end=2.0, seed=5, likelihood="student-t:nu=4,scale=0.4")
    assert not np.array_equal(a.y, c.y)


def test_estimate_result(model, record):
    e = onsager.estimate(model, record.t, record.y, method="gaussian-closure")
    assert e.status == "converged" and e.success
    assert e.x.shape == (len(e.t), 1) and e.sd.shape == e.x.shape
    assert e.theta == {"D": 0.5} and e.report["status"] == "converged"
    assert e.iterations >= 1 and e.solve_seconds >= 0


def test_parameter_estimation(model, record):
    e = onsager.estimate(model, record.t, record.y, method="jme", estimate=["D"], transcription="trapezoidal")
    assert e.report["theta"]["D"]["estimated"] and e.theta["D"] > 0


def test_missing_values_as_nan(model, record):
    y = record.y.copy()
    y[::3] = np.nan
    e = onsager.estimate(model, record.t, y, method="uks")
    assert e.success and np.isfinite(e.x).all()


def test_model_from_string_and_file(tmp_path):
    m = onsager.Model.from_str(CUBIC)
    assert m.states == ["x"] and m.params["c"] == 0.3 and m.outputs == ["y"]
    f = tmp_path / "cubic.toml"
    f.write_text(CUBIC)
    m2 = onsager.Model.from_file(f)
    s = m2.simulate(seed=2)
    for method in ["gaussian-closure", "exp-closure", "uks"]:
        e = onsager.estimate(m, s.t, s.y, method=method)
        assert e.success, (method, e.status)


def test_numpy_layouts_give_the_same_estimate(model, record):
    t, y = record.t, record.y
    ref = onsager.estimate(model, t, y, method="uks").x
    # Fortran order, a strided view, a 1-D y for one output, lists.
    yf = np.asfortranarray(np.hstack([y, y]))[:, :1]
    wide_t = np.repeat(t, 2)[::2]
    big = np.zeros((len(t), 3))
    big[:, 1] = y[:, 0]
    for tt, yy in [(t, yf), (wide_t, big[:, 1:2]), (t, y[:, 0]), (list(t), y.tolist())]:
        np.testing.assert_array_equal(onsager.estimate(model, tt, yy, method="uks").x, ref)


def test_integer_arrays_are_converted(model):
    t = np.arange(0, 20, dtype=np.int64)
    y = np.zeros((20, 1), dtype=np.int32)
    e = onsager.estimate(model, t, y, method="uks")
    ref = onsager.estimate(model, t.astype(float), y.astype(float), method="uks")
    np.testing.assert_array_equal(e.x, ref.x)


def test_compare_rows_and_pandas(model, record):
    table = onsager.compare(model, record.t, record.y, methods=["ksp", "exp-closure:moments=6", "uks"], truth=record)
    assert [r["label"] for r in table] == ["ksp", "exp-closure", "uks"]
    assert all(r["status"] == "converged" and r["rmse_truth"] > 0 for r in table)
    assert table[1]["rmse_ksp"] > 0 and table.estimates["uks"].success
    dicts = onsager.compare(model, record.t, record.y,
                            methods=[{"method": "exp-closure", "options": {"moments": 6}, "label": "q6"}])
    assert dicts[0]["label"] == "q6"
    assert dicts.estimates["q6"].x.tolist() == table.estimates["exp-closure"].x.tolist()
    pd = pytest.importorskip("pandas")
    df = table.to_pandas()
    assert isinstance(df, pd.DataFrame) and list(df.index) == ["ksp", "exp-closure", "uks"]


def test_run_experiment_quick(tmp_path):
    r = onsager.run_experiment("tanh-limits", replicates=1, jobs=1, out=tmp_path / "x", quick=True, plots=False)
    assert r["complete"] and r["written"] == r["total"] > 0
    again = onsager.run_experiment("tanh-limits", replicates=1, jobs=1, out=tmp_path / "x", quick=True,
                                   resume=True, plots=False)
    assert again["resumed"] == r["total"] and again["written"] == 0
