"""Every table and key of a stancal TOML config: its type, default and
meaning, in one place. The config reader checks a file against it before
anything else (an unknown or misspelled name is named, with the closest
known one), and docs/config.md is checked against it."""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from stancal.problem.codes import NOISE_MODES
from stancal.problem.fidelity_rho import RHO_FORMS
from stancal.problem.noise import HETEROSCEDASTIC, NOISES
from stancal.problem.observations import LIKELIHOODS
from stancal.problem.options import (
    APPROXIMATIONS,
    DISCREPANCIES,
    EXACT_SIZE_LIMIT,
    FUNCTIONAL_PARAMETRIZATIONS,
    KERNELS,
    PARAMETRIZATIONS,
)
from stancal.problem.output_basis import DEFAULT_VARIANCE_SHARE

SCALAR, VECTOR, BOTH = "scalar", "vector", "both"  # which outputs a key applies to


def _is_string(v: Any) -> bool:
    return isinstance(v, str)


def _is_strings(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(s, str) for s in v)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _is_bounds(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_is_number(b) for b in v)


# a type's name (as the docs and the errors say it) -> its check on a TOML value
TYPES: dict[str, Callable[[Any], bool]] = {
    "string": _is_string,
    "path": _is_string,
    "list of names": _is_strings,
    "list of names (or one name)": lambda v: _is_string(v) or _is_strings(v),
    "path (or a list of paths)": lambda v: _is_string(v) or _is_strings(v),
    "boolean": lambda v: isinstance(v, bool),
    "number": _is_number,
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "list of integers": lambda v: isinstance(v, list) and all(isinstance(i, int) and not isinstance(i, bool)
                                                             for i in v),
    "list of numbers": lambda v: isinstance(v, list) and all(_is_number(i) for i in v),
    "[lower, upper]": _is_bounds,
}


@dataclass(frozen=True)
class Key:
    name: str
    type: str  # a key of TYPES
    default: str  # as the docs show it; "required" when the key must be given
    meaning: str
    output: str = BOTH  # SCALAR, VECTOR or BOTH
    choices: tuple[str, ...] = ()  # the values a string key takes, when they are few
    lowest: float | None = None  # a number's smallest value (inclusive)
    above: float | None = None  # a number's bound from below (exclusive)
    highest: float | None = None  # a number's largest value (inclusive)

    def __post_init__(self) -> None:
        assert self.type in TYPES, self.type

    def out_of_range(self, value: Any) -> str | None:
        """"must be at least 1", "must lie in (0, 1]", ... when a number is
        outside the key's range (or not finite); None when it is inside or
        the key has no range."""
        if self.lowest is None and self.above is None and self.highest is None:
            return None
        inside = (math.isfinite(value) and (self.lowest is None or value >= self.lowest)
                  and (self.above is None or value > self.above) and (self.highest is None or value <= self.highest))
        if inside:
            return None
        if self.highest is not None:
            low = f"({self.above:g}" if self.above is not None else f"[{self.lowest:g}"
            return f"must lie in {low}, {self.highest:g}]"
        if self.above is not None:
            return "must be a positive number" if self.above == 0 else f"must be above {self.above:g}"
        return f"must be at least {self.lowest:g}"

    def range_text(self) -> str:
        """The range as docs/config.md shows it: " (> 0)", " (1 to 3)", " (> 0, ≤ 1)", ""."""
        low = f"> {self.above:g}" if self.above is not None else None
        if self.highest is not None:
            return f" ({low}, ≤ {self.highest:g})" if low else f" ({self.lowest:g} to {self.highest:g})"
        if low:
            return f" ({low})"
        return f" (≥ {self.lowest:g})" if self.lowest is not None else ""


@dataclass(frozen=True)
class Table:
    """A table of fixed keys, or (``entries``) one of free names whose values
    all have the type ``entries`` (a parameter's bounds, a unit)."""

    name: str
    meaning: str
    keys: tuple[Key, ...] = ()
    entries: str | None = None  # the type of every value of a table of free names
    required: bool = False

    def key(self, name: str) -> Key | None:
        return next((k for k in self.keys if k.name == name), None)


_THETA_MEANING = "The calibration parameters, `name = [lower, upper]`: the bounds of each one's uniform prior"

TABLES: tuple[Table, ...] = (
    Table("physical", "The measurements: a CSV and its columns", required=True, keys=(
        Key("csv", "path", "required", "the physical data, a CSV with a header line (relative to the config)"),
        Key("inputs", "list of names", "required", "the simulator's input columns, in the simulator's order"),
        Key("output", "string", "required", "the measured output column (the same name in the runs)"),
        Key("covariates", "list of names", "[]", "measured columns the simulator does not take; the "
            "discrepancy may depend on them (a text column is categorical)"),
        Key("experiment", "string", "required for a vector output", "the column naming each reading's "
            "experiment", VECTOR),
        Key("output_index", "list of names (or one name)", "none (a scalar output)", "where a reading sits along "
            "a vector output (time, position); giving it makes the output a vector", VECTOR),
        Key("noise_sd", "string", "none (the noise sd is estimated)", "a column of each reading's known "
            "measurement sd (a scalar output: added in quadrature to the estimated sd, docs/noise.md)"),
        Key("source", "string", "none (one source)", "a column naming each reading's measurement source "
            "(instrument), for [model] noise = \"per_source\" or biased_sources", SCALAR),
    )),
    Table("simulator", "The computer model: a Stan function, runs of it, or both", required=True, keys=(
        Key("stan", "path", "none", "a Stan file defining vector simulator(matrix X, vector theta), one value "
            "per row of X (give stan, runs or both)"),
        Key("runs", "path", "none", "a CSV of simulator runs: the inputs, every theta and the output (an "
            "emulator is fitted to them)"),
        Key("run", "string", "required with runs for a vector output", "the runs' column naming each run "
            "(long runs, one row per value)", VECTOR),
        Key("stochastic", "boolean", "false", "the runs scatter at equal inputs and theta (agent-based, Monte "
            "Carlo): the emulator of the simulator's mean carries its own variance, estimated from the replicated "
            "runs (stochastic kriging; methods modular and modular_hsgp; docs/noise.md)", SCALAR),
    )),
    Table("simulator.theta", _THETA_MEANING + ", in the simulator's order", entries="[lower, upper]",
          required=True),
    Table("simulator.low_fidelity", "Runs of cheaper simulators of the same process (coarser mesh, reduced "
          "physics): the emulator of `runs` learns from them too (docs/multifidelity.md)", keys=(
        Key("runs", "path (or a list of paths)", "required", "CSV(s) of the cheaper simulators' runs, with the "
            "columns of [simulator] runs; several files are levels, cheapest first (a vector output: each "
            "projected on the basis of [simulator] runs)"),
        Key("rho", "string", '"constant"', "each level's scale on the one below: constant, or linear in the "
            "simulator's inputs, rho(x) = beta_0 + x' beta_x (Le Gratiet & Garnier 2014; not with "
            "[simulator.low_fidelity.theta]; a vector output: constant only)", choices=RHO_FORMS),
    )),
    Table("simulator.low_fidelity.theta", "The cheapest simulator's own calibration parameters theta_l, "
          "`name = [lower, upper]` (Goh et al. 2013): its runs carry these columns in place of theta's, and theta_l "
          "is sampled with theta; one level of low-fidelity runs, names other than theta's (docs/multifidelity.md)",
          entries="[lower, upper]"),
    Table("simulator.theta_per_experiment", "Parameters with one value per experiment, `name = [lower, upper]` "
          "(vector outputs; they follow the shared theta in the simulator's theta)", entries="[lower, upper]"),
    Table("model", "The statistical model and the method", keys=(
        Key("method", "string", "koh with a Stan simulator, else an emulator of the runs", "the calibration "
            "method (koh, koh_emulator, modular, l2, ...; see `stancal calibrate --help`)"),
        Key("program", "path", "the method's shipped program", "your edited copy of the method's Stan program"),
        Key("discrepancy", "string", '"gp"', "gp (Kennedy-O\'Hagan), orthogonal (Plumlee 2017), scaled "
            "(S-GaSP) or none; gp or none for a vector output", choices=tuple(DISCREPANCIES)),
        Key("kernel", "string", '"se"', "the discrepancy GP's kernel: se or matern52", choices=KERNELS),
        Key("estimate_rho", "boolean", "false", "estimate a scale rho on the simulator (zeta = rho f + delta)",
            SCALAR),
        Key("mean_formula", "string", "none", 'discrepancy mean terms over the physical columns, a formula '
            'such as "I(v**2)"'),
        Key("mean_intercept", "boolean", "false", "a constant term in the discrepancy mean"),
        Key("mean_centred", "boolean", "false", "centre the mean terms without a constant term (set by "
            "stancal when a theta carries the level: see the gap page)", SCALAR),
        Key("scaled_lambda", "number", "sqrt(N)", "the scaled GP's penalty lambda_z (discrepancy = "
            '"scaled")', SCALAR, above=0),
        Key("functional", "list of names (or one name)", "[]", "theta that vary over functional_inputs: "
            "theta(x) as a latent GP", SCALAR),
        Key("functional_inputs", "list of names (or one name)", "[]", "the physical columns the functional "
            "theta vary over", SCALAR),
        Key("functional_parametrization", "string", '"centred"', "theta(x)'s latent GP: centred (data that "
            "pin theta(x)) or non_centred", SCALAR,
            choices=FUNCTIONAL_PARAMETRIZATIONS),
        Key("discrepancy_parametrization", "string", '"auto"', "the latent programs' discrepancy GP (counts, "
            "binomial, censored outputs, functional theta): centred, non_centred, partial (partially non-centred "
            "with the data's information per point; koh_latent), or auto (partial where offered and the data "
            "dominate the prior's variance at most points, else centred when they dominate its conditional "
            "variance at most points; refitted non-centred once if more than 5 % of transitions hit the "
            "maximum tree depth)", SCALAR, choices=PARAMETRIZATIONS),
        Key("approximation", "string", '"auto"', "exact (dense GPs), hsgp (Hilbert-space, scalable) or auto "
            f"(hsgp above {EXACT_SIZE_LIMIT:,} points plus runs)", SCALAR,
            choices=APPROXIMATIONS),
        Key("basis_functions", "list of integers", "chosen by stancal", "the Hilbert-space discrepancy's "
            "basis functions per discrepancy input", SCALAR),
        Key("boundary_factor", "list of numbers", "chosen by stancal", "the Hilbert-space boundary factor "
            "per discrepancy input (>= 1)", SCALAR),
        Key("likelihood", "string", '"gaussian"', "gaussian, poisson, negbinomial (counts) or binomial",
            SCALAR, choices=tuple(LIKELIHOODS)),
        Key("trials", "string", "none", "binomial only: the column with each row's number of trials", SCALAR),
        Key("lower", "string", "none", "gaussian only: a column of censoring lower bounds (a row with an empty "
            "output is censored)", SCALAR),
        Key("upper", "string", "none", "gaussian only: a column of censoring upper bounds", SCALAR),
        Key("noise", "string", '"iid" (scalar); "one", or "known" with noise_sd (vector)', "the measurement "
            "noise (docs/noise.md). A scalar output: " + ", ".join(NOISES)
            + "; a vector output: " + ", ".join(sorted(NOISE_MODES)),
            choices=(*NOISES, *NOISE_MODES)),
        Key("noise_inputs", "list of names (or one name)", "every simulator input", f"noise = \"{HETEROSCEDASTIC}\": "
            "the simulator inputs the log noise sd varies over (docs/noise.md)", SCALAR),
        Key("biased_sources", "list of names (or one name)", "[] (every source a reference)", "sources of "
            "[physical] source whose readings carry a bias GP of their own over the simulator inputs, beside the "
            "discrepancy; the others are references (docs/noise.md)", SCALAR),
        Key("variance_share", "number", str(DEFAULT_VARIANCE_SHARE), "the share of the runs' variance the "
            "output basis keeps", VECTOR, above=0, highest=1),
        Key("components", "integer", "by variance_share", "the output basis's number of components (overrides "
            "variance_share)", VECTOR, lowest=1),
    )),
    Table("candidates", "Candidate unmodelled effects for `stancal gap`: `name = \"formula\"` (discrepancy "
          "mean terms), or a `[candidates.NAME]` table", entries="string or table"),
    Table("candidates.NAME", "One candidate: a formula, or a simulator variant (stan, inputs and theta)", keys=(
        Key("formula", "string", "none", "discrepancy mean terms over the physical columns, e.g. \"C(batch)\""),
        Key("stan", "path", "none", "a variant simulator in Stan (instead of formula)"),
        Key("inputs", "list of names", "required with stan", "the physical columns the variant takes, in its "
            "order"),
    )),
    Table("candidates.NAME.theta", "The variant's extra parameters, `name = [lower, upper]` (after the "
          "baseline's theta, which keep their bounds)", entries="[lower, upper]"),
    Table("design", "History matching and the next runs for `stancal design` (docs/design.md)", keys=(
        Key("discrepancy_sd", "number", "discrepancy_fraction x the observations' sd", "the model discrepancy's sd "
            "in implausibility, output units (counts: on the link scale, log or logit)", lowest=0),
        Key("discrepancy_fraction", "number", "0.1", "the discrepancy sd as a share of the observations' sd over "
            "the physical points, when discrepancy_sd is not given", lowest=0),
        Key("noise_sd", "number", "the known noise_sd column, else estimated", "the measurement noise sd in "
            "implausibility, output units (estimated: the smaller of Rice's difference estimate and the "
            "emulator's least-squares residual sd); for counts, an sd on the link scale added to the count "
            "model's (a negative binomial's 1 / sqrt(phi), else estimated)", above=0),
        Key("nth_maximum", "integer", "by the number of observations", "combine the observations' "
            "implausibilities by their 1st, 2nd or 3rd largest (Vernon et al. 2010); by default the smallest "
            "whose chance of ruling out the true theta is at most 5 %", lowest=1, highest=3),
        Key("cutoff", "number", "3.0", "the implausibility cutoff (Pukelsheim's three-sigma rule); "
            "--cutoff overrides it", above=0),
        Key("nroy_points", "integer", "2000", "the size of the NROY sample (nroy.csv)", lowest=1000),
    )),
    Table("units", 'Units for the figures\' axes, `name = "unit"`: the unit of an input, covariate, output, '
          'output index or theta (e.g. `T = "°C"`)', entries="string"),
)


def table(name: str) -> Table:
    return next(t for t in TABLES if t.name == name)


def must_be(kind: str) -> str:
    """'must be a list of names', 'must be an integer', 'must be [lower, upper]'."""
    article = "" if kind.startswith("[") else "an " if kind[0] in "aeiou" else "a "
    return f"must be {article}{kind}"


def closest(name: str, known: list[str], form: str = "'{}'") -> str:
    """"; did you mean 'x'?" for the closest known name (shown in ``form``), or "".
    difflib finds the near names; the fewest edits, then the same length,
    picks among them ('runz' is 'runs' mistyped more likely than 'run' extended)."""
    near = difflib.get_close_matches(name, known, n=5, cutoff=0.6)
    if not near:
        return ""
    best = min(near, key=lambda k: (_edits(name, k), abs(len(k) - len(name))))
    return f"; did you mean {form.format(best)}?"


def _edits(a: str, b: str) -> int:
    """Levenshtein distance."""
    row = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        previous, row[0] = row[0], i
        for j, cb in enumerate(b, 1):
            previous, row[j] = row[j], min(row[j] + 1, row[j - 1] + 1, previous + (ca != cb))
    return row[-1]


def check(raw: dict[str, Any]) -> str | None:
    """The first problem of a parsed config against the schema, as one
    sentence without the file's name, or None. Unknown and misspelled names
    first (with the closest known name), then types and ranges, then the
    keys a scalar or a vector output does not take. [units]: check_units."""
    top = [t.name for t in TABLES if "." not in t.name]
    for name, value in raw.items():
        if name not in top:
            what = f"unknown table [{name}]" if isinstance(value, dict) else f"unknown key '{name}' outside any table"
            return what + (closest(name, top, "[{}]") or f"; the tables are {', '.join(f'[{t}]' for t in top)}")
        if not isinstance(value, dict):
            return f"'{name}' must be a table [{name}]; got {value!r}"
    for name in ("physical", "simulator"):
        if name not in raw:
            return f"missing the [{name}] table"
    output = VECTOR if "output_index" in raw["physical"] else SCALAR
    simulator = raw["simulator"]
    problem = (_check_table(raw["physical"], table("physical"), output)
               or _check_table(simulator, table("simulator"), output,
                               subtables=("theta", "theta_per_experiment", "low_fidelity")))
    if problem or "theta" not in simulator:
        return problem or "missing the [simulator.theta] table"
    if output == SCALAR and "theta_per_experiment" in simulator:
        return "[simulator.theta_per_experiment] applies to a vector output only (a [physical] output_index)"
    return (_check_low_fidelity(simulator, output)
            or _check_entries(simulator["theta"], table("simulator.theta"))
            or _check_entries(simulator.get("theta_per_experiment", {}), table("simulator.theta_per_experiment"))
            or _check_table(raw.get("model", {}), table("model"), output)
            or _check_scaled_lambda(raw.get("model", {}))
            or _check_table(raw.get("design", {}), table("design"), output)
            or _check_candidates(raw.get("candidates", {})))


def _check_low_fidelity(simulator: dict[str, Any], output: str) -> str | None:
    """[simulator.low_fidelity]: its keys, its runs, and the runs it needs beside it."""
    low = simulator.get("low_fidelity")
    if low is None:
        return None
    problem = (_check_table(low, table("simulator.low_fidelity"), output, subtables=("theta",))
               or _check_entries(low.get("theta", {}), table("simulator.low_fidelity.theta")))
    if problem or "runs" not in low:
        return problem or "[simulator.low_fidelity] needs runs = \"file.csv\" (the cheaper simulator's runs)"
    if "runs" not in simulator:
        return ("[simulator.low_fidelity] needs [simulator] runs: the cheaper runs inform the emulator of the "
                "simulator being calibrated")
    return None


def _check_table(values: dict[str, Any], spec: Table, output: str, subtables: tuple[str, ...] = (),
                 where: str | None = None) -> str | None:
    """Unknown keys (with the closest known), sub-tables where they belong, types, and keys of the other output."""
    where = where or f"[{spec.name}]"
    for name, value in values.items():
        if name in subtables:
            if not isinstance(value, dict):
                return f"{where} {name} must be a table [{spec.name}.{name}]; got {value!r}"
            continue
        key = spec.key(name)
        if key is None:
            if isinstance(value, dict):
                return f"unknown table [{spec.name}.{name}]" + closest(name, list(subtables), f"[{spec.name}.{{}}]")
            applicable = [k.name for k in spec.keys if k.output in (BOTH, output)]  # suggest what this output takes
            return f"unknown key '{name}' in {where}{closest(name, applicable)}"
        if not TYPES[key.type](value):
            return f"{where} {name} {must_be(key.type)}; got {value!r}"
        if key.out_of_range(value):
            return f"{where} {name} {key.out_of_range(value)}; got {value!r}"
        if key.choices and value not in key.choices:
            return (f"{where} {name} must be one of {', '.join(key.choices)}; got {value!r}"
                    + closest(value, list(key.choices)))
        if key.output not in (BOTH, output):
            return (f"{where} {name} applies to a vector output only (a [physical] output_index)" if output == SCALAR
                    else f"{where} {name} does not apply to a vector output ([physical] output_index)")
    return None


def _check_scaled_lambda(model: dict[str, Any]) -> str | None:
    """scaled_lambda is the scaled GP's penalty: in a config whose discrepancy
    is another, it would be ignored (a --discrepancy flag may still override
    a scaled config's discrepancy for one run)."""
    discrepancy = model.get("discrepancy", "gp")
    if "scaled_lambda" in model and discrepancy != "scaled":
        return f'[model] scaled_lambda applies to discrepancy = "scaled" only; this config\'s is {discrepancy!r}'
    return None


def _check_entries(values: dict[str, Any], spec: Table) -> str | None:
    for name, value in values.items():
        if not TYPES[spec.entries](value):
            return f"[{spec.name}] {name} {must_be(spec.entries)}; got {value!r}"
    return None


def _check_candidates(candidates: dict[str, Any]) -> str | None:
    """Each candidate a formula string or a [candidates.NAME] table (the
    messages keep the form `stancal gap`'s users know)."""
    spec = table("candidates.NAME")
    for name, value in candidates.items():
        where = f"[candidates.{name}]"
        if isinstance(value, str):
            continue
        if not isinstance(value, dict):
            return f"candidate '{name}': give a formula string or a table; got {value!r}"
        known = ["formula"] if "formula" in value else ["stan", "inputs", "theta"]
        unknown = sorted(set(value) - set(known))
        if unknown:
            return (f"candidate '{name}': unknown key(s) {unknown} in {where}; known: {known}"
                    + closest(unknown[0], known))
        problem = _check_table({k: v for k, v in value.items() if k != "theta"}, spec, BOTH, where=where)
        if problem:
            return problem
        theta = value.get("theta", {})
        if not isinstance(theta, dict):
            return f"{where} theta must be a table of name = [lower, upper]; got {theta!r}"
        problem = _check_entries(theta, Table(f"candidates.{name}.theta", "", entries="[lower, upper]"))
        if problem:
            return problem
    return None


def named_quantities(raw: dict[str, Any]) -> list[str]:
    """Every column and parameter a config names: what [units] may give a unit to."""
    physical, simulator = raw.get("physical", {}), raw.get("simulator", {})
    names = []
    for key in ("inputs", "output", "covariates", "output_index", "experiment", "noise_sd", "source"):
        value = physical.get(key, [])
        names += [value] if isinstance(value, str) else list(value)
    names += [*simulator.get("theta", {}), *simulator.get("theta_per_experiment", {})]
    for candidate in raw.get("candidates", {}).values():
        if isinstance(candidate, dict):
            names += [*candidate.get("inputs", []), *candidate.get("theta", {})]
    return list(dict.fromkeys(names))


def check_units(raw: dict[str, Any]) -> str | None:
    """[units] against the config's columns and parameters: checked after
    the data, so that a missing column is named as itself, not as a unit."""
    known = named_quantities(raw)
    for name, unit in raw.get("units", {}).items():
        if name not in known:
            return (f"[units] names '{name}', which is no column or parameter of this config"
                    + (closest(name, known) or f" (known: {', '.join(known)})"))
        if not isinstance(unit, str):
            return f"[units] {name} must be a string such as \"°C\"; got {unit!r}"
    return None


def reference() -> str:
    """The tables and keys as Markdown (docs/config.md holds this between
    its GENERATED markers; `python -m stancal.problem.config_schema` prints it)."""
    applies = {SCALAR: "scalar outputs", VECTOR: "vector outputs", BOTH: "both"}
    out = []
    for spec in TABLES:
        out += [f"### `[{spec.name}]`", "", spec.meaning + "." + (" Required." if spec.required else ""), ""]
        if spec.entries:
            out += [f"Every value: {spec.entries}.", ""]
        if spec.keys:
            out += ["| key | type | default | applies to | meaning |", "|---|---|---|---|---|"]
            out += [f"| `{k.name}` | {k.type}{k.range_text()}{_choices(k)} | {k.default} | {applies[k.output]} "
                    f"| {k.meaning} |" for k in spec.keys]
            out.append("")
    return "\n".join(out).replace(": [lower, upper].", ": `[lower, upper]`.")


def _choices(key: Key) -> str:
    return f": {', '.join(f'`{c}`' for c in key.choices)}" if key.choices else ""


if __name__ == "__main__":
    print(reference())
