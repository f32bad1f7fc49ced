"""Everything checked before compiling (issue 29, item 2): the config
against its schema, the data's file and lines in every row error, a Stan
simulator's length and values at the data's rows before sampling, nothing
written to --out until the checks pass, and malformed CSVs and TOMLs fed
through the command line (hypothesis) ending in one named line, exit 2."""

import re
import shutil
import string
import tempfile
import time
import tomllib
from dataclasses import fields
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, ROOT
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import stancal.cli
from stancal.cli import main
from stancal.problem.config import ConfigError, load_config
from stancal.problem.options import ModelOptions, VectorOptions
from stancal.problem.validation import DataError


def schema():  # the new modules load when a test asks: on older code each test fails alone
    from stancal.problem import config_schema

    return config_schema


def read_table(path):
    from stancal.problem.validation import read_table

    return read_table(path)

CURVES = ROOT / "case_studies" / "cooling_curves"
# the cooling config without its [units] table, which some tests write their own of
CONFIG = re.sub(r"\[units\][^\[]*", "", (COOLING / "config.toml").read_text())


def copy_case(folder: Path, source: Path = COOLING) -> Path:
    """A case study's config, CSVs and Stan files in a folder of its own."""
    for path in source.iterdir():
        if path.suffix in (".toml", ".csv", ".stan"):
            shutil.copy(path, folder / path.name)
    return folder / "config.toml"


def cli(argv: list, capsys) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def error_line(err: str) -> str:
    """The one error line; no traceback, no second error."""
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if line.startswith("stancal: error:")]
    assert len(errors) == 1, err
    return errors[0]


@pytest.fixture
def no_fit(monkeypatch):
    """The command must stop before compiling or fitting: reaching either fails the test."""
    import stancal.diagnosing.compare
    import stancal.diagnosing.gap
    import stancal.diagnosing.sbc

    def reached(*args, **kwargs):
        raise AssertionError("the bad input reached a compile or a fit")
    for module, name in [(stancal.cli, "calibrate"), (stancal.cli, "get_backend"),
                         (stancal.diagnosing.gap, "diagnose_gap"), (stancal.diagnosing.compare, "compare_methods"),
                         (stancal.diagnosing.sbc, "simulation_based_calibration")]:
        monkeypatch.setattr(module, name, reached)


# ---- 1. every table and key of the config is known ----------------------------------
@pytest.mark.parametrize("old, new, message", [
    ("[physical]", "[physicl]", "unknown table [physicl]; did you mean [physical]?"),
    ('runs = "runs.csv"', 'runz = "runs.csv"', "unknown key 'runz' in [simulator]; did you mean 'runs'?"),
    ('output = "temperature"', 'ouput = "temperature"', "unknown key 'ouput' in [physical]; did you mean 'output'?"),
    ('kernel = "se"', 'kernal = "se"', "unknown key 'kernal' in [model]; did you mean 'kernel'?"),
    ("[simulator.theta]", "[simulator.thetas]", "unknown table [simulator.thetas]; did you mean [simulator.theta]?"),
    ('inputs = ["t", "T0"]           #', 'inputs = "t"  #', "[physical] inputs must be a list of names; got 't'"),
    ("k = [0.01, 0.2]", "k = [0.01]", "[simulator.theta] k must be [lower, upper]; got [0.01]"),
    ('kernel = "se"', 'kernel = "se"\nestimate_rho = "yes"', "[model] estimate_rho must be a boolean; got 'yes'"),
    ('kernel = "se"', 'kernel = "se"\nnoise = "one"', "[model] noise applies to a vector output only"),
    ('kernel = "se"', 'kernel = "matern5"', "[model] kernel must be one of se, matern52; got 'matern5'; did you mean 'matern52'?"),
    ('discrepancy = "gp"', 'discrepancy = "orthogonl"', ("[model] discrepancy must be one of gp, orthogonal, "
                                                        "scaled, none; got 'orthogonl'; did you mean 'orthogonal'?")),
    ("[model]", "[model]\ncomponents = 2", "[model] components applies to a vector output only"),
    ("[physical]", "title = 'x'\n[physical]", "unknown key 'title' outside any table"),
    ("[simulator.theta]", "[simulator.theta_per_experiment]\no = [0, 1]\n[simulator.theta]",
     "[simulator.theta_per_experiment] applies to a vector output only"),
    ('humidity = "humidity"', "humidity = 3", "candidate 'humidity': give a formula string or a table; got 3"),
    ('inputs = ["t", "T0", "humidity"]', 'inputs = ["t", "T0", "humidity"]\ninptus = ["t"]',
     "unknown key(s) ['inptus'] in [candidates.humid_convection]"),
])
def test_an_unknown_or_mistyped_key_is_named_with_the_closest_known(tmp_path, old, new, message):
    config = copy_case(tmp_path)
    assert old in CONFIG
    config.write_text(CONFIG.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(config)
    assert str(err.value).startswith(f"{config}: "), err.value
    assert message in str(err.value)


def test_ouput_is_named_before_the_missing_output(tmp_path):
    """The old reader said "[physical] needs 'output'" for a misspelled output."""
    config = copy_case(tmp_path)
    config.write_text(CONFIG.replace('output = "temperature"', 'ouput = "temperature"'))
    with pytest.raises(ConfigError, match="did you mean 'output'") as err:
        load_config(config)
    assert "needs 'output'" not in str(err.value)


def test_units_name_the_configs_columns_and_parameters(tmp_path):
    config = copy_case(tmp_path)
    config.write_text(CONFIG + '\n[units]\nt = "min"\nT0 = "°C"\ntemperature = "°C"\nk = "1/min"\nc = "1/(°C min)"\n')
    assert load_config(config).units == {"t": "min", "T0": "°C", "temperature": "°C", "k": "1/min",
                                         "c": "1/(°C min)"}
    config.write_text(CONFIG + '\n[units]\ntemprature = "°C"\n')
    with pytest.raises(ConfigError, match=r"\[units\] names 'temprature', which is no column or parameter of "
                                          r"this config; did you mean 'temperature'\?"):
        load_config(config)
    config.write_text(CONFIG + "\n[units]\nt = 60\n")
    with pytest.raises(ConfigError, match=r"\[units\] t must be a string"):
        load_config(config)


def test_every_shipped_config_passes_the_schema():
    for path in sorted((ROOT / "case_studies").glob("*/config.toml")):
        assert schema().check(tomllib.loads(path.read_text())) is None, path


def test_the_schemas_model_keys_are_the_options_fields():
    """[model] in the schema = the method, the program, the observation
    columns and the fields of ModelOptions and VectorOptions (plus the
    vector basis's two), each applying to the outputs that take it."""
    model = schema().table("model")
    scalar = {k.name for k in model.keys if k.output != schema().VECTOR}
    vector = {k.name for k in model.keys if k.output != schema().SCALAR}
    assert scalar == {"method", "program", "likelihood", "trials", "lower", "upper",
                      *(f.name for f in fields(ModelOptions) if "set_by" not in f.metadata)}
    assert vector == {"method", "program", "variance_share", "components",
                      *(f.name for f in fields(VectorOptions) if f.name != "basis_functions")}


# ---- 2. docs/config.md --------------------------------------------------------------
def test_docs_config_lists_every_table_and_key_as_the_schema_says():
    docs = (ROOT / "docs" / "config.md").read_text()
    generated = docs.split("<!-- GENERATED from stancal/problem/config_schema.py: do not edit by hand -->\n")[1]
    assert generated.split("<!-- END GENERATED -->")[0].strip() == schema().reference().strip()
    for table in schema().TABLES:
        assert f"### `[{table.name}]`" in docs
        for key in table.keys:
            assert f"| `{key.name}` | {key.type}" in docs and f" | {key.default} | " in docs, key


def test_the_schema_prints_its_reference_without_a_warning():
    """docs/config.md's command: `import stancal` must not import the schema
    module before runpy runs it (a RuntimeWarning when DesignSettings did)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-W", "error", "-m", "stancal.problem.config_schema"], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0 and not done.stderr, done.stderr
    assert done.stdout.strip() == schema().reference().strip()


def test_the_docs_example_config_passes_the_schema():
    docs = (ROOT / "docs" / "config.md").read_text()
    example = re.search(r"```toml\n(.*?)```", docs, re.S).group(1)
    assert schema().check(tomllib.loads(example)) is None


# ---- 3. data errors name the file and its lines (header = line 1) -------------------
def _with_cell(path: Path, row: int, column: str, value: str) -> None:
    """Set one cell of a CSV by its data row (0-based), as text."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[row + 1].split(",")
    cells[header.index(column)] = value
    lines[row + 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("file, column, value, message", [
    ("physical.csv", "T0", "hot", "column 'T0' has non-numeric values in lines [14]"),
    ("physical.csv", "T0", "", "column 'T0' has NaN or inf in lines [14]"),
    ("physical.csv", "temperature", "inf", "column 'temperature' has inf in lines [14]"),
    ("physical.csv", "operator", "7", "column 'operator' mixes numbers and text; numbers in lines [14]"),
    ("runs.csv", "k", "0.9", "column 'k' lies outside its bounds [0.01, 0.2] in lines [14]"),
    ("runs.csv", "temperature", "x", "column 'temperature' has non-numeric values in lines [14]"),
])
def test_a_bad_cell_is_named_by_its_file_and_line(tmp_path, file, column, value, message):
    config = copy_case(tmp_path)
    _with_cell(tmp_path / file, 12, column, value)  # data row 12 is line 14
    with pytest.raises(DataError) as err:
        load_config(config)
    assert message in str(err.value)
    assert f"({tmp_path / file})" in str(err.value)


def test_lines_count_blank_lines_and_name_a_vector_configs_file(tmp_path):
    path = tmp_path / "blank.csv"
    path.write_text('a,b\n1,2\n\n3,4\n"two\nlines",5\n6,7\n')
    assert read_table(path).index.tolist() == [2, 4, 5, 7]
    config = copy_case(tmp_path, CURVES)
    _with_cell(tmp_path / "physical.csv", 20, "temperature", "warm")
    with pytest.raises(DataError, match=re.escape(f"physical data ({tmp_path / 'physical.csv'}): column "
                                                  "'temperature' has non-numeric values in lines [22]")):
        load_config(config)


def test_the_extrapolation_warning_names_the_file_and_line(tmp_path):
    from stancal.problem.data import InputRangeWarning

    config = copy_case(tmp_path)
    _with_cell(tmp_path / "physical.csv", 12, "T0", "99")  # above the runs' T0
    with pytest.warns(InputRangeWarning, match=re.escape(f"in lines [14] of {tmp_path / 'physical.csv'}")):
        load_config(config)


def test_frames_not_read_from_a_file_keep_their_rows():
    frame = pd.DataFrame({"t": [1.0, np.nan, 3.0, 4.0], "y": [1.0, 2.0, 3.0, 5.0]})
    with pytest.raises(DataError, match=r"physical data: column 't' has NaN or inf in rows \[1\]"):
        __import__("stancal").CalibrationData(frame, ["t"], "y", {"k": (0, 1)})


def test_a_repeated_header_column_is_named(tmp_path):
    path = tmp_path / "physical.csv"
    path.write_text("t,T0,T0,temperature\n1,2,3,4\n")
    with pytest.raises(DataError, match=re.escape(f"{path}: line 1 (the header) repeats column(s) ['T0']")):
        read_table(path)


# ---- 4. a Stan simulator's length and values, before sampling -----------------------
# One program serves both faults (one compile): the data switch them on.
FAULTY = """// Newton's law of cooling with faults planted for stancal's tests, switched on
// by the data: T0 = 999 in any row returns one value too few; T0 = 777 in a
// row returns nan there.
vector simulator(matrix X, vector theta) {
  real ambient = 20;
  vector[rows(X)] y = ambient + (X[:, 2] - ambient) .* exp(-theta[1] * X[:, 1]);
  for (i in 1:rows(X)) {
    if (X[i, 2] == 777) y[i] = not_a_number();
  }
  if (max(X[:, 2]) == 999) return y[2:rows(X)];
  return y;
}
"""


def test_simulator_failures_read_from_stans_messages():
    """The messages of functions/simulator_output.stan and Stan's size check
    as one line; other messages are not the simulator's."""
    from stancal.fitting.simulator_check import simulator_failure

    points = pd.DataFrame({"t": [1.0, 2.0, 60.0], "T0": [50.0, 60.0, 777.0]},
                          index=pd.Index([2, 3, 5], name="line of data/physical.csv"))
    stan = Path("cool/simulator.stan")
    length = ("Exception: vector assign rows: assigning variable f (40) and right hand side rows (39) must match in "
              "size (at line 13 of /x/stan_models/functions/simulator_output.stan, column 2 to column 42)")
    assert simulator_failure(length, stan, points) == ("simulator.stan returned 39 values for 40 rows; it must "
                                                      "return one value per row of X")
    nan = ("Exception: simulator(X, theta) returned nan at row 3 of X = [60,777] with theta = [0.15]; make it finite "
           "over the whole theta box (at line 20 of /x/simulator_output.stan)")
    assert simulator_failure(nan, stan, points) == ("simulator.stan returned nan at row 3 (line 5 of "
                                                   "data/physical.csv) with theta = [0.15]; make it finite over "
                                                   "the whole theta box")
    # a vector program calls it on one experiment's rows: the row is found by its values
    assert "(line 3 of data/physical.csv)" in simulator_failure(nan.replace("[60,777]", "[2,60]").replace(
        "row 3", "row 1"), stan, points)
    assert simulator_failure("Exception: normal_lpdf: Scale parameter is 0", stan, points) is None
    inside = "Exception: index 5 out of range; expecting index to be between 1 and 4 (at line 6 of cool/simulator.stan)"
    assert simulator_failure(inside, stan, points).startswith("simulator.stan failed at the data's rows: ")
    # a sampler's failure (the cmdstanpy backend has no start check) is rewritten the same way
    from stancal.fitting.simulator_check import explained
    from stancal.stan.backends import StanRuntimeError

    assert str(explained(StanRuntimeError(f"Stan failed while sampling: {length}"), stan, points)).startswith(
        "simulator.stan returned 39 values for 40 rows")
    other = StanRuntimeError("Stan failed while sampling: Scale parameter is 0")
    assert explained(other, stan, points) is other and explained(other, None, points) is other


@pytest.mark.parametrize("value, message", [
    ("999", "faulty.stan returned 38 values for 39 rows"),
    ("777", "faulty.stan returned nan at row 13 (line 14 of {csv}) with theta = ["),
])
def test_a_faulty_simulator_is_one_line_before_sampling_and_leaves_no_out(tmp_path, capsys, value, message):
    """Compiles the faulty simulator into koh.stan once per machine (about a
    minute); each check is then one log density at the first chain's start."""
    config = copy_case(tmp_path)
    (tmp_path / "faulty.stan").write_text(FAULTY)
    # without the runs, whose range the planted T0 would leave (a warning)
    config.write_text(CONFIG.replace('stan = "simulator.stan"', 'stan = "faulty.stan"').replace('runs = "runs.csv"', ""))
    _with_cell(tmp_path / "physical.csv", 12, "T0", value)
    started = time.perf_counter()
    code, err = cli(["calibrate", config, "--out", tmp_path / "out", "--chains", 1, "--warmup", 20, "--draws", 20,
                     "--backend", "pystan"], capsys)
    assert code == 2
    line = error_line(err)
    assert message.format(csv=tmp_path / "physical.csv") in line, line
    assert "httpstan" not in err and "Exception" not in err, err
    assert not (tmp_path / "out").exists()
    print(f"faulty simulator reported in {time.perf_counter() - started:.1f} s")


# ---- 5. nothing written to --out until the checks pass ------------------------------
def test_bad_config_data_or_stan_program_leave_no_out_folder(tmp_path, capsys, no_fit):
    config = copy_case(tmp_path)
    out = tmp_path / "out"
    config.write_text(CONFIG.replace("[physical]", "[physicl]"))
    for command in ("calibrate", "gap", "compare", "sbc"):
        assert cli([command, config, "--out", out], capsys)[0] == 2
    config.write_text(CONFIG)
    _with_cell(tmp_path / "physical.csv", 3, "t", "soon")
    for command in ("calibrate", "gap", "compare", "sbc"):
        code, err = cli([command, config, "--out", out], capsys)
        assert code == 2 and "lines [5]" in error_line(err)
    assert not out.exists()


def test_a_stan_syntax_error_leaves_no_out_folder(tmp_path, capsys):
    """stanc alone rejects it, before any compile."""
    config = copy_case(tmp_path)
    (tmp_path / "broken.stan").write_text("vector simulator(matrix X, vector theta) {\n  return X[:, 1] * thta[1];\n}\n")
    config.write_text(CONFIG.replace('stan = "simulator.stan"', 'stan = "broken.stan"'))
    code, err = cli(["calibrate", config, "--out", tmp_path / "out", "--backend", "pystan"], capsys)
    assert code == 2 and "thta" in error_line(err)
    assert not (tmp_path / "out").exists()


def test_a_failure_after_sampling_keeps_the_draws(tmp_path, capsys, monkeypatch):
    """The report fails after sampling: the posterior written as sampling ended stays."""
    def failing_report(*args, **kwargs):
        raise RuntimeError("the report failed")
    monkeypatch.setattr(stancal.cli, "write_calibration", failing_report)
    config = copy_case(tmp_path)
    config.write_text(CONFIG.replace('discrepancy = "gp"', 'discrepancy = "none"'))
    code, err = cli(["calibrate", config, "--out", tmp_path / "out", "--chains", 1, "--warmup", 100, "--draws", 100,
                     "--seed", 1, "--backend", "pystan"], capsys)
    assert code == 2 and "the report failed" in error_line(err)
    assert (tmp_path / "out" / "posterior.nc").is_file()


# ---- 6. property tests: malformed CSVs and TOMLs through the command line -----------
CSVS = {"physical.csv": ["t", "T0", "humidity", "temperature", "operator"],  # its columns the config uses
        "runs.csv": ["t", "T0", "k", "temperature"]}
NUMERIC = ["t", "T0", "humidity", "k", "temperature"]
JUNK = st.text(string.ascii_letters + "#$%&?", min_size=1, max_size=6)


@st.composite
def bad_csv(draw) -> tuple[str, str, str]:
    """A malformed physical.csv or runs.csv: the file, its text, and what
    the error must name (a column, a line, or the file only)."""
    file = draw(st.sampled_from(sorted(CSVS)))
    lines = (COOLING / file).read_text().splitlines()
    header = lines[0].split(",")
    row = draw(st.integers(0, len(lines) - 2))
    kind = draw(st.sampled_from(["missing column", "non-numeric", "empty cell", "nan", "empty file",
                                 "header only", "ragged long", "ragged short", "repeated header", "two rows"]))
    cells = lines[row + 1].split(",")
    if kind == "missing column":
        drop = header.index(draw(st.sampled_from(CSVS[file])))
        lines = [",".join(c for i, c in enumerate(line.split(",")) if i != drop) for line in lines]
        return file, "\n".join(lines) + "\n", f"missing column(s) ['{header[drop]}']"
    if kind in ("non-numeric", "empty cell", "nan"):
        column = draw(st.sampled_from([c for c in CSVS[file] if c in NUMERIC]))
        cells[header.index(column)] = {"non-numeric": draw(JUNK), "empty cell": "", "nan": "NaN"}[kind]
        lines[row + 1] = ",".join(cells)
        return file, "\n".join(lines) + "\n", f"column '{column}'"
    if kind == "empty file":
        return file, draw(st.sampled_from(["", "\n", "  \n\n"])), "the file is empty"
    if kind == "header only":
        return file, lines[0] + "\n", "0 rows"
    if kind == "two rows":
        return file, "\n".join(lines[:3]) + "\n", "2 rows"
    if kind == "ragged long":
        lines[row + 1] += ",1,2"
        fields = len(header)
        return file, "\n".join(lines) + "\n", f"line {row + 2} has {fields + 2} fields; the header (line 1) has {fields}"
    if kind == "ragged short":
        lines[row + 1] = ",".join(cells[:2])
        return file, "\n".join(lines) + "\n", f"line {row + 2} has 2 fields; the header (line 1) has {len(header)}"
    header[draw(st.integers(0, len(header) - 1))] = draw(st.sampled_from(header))
    if len(set(header)) == len(header):  # drew a column over itself: repeat another
        header[0] = header[1]
    lines[0] = ",".join(header)
    return file, "\n".join(lines) + "\n", "repeats column(s)"


def _one_named_error(argv: list, capsys) -> str:
    code, err = cli(argv, capsys)
    assert code == 2, err
    return error_line(err)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=bad_csv())
def test_malformed_csvs_end_in_one_named_line(case, capsys, no_fit):
    file, text, names = case
    with tempfile.TemporaryDirectory() as folder:
        config = copy_case(Path(folder))
        (Path(folder) / file).write_text(text)
        line = _one_named_error(["calibrate", config, "--out", Path(folder) / "out"], capsys)
        assert str(Path(folder) / file) in line, line
        assert names in line, line
        assert not (Path(folder) / "out").exists()


TABLES = ["physical", "simulator", "simulator.theta", "model"]
VALUES = st.one_of(st.integers(), st.booleans(), st.text(string.ascii_letters, max_size=5),
                   st.lists(st.integers(), max_size=2), st.floats(allow_nan=False))


@st.composite
def bad_toml(draw) -> tuple[str, str]:
    """A malformed config and what its error must name."""
    kind = draw(st.sampled_from(["syntax", "unknown key", "unknown table", "wrong type"]))
    if kind == "syntax":
        lines = CONFIG.splitlines()
        at = draw(st.integers(0, len(lines) - 1))
        lines.insert(at, draw(st.sampled_from(["[physical", "k = ", "= 3", "x = [1,", '"', "[[", "a.b = {"])))
        return "\n".join(lines), "not valid TOML"
    if kind == "unknown key":
        table = draw(st.sampled_from(["physical", "simulator", "model"]))
        known = {k.name for k in schema().table(table).keys} | {"theta", "theta_per_experiment"}
        name = draw(st.text(string.ascii_lowercase + "_", min_size=1, max_size=10).filter(lambda n: n not in known))
        return CONFIG.replace(f"[{table}]\n", f"[{table}]\n{name} = 1\n", 1), f"unknown key '{name}' in [{table}]"
    if kind == "unknown table":
        name = draw(st.text(string.ascii_lowercase, min_size=1, max_size=10).filter(
            lambda n: n not in ("physical", "simulator", "model", "candidates", "units")))
        return CONFIG + f"\n[{name}]\nx = 1\n", f"unknown table [{name}]"
    spec = schema().table(draw(st.sampled_from(["physical", "model"])))
    key = draw(st.sampled_from([k for k in spec.keys if k.output == schema().BOTH]))
    value = draw(VALUES.filter(lambda v: not schema().TYPES[key.type](v)))
    toml_value = {True: "true", False: "false"}.get(value, repr(value)) if isinstance(value, bool) else \
        repr(value).replace("'", '"')
    text = re.sub(rf"(?m)^{key.name} = .*$", "", CONFIG) if key.name in CONFIG else CONFIG
    return text.replace(f"[{spec.name}]\n", f"[{spec.name}]\n{key.name} = {toml_value}\n", 1), \
        f"[{spec.name}] {key.name} must be"


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=bad_toml(), command=st.sampled_from(["calibrate", "gap", "compare", "sbc", "compile"]))
def test_malformed_tomls_end_in_one_named_line(case, command, capsys, no_fit):
    text, names = case
    with tempfile.TemporaryDirectory() as folder:
        config = copy_case(Path(folder))
        config.write_text(text)
        out = ["--out", Path(folder) / "out"] if command != "compile" else []
        line = _one_named_error([command, config, *out], capsys)
        assert str(config) in line, line
        assert names in line, line
        assert not (Path(folder) / "out").exists()


# ---- 6. the model, the candidates and [design] against the data, before any compile -------
# (found by an audit of 130 perturbed configs, 2026-11-26: these reached a compile, or
# `stancal compile` exited 0 on them, or the error named no file)
FULL_CONFIG = (COOLING / "config.toml").read_text()


@pytest.mark.parametrize("command", ["calibrate", "compile"])
@pytest.mark.parametrize("old, new, message", [
    ('kernel = "se"', 'kernel = "se"\nmethod = "kho"', "method 'kho' is not built for a scalar output"),
    ('kernel = "se"', 'kernel = "se"\nscaled_lambda = -1.0', "scaled_lambda must be a positive number"),
    ('kernel = "se"', 'kernel = "se"\nscaled_lambda = 5.0',
     '[model] scaled_lambda applies to discrepancy = "scaled" only; this config\'s is \'gp\''),
    ('kernel = "se"', 'kernel = "se"\nmean_formula = "I(t**"', "[model] mean_formula: formula 'I(t**'"),
    ('kernel = "se"', 'kernel = "se"\nmean_formula = "nosuch"', "[model] mean_formula: formula 'nosuch'"),
    ('c = [0.0, 0.002]', 'c = [0.002, 0.0]', "candidate 'quadratic_loss': theta 'c': bounds must be finite"),
    ('gamma = [-0.5, 0.5]', 'gamma = [-0.5, 0.5]\nk = [0.0, 1.0]',
     "candidate 'humid_convection': theta 'k' is the baseline's"),
    ('humidity = "humidity"', 'humidity = "nosuch"', "candidate 'humidity': formula 'nosuch'"),
    ('operator = "C(operator)"', 'operator = "C(operator"', "candidate 'operator': formula 'C(operator'"),
    ('inputs = ["t", "T0", "humidity"]', 'inputs = ["t", "T0", "nosuch"]',
     "candidate 'humid_convection': unknown input column(s) ['nosuch']"),
    ("[units]", "[design]\ncutoff = inf\n\n[units]", "[design] cutoff must be a positive number; got inf"),
    ("[units]", "[design]\nnroy_points = 10\n\n[units]", "[design] nroy_points must be at least 1000; got 10"),
])
def test_the_model_candidates_and_design_are_checked_before_any_compile(tmp_path, capsys, no_compile, command, old,
                                                                       new, message):
    config = copy_case(tmp_path)
    assert old in FULL_CONFIG
    config.write_text(FULL_CONFIG.replace(old, new, 1))
    code, err = cli([command, config, *(["--out", tmp_path / "out"] if command == "calibrate" else [])], capsys)
    line = error_line(err)
    assert code == 2 and str(config) in line and message in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("old, new, message", [
    ("[model]", "[model]\ncomponents = 0", "[model] components must be at least 1; got 0"),
    ("[model]", "[model]\ncomponents = -1", "[model] components must be at least 1; got -1"),
    ("[model]", "[model]\nvariance_share = 1.5", "[model] variance_share must lie in (0, 1]; got 1.5"),
    ("[model]", "[model]\nvariance_share = 0.0", "[model] variance_share must lie in (0, 1]; got 0.0"),
])
def test_a_vector_outputs_basis_is_checked_with_the_config(tmp_path, old, new, message):
    config = copy_case(tmp_path, CURVES)
    text = (CURVES / "config.toml").read_text()
    assert old in text
    config.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(config)
    assert str(err.value) == f"{config}: {message}"


def test_a_missing_output_is_named_before_the_units_that_use_it(tmp_path):
    """[units] named the output as 'no column of this config' before the output's own error."""
    config = copy_case(tmp_path)
    config.write_text(FULL_CONFIG.replace('output = "temperature"', 'output = "temprature"'))
    with pytest.raises(DataError, match=r"missing column\(s\) \['temprature'\]") as err:
        load_config(config)
    assert "[units]" not in str(err.value)


@pytest.mark.parametrize("old, new, message", [
    ('csv = "physical.csv"', 'csv = "nosuch.csv"', "[physical] csv: file not found: "),
    ('runs = "runs.csv"', 'runs = "nosuch.csv"', "[simulator] runs: file not found: "),
    ('kernel = "se"', 'kernel = "se"\nprogram = "nosuch.stan"', "[model] program: file not found: "),
])
def test_a_missing_file_names_the_config_and_its_key(tmp_path, old, new, message):
    config = copy_case(tmp_path)
    config.write_text(FULL_CONFIG.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_config(config)
    assert str(err.value).startswith(f"{config}: {message}"), err.value
    assert "Errno" not in str(err.value)


def test_a_candidate_the_baselines_mean_already_has_is_refused_by_gap_only(tmp_path, capsys, no_compile):
    """A formula candidate with no term beyond [model] mean_formula would fit
    the baseline again: `stancal gap` refuses it before compiling, while the
    other commands take the config (the winning term moved into the mean,
    its candidate left in place)."""
    config = copy_case(tmp_path)
    config.write_text(FULL_CONFIG.replace('kernel = "se"', 'kernel = "se"\nmean_formula = "humidity + t"', 1))
    assert load_config(config).model["mean_formula"] == "humidity + t"
    code, err = cli(["gap", config, "--out", tmp_path / "out"], capsys)
    line = error_line(err)
    assert code == 2 and str(config) in line, line
    assert "candidate 'humidity': formula 'humidity' adds no term to [model] mean_formula 'humidity + t'" in line, line
    assert not (tmp_path / "out").exists()


def test_a_gap_config_without_candidates_names_the_config_once(tmp_path, capsys):
    config = copy_case(tmp_path)
    config.write_text(FULL_CONFIG.split("[candidates]")[0])
    code, err = cli(["gap", config, "--out", tmp_path / "out"], capsys)
    assert code == 2 and error_line(err) == f"stancal: error: {config}: `stancal gap` needs a [candidates] section"
