"""The latent discrepancy's parametrisation: the plan's choice from the data
(stancal.problem.parametrization), the user's override, the refit the other
way after a fit that saturates the tree depth, and what the report says. No
sampling here: the short fits are in test_latent_parametrization.py."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr

import stancal
from stancal.fitting.parametrization_fallback import SATURATED_SHARE, saturated_share, with_fallback
from stancal.fitting.plan import make_plan
from stancal.problem.options import ModelOptions
from stancal.problem.parametrization import DOMINANCE, choose_parametrization, information_per_point

COUNTS_SIMULATOR = "case_studies/detector_counts/simulator.stan"


def counts_data(mean_count: float, likelihood: str = "poisson", points: int = 30, trials: int | None = None,
                seed: int = 0) -> stancal.CalibrationData:
    rng = np.random.default_rng(seed)
    x = np.linspace(0.5, 3.0, points)
    frame = pd.DataFrame({"d": x, "s": np.zeros(points), "y": rng.poisson(mean_count, points)})
    if trials is not None:
        frame["n"] = trials
        frame["y"] = rng.binomial(trials, 0.5, points)
    return stancal.CalibrationData(frame, ["d", "s"], "y", {"mu": (0.05, 1.0)}, likelihood=likelihood,
                                   trials="n" if trials is not None else None)


def test_large_counts_are_centred_and_small_counts_non_centred():
    large = choose_parametrization(counts_data(500).observations)
    assert large.parametrization == "centred"
    assert "information per point is" in large.reason and "100 % of the points" in large.reason
    assert choose_parametrization(counts_data(3).observations).parametrization == "non_centred"
    # the threshold: a count of 4 DOMINANCE (prior sd 0.5, precision 4) is where a point is dominated
    assert choose_parametrization(counts_data(4 * DOMINANCE * 0.8).observations).parametrization == "non_centred"
    assert choose_parametrization(counts_data(4 * DOMINANCE * 1.5).observations).parametrization == "centred"


def test_information_per_likelihood():
    binomial = counts_data(0, "binomial", trials=1000)
    y = binomial.observations.value
    p = (y + 0.5) / 1001
    np.testing.assert_allclose(information_per_point(binomial.observations), 1000 * p * (1 - p))
    assert choose_parametrization(binomial.observations).parametrization == "centred"
    assert choose_parametrization(counts_data(0, "binomial", trials=10).observations).parametrization \
        == "non_centred"
    # unknown overdispersion caps what a count says: large negative binomial counts stay non-centred
    assert choose_parametrization(counts_data(500, "negbinomial").observations).parametrization == "non_centred"


def test_noisy_gaussian_and_censored_outputs_are_non_centred():
    rng = np.random.default_rng(1)
    frame = pd.DataFrame({"d": np.linspace(0.5, 3, 20), "s": 0.0, "y": rng.normal(size=20)})
    frame.loc[:9, "y"] = np.nan  # censored below 0: no information counted
    frame["hi"] = np.where(frame.y.isna(), 0.0, np.nan)  # left-censored (an open lower bound)
    data = stancal.CalibrationData(frame, ["d", "s"], "y", {"mu": (0.05, 1.0)}, upper="hi")
    info = information_per_point(data.observations)
    assert np.all(info[:10] == 0) and np.all(info[10:] > 0)
    assert choose_parametrization(data.observations).parametrization == "non_centred"


def test_the_plan_decides_once_and_the_user_overrides():
    data = counts_data(500)
    plan = make_plan(data, COUNTS_SIMULATOR)
    assert plan.program.latent and not plan.parametrization_given
    assert plan.options.discrepancy_parametrization == "centred"
    assert plan.options.discrepancy_parametrization_reason.startswith("centred (chosen from the data)")
    told = make_plan(data, COUNTS_SIMULATOR, discrepancy_parametrization="non_centred")
    assert told.parametrization_given and told.options.discrepancy_parametrization == "non_centred"
    assert "set by the user" in told.options.discrepancy_parametrization_reason
    # no discrepancy, or a Gaussian program: nothing to choose
    assert make_plan(data, COUNTS_SIMULATOR, discrepancy="none").options.discrepancy_parametrization == "auto"
    with pytest.raises(ValueError, match="discrepancy_parametrization must be one of auto, centred, non_centred"):
        ModelOptions(discrepancy_parametrization="partial")


def test_the_stan_data_carry_the_flag():
    from stancal.stan.standata import build_stan_data

    data = counts_data(500)
    for chosen, flag in (("centred", 1), ("non_centred", 0)):
        plan = make_plan(data, COUNTS_SIMULATOR, discrepancy_parametrization=chosen)
        stan_data = build_stan_data(data, plan.program.data, plan.options, data.physical[data.inputs])
        assert stan_data["delta_centred"] == flag


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
