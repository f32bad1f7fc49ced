"""The design loop as the user drives it: a wave of history matching, the
next runs (and experiments) it proposes, and, with a simulator in Python,
waves one after another (``run_waves``)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from stancal.designing.emulators import calibration_emulator
from stancal.designing.experiments import DISCREPANCY_LENGTH, index_range, next_experiments
from stancal.designing.proposals import nroy_runs, posterior_runs
from stancal.designing.targets import DesignSettings, run_table
from stancal.designing.waves import HistoryMatch, Wave, fit_emulator, history_match
from stancal.problem.data import CalibrationData
from stancal.problem.vector_data import VectorCalibrationData
from stancal.stan.registry import DESIGN, commands_taking

logger = logging.getLogger("stancal")

CRITERIA = ("nroy", "posterior")
POSTERIOR_SAMPLER = {"chains": 2, "warmup": 500, "draws": 500}  # theta's posterior for the posterior criterion


@dataclass
class Design:
    """One call of the loop: the history match and what it proposes."""

    match: HistoryMatch
    next_runs: pd.DataFrame  # the inputs, then theta, config order, original units
    criterion: str
    next_experiments: pd.DataFrame | None = None
    notes: dict = field(default_factory=dict)  # the criterion's numbers, the posterior's program
    posterior_fit: object | None = None  # the fit of theta's posterior (criterion posterior, when made here)

    def to_json(self) -> dict:
        return {**self.match.to_json(), "criterion": self.criterion, "proposed_runs": len(self.next_runs),
                "proposed_experiments": 0 if self.next_experiments is None else len(self.next_experiments),
                **self.notes}


def posterior_theta(match: HistoryMatch, seed: int, simulator=None, **sampler):
    """theta's posterior draws (unit cube) from a fit of the registry's
    program for the design command (modular: the stage-1 emulator fixed),
    and the fit."""
    data = match.data
    vector = isinstance(data, VectorCalibrationData)
    method = commands_taking(DESIGN, "vector" if vector else "scalar")[0]
    options = {**POSTERIOR_SAMPLER, **sampler, "seed": seed}
    if vector:
        from stancal.fitting.vector_calibrate import calibrate_vector

        result = calibrate_vector(data, simulator=simulator, method=method, **options)
    else:
        from stancal.fitting.calibrate import calibrate

        result = calibrate(data, simulator=simulator, method=method, **options)
    return match.box.theta_to_unit(nroy_draws(result.idata["posterior"], match.box)), result


def nroy_draws(posterior, box) -> np.ndarray:
    """A fit's theta draws (draws, NROY's theta) in original units, in
    NROY's order (UnitBox.nroy_names): the shared theta, then each
    experiment's own (``theta_experiment``, experiment by experiment)."""
    shared = np.asarray(posterior["theta"]).reshape(-1, box.shared)
    if not box.per_experiment:
        return shared
    # the fit's experiments are the data's, in the data's order, as NROY's are
    own = posterior["theta_experiment"].transpose("chain", "draw", "experiment", "experiment_theta_name")
    own = own.sel(experiment_theta_name=box.per_experiment)
    return np.hstack([shared, np.asarray(own).reshape(len(shared), -1)])


def propose_runs(match: HistoryMatch, runs: int, *, criterion: str = "nroy", seed: int = 1,
                 posterior: pd.DataFrame | None = None, **sampler) -> Design:
    """The next ``runs`` simulator runs after ``match``: space-filling in
    NROY x the inputs' range (``nroy``), or where the emulator's variance
    weighted by theta's posterior falls most (``posterior``; theta's draws
    ``posterior`` (original units), else from a modular fit with ``sampler``'s
    options). See stancal.designing.proposals.

    The posterior criterion's variance is that of the emulator the
    calibration uses, the one theta's posterior came from: the fit's stage 1
    (every run; calibration_emulator) when the fit is made here, else one
    fitted to every run as stage 1 fits it; not the wave's own, which is
    refocused on NROY's runs."""
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {', '.join(CRITERIA)}; got {criterion!r}")
    if runs < 1:
        raise ValueError(f"--runs must be at least 1; got {runs}")
    box, inputs = match.box, len(match.box.inputs)
    existing, outputs = run_table(match.data, box)
    notes: dict = {}
    fit = None
    if criterion == "nroy":
        theta = box.run_theta(match.nroy.theta_unit, np.random.default_rng(seed))
        unit, distances = nroy_runs(theta, existing, inputs, runs, seed)
        notes["maximin_distance"] = float(distances.min())
    else:
        emulator = None
        if posterior is None:
            draws, fit = posterior_theta(match, seed, **sampler)
            notes["posterior_method"] = fit.method
            notes["posterior_diagnostics"] = fit.diagnostics.summary() if fit.diagnostics else None
            emulator = calibration_emulator(match.data, box, fit.emulator)
        else:
            draws = box.theta_to_unit(posterior[box.nroy_names].to_numpy(float))
        if emulator is not None:
            notes["posterior_emulator"] = "the posterior fit's stage 1"
        else:
            emulator = fit_emulator(match.data, existing, outputs, seed)
            notes["posterior_emulator"] = "fitted to every run, as stage 1"
        targets = match.targets
        # theta per experiment: each experiment's inputs with its own theta columns (else none: a vector output's
        # groups without their own theta weigh like any other points)
        experiments = [(row, columns) for (row, _, _), columns in zip(targets.groups, targets.group_theta, strict=True)
                       ] if targets.group_theta else []
        unit, gains = posterior_runs(emulator.parts(targets.groups), draws, targets.x_unit, runs, seed, experiments)
        notes["variance_reduction"] = gains
    frame = pd.DataFrame(box.to_original(unit), columns=box.columns)
    return Design(match, frame, criterion, notes=notes, posterior_fit=fit)


def discrepancy_length(match: HistoryMatch, fit=None) -> tuple[np.ndarray | float, str]:
    """The discrepancy's length scales for the experiments criterion, on its
    positions' unit cube (the inputs', then a vector output's index), and
    where they came from: the posterior median of ``fit``'s (a calibration
    of this problem) when it has a discrepancy, else DISCREPANCY_LENGTH."""
    posterior = None if fit is None else fit.idata["posterior"]
    if posterior is None or "delta_length_scale" not in posterior:
        return DISCREPANCY_LENGTH, f"{DISCREPANCY_LENGTH:g} of each range (no fit with a discrepancy)"
    draws = posterior["delta_length_scale"]  # original units, one per discrepancy input
    median = draws.median(dim=("chain", "draw"))
    names = [*match.box.inputs, *getattr(match.data, "output_index", [])]
    widths = np.concatenate([match.box.width[:len(match.box.inputs)], index_range(match.targets)[1]])
    return median.sel(delta_input=names).to_numpy() / widths, "the posterior median of the fit's"


def propose_experiments(match: HistoryMatch, count: int, seed: int = 1, fit=None) -> pd.DataFrame:
    """``count`` physical input settings to measure next (next_experiments.csv;
    stancal.designing.experiments); the discrepancy's length scales from
    ``fit`` (a calibration of the problem) when given (discrepancy_length)."""
    if count < 1:
        raise ValueError(f"--experiments must be at least 1; got {count}")
    length, source = discrepancy_length(match, fit)
    unit, criterion = next_experiments(match.cuts[-1], match.nroy.theta_unit, count, seed, length,
                                       box=match.box)
    frame = pd.DataFrame(match.box.inputs_to_original(unit), columns=match.box.inputs)
    frame.attrs["theta_variance_trace"] = criterion
    frame.attrs["discrepancy_length"] = np.atleast_1d(length).tolist()  # the positions' unit cube
    frame.attrs["discrepancy_length_source"] = source
    return frame


def design(data, runs: int, *, criterion: str = "nroy", experiments: int = 0, settings: DesignSettings | None = None,
           waves: list[Wave] | None = None, seed: int = 1, **sampler) -> Design:
    """A wave of history matching and its proposals: what `stancal design` writes."""
    match = history_match(data, waves=waves, settings=settings, seed=seed)
    return design_of(match, runs, criterion=criterion, experiments=experiments, seed=seed, **sampler)


def design_of(match: HistoryMatch, runs: int, *, criterion: str = "nroy", experiments: int = 0, seed: int = 1,
              **sampler) -> Design:
    """A history match's proposals: its next runs and, with ``experiments``, its next experiments."""
    result = propose_runs(match, runs, criterion=criterion, seed=seed, **sampler)
    if experiments:
        result.next_experiments = propose_experiments(match, experiments, seed, result.posterior_fit)
        for key in ("theta_variance_trace", "discrepancy_length", "discrepancy_length_source"):
            result.notes[key] = result.next_experiments.attrs[key]
    return result


@dataclass
class WaveLoop:
    """run_waves' result: the data with every run, and each wave's design."""

    data: CalibrationData | VectorCalibrationData
    designs: list[Design]

    @property
    def fractions(self) -> list[float]:
        return [d.match.nroy_fraction for d in self.designs]


def run_waves(config, *, simulator: Callable[[pd.DataFrame], object], waves: int, runs_per_wave: int,
              criterion: str = "nroy", settings: DesignSettings | None = None, seed: int = 1,
              stop_shrink: float | None = None) -> WaveLoop:
    """``waves`` waves of history matching, each running ``simulator`` at the
    runs it proposes and adding them to the data. ``config``: a config file,
    a loaded config (stancal.problem.config.Problem) or the data. The
    simulator takes a DataFrame with next_runs.csv's columns and returns the
    outputs: one value per row for a scalar output; for a vector output, a
    (rows, K) array on the runs' grid of output indices (data.basis.grid).
    ``stop_shrink``: stop once a wave's NROY fraction is above this share of
    the previous one (NROY stopped shrinking)."""
    data, settings = _data_and_settings(config, settings)
    designs: list[Design] = []
    for number in range(waves):
        proposed = design(data, runs_per_wave, criterion=criterion, settings=settings,
                          waves=designs[-1].match.waves if designs else None, seed=seed + number)
        designs.append(proposed)
        data = with_runs(data, proposed.next_runs, simulator(proposed.next_runs.copy()), f"w{number + 1}_")
        if stop_shrink is not None and len(designs) > 1 and \
                designs[-1].match.nroy_fraction > stop_shrink * designs[-2].match.nroy_fraction:
            break
    return WaveLoop(data, designs)


def _data_and_settings(config, settings: DesignSettings | None):
    if isinstance(config, CalibrationData | VectorCalibrationData):
        return config, settings or DesignSettings()
    if isinstance(config, str | Path):
        from stancal.problem.config import load_config

        config = load_config(config)
    return config.data, settings or DesignSettings(**config.design)


def with_runs(data, settings: pd.DataFrame, outputs, prefix: str):
    """``data`` with new runs at ``settings`` (inputs and theta) and their ``outputs``."""
    if isinstance(data, VectorCalibrationData):
        return _with_vector_runs(data, settings, np.asarray(outputs, float), prefix)
    values = np.asarray(outputs, float).reshape(-1)
    if len(values) != len(settings):
        raise ValueError(f"the simulator returned {len(values)} outputs for {len(settings)} runs")
    added = settings.assign(**{data.output: values})
    return data.with_runs(pd.concat([data.runs, added], ignore_index=True))


def _with_vector_runs(data: VectorCalibrationData, settings: pd.DataFrame, outputs: np.ndarray, prefix: str):
    grid = data.basis.grid
    if outputs.shape != (len(settings), len(grid)):
        raise ValueError(f"the simulator returned outputs of shape {outputs.shape}; a vector output needs "
                         f"({len(settings)} runs, {len(grid)} output indices of the runs' grid)")
    rows = []
    for i, (_, setting) in enumerate(settings.iterrows()):
        block = pd.DataFrame(grid, columns=data.output_index).assign(**setting.to_dict())
        rows.append(block.assign(**{data.run: f"{prefix}{i + 1}", data.output: outputs[i]}))
    return data.with_runs(pd.concat([data.runs, *rows], ignore_index=True))
