"""L2 calibration (Tuo & Wu 2015; review eqs. 9-10), made Bayesian in the
spirit of Xie & Xu (2021): every posterior draw of the real process zeta is
projected onto the simulator,

    theta_d = argmin_theta  || zeta_d - f(., theta) ||^2_L2(input box),

so theta's distribution is that of the projection, with a well-defined target
whatever the discrepancy prior. The loss is often multimodal: each draw starts
from a global design over the theta box and is refined by Gauss-Newton."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import qmc

from stancal.fitting.stage_one import emulator_mean_function
from stancal.numerics.quadrature import Quadrature
from stancal.problem.options import ModelOptions
from stancal.stan.backends import get_backend
from stancal.stan.standata import build_stan_data, to_stan_json

# (points with the simulator inputs, theta (S, Q) in original units) -> f, (S, points)
SimulatorAt = Callable[[pd.DataFrame, np.ndarray], np.ndarray]

GRID_PER_THETA_1D = 401  # one theta: every 1/400 of its range
GLOBAL_DESIGN_PER_THETA = 256  # more: a Sobol design of 256 per theta (power of two)
STARTS = 2  # refine from this many basins of each draw's loss, keep the best result
GAUSS_NEWTON_STEPS = 30


@dataclass(frozen=True)
class Projection:
    """theta (S, Q) per draw, its loss (mean square of zeta - f over the box),
    and the loss of the best other local minimum found (inf if none)."""

    theta: np.ndarray
    loss: np.ndarray
    runner_up_loss: np.ndarray


def stan_simulator(result) -> SimulatorAt:
    """f through the fit's own koh program, without a discrepancy: the
    generated quantities' f_new for a batch of theta values."""
    data, backend = result.data, get_backend(result.backend)
    options = ModelOptions(discrepancy="none", kernel=result.options.kernel)
    last: dict = {}  # the program bound to the last points' data: projection reuses one set
    # every parameter of the (possibly edited) program at its posterior median;
    # f does not depend on them, but generated quantities need them all
    stored = result.idata["stan_parameters"]
    fixed = {name: _posterior_median(da) for name, da in stored.data_vars.items()}
    # without a discrepancy, mean terms or rho these are empty
    fixed.update({k: np.zeros(0) for k in ("delta_sd", "delta_input_length_scale", "delta_relevance",
                                           "rho_free", "beta") if k in fixed})

    def at(points: pd.DataFrame, theta: np.ndarray) -> np.ndarray:
        if last.get("points") is not points:
            stan_data = to_stan_json(build_stan_data(data, result.row.data, options, points))
            last.update(points=points, run=backend.quantities_function(result.program, stan_data, seed=1))
        unit = np.clip(_theta_unit(data, theta), 1e-12, 1 - 1e-12)
        parameters = {name: np.broadcast_to(value, (1, len(unit), *np.shape(value)))
                      for name, value in fixed.items()}
        parameters["theta_unit"] = unit[None]
        return last["run"](parameters)["f_new"][0]

    return at


def emulator_mean(result) -> SimulatorAt:
    """f through the emulator's mean given the runs (hyperparameters at their
    posterior medians; for modular, stage 1's), in original units."""
    data = result.data
    if result.emulator.get("hyperparameters"):
        hyper = result.emulator["hyperparameters"]
    else:
        posterior = result.idata["posterior"]
        hyper = {k: _posterior_median(posterior[k])
                 for k in ("emulator_mean", "emulator_sd", "emulator_length_scale", "emulator_nugget")}
    # l2 is for Gaussian outputs, whose link scale is the output's
    mean = emulator_mean_function(data, hyper, result.options.kernel_id)
    return lambda points, theta: mean(points, _theta_unit(data, theta))


def _posterior_median(draws) -> np.ndarray:
    """Median over chains and draws of a (chain, draw, ...) array, zero-size ones included."""
    values = np.asarray(draws)
    return np.median(values.reshape(values.shape[0] * values.shape[1], *values.shape[2:]), axis=0)


def _theta_unit(data, theta: np.ndarray) -> np.ndarray:
    return (np.atleast_2d(theta) - data.theta_lower) / (data.theta_upper - data.theta_lower)


def simulator_of(result) -> SimulatorAt:
    # a program with a Stan simulator runs it; one from runs has its emulator's mean
    return stan_simulator(result) if result.row.simulator else emulator_mean(result)


def global_design(lower: np.ndarray, upper: np.ndarray, seed: int = 0) -> np.ndarray:
    """Points over the theta box where every draw's loss is evaluated first."""
    if len(lower) == 1:
        return np.linspace(lower, upper, GRID_PER_THETA_1D)
    m = int(np.ceil(np.log2(GLOBAL_DESIGN_PER_THETA * len(lower))))
    return lower + qmc.Sobol(len(lower), scramble=True, seed=seed).random_base2(m) * (upper - lower)


def project(zeta: np.ndarray, quadrature: Quadrature, simulator: SimulatorAt,
            lower: np.ndarray, upper: np.ndarray, *, starts: int = STARTS) -> Projection:
    """theta_d = argmin sum_r w_r (zeta_dr - f(u_r, theta))^2 for each row d of
    ``zeta`` (S, nodes): the loss at a global design first, then Gauss-Newton
    from the best design point and from the best ones at least 10 % of the box
    away from those already chosen (other basins), inside the box."""
    nodes, w = quadrature.nodes, quadrature.weights
    design = global_design(lower, upper)
    f_design = simulator(nodes, design)  # (T, R): the design does not depend on the draw
    # loss_dt = sum_r w_r (zeta_dr - f_tr)^2, expanded so that no (S, T, R) array is formed
    losses = ((zeta**2) @ w)[:, None] - 2 * (zeta * w) @ f_design.T + ((f_design**2) @ w)[None, :]
    unit_design = (design - lower) / (upper - lower)
    thetas, loss = [], []
    for start in _starts(losses, unit_design, starts):
        theta_k, loss_k = _gauss_newton(zeta, w, nodes, simulator, design[start], lower, upper)
        thetas.append(theta_k)
        loss.append(loss_k)
    thetas, loss = np.stack(thetas, 1), np.stack(loss, 1)  # (S, starts, Q), (S, starts)
    chosen = np.argmin(loss, axis=1)
    rows = np.arange(len(zeta))
    best = thetas[rows, chosen]
    # another minimum: more than 1e-3 of the box away from the best
    elsewhere = np.any(np.abs(thetas - best[:, None]) > 1e-3 * (upper - lower), axis=-1)
    runner_up = np.where(elsewhere, loss, np.inf).min(axis=1)
    return Projection(best, loss[rows, chosen], runner_up)


def _starts(losses: np.ndarray, unit_design: np.ndarray, count: int) -> list[np.ndarray]:
    """Per draw, design indices: the best point, then the best point at least
    0.1 (unit box) from every earlier start."""
    chosen = [np.argmin(losses, axis=1)]
    blocked = np.zeros_like(losses, dtype=bool)
    for _ in range(count - 1):
        last = unit_design[chosen[-1]]  # (S, Q)
        blocked |= np.linalg.norm(unit_design[None] - last[:, None], axis=-1) < 0.1
        chosen.append(np.argmin(np.where(blocked, np.inf, losses), axis=1))
    return chosen


def _gauss_newton(zeta, w, nodes, simulator, theta, lower, upper):
    """Box-constrained Gauss-Newton with step halving for all draws at once,
    evaluating only the draws that have not converged; derivatives by forward
    differences of the simulator."""
    S, Q = theta.shape
    step_size = 1e-6 * (upper - lower)
    f = simulator(nodes, theta)
    loss = ((zeta - f) ** 2) @ w
    active = np.arange(S)
    for _ in range(GAUSS_NEWTON_STEPS):
        th, fa, za = theta[active], f[active], zeta[active]
        h = np.where(th + step_size <= upper, step_size, -step_size)  # (A, Q), into the box
        stepped = np.concatenate([th + h[:, [j]] * np.eye(Q)[j] for j in range(Q)])
        J = (simulator(nodes, stepped).reshape(Q, len(active), -1) - fa[None]) / h.T[..., None]
        JtWJ = np.einsum("qsr,r,psr->sqp", J, w, J) + 1e-12 * np.eye(Q)
        JtWr = np.einsum("qsr,r,sr->sq", J, w, za - fa)
        step = np.linalg.solve(JtWJ, JtWr[..., None])[..., 0]
        moved = np.zeros(len(active), bool)
        pending = np.arange(len(active))
        for _ in range(10):  # halve each draw's step until its loss decreases
            trial = np.clip(th[pending] + step[pending], lower, upper)
            f_trial = simulator(nodes, trial)
            trial_loss = ((za[pending] - f_trial) ** 2) @ w
            better = trial_loss < loss[active[pending]]
            rows = active[pending[better]]
            theta[rows], f[rows], loss[rows] = trial[better], f_trial[better], trial_loss[better]
            moved[pending[better]] = True
            step[pending] /= 2
            pending = pending[~better]
            if len(pending) == 0:
                break
        small = np.all(np.abs(step) < 1e-7 * (upper - lower), axis=1)
        active = active[moved & ~small]
        if len(active) == 0:
            break
    return theta, loss


def l2_result(result, quadrature: Quadrature, n_points: int):
    """The L2 calibration from a fit whose last prediction points are the
    quadrature nodes: theta becomes each draw's projection (KOH's theta is kept
    as theta_koh), and f and delta at the first ``n_points`` prediction points
    are those of the projected theta."""
    import xarray as xr

    data = result.data
    lower, upper = data.theta_lower, data.theta_upper
    predictions = result.idata["predictions"].to_dataset()
    chains, draws = predictions.sizes["chain"], predictions.sizes["draw"]
    r = len(quadrature.weights)
    zeta_nodes = np.asarray(predictions["zeta_new"])[..., -r:].reshape(chains * draws, r)
    simulator = simulator_of(result)
    projection = project(zeta_nodes, quadrature, simulator, lower, upper)

    tree = result.idata.copy()
    posterior = tree["posterior"].to_dataset()
    theta = posterior["theta"].copy(data=projection.theta.reshape(chains, draws, -1))
    posterior = posterior.assign(
        theta=theta, theta_koh=posterior["theta"],
        l2_discrepancy_rms=(("chain", "draw"), np.sqrt(projection.loss).reshape(chains, draws)))
    tree["posterior"] = xr.DataTree(posterior)
    kept = _first_points(predictions, n_points)
    points = _first_points(tree["predictions_constant_data"].to_dataset(), n_points)
    tree["predictions_constant_data"] = xr.DataTree(points)
    tree["predictions"] = xr.DataTree(_with_projected_simulator(
        kept, points.to_dataframe().reset_index(drop=True), projection.theta, simulator))
    return dataclasses.replace(result, idata=tree, l2={
        "base_method": result.method,
        "quadrature_nodes": len(quadrature.weights),
        # draws whose loss has another minimum within 10 %: the projection is nearly a tie there
        "draws_with_near_tie": float(np.mean(projection.runner_up_loss < 1.1 * projection.loss)),
        "discrepancy_rms_median": float(np.median(np.sqrt(projection.loss))),
    })


def _first_points(dataset, n_points: int):
    """The first n prediction points of every variable (dimension names vary by group)."""
    return dataset.isel({d: slice(0, n_points) for d in dataset.dims if d not in ("chain", "draw")})


def _with_projected_simulator(predictions, points: pd.DataFrame, theta: np.ndarray,
                              simulator: SimulatorAt):
    """f_new at the projected theta and delta_new = zeta_new - f_new."""
    chains, draws = predictions.sizes["chain"], predictions.sizes["draw"]
    f = simulator(points, theta).reshape(chains, draws, -1)
    zeta = np.asarray(predictions["zeta_new"])
    return predictions.assign(f_new=predictions["f_new"].copy(data=f),
                              delta_new=predictions["delta_new"].copy(data=zeta - f))


def reproject(result, points: pd.DataFrame, draws: dict[str, np.ndarray], step: int = 1) -> dict[str, np.ndarray]:
    """predict() of an L2 result: the simulator at each draw's projected theta
    (every ``step``-th draw of each chain, as predict thinned them)."""
    theta = np.asarray(result.idata["posterior"]["theta"])[:, ::step]
    f = simulator_of(result)(points, theta.reshape(-1, theta.shape[-1]))
    f = f.reshape(*draws["zeta_new"].shape)
    return {**draws, "f_new": f, "delta_new": draws["zeta_new"] - f}
