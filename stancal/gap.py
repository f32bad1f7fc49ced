"""Diagnose the sim-to-real gap: where the discrepancy lies, which candidate
unmodelled effect explains it, and how far it shrinks once that effect is
added.

A candidate is either a formula over the physical data's columns, entering
the discrepancy mean as h(x, z)' beta beside the GP, or a simulator variant:
another Stan ``simulator`` with extra parameters and possibly covariates as
inputs. Every fit keeps the baseline's discrepancy inputs and a constant
discrepancy mean, so the remaining discrepancies (GP plus constant) are
comparable. Candidates are ranked by the ELPD difference to the baseline
(PSIS-LOO on the exact conditional, with exact refits where Pareto k is
high, or K-fold).

A vector output (stancal.vector_data) is diagnosed the same way
(koh_vector.stan, or modular_vector.stan from runs; variants run
koh_vector): its values are the observations, and *where* covers the
output index beside the inputs and covariates.

Counts, binomial and censored outputs are diagnosed the same way on the
link scale: their latent discrepancy is integrated out at each left-out
point for PSIS-LOO (functions/latent_loo.stan).

Shrinkage is measured on the remaining discrepancy's variation over the
physical points (its RMS about its mean there), not on its RMS: a term that
is nearly constant over the points (air pressure, 1016 +- 5 hPa) trades its
level with the discrepancy's constant, so the level of the remaining
discrepancy is not identified, while its variation is.
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

from .backends import get_backend
from .calibrate import calibrate, choose_method, stan_programs
from .data import CalibrationData, DataError
from .gap_location import GapLocation, interval, locate_gap
from .mean_terms import FormulaError, build_mean_terms
from .models import HSGP_METHODS, ModelOptions
from .result import CalibrationResult
from .scoring import PARETO_K_LIMIT, Score, kfold_score, psis_score, refit_unreliable
from .seeds import command_seed
from .stan_source import FlatProgram, StanProgramError
from .stopwatch import Stopwatch
from .vector_calibrate import (
    VectorCalibrationResult,
    calibrate_vector,
    choose_vector_method,
    vector_program,
)
from .vector_data import VectorCalibrationData

logger = logging.getLogger("stancal")

# more observations with a high Pareto k than this in one fit: K-fold with
# this many folds costs less than refitting each of them
FALLBACK_FOLDS = 5



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
class CandidateFit:
    candidate: Candidate
    result: CalibrationResult | VectorCalibrationResult
    score: Score


@dataclass
class GapAnalysis:
    baseline: CalibrationResult | VectorCalibrationResult
    baseline_score: Score
    location: GapLocation
    candidates: list[CandidateFit]  # best first
    # wall-clock seconds of each stage: compile, fits, refits (K-fold or exact LOO), locate
    timing: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        y = self.baseline.data.physical[self.baseline.data.output].to_numpy()
        base = self.baseline_score
        base_theta = self.baseline.theta_summary()
        rng = np.random.default_rng(0)
        out = {
            "baseline": {
                "method": self.baseline.method,
                "discrepancy_scale": self.baseline.data.discrepancy_scale,
                "theta": base_theta,
                "discrepancy_rms": interval(base.discrepancy_rms),
                "discrepancy_variation": interval(base.discrepancy_variation),
                "elpd_loo": base.elpd,
                "elpd_se": base.elpd_se,
                "holdout_rmse": base.holdout_rmse(y),
                "scheme": base.scheme,
                "refits": base.refits,
                "diagnostics": _sampler(self.baseline),
            },
            "where": self.location.to_json(),
            "candidates": [],
            "timing": {k: round(v, 1) for k, v in self.timing.items()},
        }
        for fit in self.candidates:
            s = fit.score
            diff = s.elpd_i - base.elpd_i
            # the fits are independent: pair their draws at random
            after = rng.permutation(s.discrepancy_variation)[:len(base.discrepancy_variation)]
            before = rng.permutation(base.discrepancy_variation)[:len(after)]
            theta = fit.result.theta_summary()
            out["candidates"].append({
                "name": fit.candidate.name, "kind": fit.candidate.kind,
                "effect": fit.candidate.formula or str(fit.candidate.stan),
                "elpd_diff": float(diff.sum()),
                "elpd_diff_se": float(np.sqrt(len(y) * np.var(diff))),
                "discrepancy_rms": interval(s.discrepancy_rms),
                "discrepancy_variation": interval(s.discrepancy_variation),
                "shrinkage": interval(1 - after / before),
                "theta": theta,
                "theta_change": {k: theta[k]["mean"] - base_theta[k]["mean"]
                                 for k in theta if k in base_theta},
                "holdout_rmse": s.holdout_rmse(y),
                "scheme": s.scheme,
                "max_pareto_k": None if np.isnan(s.max_pareto_k) else s.max_pareto_k,
                "refits": s.refits,
                "diagnostics": _sampler(fit.result),
            })
        return out


def _sampler(result: CalibrationResult | VectorCalibrationResult) -> dict[str, Any]:
    d = result.diagnostics
    return {"divergences": d.divergences, "max_rhat": d.max_rhat, "min_ess_bulk": d.min_ess_bulk,
            "warnings": d.messages} if d else {}


def label_name(candidate: Candidate | None) -> str:
    return "the baseline" if candidate is None else f"candidate '{candidate.name}'"


def _counts(unreliable: dict[str, int]) -> str:
    return ", ".join(f"{n} observation{'s' if n > 1 else ''} of {name}" for name, n in unreliable.items())


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


# ---- checking candidates before any fit -------------------------------------
def variant_data(data: CalibrationData | VectorCalibrationData,
                 candidate: Candidate) -> CalibrationData | VectorCalibrationData:
    """The physical data as the variant sees it (each container's variant())."""
    missing = [c for c in candidate.inputs if c not in data.source.columns]
    if missing:
        raise CandidateError(f"candidate '{candidate.name}': unknown input column(s) {missing}; "
                             f"physical columns: {list(data.source.columns)}")
    try:
        return data.variant(candidate.inputs, candidate.theta)
    except DataError as err:
        raise CandidateError(f"candidate '{candidate.name}': {err}") from None


def variant_program(data: CalibrationData | VectorCalibrationData, candidate: Candidate) -> FlatProgram:
    """The program a simulator variant runs: koh (koh_vector for a vector
    output), or koh_latent for what needs it."""
    if isinstance(data, VectorCalibrationData):
        return vector_program("koh", candidate.stan)
    return stan_programs(choose_method(data, candidate.stan, "koh"), candidate.stan)[-1]


def check_candidates(data: CalibrationData | VectorCalibrationData, candidates: list[Candidate], backend) -> None:
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
        try:
            backend.check(variant_program(data, c))
        except StanProgramError as err:
            raise CandidateError(f"candidate '{c.name}': the variant does not compile: {err}") from None


# ---- the analysis --------------------------------------------------------------
def diagnose_gap(
    data: CalibrationData | VectorCalibrationData,
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
    vector = isinstance(data, VectorCalibrationData)
    if vector:
        chosen = choose_vector_method(data, simulator, method)
        calibrate_options.pop("approximation", None)
        baseline_programs = [vector_program(chosen, simulator)]
    else:
        chosen = choose_method(data, simulator, method,
                               ModelOptions(approximation=calibrate_options.get("approximation", "auto")))
        # K-fold's training sets are smaller: every fit keeps the baseline's approximation
        calibrate_options["approximation"] = "hsgp" if chosen in HSGP_METHODS else "exact"
        baseline_programs = stan_programs(chosen, simulator)
    stan_backend = get_backend(calibrate_options.get("backend"))
    check_candidates(data, candidates, stan_backend)
    clock = Stopwatch()
    # every program up front, side by side on the machine's cores
    stan_backend.compile([*baseline_programs,
                          *(variant_program(data, c) for c in candidates if c.kind == "variant")])
    clock.lap("compile")
    seed = command_seed(seed)
    out = Path(out_dir) if out_dir is not None else None
    # every fit has a constant in the discrepancy mean, so that no candidate
    # term wins by standing in for the discrepancy's overall level
    sampling = {**calibrate_options, "mean_intercept": True}

    def fitter(candidate: Candidate | None, folder: Path | None):
        """fit(train_data, new_points) for the baseline or one candidate."""
        def fit(train, new_points: pd.DataFrame | None):
            formula = candidate.formula if candidate else None
            if vector:
                variant = candidate is not None and candidate.kind == "variant"
                return calibrate_vector(train, simulator=candidate.stan if variant else simulator,
                                        method="koh" if variant else chosen,
                                        seed=seed, mean_formula=None if variant else formula,
                                        new_rows=new_points, out_dir=folder, **sampling)
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
        logger.info("gap: fitting %s", label_name(candidate))
        folder = None if out is None else (out / "baseline" if candidate is None
                                           else out / "candidates" / _slug(candidate.name))
        d = data_for(candidate)
        fits.append(fitter(candidate, folder)(d, None if vector else d.source.reset_index(drop=True)))

    clock.lap("fits")
    scores = [psis_score(r) for r in fits]
    unreliable = {label_name(c): s.unreliable.size for c, s in zip(labels, scores) if s.unreliable.size}
    if kfold is None and max(unreliable.values(), default=0) > FALLBACK_FOLDS:
        warnings.warn(f"Pareto k above {PARETO_K_LIMIT} at more than {FALLBACK_FOLDS} observations "
                      f"({_counts(unreliable)}): PSIS-LOO is unreliable, so every fit is compared by "
                      f"{FALLBACK_FOLDS}-fold cross-validation instead", GapWarning, stacklevel=2)
        kfold = FALLBACK_FOLDS
    if kfold is not None:
        scores = [kfold_score(data_for(c), fitter(c, None), kfold, seed, s.remaining)
                  for c, s in zip(labels, scores)]
    elif unreliable:
        warnings.warn(f"Pareto k above {PARETO_K_LIMIT} at {_counts(unreliable)}: each of those "
                      "observations is scored by an exact refit without it", GapWarning, stacklevel=2)
        scores = [refit_unreliable(data_for(c), fitter(c, None), s) for c, s in zip(labels, scores)]

    clock.lap("refits")
    location = locate_gap(fits[0], seed=seed, along=tuple(data.output_index) if vector else ())
    clock.lap("locate")
    ranked = sorted(
        (CandidateFit(c, r, s) for c, r, s in zip(candidates, fits[1:], scores[1:])),
        key=lambda f: -(f.score.elpd_i - scores[0].elpd_i).sum())
    return GapAnalysis(fits[0], scores[0], location, ranked, clock.laps)
