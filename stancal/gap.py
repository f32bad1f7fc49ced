"""Diagnose the sim-to-real gap: where the discrepancy lies, which candidate
unmodelled effect explains it, and how far it shrinks once that effect is
added.

A candidate is either a formula over the physical data's columns, entering
the discrepancy mean as h(x, z)' beta beside the GP, or a simulator variant:
another Stan ``simulator`` with extra parameters and possibly covariates as
inputs. Every fit keeps the baseline's discrepancy inputs and a constant
discrepancy mean, so the remaining discrepancies (GP plus constant) are
comparable. Candidates are ranked by the ELPD
difference to the baseline (exact-conditional PSIS-LOO, or K-fold when
Pareto k is high).
"""

from __future__ import annotations

import logging
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.special import logsumexp
from scipy.stats import norm

from .backends import get_backend
from .calibrate import calibrate, choose_method
from .data import CalibrationData, DataError
from .gap_location import GapLocation, discrepancy_parts, interval, locate_gap
from .mean_terms import FormulaError, build_mean_terms
from .models import Method, model_spec
from .result import CalibrationResult
from .stan_source import StanProgramError, flatten

logger = logging.getLogger("stancal")

PARETO_K_LIMIT = 0.7


class CandidateError(ValueError):
    """A candidate effect that cannot be fitted; the message names it."""


class GapWarning(UserWarning):
    """Something that weakens the gap diagnosis (e.g. high Pareto k)."""


@dataclass(frozen=True)
class Candidate:
    """One candidate unmodelled effect: give ``formula``, or ``stan`` (a
    variant simulator) with the physical ``inputs`` it takes and the bounds
    of its extra ``theta`` (the baseline's theta keep theirs)."""

    name: str
    formula: str | None = None
    stan: Path | None = None
    inputs: tuple[str, ...] = ()
    theta: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "formula" if self.formula is not None else "variant"

    def __post_init__(self) -> None:
        if (self.formula is None) == (self.stan is None):
            raise CandidateError(f"candidate '{self.name}': give a formula or a Stan simulator, not both")
        if self.stan is not None and not self.inputs:
            raise CandidateError(f"candidate '{self.name}': a simulator variant needs its 'inputs' columns")


@dataclass
class Score:
    """Predictive performance and remaining discrepancy of one fit."""

    elpd_i: np.ndarray  # pointwise held-out log predictive density
    heldout_mean: np.ndarray  # held-out predictive mean of each observation
    max_pareto_k: float  # NaN under K-fold
    scheme: str  # "psis-loo" or "kfold"
    discrepancy_rms: np.ndarray  # draws: RMS of the GP discrepancy over the physical points

    @property
    def elpd(self) -> float:
        return float(self.elpd_i.sum())

    @property
    def elpd_se(self) -> float:
        return float(np.sqrt(len(self.elpd_i) * np.var(self.elpd_i)))

    def holdout_rmse(self, y: np.ndarray) -> float:
        return float(np.sqrt(np.mean((y - self.heldout_mean) ** 2)))


@dataclass
class CandidateFit:
    candidate: Candidate
    result: CalibrationResult
    score: Score


@dataclass
class GapAnalysis:
    baseline: CalibrationResult
    baseline_score: Score
    location: GapLocation
    candidates: list[CandidateFit]  # best first

    def to_json(self) -> dict[str, Any]:
        y = self.baseline.data.physical[self.baseline.data.output].to_numpy()
        base = self.baseline_score
        base_theta = self.baseline.theta_summary()
        rng = np.random.default_rng(0)
        out = {
            "baseline": {
                "method": self.baseline.method,
                "theta": base_theta,
                "discrepancy_rms": interval(base.discrepancy_rms),
                "elpd_loo": base.elpd,
                "elpd_se": base.elpd_se,
                "holdout_rmse": base.holdout_rmse(y),
                "scheme": base.scheme,
                "diagnostics": _sampler(self.baseline),
            },
            "where": self.location.to_json(),
            "candidates": [],
        }
        for fit in self.candidates:
            s = fit.score
            diff = s.elpd_i - base.elpd_i
            # the fits are independent: pair their draws at random
            after = rng.permutation(s.discrepancy_rms)[:len(base.discrepancy_rms)]
            before = rng.permutation(base.discrepancy_rms)[:len(after)]
            theta = fit.result.theta_summary()
            out["candidates"].append({
                "name": fit.candidate.name, "kind": fit.candidate.kind,
                "effect": fit.candidate.formula or str(fit.candidate.stan),
                "elpd_diff": float(diff.sum()),
                "elpd_diff_se": float(np.sqrt(len(y) * np.var(diff))),
                "discrepancy_rms": interval(s.discrepancy_rms),
                "shrinkage": interval(1 - after / before),
                "theta": theta,
                "theta_change": {k: theta[k]["mean"] - base_theta[k]["mean"]
                                 for k in theta if k in base_theta},
                "holdout_rmse": s.holdout_rmse(y),
                "scheme": s.scheme,
                "max_pareto_k": None if np.isnan(s.max_pareto_k) else s.max_pareto_k,
                "diagnostics": _sampler(fit.result),
            })
        return out


def _sampler(result: CalibrationResult) -> dict[str, Any]:
    d = result.diagnostics
    return {"divergences": d.divergences, "max_rhat": d.max_rhat, "min_ess_bulk": d.min_ess_bulk,
            "warnings": d.messages} if d else {}


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


# ---- checking candidates before any fit -------------------------------------
def variant_data(data: CalibrationData, candidate: Candidate) -> CalibrationData:
    """The physical data as the variant sees it: its own inputs and theta;
    the discrepancy keeps every baseline variable."""
    missing = [c for c in candidate.inputs if c not in data.source.columns]
    if missing:
        raise CandidateError(f"candidate '{candidate.name}': unknown input column(s) {missing}; "
                             f"physical columns: {list(data.source.columns)}")
    theta = {p.name: (p.lower, p.upper) for p in data.parameters} | dict(candidate.theta)
    covariates = [v for v in data.discrepancy_variables if v not in candidate.inputs]
    try:
        return CalibrationData(data.source, candidate.inputs, data.output, theta, covariates)
    except DataError as err:
        raise CandidateError(f"candidate '{candidate.name}': {err}") from None


def check_candidates(data: CalibrationData, candidates: list[Candidate], backend) -> None:
    """Fail before sampling: formulas must evaluate, variants must pass stanc."""
    names = [c.name for c in candidates]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CandidateError(f"candidate name(s) {repeated} used twice")
    if not candidates:
        raise CandidateError("give at least one candidate effect")
    for c in candidates:
        if c.kind == "formula":
            try:
                build_mean_terms(c.formula, data.source)
            except FormulaError as err:
                raise CandidateError(f"candidate '{c.name}': {err}") from None
            continue
        if not Path(c.stan).is_file():
            raise CandidateError(f"candidate '{c.name}': Stan file not found: {c.stan}")
        variant_data(data, c)
        program = flatten(model_spec(Method.KOH).path, aliases={"simulator.stan": Path(c.stan)})
        try:
            backend.check(program)
        except StanProgramError as err:
            raise CandidateError(f"candidate '{c.name}': the variant does not compile: {err}") from None


# ---- scores ------------------------------------------------------------------
def _discrepancy_rms(result: CalibrationResult) -> np.ndarray:
    gp, constant = discrepancy_parts(result)
    return np.sqrt(np.mean((gp + constant[:, None]) ** 2, axis=1))


def psis_score(result: CalibrationResult) -> Score:
    """PSIS-LOO on the exact conditional log p(y_i | y_-i, params), and the
    held-out mean as the importance-weighted E(y_i | y_-i, params)."""
    import arviz_stats as ast

    loo = ast.loo(result.idata, pointwise=True, var_name="y")
    log_w = np.asarray(loo.log_weights.transpose("chain", "draw", "obs")).reshape(-1, loo.n_data_points)
    weights = np.exp(log_w - logsumexp(log_w, axis=0))
    loo_mean = np.asarray(result.idata["at_observations"]["y_loo_mean"])
    loo_mean = loo_mean.reshape(-1, loo_mean.shape[-1])
    return Score(np.asarray(loo.elpd_i), (weights * loo_mean).sum(0),
                 float(np.max(loo.pareto_k)), "psis-loo", _discrepancy_rms(result))


def kfold_score(data: CalibrationData, fit, k: int, seed: int,
                discrepancy_rms: np.ndarray) -> Score:
    """K-fold cross-validation: ``fit(train_data, heldout_points)`` returns a
    result whose predictions are at the held-out points."""
    n = len(data.physical)
    folds = np.random.default_rng(seed).permutation(n) % k
    y = data.physical[data.output].to_numpy()
    elpd, mean = np.zeros(n), np.zeros(n)
    for fold in range(k):
        test = np.flatnonzero(folds == fold)
        train = np.flatnonzero(folds != fold)
        result = fit(data.subset(train), data.source.iloc[test].reset_index(drop=True))
        zeta = np.asarray(result.idata["predictions"]["zeta_new"]).reshape(-1, len(test))
        noise = np.asarray(result.idata["posterior"]["noise_sd"]).reshape(-1, 1)
        elpd[test] = logsumexp(norm.logpdf(y[test], zeta, noise), axis=0) - np.log(len(zeta))
        mean[test] = zeta.mean(0)
    return Score(elpd, mean, float("nan"), "kfold", discrepancy_rms)


# ---- the analysis --------------------------------------------------------------
def diagnose_gap(
    data: CalibrationData,
    candidates: list[Candidate],
    *,
    simulator: str | Path | None = None,
    method: str | None = None,
    seed: int | None = None,
    out_dir: str | Path | None = None,
    kfold: int | None = None,
    **calibrate_options: Any,
) -> GapAnalysis:
    """Fit the baseline (KOH with a GP discrepancy over the inputs and
    covariates) and every candidate, then locate, rank and measure the gap.

    ``kfold``: use K-fold cross-validation with this many folds instead of
    PSIS-LOO; by default K-fold (5 folds) is used only when a Pareto k
    exceeds 0.7. Posteriors are written under ``out_dir`` as they finish.
    ``calibrate_options`` (kernel, chains, warmup, draws, backend,
    adapt_delta, ...) go to every ``calibrate`` call.
    """
    if data.latent_reason:
        raise ValueError("the gap diagnosis needs Gaussian, uncensored outputs (its methods integrate "
                         "the GP out); calibrate this problem with stancal calibrate")
    chosen = choose_method(data, simulator, method)
    stan_backend = get_backend(calibrate_options.get("backend"))
    check_candidates(data, candidates, stan_backend)
    seed = int(np.random.default_rng().integers(2**31 - 1)) if seed is None else seed
    out = Path(out_dir) if out_dir is not None else None
    # every fit has a constant in the discrepancy mean, so that no candidate
    # term wins by standing in for the discrepancy's overall level
    sampling = {**calibrate_options, "mean_intercept": True}

    def fitter(candidate: Candidate | None, folder: Path | None):
        """fit(train_data, new_points) for the baseline or one candidate."""
        def fit(train: CalibrationData, new_points: pd.DataFrame) -> CalibrationResult:
            if candidate is None or candidate.kind == "formula":
                return calibrate(train, simulator=simulator, method=str(chosen), seed=seed,
                                 mean_formula=candidate.formula if candidate else None,
                                 new_points=new_points, out_dir=folder, **sampling)
            return calibrate(train, simulator=candidate.stan, method="koh", seed=seed,
                             new_points=new_points, out_dir=folder, **sampling)
        return fit

    def data_for(candidate: Candidate | None) -> CalibrationData:
        return variant_data(data, candidate) if candidate and candidate.kind == "variant" else data

    labels = [None, *candidates]
    fits: list[CalibrationResult] = []
    for candidate in labels:
        name = "baseline" if candidate is None else f"candidate '{candidate.name}'"
        logger.info("gap: fitting the %s", name)
        folder = None if out is None else (out / "baseline" if candidate is None
                                           else out / "candidates" / _slug(candidate.name))
        d = data_for(candidate)
        fits.append(fitter(candidate, folder)(d, d.source.reset_index(drop=True)))

    scores = [psis_score(r) for r in fits]
    worst = int(np.argmax([s.max_pareto_k for s in scores]))
    if kfold is None and scores[worst].max_pareto_k > PARETO_K_LIMIT:
        name = "the baseline" if worst == 0 else f"candidate '{candidates[worst - 1].name}'"
        warnings.warn(f"Pareto k up to {scores[worst].max_pareto_k:.2f} (> {PARETO_K_LIMIT}) in "
                      f"{name}: PSIS-LOO is unreliable, so every fit is compared by 5-fold "
                      "cross-validation instead", GapWarning, stacklevel=2)
        kfold = 5
    if kfold is not None:
        scores = [kfold_score(data_for(c), fitter(c, None), kfold, seed, s.discrepancy_rms)
                  for c, s in zip(labels, scores)]

    location = locate_gap(fits[0], seed=seed)
    ranked = sorted(
        (CandidateFit(c, r, s) for c, r, s in zip(candidates, fits[1:], scores[1:])),
        key=lambda f: -(f.score.elpd_i - scores[0].elpd_i).sum())
    return GapAnalysis(fits[0], scores[0], location, ranked)
