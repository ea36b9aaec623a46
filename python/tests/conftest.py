"""Shared fixtures: a short double-well record, and the `onsager` command-line binary.

The agreement tests run the binary that `cargo build --release` (or `cargo test --release`)
leaves in `target/release/onsager`; set ONSAGER_CLI to use another one. Without it they are
skipped, never failed.
"""

from __future__ import annotations

import os
import pathlib
import shutil

import pytest

import onsager

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def model() -> onsager.Model:
    return onsager.Model.builtin("double-well")


@pytest.fixture(scope="session")
def record(model: onsager.Model) -> onsager.Simulation:
    return model.simulate(t_end=5.0, seed=3)


@pytest.fixture(scope="session")
def cli() -> str:
    path = os.environ.get("ONSAGER_CLI") or str(ROOT / "target" / "release" / "onsager")
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        found = shutil.which("onsager")
        if found is None:
            pytest.skip("the onsager binary is not built (cargo build --release) and ONSAGER_CLI is not set")
        path = found
    return path
