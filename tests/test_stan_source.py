import re

import pytest

from stancal.problem.codes import Kernel
from stancal.stan.registry import MODELS
from stancal.stan.source import StanProgramError, flatten, shipped_models_dir


def test_every_registered_program_flattens(tmp_path):
    simulator = tmp_path / "sim.stan"
    simulator.write_text("vector simulator(matrix X, vector theta) { return X[:, 1]; }\n")
    for spec in MODELS.values():
        flat = flatten(spec.path, aliases={"simulator.stan": simulator})
        assert "#include" not in flat.code
        assert ("simulator(matrix X" in flat.code) == spec.simulator


def test_includes_resolve_next_to_the_file_first(tmp_path):
    (tmp_path / "gp_kernels.stan").write_text("// my own kernels\n")
    program = tmp_path / "copy.stan"
    program.write_text("functions {\n#include gp_kernels.stan\n#include loo.stan\n}\n")
    flat = flatten(program)
    assert "// my own kernels" in flat.code
    assert "tuple(vector, vector) mvn_loo(" in flat.code


def test_origin_maps_flat_lines_back_to_files(tmp_path):
    sim = tmp_path / "mysim.stan"
    sim.write_text("// header\nvector simulator(matrix X, vector theta) {\n  return oops;\n}\n")
    flat = flatten(shipped_models_dir() / "koh.stan", aliases={"simulator.stan": sim})
    flat_line = flat.code.splitlines().index("  return oops;") + 1
    assert flat.locate(flat_line) == (str(sim), 3)
    message = flat.explain(f"Semantic error in 'string', line {flat_line}, column 9")
    assert f"line 3 of {sim}" in message


def test_missing_include_is_named(tmp_path):
    program = tmp_path / "p.stan"
    program.write_text("#include nowhere.stan\n")
    with pytest.raises(StanProgramError, match="'#include nowhere.stan' not found"):
        flatten(program)


def test_circular_include(tmp_path):
    (tmp_path / "a.stan").write_text("#include b.stan\n")
    (tmp_path / "b.stan").write_text("#include a.stan\n")
    with pytest.raises(StanProgramError, match="circular #include"):
        flatten(tmp_path / "a.stan")


# Every integer code the Python side passes to Stan: its data name, the
# Python codes, and the name the data line's comment gives each code.
def integer_codes():
    from stancal.problem.codes import NOISE_MODES, Censoring, Kernel, Likelihood, Noise
    from stancal.problem.options import DISCREPANCIES

    discrepancy_forms = {code: name for name, code in DISCREPANCIES.items() if name != "none"}
    return {
        "kernel_id": {k.value: k.name for k in Kernel},
        "likelihood_id": {k.value: k.name for k in Likelihood},
        "censoring": {k.value: k.name for k in Censoring},
        "discrepancy_form": discrepancy_forms,
        "noise_mode": {code: name for name, code in NOISE_MODES.items()},
        "noise_id": {k.value: k.name for k in Noise},
    }


# how a data line's comment names each code, for the Python name
COMMENT_NAMES = {
    "SE": "squared exponential", "MATERN52": "Matern 5/2", "GAUSSIAN": "gaussian", "POISSON": "poisson",
    "NEGBINOMIAL": "negbinomial", "BINOMIAL": "binomial", "OBSERVED": "observed", "LEFT": "left",
    "RIGHT": "right", "INTERVAL": "interval", "gp": "GP", "orthogonal": "orthogonal GP",
    "scaled": "scaled GP", "known": "known per value", "one": "one sd", "per_experiment": "one per experiment",
    "IID": "iid", "PER_SOURCE": "per_source", "STUDENT_T": "student_t",
    "HETEROSCEDASTIC": "heteroscedastic",
}
_DECLARATION = re.compile(
    r"^\s*(?:array\[[^\]]*\]\s*)?int<lower=(-?\d+),\s*upper=(-?\d+)>\s+(\w+);\s*//(.*)$")
_COMPARISON = re.compile(r"\b(\w+)(?:\[\w+\])?\s*(==|!=|<=|>=|<|>)\s*(\d+)\b")


def flat_programs(tmp_path):
    simulator = tmp_path / "sim.stan"
    simulator.write_text("// simulator\n")
    programs = sorted(shipped_models_dir().glob("*.stan"))
    assert len(programs) == 10
    return {p.name: flatten(p, aliases={"simulator.stan": simulator}).code for p in programs}


def data_block(code: str) -> str:
    start = code.index("\ndata {")
    return code[start : code.index("\n}", start)]


def test_integer_code_declarations_agree_with_python(tmp_path):
    codes = integer_codes()
    declared = dict.fromkeys(codes, 0)
    for program, code in flat_programs(tmp_path).items():
        for line in data_block(code).splitlines():
            match = _DECLARATION.match(line)
            if not match or match.group(3) not in codes:
                continue
            lower, upper, name, comment = int(match.group(1)), int(match.group(2)), match.group(3), match.group(4)
            expected = codes[name]
            assert (lower, upper) == (min(expected), max(expected)), f"{program}: {name} bounds"
            assert set(expected) == set(range(lower, upper + 1)), f"{program}: {name} codes not contiguous"
            for value, python_name in expected.items():
                assert f"{value} = {COMMENT_NAMES[python_name]}" in comment, f"{program}: {name} = {value}"
            declared[name] += 1
        # every code a program declares is read from the data with its bounds
        for name in codes:
            if re.search(rf"\b{name}\b", data_block(code)):
                assert re.search(rf"int<lower=-?\d+,\s*upper=-?\d+>\s+{name};", data_block(code)), (
                    f"{program}: {name} declared without both bounds")
    # kernel_id in every program but modular_vector (squared exponential only), the others where used
    assert declared == {"kernel_id": 9, "likelihood_id": 2, "censoring": 2, "discrepancy_form": 1,
                        "noise_mode": 2, "noise_id": 3}


def test_integer_code_comparisons_use_python_codes(tmp_path):
    codes = integer_codes()
    texts = {p.name: p.read_text() for p in (shipped_models_dir() / "functions").glob("*.stan")}
    texts.update(flat_programs(tmp_path))
    compared = {name: set() for name in codes}
    for source, text in texts.items():
        for line in text.splitlines():
            for name, _, value in _COMPARISON.findall(line.split("//")[0]):
                if name in codes:
                    assert int(value) in codes[name], f"{source}: {name} compared with {value}: {line.strip()}"
                    compared[name].add(int(value))
    # the functions branch on each code they handle
    assert {Kernel.MATERN52.value} <= compared["kernel_id"]
    for name in ("likelihood_id", "censoring", "discrepancy_form", "noise_mode", "noise_id"):
        assert compared[name], name


def test_every_data_line_has_a_comment(tmp_path):
    # the flat program: declarations included into the data block (the PyStan normals) count too
    simulator = tmp_path / "sim.stan"
    simulator.write_text("// simulator\n")
    for spec in MODELS.values():
        text = flatten(spec.path, aliases={"simulator.stan": simulator}).code
        block = text[text.index("\ndata {") + 7 : text.index("\n}", text.index("\ndata {"))]
        for line in block.splitlines():
            if line.strip():
                assert "//" in line, f"{spec.stan_file}: data line without a comment: {line.strip()}"


def stanc_warnings(flat) -> str:
    from stancal.stan.backends.pystan_compile import stanc

    return stanc(flat.code, "stancal_check")[1]


def test_stanc_warnings_in_the_users_file_are_mapped_and_shipped_ones_left_out(tmp_path):
    sim = tmp_path / "halved.stan"
    sim.write_text("// a simulator with a classic slip: 1 / 2 is integer division, 0\n"
                   "vector simulator(matrix X, vector theta) {\n  return (1 / 2) * theta[1] * X[:, 1];\n}\n")
    flat = flatten(shipped_models_dir() / "koh.stan", aliases={"simulator.stan": sim})
    raw = stanc_warnings(flat)
    assert str(shipped_models_dir()) in flat.explain(raw)  # stanc's pedantic advice on stancal's own code
    shown = flat.users_warnings(raw)
    assert len(shown) == 1 and f"line 3 of {sim}" in shown[0] and "int division" in shown[0]
    assert "/tmp/httpstan_" not in shown[0]


def test_no_program_has_a_variable_used_before_it_is_assigned():
    sim = shipped_models_dir().parent / "case_studies" / "cooling" / "simulator.stan"
    for spec in MODELS.values():
        raw = stanc_warnings(flatten(spec.path, aliases={"simulator.stan": sim}))
        assert "may not have been assigned" not in raw, spec.name


def test_the_case_studies_programs_compile_without_a_warning_of_their_own():
    """What `stancal compile` prints of stanc's warnings on the shipped case
    studies' own simulators: nothing (a new user's first set-up shows it)."""
    from stancal.cli import config_programs
    from stancal.problem.config import load_config

    root = shipped_models_dir().parent / "case_studies"
    for config in sorted(root.glob("*/config.toml")):
        for flat in config_programs(load_config(config), all_methods=True):
            assert flat.users_warnings(stanc_warnings(flat)) == [], config
