"""Read a calibration problem from a TOML config (paths relative to it)."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from stancal.problem import config_schema
from stancal.problem.candidates import Candidate, CandidateError, check_candidate_data
from stancal.problem.codes import NOISE_MODES
from stancal.problem.data import CalibrationData
from stancal.problem.noise import NOISES, check_noise, check_noise_inputs, check_noise_name
from stancal.problem.source_bias import check_biased_sources
from stancal.problem.validation import DataError, read_table
from stancal.problem.vector_data import VectorCalibrationData


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the key."""


@dataclass
class Problem:
    data: CalibrationData | VectorCalibrationData
    simulator: Path | None
    model: dict[str, Any] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)  # for `stancal gap`
    units: dict[str, str] = field(default_factory=dict)  # [units]: column or parameter -> unit, for figures
    design: dict[str, Any] = field(default_factory=dict)  # [design]: for `stancal design`


_OBSERVATION_KEYS = {"likelihood", "trials", "lower", "upper"}  # go to CalibrationData


def _candidates(table: dict[str, Any], base: Path, data) -> list[Candidate]:
    """[candidates]: name = "formula", or a [candidates.NAME] table for a
    simulator variant (stan, inputs, theta) or a formula (formula); each
    checked against the physical ``data`` (check_candidate_data)."""
    out = []
    for name, spec in table.items():  # the schema checked their keys and types
        if isinstance(spec, str):
            spec = {"formula": spec}
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
    try:
        check_candidate_data(data, out)
    except CandidateError as err:
        raise ConfigError(str(err)) from None
    return out


def _read_csv(path: Path, key: str) -> pd.DataFrame:
    if not path.is_file():
        raise ConfigError(f"{key}: file not found: {path}")
    return read_table(path)  # its errors name the file and line


def _require(table: dict, key: str, where: str) -> Any:
    if key not in table:
        raise ConfigError(f"config: [{where}] needs '{key}'")
    return table[key]


def load_config(path: str | Path) -> Problem:
    """The problem a config states, checked against the schema first; every
    error names the config file (and a data error the CSV and its lines)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, IsADirectoryError):
        raise ConfigError(f"config file not found: {path}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    problem = config_schema.check(raw)
    if problem:
        raise ConfigError(f"{path}: {problem}")
    tables = ((raw["physical"], "csv"), (raw["simulator"], "runs"))
    # a data error that names one of the config's CSVs (its lines) needs no config name; a missing file does
    csvs = [str(path.parent / table[key]) for table, key in tables
            if isinstance(table.get(key), str) and (path.parent / table[key]).is_file()]
    try:
        problem = _problem(raw, path.parent)
    except (ConfigError, DataError) as err:  # name the config, unless the message names a CSV of it
        message = str(err).removeprefix("config: ")
        raise type(err)(message if any(csv in message for csv in csvs) else f"{path}: {message}") from None
    units = config_schema.check_units(raw)
    if units:
        raise ConfigError(f"{path}: {units}")
    return problem


def _problem(raw: dict[str, Any], base: Path) -> Problem:
    physical, simulator = raw["physical"], raw["simulator"]  # the schema's check found both, and theta
    theta = simulator["theta"]
    stan = base / simulator["stan"] if "stan" in simulator else None
    if stan is not None and not stan.is_file():
        raise ConfigError(f"[simulator] stan: file not found: {stan}")
    runs = _read_csv(base / simulator["runs"], "[simulator] runs") if "runs" in simulator else None
    if stan is None and runs is None:
        raise ConfigError("config: [simulator] needs 'stan' (a Stan simulator), 'runs' (a CSV of runs), or both")
    model = dict(raw.get("model", {}))
    if simulator.get("stochastic"):  # a property of the simulator, carried as a model option (ModelOptions)
        model["stochastic"] = True
    if "output_index" in physical:
        return _vector_problem(physical, simulator, theta, runs, stan, model, raw, base)
    _resolve_program(model, base)
    for key in ("functional", "functional_inputs", "noise_inputs", "biased_sources"):  # one name or a list
        if isinstance(model.get(key), str):
            model[key] = [model[key]]
    observation = {key: model.pop(key) for key in _OBSERVATION_KEYS if key in model}
    data = CalibrationData(
        _read_csv(base / _require(physical, "csv", "physical"), "[physical] csv"),
        inputs=_require(physical, "inputs", "physical"),
        output=_require(physical, "output", "physical"),
        theta={k: tuple(v) if isinstance(v, list) else v for k, v in theta.items()},
        covariates=physical.get("covariates", []),
        runs=runs,
        noise_sd=physical.get("noise_sd"),
        source=physical.get("source"),
        **observation,
        low_fidelity_runs=_low_fidelity_runs(simulator, base),
        theta_low={k: tuple(v) for k, v in simulator.get("low_fidelity", {}).get("theta", {}).items()},
        low_fidelity_rho=simulator.get("low_fidelity", {}).get("rho", "constant"),
    )
    _check_noise(model.get("noise", "iid"), data, model.get("noise_inputs", []), model.get("biased_sources", []))
    candidates = _candidates(raw.get("candidates", {}), base, data)
    return Problem(data=data, simulator=stan, model=model, candidates=candidates, units=dict(raw.get("units", {})),
                   design=dict(raw.get("design", {})))


def _resolve_program(model: dict[str, Any], base: Path) -> None:
    """[model] program: the user's copy of a Stan program, relative to the config."""
    if "program" in model:
        model["program"] = base / model["program"]
        if not model["program"].is_file():
            raise ConfigError(f"[model] program: file not found: {model['program']}")


def _low_fidelity_runs(simulator: dict[str, Any], base: Path) -> list[pd.DataFrame]:
    """[simulator.low_fidelity] runs: one CSV, or several (levels, cheapest first)."""
    files = simulator.get("low_fidelity", {}).get("runs", [])
    return [_read_csv(base / name, "[simulator.low_fidelity] runs") for name in ([files] if isinstance(files, str)
                                                                             else files)]


def _check_noise(noise: str, data: CalibrationData, noise_inputs: list[str], biased_sources: list[str]) -> None:
    """[model] noise against [physical] noise_sd and source, noise_inputs
    against the inputs and biased_sources against the sources, before anything compiles."""
    if noise in NOISE_MODES:
        raise ConfigError(f"[model] noise applies to a vector output only as {noise!r} (a [physical] output_index); "
                          f"a scalar output's noise is one of {', '.join(NOISES)}")
    try:
        check_noise_name(noise)  # the schema's choices let through only a model not built yet
        check_noise_inputs(noise, noise_inputs, data.inputs)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    check_noise(noise, data.noise, biased_sources)  # a DataError naming the key and the column
    check_biased_sources(biased_sources, data.noise)


def _vector_problem(physical: dict, simulator: dict, theta: dict, runs: pd.DataFrame | None, stan: Path | None,
                    model: dict, raw: dict, base: Path) -> Problem:
    """A vector output ([physical] output_index): long tables, one row per value."""
    _resolve_program(model, base)
    basis = {k: model.pop(k) for k in ("variance_share", "components") if k in model}
    if model.get("noise", "one") not in NOISE_MODES:
        raise ConfigError(f"[model] noise {model['noise']!r} does not apply to a vector output ([physical] "
                          f"output_index); its noise is one of {', '.join(NOISE_MODES)}")
    low = simulator.get("low_fidelity", {})
    if "theta" in low:
        raise ConfigError("[simulator.low_fidelity.theta] (the cheap simulator's own theta_l) is not built for a "
                          "vector output: its runs take the shared theta")
    data = VectorCalibrationData(
        _read_csv(base / _require(physical, "csv", "physical"), "[physical] csv"),
        experiment=_require(physical, "experiment", "physical"),
        inputs=_require(physical, "inputs", "physical"),
        output=_require(physical, "output", "physical"),
        output_index=physical["output_index"],
        theta=theta, theta_per_experiment=simulator.get("theta_per_experiment", {}),
        runs=runs, run=_require(simulator, "run", "simulator") if runs is not None else None,
        noise_sd=physical.get("noise_sd"), covariates=physical.get("covariates", []), **basis,
        low_fidelity_runs=_low_fidelity_runs(simulator, base), low_fidelity_rho=low.get("rho", "constant"))
    return Problem(data=data, simulator=stan, model=model,
                   candidates=_candidates(raw.get("candidates", {}), base, data),
                   units=dict(raw.get("units", {})), design=dict(raw.get("design", {})))
