"""Confounding between theta and the model's own terms, found before
sampling (stancal.fitting.confounding): the share of a theta's link-scale
sensitivity that a constant (or rho * f) explains, and what the calibration
and the gap diagnosis do about it, on a log-link problem with a scale
parameter: counts ~ Poisson(S exp(-mu s))."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from conftest import ROOT, assert_healthy, fit

import stancal
from stancal.diagnosing.gap import diagnose_gap
from stancal.fitting.cluster import IN_PROCESS, FitRunner
from stancal.fitting.confounding import (
    SHARE_LIMIT,
    ConfoundingWarning,
    explained_share,
    find_confounding,
    link_sensitivity,
    resolve_confounding,
    stage_one_emulator,
    theta_design,
)
from stancal.fitting.plan import model_options, plan_scalar
from stancal.fitting.stage_one import run_stage_one
from stancal.problem.candidates import Candidate
from stancal.problem.design import latin_hypercube_with_corners
from stancal.stan.backends import get_backend
from stancal.stan.standata import mean_terms_of

SOURCE = ROOT / "tests" / "stan" / "source_attenuation.stan"
THICKNESS = np.repeat(np.arange(0.0, 8.0, 0.5), 2)  # cm: 32 points, two counts each
S_TRUE, MU_TRUE = 500.0, 0.35
BOX = {"S": (100.0, 1000.0), "mu": (0.05, 1.0)}


def source_counts(seed: int = 3) -> stancal.CalibrationData:
    """Counts from the simulator itself, with a recorded covariate (pressure)
    that plays no part: a formula candidate for the gap."""
    rng = np.random.default_rng(seed)
    frame = pd.DataFrame({"s": THICKNESS, "pressure": 1016 + 5 * rng.standard_normal(THICKNESS.size),
                          "counts": rng.poisson(S_TRUE * np.exp(-MU_TRUE * THICKNESS))})
    return stancal.CalibrationData(frame, ["s"], "counts", BOX, likelihood="poisson")


# ---- the measure, numpy only ------------------------------------------------

def test_a_scaling_theta_is_all_constant_and_an_attenuation_is_not():
    """log(S exp(-mu s)) = log S - mu s: d/dS = 1/S at every point (share 1),
    d/dmu = -s, whose share is mean(s)^2 / mean(s^2) (0.74 here)."""
    lower, upper = np.array([100.0, 0.05]), np.array([1000.0, 1.0])

    def log_counts(theta_unit):
        S, mu = (lower + theta_unit * (upper - lower)).T
        return np.log(S[:, None]) - mu[:, None] * THICKNESS[None]

    _, sensitivity = link_sensitivity(log_counts, theta_design(8, 2))
    share = explained_share(sensitivity, np.ones((THICKNESS.size, 1)))
    assert np.allclose(share[:, 0], 1.0, atol=1e-9)
    expected_mu = THICKNESS.mean() ** 2 / np.mean(THICKNESS**2)
    assert np.allclose(share[:, 1], expected_mu, atol=1e-6) and expected_mu < SHARE_LIMIT


def test_a_scale_on_the_identity_link_is_rho_not_the_constant():
    """f = S exp(-mu s) on the identity link: d/dS = f / S, all of it
    explained by the column f (rho's), a fraction of it by a constant."""
    f = 500 * np.exp(-0.35 * THICKNESS)
    sensitivity = (f / 500)[None, :, None]
    assert explained_share(sensitivity, f[:, None])[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert explained_share(sensitivity, np.ones((f.size, 1)))[0, 0] < 0.7


def test_a_theta_without_effect_is_not_called_confounded():
    share = explained_share(np.zeros((1, 5, 1)), np.ones((5, 1)))
    assert np.isnan(share).all()


# ---- through the compiled program, before sampling --------------------------

@pytest.fixture(scope="module")
def source_plan():
    data = source_counts()
    plan = plan_scalar(data, SOURCE, None, model_options(mean_intercept=True, mean_formula="pressure"))
    backend = get_backend(None)
    backend.compile(plan.stan_programs())
    return data, plan, backend


def test_detection_names_the_source_strength_and_not_the_attenuation(source_plan):
    data, plan, backend = source_plan
    found = find_confounding(plan, data, backend)
    assert [(c.theta, c.term) for c in found] == [("S", "constant")]
    assert found[0].share == pytest.approx(1.0, abs=1e-6)


def test_the_plan_drops_the_constant_and_keeps_the_terms_centred(source_plan):
    data, plan, backend = source_plan
    resolved, found = resolve_confounding(plan, data, backend)
    assert resolved.options.mean_intercept is False and resolved.options.mean_centred is True
    assert resolved.confounding_checked and found[0].dropped
    assert "S" in found[0].line() and "dropped" in found[0].line()
    terms = mean_terms_of(data, resolved.options)
    assert terms.names == ["pressure"] and abs(terms.h.mean()) < 1e-12  # centred: no level left in it
    again, none = resolve_confounding(resolved, data, backend)  # checked once per plan
    assert again == resolved and none == []


class _Stop(Exception):
    pass


class _RecordingRunner(FitRunner):
    """Compiles as the gap's runner does, records the fits it is given, and
    stops there: the gap's plan without sampling."""

    def __init__(self):
        super().__init__(IN_PROCESS, progress=False)
        self.tasks = []

    def map(self, tasks):
        self.tasks += tasks
        raise _Stop


def test_every_gap_fit_drops_the_constant_alike(source_plan, tmp_path):
    data, _, _ = source_plan
    runner = _RecordingRunner()
    with pytest.raises(_Stop):
        # cold (the default), the candidate is planned beside the baseline (warm, it waits for the baseline's draws)
        diagnose_gap(data, [Candidate("pressure", formula="pressure")], simulator=SOURCE,
                     scheduler=runner, chains=2, warmup=100, draws=100, seed=1, warm_candidates=False)
    plans = [task.kwargs["plan"] for task in runner.tasks]
    assert len(plans) == 2  # the baseline and the candidate
    assert all(not p.options.mean_intercept and p.options.mean_centred and p.confounding_checked for p in plans)
    assert plans[1].options.mean_formula == "pressure"


@pytest.mark.parametrize("form", ["orthogonal", "scaled"])
def test_the_restricted_discrepancies_keep_the_constant_beside_them(form, source_plan):
    """The restriction is on the GP part only, so the mean's terms trade with
    theta as beside the plain GP. On the identity link S scales f: it is
    not a constant there, but with the constant it is rho's direction."""
    data, _, backend = source_plan
    gaussian = stancal.CalibrationData(data.source.assign(counts=data.source["counts"].astype(float)), ["s"],
                                       "counts", BOX)
    plan = plan_scalar(gaussian, SOURCE, None, model_options(discrepancy=form, mean_intercept=True,
                                                            estimate_rho=True))
    backend.compile(plan.stan_programs())
    found = {(c.theta, c.term): c.share for c in find_confounding(plan, gaussian, backend)}
    assert list(found) == [("S", "rho")]  # S scales f: rho's column; no theta is a constant here
    assert found["S", "rho"] > 0.999


def test_from_runs_the_stage_one_emulator_names_the_source_strength(source_plan):
    """No Stan simulator: 60 runs of S exp(-mu s), whose stage-1 emulator
    (koh_latent_emulator's, on the log link) is the simulator the fit sees.
    (With 40 runs the emulator's share for S fell to 0.983 at one of the 8
    theta points, 0.994 or more at the others; with 60, 0.996 or more.)"""
    data, _, backend = source_plan
    design = latin_hypercube_with_corners([0.0, *BOX["S"][:1], BOX["mu"][0]], [7.5, BOX["S"][1], BOX["mu"][1]],
                                          60, seed=0)
    runs = pd.DataFrame(design, columns=["s", "S", "mu"])
    runs["counts"] = runs["S"] * np.exp(-runs["mu"] * runs["s"])
    from_runs = stancal.CalibrationData(data.source, ["s"], "counts", BOX, runs=runs, likelihood="poisson")
    plan = plan_scalar(from_runs, None, None, model_options(mean_intercept=True))
    assert stage_one_emulator(plan)
    programs = plan.stan_programs()
    backend.compile(programs)
    emulator = run_stage_one(plan.program.stage_one, from_runs, plan.options, programs, backend=backend, seed=1)
    resolved, found = resolve_confounding(plan, from_runs, backend, emulator)
    assert [(c.theta, c.term, c.dropped) for c in found] == [("S", "constant", True)]
    assert SHARE_LIMIT <= found[0].share < 1  # an emulator, not the simulator: nearly 1
    assert not resolved.options.mean_intercept
    # without stage 1's emulator there is nothing to check it on: the plan is left as it is
    assert resolve_confounding(plan, from_runs, backend, None)[0].options == plan.options


def test_rho_is_the_users_so_stancal_says_so_and_keeps_the_model(source_plan):
    data, _, backend = source_plan
    gaussian = stancal.CalibrationData(data.source.assign(counts=data.source["counts"].astype(float)), ["s"],
                                       "counts", BOX)
    plan = plan_scalar(gaussian, SOURCE, None, model_options(mean_intercept=True, estimate_rho=True,
                                                            discrepancy="orthogonal"))
    with pytest.warns(ConfoundingWarning, match=r"S's effect follows the simulator's output .* S and rho"):
        resolved, found = resolve_confounding(plan, gaussian, backend)
    assert resolved.options == plan.options and not found[0].dropped


# ---- the sampler, before and after ------------------------------------------

BRIGHT = {"S": (1000.0, 10000.0), "mu": (0.05, 1.0)}  # 5,000 counts at s = 0: a narrow ridge


def bright_counts() -> stancal.CalibrationData:
    rng = np.random.default_rng(3)
    frame = pd.DataFrame({"s": THICKNESS, "counts": rng.poisson(10 * S_TRUE * np.exp(-MU_TRUE * THICKNESS))})
    return stancal.CalibrationData(frame, ["s"], "counts", BRIGHT, likelihood="poisson")


def test_the_source_strength_no_longer_walks_a_ridge_at_the_maximum_tree_depth(tmp_path):
    """S against the mean's constant alone (no GP, so that the ridge is the
    only difficulty), at a maximum tree depth of 8 to keep it short: with the
    constant (the code before this check) most transitions hit it (340 of
    600; at depth 10, 332 leapfrog steps a transition on average);
    without it S carries the level, about 6 steps a transition."""
    data = bright_counts()
    result = fit(data, simulator=SOURCE, discrepancy="none", mean_intercept=True, warmup=300, draws=300,
                 max_treedepth=8)
    assert not result.options.mean_intercept and result.options.mean_centred
    assert [(c["theta"], c["dropped"]) for c in result.confounding] == [("S", True)]
    # a change stancal made, not a warning about the sampler
    assert not any("constant" in m for m in result.diagnostics.messages)
    assert_healthy(result)
    stancal.write_calibration(result, tmp_path)  # said in the report and the summary, kept on disk
    assert "- S's effect on the link scale is constant" in (tmp_path / "report.md").read_text()
    assert json.loads((tmp_path / "summary.json").read_text())["confounding"] == result.confounding
    assert stancal.load_result(result.save(tmp_path / "fit.nc")).confounding == result.confounding
    S = result.theta_summary()["S"]
    assert S["q05"] < 10 * S_TRUE < S["q95"]
    # the plan the code before this check ran: the constant kept
    kept = replace(plan_scalar(data, SOURCE, None, model_options(discrepancy="none", mean_intercept=True)),
                   confounding_checked=True)
    # the old plan's fit is expected to be unhealthy: every warning it gives is kept and read
    with warnings.catch_warnings(record=True) as said:
        before = stancal.calibrate(data, plan=kept, chains=2, warmup=300, draws=300, seed=11, max_treedepth=8)
    assert {w.category for w in said} == {stancal.SamplerWarning}, [str(w.message) for w in said]
    assert any("transitions hit the maximum tree depth 8" in str(w.message) for w in said)
    assert before.options.mean_intercept
    # 340 of 600 when measured; the health bar is 5 %
    assert before.diagnostics.treedepth_hits > 0.25 * before.diagnostics.draws


def test_the_gap_report_says_the_constant_was_dropped_and_what_carries_the_level():
    from stancal.fitting.confounding import Confounding
    from stancal.reporting.gap_report import report_markdown

    est = {"mean": 0.1, "q05": 0.05, "q95": 0.2}
    fitted = {"theta": {"S": est}, "discrepancy_rms": est, "discrepancy_variation": est, "holdout_rmse": 1.0,
              "refits": 0, "diagnostics": {}}
    summary = {
        "baseline": {**fitted, "method": "koh_latent", "discrepancy_scale": "log of the mean count",
                     "scheme": "psis-loo"},
        "where": {"importance": {"s": est}, "observations_with_credible_gap": 3, "regions": []},
        "candidates": [{**fitted, "name": "pressure", "kind": "formula", "effect": "pressure", "elpd_diff": 0.5,
                        "elpd_diff_se": 1.0, "shrinkage": est, "theta_change": {"S": 0.0}}],
        "confounding": [Confounding("S", "constant", 1.0, dropped=True).to_json()],
    }
    text = report_markdown(summary, [])
    assert "Before sampling: S's effect on the link scale is constant" in text
    assert "the discrepancy mean's constant term was dropped" in text
    assert "every fit has S carrying the level (no constant in the discrepancy's mean)" in text
    assert "every fit has a constant" in report_markdown({**summary, "confounding": []}, [])
