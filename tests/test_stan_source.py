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


def test_kernel_codes_agree_with_stan():
    text = (shipped_models_dir() / "functions" / "gp_kernels.stan").read_text()
    assert f"{Kernel.SE.value} = squared exponential" in text
    assert f"{Kernel.MATERN52.value} = Matern 5/2" in text
    assert f"kernel_id == {Kernel.MATERN52.value}" in text
    for name in ("koh.stan", "koh_emulator.stan", "modular.stan"):
        program = (shipped_models_dir() / name).read_text()
        assert f"{Kernel.SE.value} = squared exponential, {Kernel.MATERN52.value} = Matern 5/2" in program


def test_every_data_line_has_a_comment():
    for spec in MODELS.values():
        text = spec.path.read_text()
        block = text[text.index("\ndata {") + 7 : text.index("\n}", text.index("\ndata {"))]
        for line in block.splitlines():
            if line.strip():
                assert "//" in line, f"{spec.stan_file}: data line without a comment: {line.strip()}"


def stanc_warnings(flat) -> str:
    import httpstan.compile

    return httpstan.compile.compile(flat.code, "stancal_check")[1]


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
