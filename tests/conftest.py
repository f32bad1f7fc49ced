"""Shared fixtures. Every Stan program is compiled once per run (PyStan caches
it), and each fit that several tests read is made once per session."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import stancal

ROOT = Path(__file__).resolve().parent.parent
COOLING = ROOT / "case_studies" / "cooling"
sys.path.insert(0, str(COOLING))
from make_data import K_TRUE, newton  # noqa: E402  (the case study's own physics)


def cooling_data(seed: int) -> stancal.CalibrationData:
    """Data from the exact simulator at k = 0.05 with noise sd 0.3, plus the shipped runs."""
    rng = np.random.default_rng(seed)
    t = np.tile(np.linspace(2, 60, 12), 2)
    T0 = np.repeat([60.0, 90.0], 12)
    physical = pd.DataFrame({"t": t, "T0": T0,
                             "temperature": newton(t, T0, K_TRUE) + 0.3 * rng.standard_normal(t.size)})
    runs = pd.read_csv(COOLING / "runs.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stancal.InputRangeWarning)
        return stancal.CalibrationData(physical, ["t", "T0"], "temperature", {"k": (0.01, 0.2)}, runs=runs)


@pytest.fixture(scope="session")
def exact_cooling_data() -> stancal.CalibrationData:
    return cooling_data(seed=7)


def fit(data, **kwargs):
    """Small but honest sampling settings for tests. Sampler warnings are not
    hidden: recovery tests assert the fit's health with assert_healthy."""
    settings = dict(chains=2, warmup=400, draws=400, seed=11)
    settings.update(kwargs)
    return stancal.calibrate(data, **settings)


def assert_healthy(result, divergences: int = 0) -> None:
    """R-hat <= 1.01 over every diagnosed parameter, and at most
    ``divergences`` divergent transitions (a test that allows any says why)."""
    d = result.diagnostics
    assert d.max_rhat <= 1.01, f"R-hat {d.max_rhat:.4f} at {d.worst_rhat}"
    assert d.divergences <= divergences, f"{d.divergences} divergences of {d.draws}"


@pytest.fixture(scope="session")
def koh_fit(exact_cooling_data):
    # 4 x (1000 + 1000): with 2 or 4 chains of 400 + 400, R-hat of theta reached 1.015 and 1.012
    # on a freshly compiled module
    return fit(exact_cooling_data, simulator=COOLING / "simulator.stan", method="koh", prior=True, chains=4,
               warmup=1000, draws=1000)


@pytest.fixture(scope="session")
def koh_emulator_fit(exact_cooling_data):
    return fit(exact_cooling_data, method="koh_emulator", draws=800)  # 400 left R-hat 1.014 on delta_sd


@pytest.fixture(scope="session")
def modular_fit(exact_cooling_data):
    return fit(exact_cooling_data, method="modular")


# more draws for the cheap simulator keep Pareto k estimates steady
COOLING_SAMPLING = dict(chains=2, warmup=400, draws=700, seed=3)


@pytest.fixture(scope="session")
def cooling_gap(tmp_path_factory):
    """`stancal gap` on the cooling case study, on the default local cluster
    (test_gap reads its ranking; test_cluster reruns it on another cluster)."""
    out = tmp_path_factory.mktemp("gap") / "cooling"
    done = subprocess.run(
        [sys.executable, "-m", "stancal.cli", "gap", str(COOLING / "config.toml"), "--out", str(out),
         *(str(a) for k, v in COOLING_SAMPLING.items() for a in (f"--{k}", v))],
        capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads((out / "gap.json").read_text()), out
