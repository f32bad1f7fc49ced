"""The design loop (stancal design, docs/design.md): implausibility, NROY,
the next runs and experiments, waves, the command line. No Stan: the
emulators are numpy GPs."""

from __future__ import annotations

import json
import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import TOY_TRUTH, case_study_module, direct_theta_trace, toy_data
from conftest import toy_simulator as simulator

import stancal
from stancal.designing.emulators import BasisEmulator, GaussianProcess, ScalarEmulator
from stancal.designing.implausibility import Cut, nth_largest, nth_maximum_for
from stancal.designing.nroy import NroyEmpty, sample_nroy
from stancal.designing.targets import DesignSettings, Targets, UnitBox, targets_of
from stancal.numerics.scalable_emulator import Hyperparameters

ROOT_CASES = Path(__file__).resolve().parent.parent / "case_studies"


# ---- implausibility ------------------------------------------------------------------
def test_implausibility_matches_a_hand_computation_on_a_tiny_case():
    """Two runs, one input, one theta: the GP's mean and variance written
    out by hand (2 x 2 inverse), then I = |z - m| / sqrt(v + d^2 + e^2)."""
    h = Hyperparameters(mean=0.1, sd=1.3, length_scale=np.array([0.7, 0.4]), nugget=0.01)
    xt = np.array([[0.2, 0.3], [0.8, 0.6]])
    y_standardised = np.array([0.5, -1.0])
    emulator = ScalarEmulator(GaussianProcess(h, xt, y_standardised), center=10.0, scale=2.0)
    targets = Targets(np.array([[0.5]]), np.array([9.0]), np.array([0.3**2]), 0.4**2, "given", "given")
    theta = np.array([[0.45]])

    def k(a, b):
        return h.sd**2 * math.exp(-0.5 * sum(((a[d] - b[d]) / h.length_scale[d]) ** 2 for d in range(2)))

    point = (0.5, 0.45)
    diagonal = h.sd**2 + h.nugget**2 + 1e-6 * h.sd**2
    K = np.array([[diagonal, k(xt[0], xt[1])], [k(xt[1], xt[0]), diagonal]])
    inverse = np.array([[K[1, 1], -K[0, 1]], [-K[1, 0], K[0, 0]]]) / (K[0, 0] * K[1, 1] - K[0, 1] * K[1, 0])
    cross = np.array([k(point, xt[0]), k(point, xt[1])])
    mean = 10.0 + 2.0 * (h.mean + cross @ inverse @ (y_standardised - h.mean))
    variance = 4.0 * (h.sd**2 - cross @ inverse @ cross)
    expected = abs(9.0 - mean) / math.sqrt(variance + 0.4**2 + 0.3**2)
    cut = Cut(emulator, targets, nth=1, cutoff=3.0)
    assert cut.each(theta)[0, 0] == pytest.approx(expected, rel=1e-10)
    assert cut(theta)[0] == pytest.approx(expected, rel=1e-10)


def test_the_nth_maximum_and_its_default():
    values = np.array([[1.0, 5.0, 3.0, 4.0]])
    assert [nth_largest(values, n)[0] for n in (1, 2, 3)] == [5.0, 4.0, 3.0]
    # the smallest n whose chance of ruling out the truth (independent normal errors) is at most 5 %
    assert nth_maximum_for(1, 3.0) == 1 and nth_maximum_for(18, 3.0) == 1 and nth_maximum_for(19, 3.0) == 2
    assert nth_maximum_for(131, 3.0) == 2 and nth_maximum_for(132, 3.0) == 3


def test_the_nth_maximum_says_when_no_n_meets_the_risk(caplog):
    with caplog.at_level("WARNING", logger="stancal"):
        assert nth_maximum_for(303, 3.0) == 3
    assert not caplog.records  # the 3rd maximum still meets 5 % there
    with caplog.at_level("WARNING", logger="stancal"):
        assert nth_maximum_for(1000, 3.0) == 3
    (record,) = [r for r in caplog.records if r.name == "stancal"]
    assert "1000 observed values" in record.getMessage() and "chance 51 %" in record.getMessage()


def test_a_basis_emulators_variance_weights_average_over_the_observed_indices():
    """The posterior criterion's weight per component is its output variance
    per unit weight where the data are, not over the whole grid."""
    from stancal.problem.output_basis import OutputBasis

    grid = np.linspace(0, 1, 21)[:, None]
    xt = np.random.default_rng(3).uniform(size=(25, 2))
    outputs = np.array([np.exp(-(1 + 2 * t) * grid[:, 0]) * (1 + x) for x, t in xt])
    basis = OutputBasis.from_runs(grid, outputs, components=2)
    gps = [GaussianProcess(Hyperparameters(0.0, 1.0, np.array([0.5, 0.5]), 0.01), xt, basis.weights(outputs)[:, j])
           for j in range(2)]
    emulator = BasisEmulator(basis, gps, outputs)
    indices = np.array([0.0, 0.05, 0.1])  # early values only, where the curves differ most
    observed = emulator.parts([(np.array([0.5]), slice(0, 3), indices)])
    components = basis.components[:3]
    assert [w for _, w in observed] == pytest.approx(basis.scale**2 * np.mean(components**2, axis=0))
    assert [w for _, w in emulator.parts()] == pytest.approx(basis.scale**2 * np.mean(basis.components**2, axis=0))
    assert observed[0][1] != pytest.approx(emulator.parts()[0][1])


def test_the_vector_emulator_agrees_with_stage_ones():
    """The basis emulator's mean and variance at observed values equal
    stancal.numerics.vector_emulator's (all runs in its variance)."""
    from stancal.numerics.vector_emulator import VectorEmulator
    from stancal.problem.output_basis import OutputBasis

    rng = np.random.default_rng(3)
    grid = np.linspace(0, 1, 12)[:, None]
    xt = rng.uniform(size=(25, 2))
    outputs = np.array([np.exp(-(1 + 2 * t) * grid[:, 0]) * (1 + x) for x, t in xt])
    basis = OutputBasis.from_runs(grid, outputs, components=3)
    ours = BasisEmulator.fit(basis, xt, outputs, seed=4)
    theirs = VectorEmulator.fit(basis, xt, outputs, seed=4, variance_runs=25)
    theta = rng.uniform(size=(5, 1))
    indices = np.array([[0.05], [0.33], [0.9]])
    mean, variance = ours.at(np.repeat([[0.4]], 3, axis=0), theta, [(np.array([0.4]), slice(0, 3), indices)])
    their_mean, their_variance = theirs.predict(np.column_stack([np.full(5, 0.4), theta]), indices)
    np.testing.assert_allclose(mean, their_mean, rtol=1e-8)
    np.testing.assert_allclose(variance, their_variance, rtol=1e-6)


# ---- NROY ----------------------------------------------------------------------------
def test_the_nroy_fraction_matches_brute_force_on_a_two_parameter_problem(toy_match):
    match = toy_match
    cut = match.cuts[-1]
    brute = np.mean(np.concatenate([cut(chunk) <= 3.0 for chunk in
                                    np.array_split(np.random.default_rng(5).uniform(size=(200_000, 2)), 20)]))
    # the nested estimate's sd is about cv x fraction (here 5 % or so); brute force's is 0.1 % of it
    assert match.nroy_fraction == pytest.approx(brute, rel=3 * match.nroy.fraction_cv)
    assert brute < 0.05  # the problem is a small part of the box already
    assert (cut(match.nroy.theta_unit) <= 3.0).all()
    assert len(match.nroy_frame()) >= 1000 and list(match.nroy_frame().columns) == ["a", "b"]


@pytest.mark.parametrize("dimensions, radius", [(2, 0.003), (5, 0.05)])
def test_a_tiny_nroy_is_sampled_densely_and_its_volume_estimated(dimensions, radius):
    """A ball of known volume, 3e-5 and 2e-6 of the box: a uniform sample
    of 2,000 would hold no point of it."""
    centre = np.full(dimensions, 0.37)
    sample = sample_nroy(lambda t: 3 * np.linalg.norm(t - centre, axis=1) / radius, dimensions, 3.0, 2000, seed=1)
    volume = math.pi ** (dimensions / 2) / math.gamma(dimensions / 2 + 1) * radius**dimensions
    assert sample.fraction == pytest.approx(volume, rel=3 * sample.fraction_cv)
    distance = np.linalg.norm(sample.theta_unit - centre, axis=1) / radius
    assert distance.max() <= 1
    # uniform in a ball: E[r / R] = d / (d + 1); its se over 2,000 correlated points is below 0.01
    assert distance.mean() == pytest.approx(dimensions / (dimensions + 1), abs=0.02)


def test_an_empty_nroy_says_how_close_any_theta_came():
    with pytest.raises(NroyEmpty, match=r"every theta is implausible at cutoff 3: the smallest implausibility "
                                         r"found is 5"):
        sample_nroy(lambda t: 5 + t.sum(axis=1), 2, 3.0, 1000, seed=1)


# ---- the next runs -------------------------------------------------------------------
def test_proposed_runs_lie_inside_nroy_and_the_input_range_away_from_the_runs(toy_match):
    match = toy_match
    data = match.data
    design = stancal.propose_runs(match, 12, seed=3)
    runs = design.next_runs
    assert list(runs.columns) == ["x", "a", "b"] and len(runs) == 12
    assert (match.implausibility(runs) <= 3.0).all()
    assert runs["x"].between(data.physical["x"].min(), data.physical["x"].max()).all()
    # maximin: farther from the existing runs and each other than random NROY candidates are
    box = match.box
    unit = box.to_unit(runs)
    existing = box.to_unit(data.runs)
    spread = [np.linalg.norm(np.vstack([existing, np.delete(unit, i, 0)]) - unit[i], axis=1).min() for i in range(12)]
    rng = np.random.default_rng(0)
    random_theta = match.nroy.theta_unit[rng.choice(len(match.nroy.theta_unit), 12)]
    random = np.column_stack([rng.uniform(size=12), random_theta])
    random_spread = [np.linalg.norm(np.vstack([existing, np.delete(random, i, 0)]) - random[i], axis=1).min()
                     for i in range(12)]
    assert min(spread) > min(random_spread)


def test_the_posterior_criterion_removes_the_variance_it_says(toy_match):
    """The first pick's gain equals the drop of the emulator's variance,
    summed over the reference points, when the GP is refitted with that run
    added (any output: a GP's variance does not depend on it)."""
    from stancal.designing.proposals import posterior_runs

    match = toy_match
    draws = match.nroy_frame().iloc[:300]  # stands in for theta's posterior
    design = stancal.propose_runs(match, 4, criterion="posterior", posterior=draws, seed=3)
    assert (match.implausibility(design.next_runs) <= 3.0).all()
    gains = design.notes["variance_reduction"]
    assert gains == sorted(gains, reverse=True)
    emulator = match.cuts[-1].emulator
    unit_draws = match.box.theta_to_unit(draws[["a", "b"]].to_numpy())
    chosen, gain = posterior_runs(emulator.parts(), unit_draws, match.targets.x_unit, 1, seed=3)
    rng = np.random.default_rng(3)  # the references posterior_runs draws, in its order
    thetas = unit_draws[rng.choice(len(unit_draws), 60, replace=False)]
    xs = np.unique(match.targets.x_unit, axis=0)
    xs = xs[rng.choice(len(xs), len(xs), replace=False)]
    references = np.column_stack([np.tile(xs, (60, 1)), np.repeat(thetas, len(xs), axis=0)])
    gp = emulator.gp
    before = gp.predict(references)[1].sum()
    grown = GaussianProcess(gp.hyperparameters, np.vstack([gp.xt_runs, chosen]), np.append(gp.values, 0.3))
    after = grown.predict(references)[1].sum()
    assert gain[0] == pytest.approx(emulator.scale**2 * (before - after), rel=1e-3)


def test_next_experiments_lower_thetas_variance_as_a_direct_computation_says(toy_match):
    match = toy_match
    settings = stancal.propose_experiments(match, 3, seed=4)
    assert list(settings.columns) == ["x"] and settings["x"].between(0, 1).all()
    trace = settings.attrs["theta_variance_trace"]
    assert trace == sorted(trace, reverse=True)
    # the first pick's criterion from the full covariance of every value, old and new
    cut = match.cuts[-1]
    rng = np.random.default_rng(4)
    theta = match.nroy.theta_unit[rng.choice(len(match.nroy.theta_unit), 16, replace=False)]
    x = np.vstack([cut.targets.x_unit, settings[["x"]].to_numpy()[:1]])
    assert trace[0] == pytest.approx(direct_theta_trace(cut, theta, x), rel=1e-6)


# ---- waves ---------------------------------------------------------------------------
def test_run_waves_shrinks_nroy_and_keeps_every_waves_cut(toy_two_waves):
    # 30 runs a wave: wave 1's proposals lie inside its NROY, so wave 2 has the 10 per dimension of (x, a, b)
    # it needs to refocus
    loop = toy_two_waves
    assert len(loop.designs) == 2 and len(loop.data.runs) == 12 + 2 * 30
    fractions = loop.fractions
    assert fractions[-1] < fractions[0]
    last = loop.designs[-1].match
    assert [w.number for w in last.waves] == [1, 2] and last.waves[-1].refocused
    assert last.waves[-1].runs_used < last.waves[-1].runs_total  # refocused on the runs inside NROY
    first_cut = last.cuts[0]
    assert (first_cut(last.nroy.theta_unit) <= first_cut.cutoff).all()  # wave 1's cut still holds
    truth = pd.DataFrame([TOY_TRUTH])
    assert last.implausibility(truth)[0] <= 3.0  # the truth is not ruled out


def test_a_wave_with_no_new_runs_is_redone_not_added(toy_match):
    first = toy_match
    again = stancal.history_match(first.data, waves=first.waves, seed=2)
    assert [w.number for w in again.waves] == [1]
    assert again.nroy_fraction == pytest.approx(first.nroy_fraction)


def test_design_settings_are_the_config_schemas_design_keys():
    from stancal.problem.config_schema import table

    assert {f.name for f in fields(DesignSettings)} == {k.name for k in table("design").keys}


def test_targets_take_the_given_noise_and_discrepancy():
    data = toy_data()
    targets = targets_of(data, DesignSettings(noise_sd=0.05, discrepancy_sd=0.2))
    assert np.allclose(targets.noise_variance, 0.05**2) and targets.discrepancy_variance == pytest.approx(0.04)
    assert UnitBox.of(data).columns == ["x", "a", "b"]


# ---- the command line ----------------------------------------------------------------
def write_toy_case(folder, runs: int = 30, design_table: str = "[design]\nnroy_points = 1000\n"):
    """The toy problem as a config, its physical data and runs, in ``folder``."""
    data = toy_data(runs)
    data.physical[["x", "y"]].to_csv(folder / "physical.csv", index=False)
    data.runs.to_csv(folder / "runs.csv", index=False)
    config = folder / "config.toml"
    config.write_text('[physical]\ncsv = "physical.csv"\ninputs = ["x"]\noutput = "y"\n\n'
                      '[simulator]\nruns = "runs.csv"\n\n[simulator.theta]\na = [0.0, 1.0]\nb = [-1.0, 1.0]\n\n'
                      '[units]\nx = "m"\ny = "K"\n\n' + design_table)
    return config


def cli(capsys, *args) -> tuple[int, str, str]:
    from stancal.cli import main

    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_the_cli_writes_every_file_and_the_next_call_is_the_next_wave(tmp_path, capsys):
    config = write_toy_case(tmp_path)
    out = tmp_path / "design"
    code, text, err = cli(capsys, "design", config, "--runs", 6, "--out", out, "--experiments", 2, "--seed", 4)
    assert code == 0, err
    assert "design: wave 1, NROY" in text
    names = {"next_runs.csv", "nroy.csv", "design.json", "waves.json", "next_experiments.csv", "report.md",
             "report.html", "nroy_pairs.png", "nroy_by_wave.png", "proposed_runs.png"}
    assert names <= {p.name for p in out.iterdir()}
    runs = pd.read_csv(out / "next_runs.csv")
    assert list(runs.columns) == ["x", "a", "b"] and len(runs) == 6
    nroy = pd.read_csv(out / "nroy.csv")
    assert list(nroy.columns) == ["a", "b"] and len(nroy) >= 1000
    summary = json.loads((out / "design.json").read_text())
    assert {"nroy_fraction", "cutoff", "runs", "criterion", "waves"} <= set(summary)
    assert summary["runs"] == 30 and summary["criterion"] == "nroy" and summary["cutoff"] == 3.0
    assert list(pd.read_csv(out / "next_experiments.csv").columns) == ["x"]
    # the wave loop: run the simulator at next_runs.csv, append, design again into the same folder
    table = pd.concat([pd.read_csv(tmp_path / "runs.csv"), runs.assign(y=simulator(runs))])
    table.to_csv(tmp_path / "runs.csv", index=False)
    code, text, err = cli(capsys, "design", config, "--runs", 6, "--out", out, "--seed", 4)
    assert code == 0, err
    second = json.loads((out / "design.json").read_text())
    assert [w["number"] for w in second["waves"]] == [1, 2] and second["runs"] == 36
    assert second["waves"][0]["nroy_fraction"] == pytest.approx(summary["nroy_fraction"])
    assert not (out / "next_experiments.csv").exists()  # wave 1's settings are not left to read as wave 2's
    assert second["proposed_experiments"] == 0


@pytest.mark.parametrize("arguments, design_table, message", [
    (["--runs", 0], "", "--runs must be at least 1; got 0"),
    (["--runs", 5, "--experiments", -1], "", "--experiments must be at least 0; got -1"),
    (["--runs", 5, "--cutoff", 0], "", "--cutoff must be positive; got 0.0"),
    (["--runs", 5], "[design]\ncutof = 2\n", "unknown key 'cutof' in [design]; did you mean 'cutoff'?"),
    (["--runs", 5], "[design]\nnroy_points = 10\n", "[design] nroy_points must be at least 1000; got 10"),
    (["--runs", 5], "[design]\ndiscrepancy_sd = \"big\"\n", "[design] discrepancy_sd must be a number; got 'big'"),
])
def test_bad_input_is_one_line_before_any_work(tmp_path, capsys, arguments, design_table, message):
    config = write_toy_case(tmp_path, design_table=design_table)
    out = tmp_path / "design"
    code, _, err = cli(capsys, "design", config, "--out", out, *arguments)
    assert code == 2
    assert err.strip().splitlines()[-1].startswith("stancal: error: ") and message in err
    assert not out.exists()


def test_a_config_without_runs_and_a_folder_of_another_problem_are_refused(tmp_path, capsys):
    config = write_toy_case(tmp_path)
    out = tmp_path / "design"
    assert cli(capsys, "design", config, "--runs", 3, "--out", out)[0] == 0
    config.write_text(config.read_text().replace("b = [-1.0, 1.0]", "b = [-2.0, 1.0]"))
    code, _, err = cli(capsys, "design", config, "--runs", 3, "--out", out)
    assert code == 2 and "waves.json holds the waves of another problem" in err
    config.write_text(config.read_text().replace('runs = "runs.csv"\n', 'stan = "simulator.stan"\n'))
    (tmp_path / "simulator.stan").write_text("functions { vector simulator(matrix X, vector theta) "
                                             "{ return X[:, 1]; } }\n")
    code, _, err = cli(capsys, "design", config, "--runs", 3, "--out", tmp_path / "other")
    assert code == 2 and "stancal design needs simulator runs ([simulator] runs)" in err


# ---- a vector output -----------------------------------------------------------------
def newton_cooling(frame: pd.DataFrame, grid: np.ndarray) -> np.ndarray:
    """cooling_wind's simulator.stan in numpy: (runs, K) on the runs' grid of times."""
    T0, k, Ta = (frame[c].to_numpy()[:, None] for c in ("T0", "k", "Ta"))
    return Ta + (T0 - Ta) * np.exp(-k * grid[None, :, 0])


def test_a_vector_output_runs_waves_with_the_basis_emulator():
    """cooling_wind (eight cups, curves over time; a draught the simulator
    leaves out, so a wider discrepancy than the default: at 0.3 of the
    observations' sd the true theta sits at the cutoff, 3.0): two waves
    through run_waves, the true k and Ta kept."""
    from stancal.problem.config import load_config

    data = load_config(ROOT_CASES / "cooling_wind" / "config.toml").data
    grid = data.basis.grid
    loop = stancal.run_waves(data, simulator=lambda runs: newton_cooling(runs, grid), waves=2, runs_per_wave=6,
                             settings=DesignSettings(discrepancy_fraction=0.4, nroy_points=1000), seed=2)
    assert len(loop.data.run_settings) == 60 + 12
    last = loop.designs[-1]
    assert list(last.next_runs.columns) == ["T0", "k", "Ta"]
    assert [w.number for w in last.match.waves] == [1, 2]
    assert last.match.implausibility(pd.DataFrame([{"k": 0.045, "Ta": 21.3}]))[0] <= 3.0
    assert (last.match.implausibility(last.next_runs) <= 3.0).all()
    summary = last.to_json()
    assert summary["noise_sd_source"] == "the physical data's known noise sd column"
    assert summary["nth_maximum"] == nth_maximum_for(len(data.physical), 3.0)


def test_the_posterior_criterion_on_a_vector_output_with_shared_theta():
    """cooling_wind (no theta per experiment): the posterior criterion picks
    runs inside NROY, its gains falling, with the NROY sample standing in
    for theta's posterior (this path once failed on the per-experiment
    bookkeeping it does not need)."""
    from stancal.problem.config import load_config

    data = load_config(ROOT_CASES / "cooling_wind" / "config.toml").data
    match = stancal.history_match(data, settings=DesignSettings(discrepancy_fraction=0.4, nroy_points=1000), seed=2)
    design = stancal.propose_runs(match, 3, criterion="posterior", posterior=match.nroy_frame().iloc[:200], seed=3)
    assert list(design.next_runs.columns) == ["T0", "k", "Ta"]
    assert (match.implausibility(design.next_runs) <= 3.0).all()
    gains = design.notes["variance_reduction"]
    assert gains == sorted(gains, reverse=True) and gains[-1] > 0


# ---- the posterior criterion with a real fit (one small modular fit, cached program) ----
def test_the_posterior_criterion_fits_modular_and_proposes_runs_where_theta_is(tmp_path, capsys):
    from conftest import assert_healthy

    data = toy_data()
    match = stancal.history_match(data, settings=DesignSettings(noise_sd=0.02, nroy_points=1000), seed=2)
    # the toy's data are the simulator's plus noise: no discrepancy to fit (its sd would mix slowly at zero)
    design = stancal.propose_runs(match, 5, criterion="posterior", seed=3, chains=2, warmup=500, draws=1000,
                                  discrepancy="none")
    assert design.notes["posterior_method"] == "modular"
    assert design.notes["posterior_emulator"] == "the posterior fit's stage 1"  # not the wave's own
    assert_healthy(design.posterior_fit)
    draws = design.posterior_fit.theta_draws()[["a", "b"]].to_numpy()
    proposed = design.next_runs[["a", "b"]].to_numpy()
    # the candidates' theta are the posterior's draws
    assert all(np.isclose(draws, row, rtol=1e-9).all(axis=1).any() for row in proposed)
    assert design.to_json()["posterior_diagnostics"]["divergences"] == 0


def test_the_case_studys_real_fin_is_the_simulator_plus_radiation(monkeypatch):
    """case_studies/design_loop: the finite-difference "real" fin without
    radiation is the closed-form simulator (to 1e-3 deg C on 400 nodes), and
    with it the fin is cooler, most at the hot base's side."""
    fin = case_study_module(ROOT_CASES / "design_loop", "simulator")
    x = np.linspace(0, 0.3, 7)
    simulated = fin.fin_temperature(pd.DataFrame({"x": x, "T_b": 120.0, **fin.TRUTH}))
    radiating = fin.measured(x, 120.0)
    monkeypatch.setattr(fin, "EMISSIVITY", 0.0)
    np.testing.assert_allclose(fin.measured(x, 120.0), simulated, atol=1e-3)
    gap = simulated - radiating
    assert (gap[1:] > 0).all() and gap[0] == pytest.approx(0, abs=1e-9) and 0.3 < gap.max() < 1.5
