"""Vector outputs at parity with scalar ones (issue 31, items 4 and 5): a
categorical covariate enters the discrepancy one-hot as for a scalar output,
and a problem with no simulator inputs besides theta (``inputs = []``)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_vector_outputs import THETA, long_experiments, long_runs

from stancal.problem.config import load_config
from stancal.problem.data import CalibrationData
from stancal.problem.options import VectorOptions
from stancal.problem.validation import DataError
from stancal.problem.vector_data import VectorCalibrationData

CUPS = {"shot0": "glass", "shot1": "steel", "shot2": "glass", "shot3": "steel"}


def with_cups(physical: pd.DataFrame) -> pd.DataFrame:
    """Each experiment's cup (text) and humidity (a number), constant within it."""
    humidity = {name: 30.0 + 5 * e for e, name in enumerate(CUPS)}
    return physical.assign(cup=physical["exp"].map(CUPS), humidity=physical["exp"].map(humidity))


def cup_data(physical: pd.DataFrame | None = None, **kwargs) -> VectorCalibrationData:
    physical = with_cups(long_experiments(1)) if physical is None else physical
    return VectorCalibrationData(physical, "exp", ["T0"], "T", "t", THETA, noise_sd="sd",
                                 covariates=["humidity", "cup"], **kwargs)


def test_a_categorical_covariate_enters_a_vector_discrepancy_one_hot_as_for_a_scalar_output():
    """The same text column that a scalar config takes: its levels, its one
    0/1 column per level in the discrepancy's inputs (after the inputs and
    the output index), each experiment's coding in the Stan data."""
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.stan.vector_standata import koh_vector_data

    physical = with_cups(long_experiments(1))
    data = cup_data(physical)
    scalar = CalibrationData(physical.drop(columns="exp"), ["T0", "t"], "T", THETA, covariates=["humidity", "cup"])
    assert data.levels == scalar.levels == {"cup": ["glass", "steel"]}
    assert data.discrepancy_variables["cup"] == scalar.discrepancy_variables["cup"] == ["cup[glass]", "cup[steel]"]
    assert data.discrepancy_inputs == ["T0", "t", "humidity", "cup[glass]", "cup[steel]"]
    assert data.experiments.loc["shot1", "cup[steel]"] == 1 and data.experiments.loc["shot1", "cup[glass]"] == 0
    rows = prediction_rows(data)
    stan_data = koh_vector_data(data, VectorOptions("gp", "known"), None, rows)
    assert stan_data["D_cov"] == 3
    steel = (physical["cup"] == "steel").to_numpy(float)
    np.testing.assert_array_equal(stan_data["x_delta"][:, 4], steel)
    np.testing.assert_array_equal(stan_data["x_delta"][:, 3], 1 - steel)
    np.testing.assert_array_equal(stan_data["x_delta_new"][:, 4], (rows["cup"] == "steel").to_numpy(float))


def test_the_runs_program_takes_each_experiments_cup_coding():
    """modular_vector.stan's z: one row per experiment, humidity on [0, 1],
    then the cup's two 0/1 columns."""
    from stancal.fitting.stage_one import fit_vector_emulator
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.stan.vector_standata import modular_vector_data

    data = cup_data(runs=long_runs(30, 2), run="run")
    emulator = fit_vector_emulator(data, seed=1)
    stan_data = modular_vector_data(data, VectorOptions("gp", "known"), emulator, prediction_rows(data))
    assert stan_data["D_cov"] == 3
    np.testing.assert_allclose(stan_data["z"], [[0, 1, 0], [1 / 3, 0, 1], [2 / 3, 1, 0], [1, 0, 1]])


def test_a_subset_keeps_every_level_and_a_varying_cup_is_named():
    data = cup_data()
    glass = np.flatnonzero(data.physical["exp"].isin(["shot0", "shot2"]).to_numpy())
    subset = data.subset(glass)
    assert subset.levels == data.levels and subset.discrepancy_inputs == data.discrepancy_inputs
    physical = with_cups(long_experiments(1))
    physical.loc[physical.index[1], "cup"] = "steel"  # shot0's second reading
    with pytest.raises(DataError, match=r"column 'cup' varies within experiment 'shot0' \(\['glass', 'steel'\]\)"):
        cup_data(physical)


def _write_cup_config(folder, method: str) -> None:
    with_cups(long_experiments(1)).to_csv(folder / "physical.csv", index=False)
    long_runs(30, 2).to_csv(folder / "runs.csv", index=False)
    (folder / "config.toml").write_text(f"""
[physical]
csv = "physical.csv"
experiment = "exp"
inputs = ["T0"]
output = "T"
output_index = "t"
noise_sd = "sd"
covariates = ["humidity", "cup"]

[simulator]
runs = "runs.csv"
run = "run"

[simulator.theta]
k = [0.01, 0.1]
Ta = [15.0, 25.0]

[model]
method = "{method}"

[candidates]
cup = "C(cup)"
""")


def test_a_vector_config_with_a_cup_and_its_candidate_loads(tmp_path):
    """The issue's config: `covariates = ["humidity", "cup"]` and a candidate
    `cup = "C(cup)"`; the candidate's mean term is cup = steel against glass."""
    from stancal.stan.vector_standata import mean_terms

    _write_cup_config(tmp_path, "modular")
    problem = load_config(tmp_path / "config.toml")
    assert problem.data.levels == {"cup": ["glass", "steel"]}
    terms = mean_terms(problem.data, VectorOptions("gp", "known", mean_formula=problem.candidates[0].formula))
    assert terms.names == ["C(cup)[T.steel]"]
    steel = (problem.data.source["cup"] == "steel").to_numpy()
    assert np.all(terms.h[steel] != 0) and np.all(terms.h[~steel] == 0)
