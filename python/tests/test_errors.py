"""Bad calls raise Python exceptions with clear messages and leave the interpreter usable."""

from __future__ import annotations

import numpy as np
import pytest

import onsager


@pytest.fixture(autouse=True)
def still_usable(model, record):
    """After every bad call, a good one still works."""
    yield
    assert onsager.estimate(model, record.t, record.y, method="uks").success


def test_unknown_model():
    with pytest.raises(ValueError, match="unknown model `nope`.*double-well"):
        onsager.Model.builtin("nope")


def test_unknown_parameter():
    with pytest.raises(ValueError, match="unknown parameter `Q`"):
        onsager.Model.builtin("double-well", Q=1.0)


def test_unknown_method(model, record):
    with pytest.raises(ValueError, match="unknown method `exp-closur`.*exp-closure"):
        onsager.estimate(model, record.t, record.y, method="exp-closur")


def test_unknown_option(model, record):
    with pytest.raises(ValueError, match="`uks` has no such option.*alpha"):
        onsager.estimate(model, record.t, record.y, method="uks", momnets=4)


def test_option_of_the_wrong_type(model, record):
    with pytest.raises(ValueError, match="`moments` of `exp-closure`.*expected usize"):
        onsager.estimate(model, record.t, record.y, method="exp-closure", moments="six")


@pytest.mark.parametrize("y,shape", [(np.zeros((3, 1)), r"\(3, 1\)"), (np.zeros((21, 2)), r"\(21, 2\)"),
                                     (np.zeros((21, 1, 1)), r"\(21, 1, 1\)")])
def test_wrong_shape_of_y(model, y, shape):
    t = np.linspace(0, 2, 21)
    with pytest.raises(ValueError, match=r"y: expected shape \(21, 1\).*got shape " + shape):
        onsager.estimate(model, t, y, method="uks")


def test_wrong_shape_of_t(model, record):
    with pytest.raises(ValueError, match=r"t: expected a 1-D array of shape \(n,\), got shape \(\d+, 1\)"):
        onsager.estimate(model, record.t.reshape(-1, 1), record.y, method="uks")


def test_decreasing_times(model, record):
    t = record.t.copy()
    t[5], t[6] = t[6], t[5]
    with pytest.raises(ValueError, match=r"t: times must be strictly increasing: t\[6\]"):
        onsager.estimate(model, t, record.y, method="uks")


def test_nan_times(model, record):
    t = record.t.copy()
    t[2] = np.nan
    with pytest.raises(ValueError, match=r"t: time NaN \(index 2\) is not finite"):
        onsager.estimate(model, t, record.y, method="uks")


def test_malformed_model_string():
    with pytest.raises(ValueError, match=r"<string>:\d+:\d+"):
        onsager.Model.from_str("name = 'x'\n[drift\nx = '1'")


def test_model_string_with_a_bad_expression():
    text = 'name = "m"\nstates = ["x"]\n[params]\na = 1.0\n[drift]\nx = "a * * x"\n[diffusion]\nx = "1"\n'
    with pytest.raises(ValueError, match="m"):
        onsager.Model.from_str(text, name="m.toml")


def test_missing_model_file(tmp_path):
    with pytest.raises(ValueError, match="nope.toml"):
        onsager.Model.from_file(tmp_path / "nope.toml")


def test_non_numeric_data(model, record):
    with pytest.raises(ValueError, match="y: expected real numbers"):
        onsager.estimate(model, record.t, np.array([["a"]] * len(record.t)), method="uks")


def test_complex_data_is_refused(model, record):
    with pytest.raises(ValueError, match="y: expected real numbers.*complex"):
        onsager.estimate(model, record.t, record.y.astype(complex), method="uks")


def test_parameter_a_method_cannot_estimate(model, record):
    with pytest.raises(ValueError, match="takes the parameters as given"):
        onsager.estimate(model, record.t, record.y, method="uks", estimate=["D"])


def test_unknown_experiment():
    with pytest.raises(ValueError, match="unknown experiment `nope`"):
        onsager.run_experiment("nope")


def test_not_a_model():
    with pytest.raises(TypeError, match="onsager.Model"):
        onsager.estimate("double-well", [0.0, 1.0], [0.0, 1.0])


def test_bad_likelihood(model):
    with pytest.raises(ValueError, match="likelihood|cauchy"):
        model.simulate(likelihood="cauchy:scale=1")
