"""Held-out predictive scores of a fit: PSIS-LOO on the exact conditional
log p(y_i | y_-i, parameters), with exact refits for the points where PSIS is
unreliable, or K-fold cross-validation by refitting. The gap diagnosis ranks
candidates with them, and compare reports them."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy.special import logsumexp

from stancal.diagnosing.gap_location import discrepancy_parts
from stancal.diagnosing.moment_match import MatchedPoint
from stancal.problem.data import CalibrationData
from stancal.results.result import BIAS_NEW, NOISE_LOCATIONS, CalibrationResult

PARETO_K_LIMIT = 0.7  # above it PSIS-LOO is unreliable (Vehtari et al. 2024)
# a candidate that trails the leader by more than this many ses, even with the
# points PSIS cannot score set at its best and the leader's at its worst, keeps
# its PSIS scores: no refit there can change the ranking (settled())
SETTLED_SES = 4.0
# the report calls the leading candidate's ELPD gain over the baseline credible beyond this many ses
CREDIBLE_SES = 2.0


@dataclass
class Score:
    """Predictive performance and remaining discrepancy of one fit."""

    elpd_i: np.ndarray  # pointwise held-out log predictive density
    heldout_mean: np.ndarray  # held-out predictive mean of each observation
    pareto_k: np.ndarray  # PSIS's Pareto k per observation; NaN under K-fold
    # "psis-loo", then "+moment-matching" and "+refits" as used, and " (settled: refits skipped)"; or "kfold"
    scheme: str
    remaining: np.ndarray  # draws (draws, N): the discrepancy GP plus its constant at the physical points
    refits: int = 0  # fits beyond the main one: one per refitted observation, or K under K-fold
    # per observation, what log p(y_i | y_-i) can be (settled()): at most the full fit's own
    # log predictive density there, at least the lowest log likelihood over its draws
    lowest_i: np.ndarray | None = None
    in_sample_i: np.ndarray | None = None
    # the observations moment matching tried (stancal.diagnosing.moment_match): Pareto k before and after
    matched: tuple[MatchedPoint, ...] = ()

    @property
    def discrepancy_rms(self) -> np.ndarray:
        """Draws of the remaining discrepancy's root mean square over the physical points."""
        return np.sqrt(np.mean(self.remaining**2, axis=1))

    @property
    def discrepancy_variation(self) -> np.ndarray:
        """Draws of its root mean square about its mean over the physical points:
        the part of the discrepancy that a term constant over the points cannot
        trade with its level, and so the part that shrinkage is measured on."""
        return np.std(self.remaining, axis=1)

    @property
    def max_pareto_k(self) -> float:
        return float(np.max(self.pareto_k))

    @property
    def unreliable(self) -> np.ndarray:
        """Observations where PSIS is unreliable (Pareto k above 0.7)."""
        return np.flatnonzero(self.pareto_k > PARETO_K_LIMIT)

    @property
    def elpd(self) -> float:
        return float(self.elpd_i.sum())

    @property
    def elpd_se(self) -> float:
        return float(np.sqrt(len(self.elpd_i) * np.var(self.elpd_i)))

    def holdout_rmse(self, y: np.ndarray) -> float:
        """Over the exact observations (a censored one has no value)."""
        return float(np.sqrt(np.nanmean((y - self.heldout_mean) ** 2)))



def _remaining_discrepancy(result: CalibrationResult) -> np.ndarray:
    gp, constant = discrepancy_parts(result)
    return gp + constant[:, None]


def psis_score(result: CalibrationResult) -> Score:
    """PSIS-LOO on the exact conditional log p(y_i | y_-i, params), and the
    held-out mean as the importance-weighted E(y_i | y_-i, params)."""
    import arviz_stats as ast

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        loo = ast.loo(result.idata, pointwise=True, var_name="y")
    for w in said:  # arviz's Pareto k warning is the Score's pareto_k, which every caller reports
        if "shape parameter of Pareto" not in str(w.message):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    log_w = np.asarray(loo.log_weights.transpose("chain", "draw", "obs")).reshape(-1, loo.n_data_points)
    weights = np.exp(log_w - logsumexp(log_w, axis=0))
    loo_mean = np.asarray(result.idata["at_observations"]["y_loo_mean"])
    loo_mean = loo_mean.reshape(-1, loo_mean.shape[-1])
    log_lik = np.asarray(result.idata["log_likelihood"]["y"]).reshape(-1, loo.n_data_points)
    return Score(np.asarray(loo.elpd_i), (weights * loo_mean).sum(0),
                 np.asarray(loo.pareto_k), "psis-loo", _remaining_discrepancy(result),
                 lowest_i=log_lik.min(0), in_sample_i=logsumexp(log_lik, axis=0) - np.log(len(log_lik)))


def scored(matched) -> list[MatchedPoint]:
    """The moment-matched observations whose Pareto k it brought to 0.7 or below."""
    return [p for p in matched if p.k_after <= PARETO_K_LIMIT]


def moment_matched(score: Score, matched: list[MatchedPoint]) -> Score:
    """``score`` with moment matching's held-out density and mean at the
    observations whose Pareto k it brought to 0.7 or below (Paananen et al.
    2021); every tried observation's Pareto k is its k after, so those still
    above 0.7 stay unreliable (refitted, or K-fold)."""
    elpd, mean, k = score.elpd_i.copy(), score.heldout_mean.copy(), score.pareto_k.copy()
    for point in matched:
        k[point.row] = point.k_after
    for point in scored(matched):
        elpd[point.row], mean[point.row] = point.elpd, point.heldout_mean
    scheme = score.scheme + ("+moment-matching" if scored(matched) else "")
    return replace(score, elpd_i=elpd, heldout_mean=mean, pareto_k=k, matched=tuple(matched), scheme=scheme)


def settled(scores: list[Score]) -> list[int]:
    """The fits (indices into ``scores``; 0 is the baseline) whose refits
    cannot change the answer: which candidate leads, and whether its gain
    over the baseline is credible. Each fit's log p(y_i | y_-i) at a point
    where its Pareto k is high is bounded: above by the full fit's log
    predictive density there (p(y_i | y) = E_-i[p_i^2] / E_-i[p_i] >=
    E_-i[p_i] = p(y_i | y_-i), with p_i = p(y_i | y_-i, parameters), by
    Cauchy-Schwarz), below by the lowest log likelihood over the full fit's
    draws (the refit's posterior stays where the full fit's draws are: a
    pragmatic bound, loose as it is). The leader is the candidate with the
    best total at its lower bounds; a candidate whose total at its upper
    bounds trails it by more than SETTLED_SES ses of their pointwise
    difference is settled: its refits are skipped and its PSIS scores kept.
    When the leader is certain (no candidate's upper total reaches its
    lower one; by SETTLED_SES ses when its own lower bound is the pragmatic
    one) and its gain over the baseline is credible at every end of both
    fits' bounds (_verdict_fixed), the leader's and the baseline's refits
    are skipped too: the baseline's move every total difference alike, so
    they never change the ranking. The identity behind the upper
    bound, p(y_i | y_-i) = 1 / E_post[1 / p_i], is Gelfand, Dey & Chang
    (1992), the one PSIS-LOO estimates (Vehtari, Gelman & Gabry 2017, whose
    rule, as the loo package's reloo, refits every such point); skipping
    is stancal's, to spend exact refits only where they can change the
    answer."""
    if len(scores) < 3 or any(s.lowest_i is None for s in scores):
        return []
    worst = [_total(s, s.lowest_i) for s in scores]
    best = [_total(s, s.in_sample_i) for s in scores]
    leader = max(range(1, len(scores)), key=lambda f: worst[f])
    out = [f for f in range(1, len(scores)) if f != leader and scores[f].unreliable.size
           and worst[leader] - best[f] > SETTLED_SES * _se(scores[leader], scores[f])]
    if _leader_certain(scores, worst, best, leader) and _verdict_fixed(scores, worst, best, leader):
        out = sorted({*out, *(f for f in (0, leader) if scores[f].unreliable.size)})
    return out


def _se(one: Score, other: Score) -> float:
    """The se of two fits' ELPD difference, from their pointwise one."""
    diff = one.elpd_i - other.elpd_i
    return float(np.sqrt(len(diff) * np.var(diff)))


def _leader_certain(scores: list[Score], worst: list[float], best: list[float], leader: int) -> bool:
    """No candidate's total can reach the leader's, whatever the refits give."""
    margin = SETTLED_SES if scores[leader].unreliable.size else 0.0  # its lower bound is the pragmatic one
    return all(worst[leader] - best[f] > margin * _se(scores[leader], scores[f])
               for f in range(1, len(scores)) if f != leader)


def _verdict_fixed(scores: list[Score], worst: list[float], best: list[float], leader: int) -> bool:
    """The leader's gain over the baseline is credible (above CREDIBLE_SES
    ses, and SETTLED_SES more where the leader's lower bound is the
    pragmatic one) at both fits' worst ends: the leader at its lower
    bounds, the baseline at its upper ones. The se is the larger of the
    PSIS one and the one at those ends: the totals move alike, the
    pointwise differences do not. "Not credible" is never taken as fixed:
    it would rest on the baseline's lower bound, which a high Pareto k
    leaves open (the exact value can fall below every draw's)."""
    leader_score, baseline = scores[leader], scores[0]
    se = max(_se(leader_score, baseline),
             _se(replace(leader_score, elpd_i=_bounded(leader_score, leader_score.lowest_i)),
                 replace(baseline, elpd_i=_bounded(baseline, baseline.in_sample_i))))
    margin = SETTLED_SES * se if leader_score.unreliable.size else 0.0
    return worst[leader] - best[0] > CREDIBLE_SES * se + margin


def _bounded(score: Score, bound: np.ndarray) -> np.ndarray:
    """The score's pointwise ELPD with ``bound`` in place of PSIS where its Pareto k is high."""
    elpd = score.elpd_i.copy()
    elpd[score.unreliable] = bound[score.unreliable]
    return elpd


def _total(score: Score, bound: np.ndarray) -> float:
    """The score's total ELPD with ``bound`` in place of PSIS where its Pareto k is high."""
    return float(_bounded(score, bound).sum())


def kfold_tests(n: int, k: int, seed: int) -> list[np.ndarray]:
    """The held-out rows of each of K folds, assigned at random."""
    folds = np.random.default_rng(seed).permutation(n) % k
    return [np.flatnonzero(folds == fold) for fold in range(k)]


def unreliable_tests(score: Score) -> list[np.ndarray]:
    """One refit per observation whose Pareto k exceeds 0.7, holding out that
    observation alone (Vehtari, Gelman & Gabry 2017, section 2.1; the loo
    package's reloo): a few refits instead of K-fold's K per fit."""
    return [np.array([i]) for i in score.unreliable]


def refit_rows(data: CalibrationData, test: np.ndarray) -> tuple[CalibrationData, pd.DataFrame]:
    """The training data without the ``test`` rows, and those rows as the new points to predict."""
    train = np.setdiff1d(np.arange(len(data.physical)), test)
    return data.subset(train), data.source.iloc[test].reset_index(drop=True)


def held_out(data: CalibrationData, test: np.ndarray, result) -> tuple[np.ndarray, np.ndarray]:
    """log p(y_test | y_train) and the predictive mean at the ``test`` rows,
    from a fit to the other rows whose predictions are at the test rows."""
    predictions = result.idata["predictions"]
    zeta = np.asarray(predictions["zeta_new" if "zeta_new" in predictions else "zeta"]).reshape(-1, len(test))
    points = data.source.iloc[test].reset_index(drop=True)
    if BIAS_NEW in predictions:  # a held-out reading by a biased source: the process plus that source's bias
        zeta = zeta + result.reading_bias(points, result.source_biases(predictions[BIAS_NEW], len(test)))
    # heteroscedastic noise (the fit sampled its log sd GP at the settings): the sd at the held-out rows from that
    # GP, one draw of it per posterior draw
    estimated_sd = (result.noise_sd_at(points, np.random.default_rng(0))
                    if NOISE_LOCATIONS in result.idata.children else None)
    log_density = data.heldout_log_density(test, zeta, result.idata["posterior"], estimated_sd)
    return logsumexp(log_density, axis=0) - np.log(len(zeta)), zeta.mean(0)


def rescored(score: Score, data: CalibrationData, tests: list[np.ndarray], refits: list, *,
             kfold: bool) -> Score:
    """``score`` with the held-out values of the refits (one per test set)
    in place of PSIS's: at every observation under K-fold, else at the
    observations with high Pareto k."""
    elpd, mean = score.elpd_i.copy(), score.heldout_mean.copy()
    for test, result in zip(tests, refits, strict=True):
        elpd[test], mean[test] = held_out(data, test, result)
    if kfold:
        return Score(elpd, mean, np.full(len(elpd), np.nan), "kfold", score.remaining, refits=len(tests))
    return replace(score, elpd_i=elpd, heldout_mean=mean, refits=len(tests),
                   scheme=f"{score.scheme}+refits" if tests else score.scheme)
