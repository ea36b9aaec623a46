"""Type stubs of the extension module `onsager._onsager` (use the wrappers in `onsager`)."""

from __future__ import annotations

import os
from typing import Any, Mapping, Sequence

import numpy as np
import numpy.typing as npt

__version__: str

class Model:
    """A model: SDE, parameter values, priors, measurement model and simulation defaults."""

    @staticmethod
    def builtin(name: str, **params: float) -> Model:
        """A built-in model by name (``onsager.builtin_models()``), parameters set by keyword."""
    @staticmethod
    def from_file(path: str | os.PathLike[str]) -> Model:
        """The model a TOML model file declares (docs/models.md, "Models in a file")."""
    @staticmethod
    def from_str(text: str, name: str = "<string>") -> Model:
        """The model a TOML text declares; ``name`` stands for the file in error messages."""
    def with_params(self, **params: float) -> Model:
        """A copy with parameters set by keyword."""
    def with_likelihood(self, spec: str) -> Model:
        """A copy with another measurement model (``"student-t:nu=4,scale=0.5"``, ...)."""
    @property
    def name(self) -> str:
        """The model's name."""
    @property
    def description(self) -> str:
        """One-line description."""
    @property
    def states(self) -> list[str]:
        """State names: noisy states, then clean states."""
    @property
    def params(self) -> dict[str, float]:
        """Parameter values by name."""
    @property
    def estimated_by_default(self) -> list[str]:
        """The parameters the model's source estimates."""
    @property
    def outputs(self) -> list[str]:
        """Names of the measured outputs (the columns of ``y``)."""
    @property
    def likelihood(self) -> str:
        """The measurement model, as text."""
    @property
    def simulation(self) -> dict[str, float]:
        """Simulation defaults: ``t_end``, ``dt``, ``first_sample``, ``sample_every``."""
    def simulate(
        self,
        t_end: float | None = None,
        dt: float | None = None,
        sample_every: float | None = None,
        seed: int = 1,
        likelihood: str | None = None,
        scheme: str = "ito-taylor-1.5",
    ) -> Simulation:
        """Simulates the model as ``onsager simulate`` does (same seed, same numbers)."""

class Simulation:
    """A simulated record."""

    t: npt.NDArray[np.float64]
    """Measurement times, shape (n,)."""
    y: npt.NDArray[np.float64]
    """Measurements, shape (n, outputs); NaN marks a missing value."""
    truth_t: npt.NDArray[np.float64]
    """Times of the true path, shape (m,)."""
    truth_x: npt.NDArray[np.float64]
    """The true path, shape (m, states)."""
    outputs: list[str]
    states: list[str]

class Estimate:
    """The result of an estimator."""

    method: str
    t: npt.NDArray[np.float64]
    """Times of the path, shape (n,)."""
    x: npt.NDArray[np.float64]
    """The estimated path, shape (n, states)."""
    sd: npt.NDArray[np.float64] | None
    """Standard deviations of the path, shape (n, states), or None."""
    states: list[str]
    theta: dict[str, float]
    """Every parameter: the estimate for the estimated ones, the given value otherwise."""
    theta_sd: dict[str, float] | None
    """Standard deviations of the estimated parameters, when known."""
    status: str
    """``converged``, ``acceptable``, ``max-iterations``, ``numerical-failure``, ..."""
    success: bool
    iterations: int
    solve_seconds: float
    report: dict[str, Any]
    """The JSON report of ``onsager estimate --report``."""
    notes: list[str]

def estimate(
    model: Model,
    t: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    method: str,
    options: Mapping[str, Any] | None = None,
    estimate: Sequence[str] | None = None,
    seed: int = 1,
    t0: float | None = None,
) -> Estimate:
    """One estimator on contiguous or strided float64 arrays ``t`` (n,) and ``y`` (n, outputs)."""

def compare(
    model: Model,
    t: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    methods: str | Sequence[str] | Sequence[Mapping[str, Any]] | None = None,
    truth_t: npt.NDArray[np.float64] | None = None,
    truth_x: npt.NDArray[np.float64] | None = None,
    seed: int = 1,
) -> tuple[list[dict[str, Any]], list[tuple[str, Estimate | None]]]:
    """Several estimators: the summary rows and each label's estimate."""

def run_experiment(
    name_or_path: str,
    replicates: int | None = None,
    jobs: int = 0,
    out: str | None = None,
    quick: bool = False,
    resume: bool = False,
    seed: int | None = None,
    plots: bool = True,
) -> dict[str, Any]:
    """Runs an experiment; what it wrote and the row counts."""

def builtin_models() -> list[str]:
    """The names of the built-in models."""

def methods() -> list[tuple[str, str, list[str]]]:
    """Every method: (name, description, option names)."""
