"""One problem, several identifiable-calibration methods side by side
(review section 6): KOH, L2 calibration, orthogonal GP and scaled GP."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stancal.diagnosing.scoring import psis_score
from stancal.fitting.calibrate import calibrate, model_options
from stancal.fitting.cluster import FitFailure, FitRunner, FitTask, fit_runner
from stancal.fitting.l2 import l2_result
from stancal.fitting.plan import Plan, model_keywords, plan_scalar, require_gaussian
from stancal.fitting.postfit import DRAWS_FILE
from stancal.fitting.resume import Resume
from stancal.fitting.seeds import fit_seed
from stancal.numerics.quadrature import Quadrature, input_box_quadrature
from stancal.problem.data import CalibrationData
from stancal.problem.sampling import SamplerOptions
from stancal.results.result import CalibrationResult
from stancal.results.summaries import band
from stancal.stan.registry import DEFAULT_ESTIMATOR, ESTIMATORS, L2

METHODS = tuple(ESTIMATORS)


@dataclass
class MethodFit:
    name: str
    result: CalibrationResult | None
    seconds: float = 0.0
    skipped: str | None = None  # why the method could not run on this problem


@dataclass
class Comparison:
    fits: list[MethodFit]
    quadrature: Quadrature

    @property
    def theta_names(self) -> list[str]:
        return next((f.result.data.theta_names for f in self.fits if f.result is not None), [])

    def table(self) -> pd.DataFrame:
        """One row per method: theta (median, 90 %), the discrepancy's RMS over
        the input box ||zeta - f(., theta)||, PSIS-LOO ELPD and held-out RMSE."""
        return pd.DataFrame([self._row(fit) for fit in self.fits]).set_index("method")

    def _row(self, fit: MethodFit) -> dict[str, Any]:
        row: dict[str, Any] = {"method": fit.name}
        if fit.result is None:
            return {**row, "skipped": fit.skipped}
        result = fit.result
        for name, s in result.theta_summary().items():
            row.update({f"{name}_q50": s["q50"], f"{name}_q05": s["q05"], f"{name}_q95": s["q95"]})
        size = band(discrepancy_rms(result, self.quadrature))
        row.update({f"discrepancy_rms_{q}": float(size[q]) for q in ("q05", "q50", "q95")})
        score = psis_score(result)  # Pareto k goes into the table (max_pareto_k)
        y = result.data.physical[result.data.output].to_numpy()
        row.update(elpd=score.elpd, elpd_se=score.elpd_se,
                   loo_rmse=score.holdout_rmse(y),
                   max_pareto_k=score.max_pareto_k,
                   divergences=result.diagnostics.divergences if result.diagnostics else None,
                   max_rhat=result.diagnostics.max_rhat if result.diagnostics else None,
                   seconds=fit.seconds, skipped=None)
        return row


def discrepancy_rms(result: CalibrationResult, quadrature: Quadrature) -> np.ndarray:
    """Per draw, sqrt(mean over the input box of (zeta - f(., theta))^2), from
    the predictions at the quadrature nodes (the fit's last prediction points)."""
    predictions = result.idata["predictions"]
    r = len(quadrature.weights)
    gap = np.asarray(predictions["zeta_new"])[..., -r:] - np.asarray(predictions["f_new"])[..., -r:]
    return np.sqrt(quadrature.mean_square(gap.reshape(-1, r)))


def _method_fit(name: str, **options: Any) -> MethodFit:
    """One method's fit, timed where it runs."""
    started = time.perf_counter()
    return MethodFit(name, calibrate(**options), time.perf_counter() - started)


def _seconds(fit: MethodFit) -> float:
    """What a rerun keeps of a finished fit beyond its draws: its time."""
    return fit.seconds


def _plans(data: CalibrationData, simulator, methods: tuple[str, ...], model: dict[str, Any],
           program) -> dict[str, Plan | str]:
    """Each compared estimator's plan, or why it cannot run on this problem;
    a projection of the default fit needs no plan of its own when that fit
    is compared too."""
    plans: dict[str, Plan | str] = {}
    # the problem's default fit: what it cannot do is an error, as in calibrate
    default = plan_scalar(data, simulator, None, model_options(**model), program)
    for name in methods:
        estimator = ESTIMATORS[name]
        if estimator.projects and DEFAULT_ESTIMATOR in methods:
            continue
        if name == DEFAULT_ESTIMATOR:
            plans[name] = default
            continue
        try:
            plans[name] = plan_scalar(data, simulator, L2 if estimator.projects else estimator.method,
                                      model_options(**{**model, "discrepancy": estimator.discrepancy
                                                       or model.get("discrepancy")}), program)
        except ValueError as err:  # an estimator this problem cannot run
            plans[name] = str(err)
    return plans


def compare_methods(data: CalibrationData, *, simulator: str | Path | None = None,
                    methods: tuple[str, ...] = METHODS, seed: int | None = None,
                    out_dir: str | Path | None = None, scheduler: str | FitRunner | None = None,
                    **calibrate_options) -> Comparison:
    """Fit ``data`` with each method (same sampler settings; each fit its
    own seed), side by side on Dask (``scheduler``, see stancal.fitting.cluster). L2
    projects the KOH fit's zeta draws, so it adds no sampling when koh is also
    compared. Methods that cannot run on this problem, or whose fit failed
    twice, are listed as skipped. A rerun with the same ``out_dir`` reuses
    the fits finished there (stancal.fitting.resume). ``calibrate_options`` go to every
    calibrate() call (chains, draws, kernel, ...)."""
    SamplerOptions.from_keywords({**calibrate_options, "seed": seed})  # before anything is planned or compiled
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ValueError(f"unknown methods {sorted(unknown)}; choose from {', '.join(METHODS)}")
    require_gaussian("the method comparison", data)
    quadrature = input_box_quadrature(data)
    resume = Resume(out_dir, seed)  # a rerun into the same folder reuses the fits it finished
    seed = resume.seed
    model = model_keywords(calibrate_options, vector=False)
    fits: dict[str, MethodFit] = {}
    tasks: list[FitTask] = []
    for name, plan in _plans(data, simulator, methods, model, calibrate_options.pop("program", None)).items():
        if isinstance(plan, str):
            fits[name] = MethodFit(name, None, skipped=plan)
            continue
        tasks.append(FitTask(name, _method_fit, dict(
            name=name, data=data, plan=plan, seed=fit_seed(seed, name), new_points=quadrature.nodes,
            out_dir=None if out_dir is None else Path(out_dir) / name, **calibrate_options)))
    with fit_runner(scheduler) as runner:
        runner.prepare([], calibrate_options.get("backend"))  # each fit compiles its program once per machine
        done = resume.map(runner, tasks, keep=_seconds, restore=lambda task, folder, seconds: MethodFit(
            task.name, CalibrationResult.load(folder / DRAWS_FILE), seconds))
        for task, fit in zip(tasks, done, strict=False):
            fits[task.name] = (MethodFit(task.name, None, skipped=f"the fit failed twice: {fit.error}")
                               if isinstance(fit, FitFailure) else fit)
    koh = fits.get(DEFAULT_ESTIMATOR)
    if L2 in methods and DEFAULT_ESTIMATOR in methods and koh.result is not None:
        started = time.perf_counter()
        result = l2_result(koh.result, quadrature, len(quadrature.weights))
        if out_dir is not None:
            result.save(Path(out_dir) / L2 / "posterior.nc")
        fits[L2] = MethodFit(L2, result, koh.seconds + time.perf_counter() - started)
    elif L2 in methods and DEFAULT_ESTIMATOR in methods:
        fits[L2] = MethodFit(L2, None, skipped="projects koh's fit, which failed")
    return Comparison([fits[name] for name in methods], quadrature)
