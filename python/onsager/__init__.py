"""State-path and parameter estimation in nonlinear SDEs, from Python.

The estimators of the Rust crate ``onsager`` on numpy arrays: Eyink's effective action
(the exact mean-optimal estimator and its Rayleigh-Ritz closures: Gaussian, exponential
family, double exponential, KSP), the Onsager-Machlup MAP path (JME) and the minimum-energy
path (MEE), the exact KSP smoother, EKS/UKS, PEM, a particle smoother and an ensemble Kalman
smoother.

    >>> import onsager
    >>> model = onsager.Model.builtin("double-well")
    >>> sim = model.simulate(seed=1)
    >>> est = onsager.estimate(model, sim.t, sim.y, method="exp-closure", moments=4)
    >>> est.status, est.x.shape
    ('converged', (..., 1))

Options have the names of ``onsager estimate --option NAME=VALUE`` and of the experiment specs
(``onsager.methods()`` lists them). Bad input raises ``ValueError`` with the library's message;
a method that does not converge returns an ``Estimate`` whose ``status`` says so. Long calls
release the GIL, and Ctrl-C raises ``KeyboardInterrupt`` within about a second.
See docs/python.md for a walk-through.
"""

from __future__ import annotations

import numbers
import os
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from . import _onsager
from ._onsager import Estimate, Model, Simulation, builtin_models

__version__: str = _onsager.__version__

__all__ = [
    "Model",
    "Simulation",
    "Estimate",
    "CompareTable",
    "estimate",
    "compare",
    "run_experiment",
    "methods",
    "builtin_models",
]


def _times(t: Any, name: str) -> np.ndarray:
    """``t`` as a contiguous float64 vector, or ``ValueError`` naming the argument."""
    a = _floats(t, name)
    if a.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of shape (n,), got shape {a.shape}")
    return a


def _floats(x: Any, name: str) -> np.ndarray:
    """``x`` converted to a C-contiguous float64 array (integers and booleans are converted;
    anything that is not numeric is refused)."""
    try:
        a = np.asarray(x)
    except Exception as e:  # ragged lists and the like
        raise ValueError(f"{name}: cannot be read as a numeric array ({e})") from None
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{name}: expected real numbers (float64 or integers), got an array of dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float64)


def _table(y: Any, n: int, columns: Sequence[str], name: str) -> np.ndarray:
    """``y`` as an (n, len(columns)) float64 array; a vector is one column."""
    a = _floats(y, name)
    m = len(columns)
    if a.ndim == 1 and m == 1:
        a = a.reshape(-1, 1)
    if a.ndim != 2 or a.shape != (n, m):
        raise ValueError(
            f"{name}: expected shape ({n}, {m}) (one row per time, one column per "
            f"{'/'.join(columns)}), got shape {a.shape}"
        )
    return a


def _json_value(v: Any) -> Any:
    """Numpy scalars and arrays as plain Python values, for the JSON form of options."""
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Mapping):
        return {str(k): _json_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    return v


def estimate(
    model: Model,
    t: Any,
    y: Any,
    method: str = "exp-closure",
    *,
    estimate: Iterable[str] | None = None,
    seed: int = 1,
    t0: float | None = None,
    **options: Any,
) -> Estimate:
    """Runs one estimator on measurements ``y`` at times ``t``.

    Parameters
    ----------
    model : Model
        The model (its parameter values, priors and measurement model are used).
    t : array_like, shape (n,)
        Strictly increasing, finite measurement times.
    y : array_like, shape (n, outputs) (or (n,) for one output)
        Measurements, one column per ``model.outputs``; NaN marks a missing value.
    method : str
        An estimator (``onsager.methods()``): ``ksp``, ``mean-optimal``, ``gaussian-closure``,
        ``exp-closure``, ``double-exp-closure``, ``ksp-closure``, ``jme``, ``mee``, ``eks``,
        ``uks``, ``pem``, ``particle``, ``enks``, ...
    estimate : list of str, optional
        Parameters to estimate with them (``jme``, ``mee``, ``pem``), by name.
    seed : int
        Seed of the methods that draw random numbers.
    t0 : float, optional
        Time of the initial-state prior (default: 0, or the first time if earlier).
    **options
        The method's options, with the names of ``onsager estimate --option`` and of the
        experiment specs, e.g. ``moments=6``, ``grid="lo=-2.5,hi=2.5,cells=400"``,
        ``transcription="trapezoidal"``, ``dual={"max_iterations": 100}``.

    Returns
    -------
    Estimate
        ``t``, ``x`` (n, states), ``sd`` (or None), ``theta`` and ``theta_sd`` (dicts),
        ``status``, ``success``, ``iterations``, ``solve_seconds``, ``report`` (dict), ``notes``.

    Raises
    ------
    ValueError
        An unknown method or option, an option of the wrong type, arrays of the wrong shape,
        non-increasing or non-finite times, parameters the method cannot estimate.
    """
    if not isinstance(model, Model):
        raise TypeError(f"model: expected an onsager.Model, got {type(model).__name__}")
    if not isinstance(method, str):
        raise TypeError(f"method: expected a method name (str), got {type(method).__name__}")
    tt = _times(t, "t")
    yy = _table(y, len(tt), model.outputs, "y")
    names = None if estimate is None else [estimate] if isinstance(estimate, str) else list(estimate)
    if not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
    return _onsager.estimate(
        model, tt, yy, method, _json_value(options), names, int(seed), None if t0 is None else float(t0)
    )


class CompareTable(list):
    """The rows of ``onsager.compare``, one dict per estimator (the rows of ``onsager compare``'s
    summary.json): ``label``, ``method``, ``status``, ``error``, ``rmse_truth``, ``rmse_ksp``,
    ``rmse_mean_optimal``, ``same_well_fraction``, ``solve_seconds``, ``iterations``, ``notes``.

    ``estimates`` maps each label to its ``Estimate`` (None where the estimator could not run).
    """

    estimates: dict[str, Estimate | None]

    def __init__(self, rows: Iterable[dict], estimates: dict[str, Estimate | None]) -> None:
        super().__init__(rows)
        self.estimates = estimates

    def to_pandas(self) -> Any:
        """The rows as a ``pandas.DataFrame`` indexed by label (needs pandas)."""
        try:
            import pandas as pd
        except ImportError as e:
            raise ImportError("CompareTable.to_pandas needs pandas: pip install pandas") from e
        return pd.DataFrame(list(self)).set_index("label")


def compare(
    model: Model,
    t: Any,
    y: Any,
    methods: str | Sequence[str] | Sequence[Mapping[str, Any]] | None = None,
    truth: tuple[Any, Any] | Simulation | None = None,
    *,
    seed: int = 1,
) -> CompareTable:
    """Several estimators on the same data, measured against each other and the truth
    (``onsager compare``).

    Parameters
    ----------
    model, t, y
        As in ``estimate``.
    methods : optional
        ``None`` for the defaults of ``onsager compare``; a text
        ``"exp-closure:moments=6,jme:transcription=trapezoidal,uks"``; a list of such texts;
        or a list of dicts ``{"method": "exp-closure", "options": {"moments": 6}, "label": "q6"}``.
    truth : (t, x) or Simulation, optional
        The true path (times (m,), states (m, states)): adds ``rmse_truth`` (and for the double
        well ``same_well_fraction``).
    seed : int
        Seed of the methods that draw random numbers.

    Returns
    -------
    CompareTable
        A list of dicts, one per estimator, with ``estimates`` and ``to_pandas()``.
    """
    if not isinstance(model, Model):
        raise TypeError(f"model: expected an onsager.Model, got {type(model).__name__}")
    tt = _times(t, "t")
    yy = _table(y, len(tt), model.outputs, "y")
    truth_t = truth_x = None
    if isinstance(truth, Simulation):
        truth = (truth.truth_t, truth.truth_x)
    if truth is not None:
        if not (isinstance(truth, (tuple, list)) and len(truth) == 2):
            raise ValueError("truth: expected a pair (t, x) or a Simulation")
        truth_t = _times(truth[0], "truth t")
        truth_x = _table(truth[1], len(truth_t), model.states, "truth x")
    if methods is not None and not isinstance(methods, str):
        methods = [_json_value(m) if isinstance(m, Mapping) else m for m in methods]
    rows, estimates = _onsager.compare(model, tt, yy, methods, truth_t, truth_x, int(seed))
    return CompareTable(rows, dict(estimates))


def run_experiment(
    name_or_path: str | os.PathLike,
    replicates: int | None = None,
    jobs: int = 0,
    out: str | os.PathLike | None = None,
    quick: bool = False,
    resume: bool = False,
    *,
    seed: int | None = None,
    plots: bool = True,
) -> dict[str, Any]:
    """Runs a Monte Carlo experiment (``onsager experiment run``): a built-in one by name
    (``onsager experiment list``) or a TOML spec file.

    Parameters
    ----------
    name_or_path : str or path
        A built-in experiment's name, or a spec file (``*.toml``).
    replicates : int, optional
        Replicates per scenario (default: the spec's).
    jobs : int
        Worker threads (0: one per core). The results do not depend on it.
    out : path, optional
        Output folder (default ``out/experiments/NAME``, ``.../quick`` for the quick version).
    quick : bool
        Run the spec's quick version.
    resume : bool
        Continue an interrupted run in ``out``.
    seed : int, optional
        Seed (default: the spec's).
    plots : bool
        Write the plots.

    Returns
    -------
    dict
        ``results`` (results.csv), ``summary`` (summary.json, None when incomplete), ``plots``,
        ``written``, ``resumed``, ``total``, ``complete``.

    Ctrl-C stops the run with ``KeyboardInterrupt``; the rows written stay, and
    ``resume=True`` continues it.
    """
    return _onsager.run_experiment(
        os.fspath(name_or_path),
        replicates,
        int(jobs),
        None if out is None else os.fspath(out),
        bool(quick),
        bool(resume),
        seed,
        bool(plots),
    )


def methods() -> dict[str, dict[str, Any]]:
    """Every estimator by name: its ``description`` and its ``options`` (names)."""
    return {name: {"description": d, "options": list(o)} for name, d, o in _onsager.methods()}
