"""The compiler of Stan programs: clang++ with a precompiled Stan header that
matches the compiles using it, built once per set of flags; g++ otherwise.
A fake clang++ records its command lines, so no test here compiles C++."""

import json
import logging
import os
import stat
import sys
from pathlib import Path

from stancal.stan.backends import pystan_compile
from stancal.stan.backends.toolchain import Toolchain, choose_toolchain, precompiled_header

PROGRAM = "parameters { real x; }\nmodel { x ~ std_normal(); }\n"


def fake_compiler(folder: Path, fail_on: str = "") -> Path:
    """A 'clang++' that logs each command line and writes the file after -o
    (failing on a command that holds ``fail_on``)."""
    script = folder / "clang++"
    script.write_text(f"""#!{sys.executable}
import json, sys
args = sys.argv[1:]
if args == ["--version"]:
    print("clang version 14.0.6 (stancal's fake)"); sys.exit(0)
with open({str(folder / "calls.jsonl")!r}, "a") as log:
    log.write(json.dumps(args) + "\\n")
if {fail_on!r} and {fail_on!r} in args:
    print("fatal error: no", file=sys.stderr); sys.exit(1)
open(args[args.index("-o") + 1], "w").close()
""")
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return script


def calls(folder: Path) -> list[list[str]]:
    return [json.loads(line) for line in (folder / "calls.jsonl").read_text().splitlines()]


def flags(command: list[str]) -> list[str]:
    """What must agree between the header and a program's compile: macros,
    optimisation, language and code generation flags, in order."""
    return [a for a in command if a.startswith(("-D", "-U", "-O", "-std", "-f", "-g", "-m"))
            and a != "-fpch-instantiate-templates"]


def test_clang_compiles_with_a_header_built_with_the_same_flags(tmp_path, monkeypatch):
    """The program's compile command (as setuptools runs it) includes the
    precompiled header, and the header was built with the same macros and
    flags, Python's own (-DNDEBUG, -fPIC...) among them; clang refuses or
    mis-reads a header built otherwise."""
    monkeypatch.setenv("STANCAL_CXX", str(fake_compiler(tmp_path)))
    monkeypatch.setenv("STANCAL_CACHE", str(tmp_path / "store"))
    toolchain = pystan_compile.prepare_toolchain()
    assert toolchain.pch and Path(toolchain.pch).is_file() and toolchain.describe().startswith("clang++")
    (tmp_path / "build").mkdir()
    pystan_compile.build_module(PROGRAM, tmp_path / "build", toolchain)
    header, = [c for c in calls(tmp_path) if "c++-header" in c]
    program, = [c for c in calls(tmp_path) if "-c" in c]
    assert program[program.index("-include-pch") + 1] == toolchain.pch
    assert flags(program) == flags(header)
    assert "-DNDEBUG" in flags(header) and "-DSTAN_THREADS" in flags(header)
    assert header[-4:-2] == ["-Xclang", "-fpch-instantiate-templates"]
    assert len([c for c in calls(tmp_path) if "-shared" in c]) == 1  # linked by the same compiler
    assert not os.environ.get("CXX", "").endswith("clang++")  # put back after the build


def test_the_header_is_built_once_per_flags_and_header_version(tmp_path):
    """Asked again with the same flags, the stored header is reused; other
    flags, or a reinstalled httpstan (the header's time stamp), build another."""
    compiler = fake_compiler(tmp_path)
    include = tmp_path / "include"
    (include / "stan" / "model").mkdir(parents=True)
    (include / "stan" / "model" / "model_header.hpp").write_text("// Stan\n")
    macros, args = pystan_compile.STAN_MACROS, pystan_compile.COMPILE_ARGS
    first = precompiled_header(tmp_path / "store", str(compiler), macros, include, args)
    assert precompiled_header(tmp_path / "store", str(compiler), macros, include, args) == first
    assert len(calls(tmp_path)) == 1
    other = precompiled_header(tmp_path / "store", str(compiler), macros, include, ("-O2", *args[1:]))
    assert other != first and other.is_file() and len(calls(tmp_path)) == 2
    os.utime(include / "stan" / "model" / "model_header.hpp", ns=(1, 1))
    assert precompiled_header(tmp_path / "store", str(compiler), macros, include, args) not in (first, other)
    assert not list((tmp_path / "store").glob("tmp*")), "staging folders are removed"


def test_g_plus_plus_when_clang_is_absent_asked_against_or_broken(tmp_path, monkeypatch, caplog):
    """Without clang++ on the PATH, or with STANCAL_CXX=g++, Python's
    compiler builds as before; a clang++ that cannot build the header is
    left for g++ with a warning."""
    store, include = tmp_path / "store", pystan_compile.httpstan_include()
    macros, args = pystan_compile.STAN_MACROS, pystan_compile.COMPILE_ARGS
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.delenv("STANCAL_CXX", raising=False)
    assert choose_toolchain(store, macros, include, args) == Toolchain()
    monkeypatch.setenv("STANCAL_CXX", "g++")
    assert choose_toolchain(store, macros, include, args) == Toolchain()
    monkeypatch.setenv("STANCAL_CXX", "clang++-99")
    with caplog.at_level(logging.WARNING, logger="stancal"):
        assert choose_toolchain(store, macros, include, args) == Toolchain()
    assert "STANCAL_CXX=clang++-99 is not a compiler on the PATH" in caplog.text
    assert Toolchain().extra_args() == [] and Toolchain().describe() == "g++"
    monkeypatch.setenv("STANCAL_CXX", str(fake_compiler(tmp_path, fail_on="c++-header")))
    with caplog.at_level(logging.WARNING, logger="stancal"):
        assert choose_toolchain(store, macros, include, args) == Toolchain()
    assert "precompiling the Stan header failed" in caplog.text and "compiling with g++ instead" in caplog.text
