"""Diagnose the sim-to-real gap: where the discrepancy lies, which candidate
unmodelled effect explains it, and how far it shrinks once that effect is
added.

A candidate is either a formula over the physical data's columns, entering
the discrepancy mean as h(x, z)' beta beside the GP, or a simulator variant:
another Stan ``simulator`` with extra parameters and possibly covariates as
inputs. Every fit keeps the baseline's discrepancy inputs and a constant
discrepancy mean, so the remaining discrepancies (GP plus constant) are
comparable; unless a calibration parameter already carries that level:
under a log link a source strength that scales the simulator's output is a
constant on the link scale, and trades with the constant along a ridge that
NUTS walks at its maximum tree depth. Such a parameter is found before
sampling (stancal.fitting.confounding) and the constant is then dropped
from every fit alike, the candidates' terms staying centred, so the
comparison stays fair: the parameter is the level in every fit. Candidates
are ranked by the ELPD difference to the baseline
(PSIS-LOO on the exact conditional, with moment matching, then exact refits,
where Pareto k stays high; or K-fold).

A vector output (stancal.problem.vector_data) is diagnosed the same way
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

import functools
import logging
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.diagnosing.density_pool import DensityPool
from stancal.diagnosing.gap_location import GapLocation, interval, locate_gap
from stancal.diagnosing.moment_match import match_fit
from stancal.diagnosing.scoring import (
    PARETO_K_LIMIT,
    Score,
    kfold_tests,
    moment_matched,
    psis_score,
    refit_rows,
    rescored,
    scored,
    settled,
    unreliable_tests,
)
from stancal.fitting.calibrate import calibrate
from stancal.fitting.cluster import FitFailure, FitRunner, FitTask, fit_runner
from stancal.fitting.confounding import Confounding, resolve_confounding, stage_one_emulator
from stancal.fitting.plan import Plan, make_plan, model_keywords, plan_scalar
from stancal.fitting.postfit import DRAWS_FILE
from stancal.fitting.resume import Resume
from stancal.fitting.seeds import fit_seed
from stancal.fitting.stage_one import run_stage_one
from stancal.fitting.stopwatch import COMPILED_EARLIER, Stopwatch
from stancal.fitting.vector_calibrate import calibrate_vector
from stancal.fitting.warm_start import warm_candidate_options, warm_refit_options
from stancal.problem.candidates import Candidate, CandidateError, check_adds_terms, check_candidate_data, variant_data
from stancal.problem.data import CalibrationData, bounds_of
from stancal.problem.sampling import SamplerOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.results.result import CalibrationResult
from stancal.results.vector_result import VectorCalibrationResult
from stancal.stan.backends import get_backend
from stancal.stan.source import FlatProgram, StanProgramError

logger = logging.getLogger("stancal")

# more observations with a high Pareto k than this in one fit: K-fold with
# this many folds costs less than refitting each of them
FALLBACK_FOLDS = 5



class GapWarning(UserWarning):
    """Something that weakens the gap diagnosis (e.g. high Pareto k)."""


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
    failed: list[FitFailure] = field(default_factory=list)  # candidates left out: a fit failed twice
    # theta confounded with the discrepancy mean's constant, found before sampling: every fit dropped it
    confounding: list[Confounding] = field(default_factory=list)

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
                "moment_matching": _matching(base),
                "diagnostics": _sampler(self.baseline),
            },
            "where": self.location.to_json(),
            "candidates": [],
            "failed": [{"name": f.name, "error": f.error} for f in self.failed],
            "confounding": [c.to_json() for c in self.confounding],
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
                "moment_matching": _matching(s),
                "diagnostics": _sampler(fit.result),
            })
        return out


def _matching(score: Score) -> dict[str, Any]:
    """What moment matching did in one fit: the observations it scored
    (Pareto k brought to 0.7 or below), and each tried one's k before and after."""
    return {"points": len(scored(score.matched)),
            "tried": [p.to_json() for p in score.matched]}


def _sampler(result: CalibrationResult | VectorCalibrationResult) -> dict[str, Any]:
    return result.diagnostics.summary() if result.diagnostics else {}


def label_name(candidate: Candidate | None) -> str:
    return "the baseline" if candidate is None else f"candidate '{candidate.name}'"


def _counts(unreliable: dict[str, int]) -> str:
    return ", ".join(f"{n} observation{'s' if n > 1 else ''} of {name}" for name, n in unreliable.items())


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


# ---- checking candidates before any fit -------------------------------------
def variant_program(data: CalibrationData | VectorCalibrationData, candidate: Candidate,
                    plan: Plan | None = None) -> FlatProgram:
    """The program a simulator variant runs: the baseline plan's model on
    the variant (koh, or its latent or scalable version; koh_vector for a
    vector output)."""
    plan = plan or make_plan(data, candidate.stan)
    return plan.with_simulator(candidate.stan).main_program()


def check_candidates(data: CalibrationData | VectorCalibrationData, candidates: list[Candidate], backend,
                     plan: Plan | None = None) -> None:
    """Fail before sampling: formulas must evaluate, variants must pass stanc."""
    if not candidates:
        raise CandidateError("give at least one candidate effect")
    variants = check_candidate_data(data, candidates)
    if plan is not None:
        check_adds_terms(data, candidates, plan.options.mean_formula)
    for c in (c for c in candidates if c.kind == "variant"):
        if not Path(c.stan).is_file():
            raise CandidateError(f"candidate '{c.name}': Stan file not found: {c.stan}")
        variant = variants[c.name]
        if plan is not None and not isinstance(data, VectorCalibrationData):
            try:  # the baseline's model on the variant's data: what it cannot do is named now
                plan_scalar(variant, c.stan, None, plan.options)
            except ValueError as err:
                raise CandidateError(f"candidate '{c.name}': {err}") from None
        try:
            backend.check(variant_program(data, c, plan))
        except StanProgramError as err:
            raise CandidateError(f"candidate '{c.name}': the variant does not compile: {err}") from None


# ---- the analysis --------------------------------------------------------------
def _fit_task(name: str, candidate: Candidate | None, data, new_points: pd.DataFrame | None,
              folder: Path | None, warm: dict[str, Any] | None = None, *, vector: bool, plan: Plan, seed: int,
              sampling: dict[str, Any]) -> FitTask:
    """The baseline's or a candidate's fit to ``data`` (all of it, or a
    training set), with its own seed, as a task for the runner: the baseline
    plan, with the candidate's mean terms or on its simulator variant.
    ``warm``: a refit's warm start and short warm-up (warm_refit_options)."""
    if candidate is not None and candidate.kind == "variant":
        plan = plan.with_simulator(candidate.stan)
    elif candidate is not None:
        plan = replace(plan, options=replace(plan.options,
                                             mean_formula=candidate.with_baseline_terms(plan.options.mean_formula)))
    options = dict(data=data, plan=plan, seed=fit_seed(seed, name), out_dir=folder, **{**sampling, **(warm or {})})
    if vector:
        return FitTask(name, calibrate_vector, {**options, "new_rows": new_points})
    return FitTask(name, calibrate, {**options, "new_points": new_points})


def diagnose_gap(
    data: CalibrationData | VectorCalibrationData,
    candidates: list[Candidate],
    *,
    simulator: str | Path | None = None,
    method: str | None = None,
    seed: int | None = None,
    out_dir: str | Path | None = None,
    kfold: int | None = None,
    scheduler: str | FitRunner | None = None,
    warm_refits: bool = True,
    warm_candidates: bool = False,
    every_candidate: bool = False,
    moment_matching: bool = True,
    matching_workers: int | None = None,
    **calibrate_options: Any,
) -> GapAnalysis:
    """Fit the baseline (KOH with a GP discrepancy over the inputs and
    covariates) and every candidate, then locate, rank and measure the gap.

    ``kfold``: use K-fold cross-validation with this many folds instead of
    PSIS-LOO; by default K-fold (5 folds) is used only when a Pareto k
    exceeds 0.7. The fits run side by side on Dask (``scheduler``: None for
    a local cluster, an address, "in-process", or a FitRunner; see
    stancal.fitting.cluster); each is written under ``out_dir`` as it finishes. A
    candidate whose fit fails twice is left out of the ranking and named in
    ``failed``. A rerun with the same ``out_dir`` reuses the fits and refits
    finished there with the same inputs (stancal.fitting.resume; scalar
    outputs only so far: a vector result is not read back from its files).
    ``calibrate_options`` (kernel, chains, warmup, draws, backend,
    adapt_delta, ...) go to every fit.
    ``warm_refits``: each refit (a scalar output's) starts from its full
    fit's draws and adaptation, with a short warm-up
    (stancal.fitting.warm_start). ``warm_candidates``: so does each
    candidate's fit (a scalar output's), from the baseline's, which then
    runs first, with half its warm-up; off by default, as on the cooling
    case it saved no wall time on two cores, nor on the counts case (943 s
    of fits against 524 s cold: docs/benchmarks.md). Unless
    ``every_candidate`` or ``kfold``,
    or the comparison falls back to K-fold (too many unreliable points), a
    fit whose refits cannot change the answer whatever its unreliable
    points' held-out densities turn out to be keeps its PSIS scores,
    unrefitted (scoring.settled; its scheme says so): a candidate that
    cannot lead; the leader and the baseline, when the leader is certain
    and its verdict (credible or not) holds at every end of the bounds. ``moment_matching``: before any
    refit, PSIS-LOO with moment matching (Paananen et al. 2021;
    stancal.diagnosing.moment_match) at each fit's points with Pareto k
    above 0.7 (scalar outputs); only the points it leaves above 0.7 are
    refitted; a candidate settled on its PSIS bounds is neither matched nor
    refitted. ``matching_workers``: the processes its passes over the draws
    are split between (None: the machine's cores; 1: this process alone).
    """
    SamplerOptions.from_keywords({**calibrate_options, "seed": seed})  # before anything is planned or compiled
    vector = isinstance(data, VectorCalibrationData)
    plan = _gap_plan(data, simulator, method, calibrate_options, vector)
    stan_backend = get_backend(calibrate_options.get("backend"))
    check_candidates(data, candidates, stan_backend, plan)
    clock = Stopwatch()
    resume = Resume(out_dir, seed)  # a rerun into the same folder reuses the fits and refits it finished
    seed = resume.seed
    out = Path(out_dir) if out_dir is not None else None
    # a vector result cannot be read back from its files yet, so its fits always run
    run = functools.partial(resume.map, restore=_restored) if not vector else lambda runner, tasks: runner.map(tasks)

    def folder(*parts: str) -> Path | None:
        return None if out is None else out.joinpath(*parts)

    def home(candidate: Candidate | None) -> tuple[str, ...]:  # a fit's folder under out (and under refits)
        return ("baseline",) if candidate is None else ("candidates", _slug(candidate.name))

    # each candidate's data, built and checked once (a variant's has its own inputs and theta)
    datasets = {label_name(c): variant_data(data, c) if c and c.kind == "variant" else data
                for c in [None, *candidates]}

    def data_for(candidate: Candidate | None):
        return datasets[label_name(candidate)]

    labels = [None, *candidates]
    failed: list[FitFailure] = []
    with fit_runner(scheduler) as runner:
        # every program up front, side by side on the machine's cores, then on every worker
        compiled = runner.prepare([*plan.stan_programs(), *(variant_program(data, c, plan) for c in candidates
                                                            if c.kind == "variant")],
                                  calibrate_options.get("backend"))
        clock.lap("compile" if compiled else COMPILED_EARLIER)
        # a theta that carries the constant's level: the constant leaves every fit alike (checked once, here;
        # from runs, on stage 1's emulator, which every fit then reuses: stage 1 reads the runs alone, which the
        # fits, refits and formula candidates share, so they are compared on one emulator)
        emulator = run_stage_one(plan.stage_one, data, plan.options, plan.stan_programs(),
                                 backend=stan_backend, seed=seed) if stage_one_emulator(plan) else None
        plan, confounding = resolve_confounding(plan, data, stan_backend, emulator)
        plan = replace(plan, stage_one_result=emulator) if emulator else plan
        task = functools.partial(_fit_task, vector=vector, plan=plan, seed=seed, sampling=calibrate_options)

        def fit_task(c: Candidate | None, start: CalibrationResult | None) -> FitTask:
            fitted = data_for(c)
            return task(label_name(c), c, fitted, None if vector else fitted.source.reset_index(drop=True),
                        folder(*home(c)), None if start is None else warm_candidate_options(
                            start, bounds_of(fitted.parameters), calibrate_options,
                            fit_seed(seed, f"warm {label_name(c)}")))

        fits = _full_fits(functools.partial(run, runner), fit_task, candidates, warm_candidates and not vector,
                          failed)
        labels, fits = _without_failures(labels, fits, failed)
        clock.lap("fits")
        scores = [psis_score(r) for r in fits]
        if moment_matching and kfold is None and not vector:  # K-fold refits every point; vectors: not yet
            scores = moment_match_fits(labels, fits, scores, matching_workers, every_candidate)
            clock.lap("moment matching")
        scores, skipped, kfold = comparison_scheme(labels, scores, kfold, every_candidate)
        tests = [[] if i in skipped else kfold_tests(len(data_for(c).physical), kfold, seed) if kfold is not None
                 else unreliable_tests(s) for i, (c, s) in enumerate(zip(labels, scores, strict=True))]
        # every refit of every fit in one batch
        jobs = [(i, j, test) for i, label_tests in enumerate(tests) for j, test in enumerate(label_tests)]
        warm = warm_refits and not vector  # a vector result's refits start cold
        refits = run(runner, [task(f"{label_name(labels[i])} without {_rows(test)}", labels[i],
                                   *refit_rows(data_for(labels[i]), test),
                                   folder("refits", *home(labels[i]), f"{j:03d}"),
                                   _warm(fits[i], test, calibrate_options, fit_seed(seed, f"warm {i} {j}"))
                                   if warm else None)
                              for i, j, test in jobs])
    labels, fits, scores = _rescored(labels, fits, scores, tests, jobs, refits, data_for, kfold, failed)
    clock.lap("refits")
    location = locate_gap(fits[0], seed=seed, along=tuple(data.output_index) if vector else ())
    clock.lap("locate")
    ranked = sorted(
        (CandidateFit(c, r, s) for c, r, s in zip(labels[1:], fits[1:], scores[1:], strict=False)),
        key=lambda f: -(f.score.elpd_i - scores[0].elpd_i).sum())
    return GapAnalysis(fits[0], scores[0], location, ranked, clock.laps, failed, confounding)


def _gap_plan(data, simulator, method: str | None, calibrate_options: dict[str, Any], vector: bool) -> Plan:
    """One plan for every fit: K-fold's smaller training sets keep the
    baseline's program and approximation, and every fit has a constant in
    the discrepancy mean, so that no candidate term wins by standing in for
    the discrepancy's overall level; the baseline's own mean terms (a
    mean_formula) stay in every fit, a formula candidate's added to them.
    Takes the plan's keys out of ``calibrate_options``."""
    if vector:
        calibrate_options.pop("approximation", None)
    plan = make_plan(data, simulator, method, calibrate_options.pop("program", None),
                     **model_keywords(calibrate_options, vector))
    return replace(plan, options=replace(plan.options, mean_intercept=True))


def _full_fits(run, fit_task, candidates: list[Candidate], warm: bool, failed: list[FitFailure]) -> list:
    """The baseline's and the candidates' fits to all the data: the baseline
    first and each candidate started where it ended when ``warm``, else all
    side by side (a vector result's fits start cold)."""
    if not warm:
        return run([fit_task(c, None) for c in [None, *candidates]])
    baseline = run([fit_task(None, None)])
    if isinstance(baseline[0], FitFailure):  # raises: without the baseline, nothing to start from or compare
        _record_failure(None, baseline[0], failed)
    return [*baseline, *run([fit_task(c, baseline[0]) for c in candidates])]


def _without_failures(labels: list, fits: list, failed: list[FitFailure]) -> tuple[tuple, tuple]:
    """The labels and fits of the fits that did not fail; the failures named in ``failed``."""
    for c, fit in zip(labels, fits, strict=True):
        if isinstance(fit, FitFailure):
            _record_failure(c, fit, failed)
    return tuple(zip(*((c, fit) for c, fit in zip(labels, fits, strict=True) if not isinstance(fit, FitFailure)),
                     strict=True))


def to_match(scores: list[Score], done: set[int], every: bool) -> list[int]:
    """The fits (indices into ``scores``; 0 is the baseline) whose high
    Pareto k points moment matching scores next: those with such points,
    not matched yet, and not a candidate settled by the scores so far
    (scoring.settled: nothing those points can score changes the ranking,
    so neither matching nor refits are spent on them; unless ``every``
    candidate was asked for). The baseline is matched even when settled:
    its scores enter every difference, and on the counts case its PSIS
    scores at 6 points moved all three by 0.67, more than one's se
    (docs/benchmarks.md), for half of the matching's time."""
    skipped = set() if every else set(settled(scores)) - {0}
    return [i for i, s in enumerate(scores) if s.unreliable.size and i not in skipped | done]


def moment_match_fits(labels: list, fits: list, scores: list[Score], workers: int | None,
                      every: bool = False) -> list[Score]:
    """Each fit's observations with Pareto k above 0.7 moment-matched
    (Paananen et al. 2021; stancal.diagnosing.moment_match) before any
    refit, except in a candidate settled on its PSIS bounds (to_match): an
    observation whose k it brings to 0.7 or below keeps its moment-matched
    score and is not refitted. Matched scores move the bounds, so the fits
    are judged again after each round, and a fit no longer settled is
    matched then. It runs here, in the command's
    main thread, not on the cluster: the log density's autodiff, called from
    a Dask worker's thread, crashed workers (pystan_backend.start_error).
    Where it cannot run (PyStan outside the main thread; the cmdstanpy
    backend has no unconstrained log density: each backend says why) every
    such point is refitted, as before. Each pass over a fit's draws is split
    between ``workers`` processes (None: the machine's cores;
    stancal.diagnosing.density_pool): the fits are done by then, so the
    cores are free."""
    scores = list(scores)
    done: set[int] = set()
    todo = to_match(scores, done, every)
    if not todo:
        return scores  # no worker processes started for nothing
    with DensityPool(workers) as pool:
        while todo:
            for i in todo:
                scores[i] = _matched_score(labels[i], fits[i], scores[i], pool)
            done.update(todo)
            todo = to_match(scores, done, every)
    return scores


def _matched_score(label: Candidate | None, fit, score: Score, pool: DensityPool) -> Score:
    """One fit's score with its high Pareto k points moment-matched, where its backend can."""
    try:
        matched = match_fit(fit, score.unreliable.tolist(), pool=pool)
    except NotImplementedError as reason:
        logger.info("%s: no moment matching (%s): its high Pareto k points are refitted",
                    label_name(label), reason)
        return score
    logger.info("%s: moment matching scored %d of %d points with Pareto k above %g", label_name(label),
                len(scored(matched)), len(matched), PARETO_K_LIMIT)
    return moment_matched(score, matched)


def _warm(fit: CalibrationResult, test: np.ndarray, calibrate_options: dict[str, Any], seed: int) -> dict[str, Any]:
    """A refit without the rows ``test``, started from ``fit`` (stancal.fitting.warm_start)."""
    train = np.setdiff1d(np.arange(len(fit.data.physical)), test)
    return warm_refit_options(fit, train, calibrate_options, seed)


def _restored(task: FitTask, folder: Path, kept: None) -> CalibrationResult:
    """A scalar fit finished by an earlier run, read back from its folder."""
    return CalibrationResult.load(folder / DRAWS_FILE)


def comparison_scheme(labels: list, scores: list[Score], kfold: int | None,
                      every: bool) -> tuple[list[Score], set[int], int | None]:
    """How the fits are compared: their scores, the settled candidates
    (scoring.settled) whose refits are skipped, marked so, and K-fold's fold
    count (None: PSIS-LOO with exact refits where Pareto k is high). A
    settled candidate is judged on PSIS-LOO's bounds, so when the comparison
    falls back to K-fold every fit is refitted: its PSIS score beside the
    others' K-fold ones would rank two scales as one."""
    skipped = set() if every else set(settled(scores))  # every candidate asked for: none skipped
    chosen = _scheme([c for i, c in enumerate(labels) if i not in skipped],
                     [s for i, s in enumerate(scores) if i not in skipped], kfold)
    if chosen is not None:
        skipped = set()
    for i in sorted(skipped):
        logger.info("%s: whatever its %d unreliable points score, the leader and its verdict stay: "
                    "its refits are skipped", label_name(labels[i]), scores[i].unreliable.size)
        scores[i] = replace(scores[i], scheme=f"{scores[i].scheme} (settled: refits skipped)")
    return scores, skipped, chosen


def _scheme(labels: list, scores: list[Score], kfold: int | None) -> int | None:
    """K-fold's fold count, or None for PSIS-LOO with exact refits of the
    observations whose Pareto k is too high; said as a warning."""
    unreliable = {label_name(c): s.unreliable.size for c, s in zip(labels, scores, strict=True)
                  if s.unreliable.size}
    if kfold is None and max(unreliable.values(), default=0) > FALLBACK_FOLDS:
        warnings.warn(f"Pareto k above {PARETO_K_LIMIT} at more than {FALLBACK_FOLDS} observations "
                      f"({_counts(unreliable)}): PSIS-LOO is unreliable, so every fit is compared by "
                      f"{FALLBACK_FOLDS}-fold cross-validation instead", GapWarning, stacklevel=4)
        return FALLBACK_FOLDS
    if kfold is None and unreliable:
        warnings.warn(f"Pareto k above {PARETO_K_LIMIT} at {_counts(unreliable)}: each of those "
                      "observations is scored by an exact refit without it", GapWarning, stacklevel=4)
    return kfold


def _rescored(labels, fits, scores, tests, jobs, refits, data_for, kfold, failed) -> tuple[list, list, list]:
    """Each fit's score with its refits' held-out densities; a fit whose
    refit failed is left out (and recorded)."""
    grouped: list[list] = [[] for _ in labels]
    for (i, *_), refit in zip(jobs, refits, strict=True):
        grouped[i].append(refit)
    kept = []
    for c, fit, score, label_tests, results in zip(labels, fits, scores, tests, grouped, strict=True):
        failure = next((r for r in results if isinstance(r, FitFailure)), None)
        if failure is not None:
            _record_failure(c, failure, failed)
        else:
            kept.append((c, fit, rescored(score, data_for(c), label_tests, results,
                                          kfold=kfold is not None and bool(label_tests))))
    labels, fits, scores = (list(column) for column in zip(*kept, strict=True))
    return labels, fits, scores


def _rows(test: np.ndarray) -> str:
    if len(test) == 1:
        return f"row {test[0]}"
    return f"{len(test)} rows ({', '.join(map(str, test[:4]))}{', ...' if len(test) > 4 else ''})"


def _record_failure(label: Candidate | None, failure: FitFailure, failed: list[FitFailure]) -> None:
    """A candidate's failure goes to ``failed``; without the baseline nothing can be compared."""
    if label is None:
        raise RuntimeError(f"the gap diagnosis needs the baseline, and {failure}"
                           + (f"; also {'; '.join(map(str, failed))}" if failed else ""))
    failed.append(failure)
