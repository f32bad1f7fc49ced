"""The latent discrepancy's parametrisation: the plan's choice from the data
(stancal.numerics.parametrization), the user's override, the refit the other
way after a fit that saturates the tree depth, and what the report says. No
sampling here: the short fits are in test_latent_parametrization.py."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from scipy import stats

import stancal
from stancal.fitting.parametrization_fallback import SATURATED_SHARE, saturated_share, with_fallback
from stancal.fitting.plan import make_plan
from stancal.numerics import parametrization as rule
from stancal.problem.codes import Kernel
from stancal.problem.options import ModelOptions

COUNTS_SIMULATOR = "case_studies/detector_counts/simulator.stan"
SE = int(Kernel.SE)


def counts_data(mean_count: float, likelihood: str = "poisson", points: int = 30, trials: int | None = None,
                seed: int = 0, corners: bool = False) -> stancal.CalibrationData:
    """Counts on a line of ``points`` distances (close together against the
    prior's length scale), or at the four corners of the (d, s) box (far apart)."""
    rng = np.random.default_rng(seed)
    d, s = (np.array([0.5, 3.0, 0.5, 3.0]), np.array([0.0, 0.0, 5.0, 5.0])) if corners else (
        np.linspace(0.5, 3.0, points), np.zeros(points))
    frame = pd.DataFrame({"d": d, "s": s, "y": rng.poisson(mean_count, len(d))})
    if trials is not None:
        frame["n"] = trials
        frame["y"] = rng.binomial(trials, 0.5, len(d))
    return stancal.CalibrationData(frame, ["d", "s"], "y", {"mu": (0.05, 1.0)}, likelihood=likelihood,
                                   trials="n" if trials is not None else None)


def choose(data: stancal.CalibrationData, kernel: int = SE, partial: bool = False) -> rule.Choice:
    x_delta = data.scaling.to_unit(data.physical, data.discrepancy_inputs)
    return rule.choose_parametrization(data.observations, x_delta, len(data.inputs), kernel, partial=partial)


def test_the_prior_medians_are_the_programs_priors():
    assert rule.INPUT_LENGTH_SCALE == pytest.approx(stats.invgamma(3).median(), abs=1e-3)
    assert rule.COVARIATE_LENGTH_SCALE == pytest.approx(1 / stats.halfnorm(scale=2).median(), abs=1e-3)
    assert rule.NOISE_PRIOR_MEDIAN == pytest.approx(stats.halfnorm().median(), abs=1e-4)


def test_the_prior_precision_at_a_point_counts_its_neighbours():
    # far apart against the length scale: the prior's variance sigma^2; close: far less
    far = rule.prior_conditional_variance(np.array([[0.0], [10.0]]), 1, SE)
    np.testing.assert_allclose(far, rule.DISCREPANCY_PRIOR_SD**2 * (1 + rule.JITTER), rtol=1e-9)
    close = rule.prior_conditional_variance(np.linspace(0, 1, 30)[:, None], 1, SE)
    assert np.all(close < 1e-3 * rule.DISCREPANCY_PRIOR_SD**2)
    # a covariate's length scale is longer: its neighbours tie it more
    pair = np.array([[0.0], [0.5]])
    assert rule.prior_conditional_variance(pair, 0, SE)[0] < rule.prior_conditional_variance(pair, 1, SE)[0]


def test_large_counts_at_separate_points_are_centred_small_or_close_ones_not():
    large = choose(counts_data(1e5, corners=True))
    assert large.parametrization == "centred"
    assert "information per point is" in large.reason and "at 100 % of the points" in large.reason
    assert choose(counts_data(3, corners=True)).parametrization == "non_centred"
    # the threshold: DOMINANCE times the prior's precision 1 / 0.5^2 = 4, at points nearly independent
    assert choose(counts_data(4 * rule.DOMINANCE * 0.8, corners=True)).parametrization == "non_centred"
    assert choose(counts_data(4 * rule.DOMINANCE * 1.5, corners=True)).parametrization == "centred"
    # the same large counts at 30 points close together: the GP ties each to its neighbours
    assert choose(counts_data(1e5)).parametrization == "non_centred"


def test_information_per_likelihood():
    binomial = counts_data(0, "binomial", trials=10**6, corners=True)
    y = binomial.observations.value
    p = (y + 0.5) / (10**6 + 1)
    np.testing.assert_allclose(rule.information_per_point(binomial.observations), 10**6 * p * (1 - p))
    assert choose(binomial).parametrization == "centred"
    assert choose(counts_data(0, "binomial", trials=10, corners=True)).parametrization == "non_centred"
    # unknown overdispersion caps what a count says: large negative binomial counts stay non-centred
    assert choose(counts_data(1e5, "negbinomial", corners=True)).parametrization == "non_centred"


def test_noisy_gaussian_and_censored_outputs_are_non_centred():
    rng = np.random.default_rng(1)
    frame = pd.DataFrame({"d": np.linspace(0.5, 3, 20), "s": 0.0, "y": rng.normal(size=20)})
    frame.loc[:9, "y"] = np.nan
    frame["hi"] = np.where(frame.y.isna(), 0.0, np.nan)  # left-censored (an open lower bound)
    data = stancal.CalibrationData(frame, ["d", "s"], "y", {"mu": (0.05, 1.0)}, upper="hi")
    info = rule.information_per_point(data.observations)
    assert np.all(info[:10] == 0) and np.all(info[10:] > 0)
    assert choose(data).parametrization == "non_centred"


def test_where_the_program_offers_it_large_counts_are_partially_non_centred():
    # information times the prior's variance 0.5^2 against DOMINANCE, at the points themselves:
    # close together or far apart alike, for the partial form adapts to each direction of the GP
    for corners in (True, False):
        assert choose(counts_data(1e5, corners=corners), partial=True).parametrization == "partial"
        assert choose(counts_data(1e5, corners=corners)).parametrization != "partial"
    assert choose(counts_data(4 * rule.DOMINANCE * 1.5), partial=True).parametrization == "partial"
    assert choose(counts_data(4 * rule.DOMINANCE * 0.8), partial=True).parametrization == "non_centred"
    assert choose(counts_data(1e5, corners=True), partial=True).reason.startswith(
        "partial (partially non-centred with the data's information, chosen from the data)")
    # a few trials say little: the rule falls through to its centred / non-centred choice
    assert choose(counts_data(0, "binomial", trials=10), partial=True).parametrization == "non_centred"


def test_the_data_on_the_model_scale():
    counts = counts_data(20)
    y = counts.observations.value
    np.testing.assert_allclose(rule.model_scale_values(counts.observations, y), np.log(y + 0.5))
    binomial = counts_data(0, "binomial", trials=10)
    y = binomial.observations.value
    np.testing.assert_allclose(rule.model_scale_values(binomial.observations, y),
                               np.log((y + 0.5) / (10 - y + 0.5)))


def test_the_plan_decides_once_and_the_user_overrides():
    plan = make_plan(counts_data(1e5, corners=True), COUNTS_SIMULATOR)
    assert plan.program.latent and plan.program.partial_centring and not plan.parametrization_given
    assert plan.options.discrepancy_parametrization == "partial"
    assert plan.options.discrepancy_parametrization_reason.startswith("partial (partially non-centred")
    data = counts_data(5)
    assert make_plan(data, COUNTS_SIMULATOR).options.discrepancy_parametrization == "non_centred"
    told = make_plan(data, COUNTS_SIMULATOR, discrepancy_parametrization="centred")
    assert told.parametrization_given and told.options.discrepancy_parametrization == "centred"
    assert "set by the user" in told.options.discrepancy_parametrization_reason
    # no discrepancy: nothing to choose
    assert make_plan(data, COUNTS_SIMULATOR, discrepancy="none").options.discrepancy_parametrization == "auto"
    with pytest.raises(ValueError, match="discrepancy_parametrization must be one of auto, centred, non_centred, "
                                         "partial"):
        ModelOptions(discrepancy_parametrization="fully_centred")


def test_the_stan_data_carry_the_flag():
    from stancal.stan.standata import build_stan_data

    data = counts_data(500)
    for chosen, flag in (("centred", 1), ("non_centred", 0), ("partial", 2)):
        plan = make_plan(data, COUNTS_SIMULATOR, discrepancy_parametrization=chosen)
        stan_data = build_stan_data(data, plan.program.data, plan.options, data.physical[data.inputs])
        assert stan_data["delta_centred"] == flag
        np.testing.assert_allclose(stan_data["delta_pseudo"], np.log(data.observations.value + 0.5))
        np.testing.assert_allclose(stan_data["delta_information"], data.observations.value)
    # a censored Gaussian output: the program's own y_real, 0 where censored
    rng = np.random.default_rng(1)
    frame = pd.DataFrame({"d": np.linspace(0.5, 3, 6), "s": 0.0, "y": rng.normal(size=6)})
    frame.loc[:2, "y"] = np.nan
    frame["hi"] = np.where(frame.y.isna(), 0.0, np.nan)
    gaussian = stancal.CalibrationData(frame, ["d", "s"], "y", {"mu": (0.05, 1.0)}, upper="hi")
    plan = make_plan(gaussian, COUNTS_SIMULATOR, discrepancy_parametrization="partial")
    stan_data = build_stan_data(gaussian, plan.program.data, plan.options, gaussian.physical[gaussian.inputs])
    np.testing.assert_array_equal(stan_data["delta_pseudo"], stan_data["y_real"])
    np.testing.assert_allclose(stan_data["delta_pseudo"][3:], gaussian.scaling.standardise(frame.y[3:]))
    assert np.all(stan_data["delta_pseudo"][:3] == 0)


def test_partial_is_offered_only_where_the_registry_says():
    from stancal.stan.registry import PROGRAMS

    assert [p.name for p in PROGRAMS.values() if p.partial_centring] == ["koh_latent"]
    runs = pd.DataFrame({"d": [0.5, 3.0, 0.5, 3.0], "s": [0.0, 5.0, 5.0, 0.0], "mu": [0.1, 0.5, 0.9, 0.3],
                         "y": [800.0, 10.0, 60.0, 200.0]})
    data = counts_data(1e5, corners=True)
    with pytest.raises(ValueError, match="'partial' is offered by koh_latent, not by koh_latent_emulator"):
        make_plan(data.with_runs(runs), method="modular", discrepancy_parametrization="partial")
    # a Gaussian program integrates its GP out: 'partial' is an error there too, not silently ignored
    with pytest.raises(ValueError, match="'partial' is offered by koh_latent, not by koh;"):
        make_plan(counts_data(20, "gaussian"), COUNTS_SIMULATOR, discrepancy_parametrization="partial")


def fake_fit(share: float, draws: int = 200, max_treedepth: int = 10) -> dict:
    """A fit known only by its tree depths: ``share`` of them at the maximum."""
    depth = np.full((2, draws // 2), 4)
    depth.ravel()[: int(round(share * draws))] = max_treedepth
    return {"sample_stats": xr.Dataset({"tree_depth": (("chain", "draw"), depth)}), "share": share}


def test_a_saturated_fit_is_refitted_the_other_way_once():
    options = ModelOptions(discrepancy_parametrization="centred", discrepancy_parametrization_reason="centred (x)")
    asked = []

    def sample_once(opts):
        asked.append(opts.discrepancy_parametrization)
        return fake_fit(0.01)

    fit, kept = with_fallback(sample_once, fake_fit(0.40), options, 10, lambda f: f)
    assert asked == ["non_centred"] and fit["share"] == 0.01
    assert kept.discrepancy_parametrization == "non_centred"
    assert kept.discrepancy_parametrization_reason == (
        "centred (x); then centred spent 40 % of transitions at the maximum tree depth 10 (> 5 %), so it was "
        "refitted non_centred: 1 %; kept non_centred")


def test_the_fallback_keeps_the_better_fit_and_leaves_healthy_fits_alone():
    options = ModelOptions(discrepancy_parametrization="non_centred")
    fit, kept = with_fallback(lambda o: fake_fit(0.9), fake_fit(0.3), options, 10, lambda f: f)
    assert fit["share"] == 0.3 and kept.discrepancy_parametrization == "non_centred"
    assert "refitted centred: 90 %; kept non_centred" in kept.discrepancy_parametrization_reason

    def never(opts):
        raise AssertionError("a healthy fit is not refitted")

    at_limit = fake_fit(SATURATED_SHARE)
    assert saturated_share(at_limit, 10) == pytest.approx(SATURATED_SHARE)
    assert with_fallback(never, at_limit, options, 10, lambda f: f) == (at_limit, options)


def test_calibrate_refits_only_the_plans_choice(monkeypatch):
    """calibrate's sampling step calls the fallback for an automatic choice
    on a latent program, never for the user's."""
    from stancal.fitting import calibrate as calibrate_module

    calls = []
    monkeypatch.setattr(calibrate_module, "with_fallback",
                        lambda sample_once, fit, options, depth, tree_of: (calls.append(depth), (fit, options))[1])
    data = counts_data(500)

    class Fit:
        tree = None

    for given, expected in ((None, [12]), ("centred", [])):
        calls.clear()
        plan = make_plan(data, COUNTS_SIMULATOR, **({"discrepancy_parametrization": given} if given else {}))
        calibrate_module._sample_checked(lambda o: Fit(), data, plan, {}, chosen_by_user=False, max_treedepth=12)
        assert calls == expected


def test_the_report_says_which_and_why():
    from stancal.reporting.report import parametrization_line

    summary = {"options": {"discrepancy_parametrization_reason": "centred (chosen from the data): because"}}
    line = "- the discrepancy's latent GP was sampled centred (chosen from the data): because"
    assert parametrization_line(summary) == [line]
    assert parametrization_line({"options": {}}) == []
