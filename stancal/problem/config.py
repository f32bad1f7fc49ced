"""Read a calibration problem from a TOML config (paths relative to it)."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import pandas as pd

from stancal.problem.candidates import Candidate, CandidateError
from stancal.problem.data import CalibrationData
from stancal.problem.options import ModelOptions, VectorOptions
from stancal.problem.vector_data import VectorCalibrationData


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the key."""


@dataclass
class Problem:
    data: CalibrationData | VectorCalibrationData
    simulator: Path | None
    model: dict[str, Any] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)  # for `stancal gap`
    units: dict[str, str] = field(default_factory=dict)  # [units]: name -> unit, for the figures' axes


_OBSERVATION_KEYS = {"likelihood", "trials", "lower", "upper"}  # go to CalibrationData
# [model]: the method, the user's copy of its program, and the options of the model (problem.options)
_MODEL_KEYS = {"method", "program", *(f.name for f in fields(ModelOptions)), *_OBSERVATION_KEYS}
_VARIANT_KEYS = {"stan", "inputs", "theta"}
# the vector programs' discrepancy is an exact GP: no basis to set
_VECTOR_MODEL_KEYS = {"method", "program", "variance_share", "components",
                      *(f.name for f in fields(VectorOptions) if f.name != "basis_functions")}


def _candidates(table: dict[str, Any], base: Path) -> list[Candidate]:
    """[candidates]: name = "formula", or a [candidates.NAME] table for a
    simulator variant (stan, inputs, theta) or a formula (formula)."""
    out = []
    for name, spec in table.items():
        where = f"[candidates.{name}]"
        if isinstance(spec, str):
            spec = {"formula": spec}
        if not isinstance(spec, dict):
            raise ConfigError(f"candidate '{name}': give a formula string or a table; got {spec!r}")
        allowed = {"formula"} if "formula" in spec else _VARIANT_KEYS
        unknown = set(spec) - allowed
        if unknown:
            raise ConfigError(f"candidate '{name}': unknown key(s) {sorted(unknown)} in {where}; "
                              f"known: {sorted(allowed)}")
        try:
            if "formula" in spec:
                out.append(Candidate(name, formula=str(spec["formula"])))
                continue
            stan = base / _require(spec, "stan", f"candidates.{name}")
            if not stan.is_file():
                raise ConfigError(f"candidate '{name}': Stan file not found: {stan}")
            theta = {k: tuple(v) for k, v in spec.get("theta", {}).items()}
            out.append(Candidate(name, stan=stan, inputs=tuple(_require(spec, "inputs", f"candidates.{name}")),
                                 theta=theta))
        except CandidateError as err:
            raise ConfigError(str(err)) from None
    return out


def _read_csv(path: Path, key: str) -> pd.DataFrame:
    if not path.is_file():
        raise ConfigError(f"{key}: file not found: {path}")
    try:
        return pd.read_csv(path)
    except Exception as err:  # pandas raises many parser errors
        raise ConfigError(f"{key}: cannot read {path} as CSV: {err}") from None


def _require(table: dict, key: str, where: str) -> Any:
    if key not in table:
        raise ConfigError(f"config: [{where}] needs '{key}'")
    return table[key]


def load_config(path: str | Path) -> Problem:
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"config {path}: not valid TOML: {err}") from None
    base = path.parent
    physical = raw.get("physical")
    if physical is None:
        raise ConfigError("config: missing the [physical] section")
    simulator = raw.get("simulator")
    if simulator is None:
        raise ConfigError("config: missing the [simulator] section")
    theta = _require(simulator, "theta", "simulator")
    stan = base / simulator["stan"] if "stan" in simulator else None
    if stan is not None and not stan.is_file():
        raise ConfigError(f"simulator.stan: file not found: {stan}")
    runs = _read_csv(base / simulator["runs"], "simulator.runs") if "runs" in simulator else None
    if stan is None and runs is None:
        raise ConfigError("config: [simulator] needs 'stan' (a Stan simulator), 'runs' (a CSV of runs), or both")
    model = dict(raw.get("model", {}))
    if "output_index" in physical:
        return _with_units(_vector_problem(physical, simulator, theta, runs, stan, model, raw, base), raw)
    unknown = set(model) - _MODEL_KEYS
    if unknown:
        raise ConfigError(f"config: unknown key(s) {sorted(unknown)} in [model]; known: {sorted(_MODEL_KEYS)}")
    if "program" in model:
        model["program"] = base / model["program"]
    for key in ("functional", "functional_inputs"):
        if isinstance(model.get(key), str):
            model[key] = [model[key]]
        if key in model and not (isinstance(model[key], list) and all(isinstance(v, str) for v in model[key])):
            raise ConfigError(f"config: [model] {key} must be a list of names; got {model[key]!r}")
    observation = {key: model.pop(key) for key in _OBSERVATION_KEYS if key in model}
    data = CalibrationData(
        _read_csv(base / _require(physical, "csv", "physical"), "physical.csv"),
        inputs=_require(physical, "inputs", "physical"),
        output=_require(physical, "output", "physical"),
        theta={k: tuple(v) if isinstance(v, list) else v for k, v in theta.items()},
        covariates=physical.get("covariates", []),
        runs=runs,
        **observation,
    )
    candidates = _candidates(raw.get("candidates", {}), base)
    return _with_units(Problem(data=data, simulator=stan, model=model, candidates=candidates), raw)


def _with_units(problem: Problem, raw: dict[str, Any]) -> Problem:
    """[units]: name = "unit" for the inputs, covariates, output (and output
    index) and theta, shown on the figures' axes. Optional; every name must
    be one of the problem's."""
    table = raw.get("units", {})
    if not isinstance(table, dict):
        raise ConfigError('config: [units] must be a table of name = "unit" lines, such as T = "°C"')
    data = problem.data
    names = {*data.inputs, *data.covariates, data.output, *data.theta_names,
             *([*data.output_index, *(p.name for p in data.per_experiment)]
               if isinstance(data, VectorCalibrationData) else [])}
    for name, unit in table.items():
        if name not in names:
            raise ConfigError(f"config: [units] names '{name}', which is not an input, covariate, output or "
                              f"theta of this problem; known: {sorted(names)}")
        if not isinstance(unit, str):
            raise ConfigError(f'config: [units] {name} must be a string such as "°C"; got {unit!r}')
    problem.units = dict(table)
    return problem


def _vector_problem(physical: dict, simulator: dict, theta: dict, runs: pd.DataFrame | None, stan: Path | None,
                    model: dict, raw: dict, base: Path) -> Problem:
    """A vector output ([physical] output_index): long tables, one row per value."""
    unknown = set(model) - _VECTOR_MODEL_KEYS
    if unknown:
        raise ConfigError(f"config: unknown key(s) {sorted(unknown)} in [model] for a vector output; "
                          f"known: {sorted(_VECTOR_MODEL_KEYS)}")
    if "program" in model:
        model["program"] = base / model["program"]
    basis = {k: model.pop(k) for k in ("variance_share", "components") if k in model}
    data = VectorCalibrationData(
        _read_csv(base / _require(physical, "csv", "physical"), "physical.csv"),
        experiment=_require(physical, "experiment", "physical"),
        inputs=_require(physical, "inputs", "physical"),
        output=_require(physical, "output", "physical"),
        output_index=physical["output_index"],
        theta=theta, theta_per_experiment=simulator.get("theta_per_experiment", {}),
        runs=runs, run=_require(simulator, "run", "simulator") if runs is not None else None,
        noise_sd=physical.get("noise_sd"), covariates=physical.get("covariates", []), **basis)
    return Problem(data=data, simulator=stan, model=model, candidates=_candidates(raw.get("candidates", {}), base))
