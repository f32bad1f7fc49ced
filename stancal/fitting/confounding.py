"""Confounding between theta and the model's own terms, found before
sampling from the simulator's sensitivity on the link scale.

A calibration parameter theta_j whose effect on the link scale,
s_ij = d g(f(x_i, theta)) / d theta_j, is the same at every physical point
adds a constant there. A constant term in the discrepancy's mean (the gap
diagnosis puts one in every fit; ``mean_intercept``) adds one too, so the
two trade exactly along a ridge of the posterior: KOH's theta is not
identified against the discrepancy's mean (Brynjarsdottir & O'Hagan 2014;
Tuo & Wu 2015), and NUTS walks such a ridge at its maximum tree depth
(Betancourt 2017, "A conceptual introduction to Hamiltonian Monte Carlo",
section 6). The typical case: under a log link, a source strength S that
scales the counts is log S on the link scale, a constant.

The measure, per theta_j and per theta point t: the share of the sum of
squares of s_.j explained by least squares on the term's columns,
||P s||^2 / ||s||^2 (for the constant, N mean(s)^2 / sum(s^2)). theta_j is
confounded when that share is at least SHARE_LIMIT at every one of a few
theta points spread over the prior. In a linearised Gaussian model with
flat priors the posterior correlation of theta_j with the term is
sqrt(share): 0.99 is a correlation of 0.995, a ridge about 20 times longer
than it is wide, whose long axis NUTS must cross with steps sized for the
short one; the discrepancy GP's own freedom along the level makes it worse.

The terms checked are the model's own:
- the constant in the discrepancy mean (``mean_intercept``), for every
  discrepancy form: the orthogonal GP (Plumlee 2017) and the scaled GP
  (S-GaSP, Gu & Wang 2018) restrict the GP part of the discrepancy only
  (functions/restricted_gp.stan), and the mean terms h' beta sit beside it,
  so theta trades with the constant in those variants exactly as with the
  plain GP. When theta_j is confounded with it the constant is dropped and
  the other mean terms stay centred: theta_j carries the level.
- the KOH scale rho (``estimate_rho``, the Gaussian programs: y = rho f +
  delta on the standardised scale), whose column is the standardised f,
  (f - y_center) / y_scale, taken with the constant when the mean has one:
  a theta_j that scales f on the identity link is then confounded with rho
  (without the constant, the shift by y_center leaves them apart).
  rho is the user's choice, so stancal does not drop it: it says so, naming
  theta_j and its share (a ConfoundingWarning, and the report's 'Before sampling').

The sensitivity is a central finite difference through the program the fit
runs anyway (its generated quantities' f_new at the physical points, on the
compiled program): no other program is compiled. From simulator runs, it is
that of stage 1's emulator mean (modular, koh_latent_emulator: the GP
emulator's mean given the runs at stage 1's hyperparameters, on the link
scale), the simulator as the fit sees it. Not checked yet: koh_emulator
(its emulator's hyperparameters are sampled with theta, so none exist
before sampling), the scalable and vector emulators, and functional theta.
"""

from __future__ import annotations

import logging
import threading
import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import qmc

from stancal.fitting.plan import Plan
from stancal.fitting.stage_one import emulator_mean_function
from stancal.problem.data import CalibrationData
from stancal.problem.observations import LINKS
from stancal.stan.registry import STAGE_ONE_FIDELITY, STAGE_ONE_GP
from stancal.stan.standata import build_stan_data, to_stan_json

logger = logging.getLogger("stancal")

SHARE_LIMIT = 0.99  # see the module docstring: a posterior correlation of 0.995 with the term
THETA_POINTS = 8  # theta points spread over the prior (a scrambled Sobol design)
STEP = 1e-3  # central differences, in units of theta's prior range
MARGIN = 0.05  # the theta points stay this far (unit scale) inside the box, so both steps stay in it


class ConfoundingWarning(UserWarning):
    """A calibration parameter confounded with a model term stancal may not drop."""


@dataclass(frozen=True)
class Confounding:
    """theta_j confounded with a term of the model, and what was done."""

    theta: str
    term: str  # "constant" (the discrepancy mean's) or "rho" (the KOH scale)
    share: float  # the smallest share over the theta points
    dropped: bool  # the term was dropped from the model (else the user is told)

    def line(self) -> str:
        where = (f"{self.theta}'s effect on the link scale is constant over the physical points "
                 f"(a constant explains {self.share:.3f} of its sum of squares, >= {SHARE_LIMIT})"
                 if self.term == "constant" else
                 f"{self.theta}'s effect follows the simulator's output (rho * f, with the mean's constant "
                 f"if it has one, explains {self.share:.3f} of its sum of squares, >= {SHARE_LIMIT})")
        if self.dropped:
            return f"{where}: the discrepancy mean's constant term was dropped, and {self.theta} carries the level"
        return (f"{where}: {self.theta} and rho are not identified together; fix one of them "
                f"(estimate_rho = false, or a narrow prior on {self.theta})")

    def to_json(self) -> dict:
        return {"theta": self.theta, "term": self.term, "share": round(self.share, 4), "dropped": self.dropped,
                "message": self.line()}


def explained_share(sensitivity: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """The share of each sensitivity's sum of squares that least squares on
    the terms explains: (T, N, Q) sensitivities and (T, N, K) term columns
    (the same columns at every t may be given as (N, K)) -> (T, Q), in
    [0, 1]; NaN where a theta has no effect at all at that theta point."""
    sensitivity = np.asarray(sensitivity, float)
    terms = np.broadcast_to(np.asarray(terms, float), (*sensitivity.shape[:2], np.shape(terms)[-1]))
    out = np.empty((sensitivity.shape[0], sensitivity.shape[2]))
    for t, (s, h) in enumerate(zip(sensitivity, terms, strict=True)):
        u, singular, _ = np.linalg.svd(h, full_matrices=False)
        basis = u[:, singular > 1e-10 * max(singular.max(initial=0.0), 1e-300)]  # the span of the terms
        total = np.sum(s**2, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[t] = np.where(total > 0, np.sum((basis.T @ s) ** 2, axis=0) / total, np.nan)
    return np.clip(out, 0.0, 1.0)


def theta_design(count: int, dimension: int, seed: int = 0) -> np.ndarray:
    """``count`` theta points on the unit box, spread over it (scrambled
    Sobol) and kept MARGIN inside it."""
    unit = qmc.Sobol(dimension, scramble=True, seed=seed).random(count)
    return MARGIN + (1 - 2 * MARGIN) * unit


def link_sensitivity(simulator_at, theta_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """g(f) at each theta point and its central differences per unit of
    theta's range: ``simulator_at`` maps (S, Q) unit theta to g(f) (S, N).
    Returns (T, N) link values and (T, N, Q) sensitivities."""
    T, Q = theta_unit.shape
    steps = np.concatenate([theta_unit + sign * STEP * np.eye(Q)[j] for j in range(Q) for sign in (1, -1)])
    values = simulator_at(np.concatenate([theta_unit, steps]))
    centre, stepped = values[:T], values[T:].reshape(Q, 2, T, -1)
    return centre, np.moveaxis((stepped[:, 0] - stepped[:, 1]) / (2 * STEP), 0, -1)


def program_simulator(plan: Plan, data: CalibrationData, stan_backend):
    """unit theta (S, Q) -> g(f) at the physical points (S, N), through the
    plan's compiled program: its generated quantities' f_new there, with no
    discrepancy and no mean terms (every other parameter at 0.1, inside its
    constraints; f_new does not depend on them)."""
    options = replace(plan.options, discrepancy="none", mean_formula=None, mean_intercept=False,
                      mean_centred=False, estimate_rho=False)
    stan_json = to_stan_json(build_stan_data(data, plan.program.data, options, data.source.reset_index(drop=True)))
    program = plan.main_program()
    shapes = stan_backend.parameter_shapes(program, stan_json)
    run = stan_backend.quantities_function(program, stan_json, seed=1)
    link = LINKS[data.observations.likelihood].transform

    def at(theta_unit: np.ndarray) -> np.ndarray:
        parameters = {name: np.full((1, len(theta_unit), *shape), 0.1) for name, shape in shapes.items()}
        parameters["theta_unit"] = theta_unit[None]
        return link(run(parameters)["f_new"][0])

    return at


def emulator_simulator(plan: Plan, data: CalibrationData, emulator: dict):
    """unit theta (S, Q) -> g(f) at the physical points (S, N) through stage
    1's emulator mean."""
    mean = emulator_mean_function(data, emulator["hyperparameters"], plan.options.kernel_id)
    return lambda theta_unit: mean(data.physical, theta_unit)


def checked_terms(plan: Plan) -> list[str]:
    """The model's own terms that a theta can be confounded with, in this plan."""
    options = plan.options
    return [term for term, present in (("constant", options.mean_intercept),
                                       ("rho", getattr(options, "estimate_rho", False))) if present]


def find_confounding(plan: Plan, data: CalibrationData, stan_backend,
                     emulator: dict | None = None) -> list[Confounding]:
    """Each theta confounded with the constant or rho (never dropped here):
    through the program's simulator, or stage 1's ``emulator``."""
    terms = checked_terms(plan)
    simulator = program_simulator(plan, data, stan_backend) if plan.program.simulator \
        else emulator_simulator(plan, data, emulator)
    theta_unit = theta_design(THETA_POINTS, len(data.theta_names))
    link_f, sensitivity = link_sensitivity(simulator, theta_unit)
    ones = np.ones(link_f.shape[:2] + (1,))
    # rho multiplies the standardised simulator, (f - y_center) / y_scale: the shift matters, the
    # scale does not; beside a constant term, rho's direction is the span of both
    scaled = (link_f - data.scaling.y_center)[..., None]
    columns = {"constant": ones, "rho": np.concatenate([scaled, ones], axis=-1) if "constant" in terms else scaled}
    found = []
    for term in terms:
        share = np.nanmin(explained_share(sensitivity, columns[term]), axis=0, initial=np.inf)
        logger.info("theta against the %s term: shares %s", term,
                    dict(zip(data.theta_names, np.round(share, 4).tolist(), strict=True)))
        found += [Confounding(name, term, float(value), dropped=False)
                  for name, value in zip(data.theta_names, share, strict=True) if np.isfinite(value)
                  and value >= SHARE_LIMIT]
    return found


def checkable(plan: Plan, data, emulator: dict | None) -> bool:
    """Whether this module can check the plan: a scalar output and scalar
    theta, with a Stan simulator or stage 1's GP emulator."""
    return (isinstance(data, CalibrationData) and not getattr(plan.options, "functional", ())
            and (plan.program.simulator or (stage_one_emulator(plan) and bool(emulator))))


def stage_one_emulator(plan: Plan) -> bool:
    """The plan's simulator is stage 1's GP emulator (modular, koh_latent_emulator),
    of one fidelity or several."""
    return not plan.program.simulator and plan.stage_one in (STAGE_ONE_GP, STAGE_ONE_FIDELITY)


def resolve_confounding(plan: Plan, data: CalibrationData, stan_backend,
                        emulator: dict | None = None) -> tuple[Plan, list[Confounding]]:
    """The plan with the discrepancy mean's constant dropped when a theta is
    confounded with it (the other mean terms stay centred), and every
    finding; a theta confounded with rho is said as a ConfoundingWarning.
    ``emulator``: stage 1's results, for a plan from simulator runs. The
    plan comes back marked as checked, so that its fits do not check again.
    Plans with nothing to check, or that this module cannot check yet
    (checkable), come back unchanged but for the mark."""
    checked = replace(plan, confounding_checked=True)
    if plan.confounding_checked or not checked_terms(plan) or not checkable(plan, data, emulator):
        return checked, []
    if plan.program.simulator and threading.current_thread() is not threading.main_thread():
        # a Dask worker's thread: loading a program there before sampling crashed workers
        # (stancal.stan.backends.pystan_backend.start_error); the command that planned the fit checks
        logger.info("confounding of theta not checked in a worker thread")
        return checked, []
    found = find_confounding(plan, data, stan_backend, emulator)
    if any(c.term == "constant" for c in found):
        checked = replace(checked, options=replace(plan.options, mean_intercept=False, mean_centred=True))
        found = [replace(c, dropped=True) if c.term == "constant" else c for c in found]
    for c in found:
        if c.dropped:
            logger.info("%s", c.line())
        else:
            warnings.warn(c.line(), ConfoundingWarning, stacklevel=3)
    return checked, found
