"""The gap diagnosis's refits cost what they must: warm-started from the full
fit (stancal.fitting.warm_start), and skipped for candidates whose refits
cannot change the ranking (scoring.settled)."""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from conftest import COOLING, cooling_data

import stancal
from stancal.diagnosing.scoring import SETTLED_SES, Score, held_out, refit_rows, settled
from stancal.fitting.warm_start import (
    candidate_start,
    candidate_warmup,
    refit_draws,
    refit_warmup,
    warm_candidate_options,
    warm_refit_options,
    warm_start,
)
from stancal.stan.backends import WarmStart
from stancal.stan.backends.base import warm_windows
from stancal.stan.backends.cmdstanpy_backend import CmdStanPyBackend


def full_fit(rows: int = 5, metric: bool = False) -> SimpleNamespace:
    """A stand-in for a full fit: 2 chains x 4 draws of a theta, a latent
    vector with one value per row, a matrix with a row axis, an empty
    array; step sizes per chain 0.2 and 0.4."""
    draws = np.arange(2 * 4, dtype=float).reshape(2, 4)
    parameters = xr.Dataset({
        "theta_unit": (("chain", "draw", "q"), draws[..., None] / 10),
        "delta_z": (("chain", "draw", "row"), draws[..., None] + np.arange(rows)),
        "theta_function_raw": (("chain", "draw", "row", "f"), np.zeros((2, 4, rows, 1))),
        "noise_sd": (("chain", "draw"), draws + 1),
        "rho_free": (("chain", "draw", "e"), np.zeros((2, 4, 0))),
    })
    groups = {"stan_parameters": parameters,
              "sample_stats": xr.Dataset({"step_size": (("chain", "draw"), np.repeat([[0.2], [0.4]], 4, 1))})}
    if metric:
        groups["adaptation"] = xr.Dataset({"inv_metric": (("chain", "unconstrained"), [[1.0, 2.0], [3.0, 4.0]])})
    return SimpleNamespace(idata=xr.DataTree.from_dict(groups),
                           data=SimpleNamespace(physical=pd.DataFrame({"x": np.arange(rows)})))


def test_warm_start_starts_each_chain_at_a_draw_of_the_full_fit():
    train = np.array([0, 1, 3, 4])
    start = warm_start(full_fit(), train, chains=3, seed=1)
    assert len(start.inits) == 3
    for chain, init in enumerate(start.inits):
        source = chain % 2  # chain c starts at a draw of the full fit's chain c
        draw = int(round(init["noise_sd"] - 1)) - 4 * source
        assert 0 <= draw < 4
        assert init["theta_unit"] == pytest.approx([(4 * source + draw) / 10])
        # the latent vector keeps the training rows' values; a matrix with a row axis and an
        # empty array are left to Stan
        assert init["delta_z"] == pytest.approx(4 * source + draw + train)
        assert set(init) == {"theta_unit", "delta_z", "noise_sd"}
    assert start.step_size == pytest.approx(0.3)
    assert start.inv_metric is None  # PyStan reports none
    options = warm_refit_options(full_fit(), train, {"chains": 2, "warmup": 1000, "draws": 1000}, seed=1)
    assert (options["warmup"], options["draws"]) == (200, 500)
    assert (refit_warmup(300), refit_draws(700), refit_warmup(100), refit_draws(300)) == (150, 500, 100, 300)


def test_warm_start_carries_the_metric_when_the_space_keeps_its_size():
    start = warm_start(full_fit(metric=True), np.arange(4), chains=2, seed=1)
    assert start.inv_metric is None  # a parameter per row: the unconstrained space shrinks
    fit = full_fit(metric=True)
    fit.idata["stan_parameters"] = xr.DataTree(fit.idata["stan_parameters"].to_dataset()[["theta_unit",
                                                                                          "noise_sd"]])
    start = warm_start(fit, np.arange(4), chains=2, seed=1)
    np.testing.assert_array_equal(start.inv_metric, [[1.0, 2.0], [3.0, 4.0]])


def test_a_candidate_starts_at_the_baselines_draws_with_theta_by_name():
    """A variant's fit (a parameter more, c, before k here) gets k from the
    baseline's draw on its own bounds, c at random in the middle of its box,
    the other parameters as they were; the shorter warm-up, the same draws."""
    baseline = full_fit(metric=True)
    kept = baseline.idata["stan_parameters"].to_dataset()[["theta_unit", "noise_sd"]]  # no parameter per row
    baseline.idata["stan_parameters"] = xr.DataTree(kept)
    theta = kept["theta_unit"].values * 0.2  # k on (0, 0.2)
    baseline.idata["posterior"] = xr.DataTree(xr.Dataset({"theta": (("chain", "draw", "q"), theta)}))
    baseline.data.theta_names = ["k"]
    start = candidate_start(baseline, {"c": (0.0, 2.0), "k": (0.0, 0.4)}, chains=4, seed=2)
    for chain, init in enumerate(start.inits):
        draw = int(round(init["noise_sd"] - 1)) - 4 * (chain % 2)
        c, k = init["theta_unit"]
        # the same k, on the new box (kept off its edge, where theta_unit's transform is infinite)
        assert k == pytest.approx(max((4 * (chain % 2) + draw) / 10 * 0.2 / 0.4, 1e-3))
        assert 0.25 <= c <= 0.75
    assert start.inv_metric.shape == (4, 2)
    options = warm_candidate_options(baseline, {"k": (0.0, 0.2)}, {"chains": 2, "warmup": 1000, "draws": 700}, 1)
    assert options["warmup"] == candidate_warmup(1000) == 500 and "draws" not in options
    assert (candidate_warmup(300), candidate_warmup(200)) == (250, 200)


def test_a_warm_start_keeps_what_the_program_has_in_that_shape():
    start = WarmStart([{"theta_unit": [0.5], "beta": [1.0], "noise_sd": 1.0}], 0.3, np.ones((1, 3)))
    same = start.fitted({"theta_unit": (1,), "beta": (1,), "noise_sd": (), "rho_free": (0,)})
    assert same.inits == start.inits and same.inv_metric is not None
    # a candidate's longer coefficient vector: left to Stan, and the metric no longer fits
    longer = start.fitted({"theta_unit": (1,), "beta": (3,), "noise_sd": ()})
    assert longer.inits == [{"theta_unit": [0.5], "noise_sd": 1.0}] and longer.inv_metric is None
    # a parameter the earlier program lacked: the metric goes too
    assert start.fitted({"theta_unit": (1,), "beta": (1,), "noise_sd": (), "delta_sd": (1,)}).inv_metric is None


def test_warm_windows_fit_the_warmup():
    for warmup in (20, 150, 200, 1000):
        windows = warm_windows(warmup)
        assert sum(windows.values()) == warmup and min(windows.values()) >= 1
    assert warm_windows(200) == {"init_buffer": 25, "term_buffer": 50, "window": 125}


def test_cmdstanpy_is_given_the_warm_start(monkeypatch):
    """CmdStan takes the inits, the step size, the inverse metric per chain and
    the windows; and the backend reports the metric it adapted."""
    given = {}

    class Model:
        def sample(self, **kwargs):
            given.update(kwargs)
            return SimpleNamespace(stan_variables=lambda: {"a": np.zeros(2 * 3)},
                                   method_variables=lambda: {"stepsize__": np.full((3, 2), 0.5)},
                                   metric=np.ones((2, 1)))

    monkeypatch.setattr(CmdStanPyBackend, "_model", lambda self, program: Model())
    start = WarmStart([{"a": 0.1}, {"a": 0.2}], 0.3, np.array([[2.0], [3.0]]))
    out = CmdStanPyBackend().sample(None, {}, chains=2, warmup=200, draws=3, seed=1, inits=[{}, {}],
                                    adapt_delta=0.9, max_treedepth=10, warm_start=start)
    assert given["inits"] == start.inits and given["step_size"] == 0.3 and given["iter_warmup"] == 200
    assert given["metric"] == [{"inv_metric": [2.0]}, {"inv_metric": [3.0]}]
    assert (given["adapt_init_phase"], given["adapt_metric_window"], given["adapt_step_size"]) == (25, 125, 50)
    np.testing.assert_array_equal(out.inv_metric, np.ones((2, 1)))


# ---- candidates whose refits cannot change the ranking ------------------------------------
def score(elpd: np.ndarray, unreliable: list[int], lowest: float, in_sample: float) -> Score:
    """PSIS scores with Pareto k 0.9 at the ``unreliable`` points, and bounds there."""
    k = np.full(len(elpd), 0.2)
    k[unreliable] = 0.9
    n = len(elpd)
    return Score(elpd, np.zeros(n), k, "psis-loo", np.zeros((4, n)),
                 lowest_i=np.full(n, lowest), in_sample_i=np.full(n, in_sample))


def test_a_candidate_that_cannot_lead_is_settled():
    rng = np.random.default_rng(1)
    noise = rng.normal(0, 0.1, 40)
    base = score(-2.0 + noise, [3], -9.0, -1.0)
    leader = score(-1.0 + noise, [5], -4.0, -0.5)  # worst case: 39 x -1 - 4 = -43
    far = score(-3.0 + noise, [7, 8], -9.0, -1.0)  # best case: 38 x -3 - 2 = -116
    close = score(-1.05 + noise, [9], -9.0, -0.9)  # best case -41.85: could lead
    reliable = score(-3.0 + noise, [], -9.0, -1.0)  # nothing to refit
    assert settled([base, leader, far, close, reliable]) == [2]
    assert settled([base, leader, close]) == []
    assert settled([base, far]) == []  # one candidate: nothing to rank


def test_settled_needs_many_ses():
    """The same gap in totals settles a candidate when the pointwise
    differences are steady, not when they are noisy."""
    rng = np.random.default_rng(2)
    gap = 12.0 / 40  # the candidate trails by 12 at its best
    steady, noisy = (spread - spread.mean() for spread in (rng.normal(0, 0.05, 40), rng.normal(0, 3.0, 40)))
    for spread, expected in ((steady, [2]), (noisy, [])):
        leader = score(-1.0 + spread, [], -1.0, -1.0)
        trailing = score(-1.0 - gap + np.zeros(40), [4], -1.0 - gap, -1.0 - gap)
        assert settled([score(np.full(40, -2.0), [], 0, 0), leader, trailing]) == expected
        se = np.sqrt(40 * np.var(leader.elpd_i - trailing.elpd_i))
        assert (12.0 > SETTLED_SES * se) == bool(expected)


def test_the_leader_and_the_baseline_are_settled_when_neither_can_change_the_answer():
    """The leader's and the baseline's refits are skipped when no candidate
    can overtake the leader and its gain over the baseline is credible at
    every end of both fits' bounds (the baseline's refits move every
    difference alike, so they never change the ranking); refitted when that
    verdict could flip, or when another candidate could lead."""
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 0.1, 40)
    leader = score(-1.0 + noise, [5], -1.6, -0.9)  # worst case: 39 x -1 - 1.6
    far = score(-3.0 + noise, [7, 8], -9.0, -1.0)  # best case: 38 x -3 - 2: cannot lead
    credible = score(-1.5 + rng.normal(0, 0.1, 40), [3, 4], -3.0, -1.2)  # 20 below at the worst ends
    assert settled([credible, leader, far]) == [0, 1, 2]
    doubtful = score(-1.02 + rng.normal(0, 0.1, 40), [3], -9.0, -1.0)  # the gain is 1 +- 0.9: the bounds decide
    assert settled([doubtful, leader, far]) == [2]
    close = score(-1.05 + noise, [9], -9.0, 1.0)  # its best case, -39.95, beats the leader's worst: it could lead
    assert settled([credible, leader, far, close]) == [2]
    reliable = score(-1.5 + noise, [], 0, 0)  # nothing to refit in the baseline: only the leader is skipped
    assert settled([reliable, leader, far]) == [1, 2]


def test_a_fallback_to_kfold_refits_the_settled_candidates_too():
    """Settled candidates keep PSIS-LOO scores only while the others are
    PSIS-LOO as well: when too many unreliable points send the comparison to
    K-fold, every fit is scored by K-fold, so that no ranking mixes the two
    scales (a K-fold ELPD is lower than the LOO one of the same fit)."""
    from stancal.diagnosing.gap import FALLBACK_FOLDS, GapWarning, comparison_scheme

    rng = np.random.default_rng(1)
    noise = rng.normal(0, 0.1, 40)
    labels = [None, *(stancal.Candidate(name, formula=f"~ {name}") for name in ("near", "far"))]
    far = score(-3.0 + noise, [7, 8], -9.0, -1.0)  # settled beside the leader, as in the test above
    leader = score(-1.0 + noise, [5], -4.0, -0.5)
    # a baseline as good as the leader: whether the leader's gain is credible hangs on the refits
    base = score(-1.0 + noise, [3], -9.0, -1.0)
    assert settled([base, leader, far]) == [2]
    many = score(-1.0 + noise, list(range(FALLBACK_FOLDS + 1)), -9.0, -1.0)  # the baseline, unsettled: K-fold
    with pytest.warns(GapWarning, match=f"every fit is compared by {FALLBACK_FOLDS}-fold"):
        scores, skipped, kfold = comparison_scheme(labels, [many, leader, far], None, every=False)
    assert kfold == FALLBACK_FOLDS and skipped == set() and all(s.scheme == "psis-loo" for s in scores)
    # without the fallback the settled candidate's refits are skipped, and its score says so
    with pytest.warns(GapWarning, match="scored by an exact refit"):
        scores, skipped, kfold = comparison_scheme(labels, [base, leader, far], None, every=False)
    assert kfold is None and skipped == {2} and scores[2].scheme.endswith("(settled: refits skipped)")


# ---- a warm refit answers as a cold one does -----------------------------------------------
@pytest.mark.slow  # 12 fits of the cooling case: a few minutes on 2 cores
def test_warm_refit_holds_out_as_a_cold_refit_does():
    """The held-out log density of one point (the one the exact LOO refit
    exists for) from warm-started refits lies within the spread of cold
    refits over seeds: 4 x (1000 + 1000) as the CLI's default."""
    data = cooling_data(seed=7)
    sampling = {"simulator": COOLING / "simulator.stan", "mean_intercept": True, "chains": 4,
                "warmup": 1000, "draws": 1000}
    full = stancal.calibrate(data, seed=1, **sampling)
    test = np.array([11])  # the last reading of the first curve: the far end of t
    train, new = refit_rows(data, test)
    cold, warm = [], []
    for seed in range(2, 7):
        cold.append(held_out(data, test, stancal.calibrate(train, seed=seed, new_points=new, **sampling))[0][0])
        options = warm_refit_options(full, np.setdiff1d(np.arange(24), test), sampling, seed)
        warm.append(held_out(data, test, stancal.calibrate(train, seed=seed, new_points=new,
                                                           **{**sampling, **options}))[0][0])
    spread = max(np.std(cold, ddof=1), 0.01)  # Monte Carlo spread of a cold refit's answer
    assert abs(np.mean(warm) - np.mean(cold)) < 3 * spread / np.sqrt(len(cold)) * np.sqrt(2) + 0.02, (cold, warm)
    assert np.std(warm, ddof=1) < 3 * spread, (cold, warm)


def test_a_gain_that_is_not_credible_leaves_the_baseline_to_its_refits():
    """"Not credible at the fits' best ends" rests on the baseline's lower
    bound, the lowest log likelihood over its draws, which a Pareto k above
    0.7 leaves open (the exact log p(y_i | y_-i) can fall below every draw's):
    a lower exact value would make the gain credible, so only a credible
    verdict settles the baseline and the leader (review of issue 30)."""
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 0.1, 40)
    leader = score(-1.0 + noise, [5], -1.6, -0.9)
    far = score(-3.0 + noise, [7, 8], -9.0, -1.0)
    alike = score(-1.0 + rng.normal(0, 0.1, 40), [3], -1.3, -0.95)  # as good as the leader at every bound
    assert settled([alike, leader, far]) == [2]


# ---- moment matching spent only where it can change the answer -------------------------------
def test_a_settled_fit_is_not_moment_matched_until_the_others_scores_unsettle_it(monkeypatch):
    """Moment matching, as a refit, is skipped for a candidate that is settled
    on its PSIS bounds (scoring.settled), not for the baseline; once the other fits' points are
    matched their scores move, the fits are judged again, and a fit that is
    no longer settled is matched then."""
    from stancal.diagnosing import gap
    from stancal.diagnosing.moment_match import MatchedPoint

    rng = np.random.default_rng(1)
    noise = rng.normal(0, 0.1, 40)
    labels = [None, *(stancal.Candidate(name, formula=f"~ {name}") for name in ("leader", "far"))]
    # far is settled beside the leader; a baseline as good as the leader leaves those two to be scored
    scores = [score(-1.0 + noise, [3], -9.0, -1.0), score(-1.0 + noise, [5], -4.0, -0.5),
              score(-3.0 + noise, [7, 8], -9.0, -1.0)]
    assert gap.to_match(scores, set(), every=False) == [0, 1]
    assert gap.to_match(scores, set(), every=True) == [0, 1, 2]  # every candidate asked for: none skipped
    # a baseline the leader beats credibly at every bound settles all three, but its scores enter every
    # difference, so it is matched all the same
    credible = score(-2.0 + noise, [3], -9.0, -1.0)
    assert settled([credible, *scores[1:]]) == [0, 1, 2]
    assert gap.to_match([credible, *scores[1:]], set(), every=False) == [0]
    for leader_elpd, matched_fits in ((-1.0, [0, 1]), (-80.0, [0, 1, 2])):
        calls = []

        def match_fit(fit, rows, pool, leader_elpd=leader_elpd, calls=calls):
            calls.append(fit)
            return [MatchedPoint(row, 0.9, 0.5, leader_elpd if fit == 1 else -3.0, 0.0, 1) for row in rows]

        monkeypatch.setattr(gap, "match_fit", match_fit)
        out = gap.moment_match_fits(labels, [0, 1, 2], scores, workers=1)
        assert calls == matched_fits  # a leader matched down to -80 at a point no longer keeps far out of reach
        assert out[2].unreliable.tolist() == ([] if 2 in matched_fits else [7, 8])
        assert out[1].elpd_i[5] == leader_elpd and out[0].unreliable.size == 0
