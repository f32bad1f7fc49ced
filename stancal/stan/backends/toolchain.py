"""The C++ compiler that builds Stan programs: clang++ with a precompiled
Stan header when the machine has clang++, else g++ (Python's compiler).

clang's precompiled header, built with ``-fpch-instantiate-templates``,
carries the template instantiations of ``stan/model/model_header.hpp``, so
each program compiles only its own code (CmdStan does the same: Johnson,
"Use clang PCH template instantiation when available", stan-dev/cmdstan
PR #1346, 2021). g++'s precompiled header has no such option and saved 6 %
(docs/benchmarks.md). With its header, clang++ takes about half g++'s CPU
time per program; its programs sample about 12 % slower (the same draws):
a first result comes sooner, a long fit later, and STANCAL_CXX=g++ keeps g++.
The header is built once per machine, into the store of compiled modules,
named by everything that must match between it and the compiles that use
it: the whole command line (compiler, Python's flags, stancal's flags and
macros, httpstan's include folder), the compiler's version and the header's
time stamp (a reinstalled httpstan). A stale header is never reused: clang
refuses one, and CmdStan's users meet that often
(stan-dev/bridgestan issue #151).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

logger = logging.getLogger("stancal")

MODEL_HEADER = "stan/model/model_header.hpp"  # what every stanc-generated program includes first
# STANCAL_CXX names the compiler (a path, or g++ to keep Python's); unset, clang++ if found
COMPILER_VARIABLE = "STANCAL_CXX"


@dataclass(frozen=True)
class Toolchain:
    """How a batch of programs is compiled: the compiler (None: Python's,
    g++ here) and the precompiled header its compiles include (clang only)."""

    compiler: str | None = None
    pch: str | None = None

    def describe(self) -> str:
        if self.compiler is None:
            return "g++"
        name = Path(self.compiler).name
        return f"{name} and a precompiled Stan header" if self.pch else name

    def extra_args(self) -> list[str]:
        """Added to a program's compile command."""
        return ["-include-pch", self.pch] if self.pch else []

    @contextlib.contextmanager
    def environment(self) -> Iterator[None]:
        """setuptools reads the compiler from CXX and LDCXXSHARED (both kept for Python's)."""
        if self.compiler is None:
            yield
            return
        wanted = {"CXX": self.compiler, "LDCXXSHARED": f"{self.compiler} -shared"}
        saved = {k: os.environ.get(k) for k in wanted}
        os.environ.update(wanted)
        try:
            yield
        finally:
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value


def wanted_compiler() -> str | None:
    """The compiler to use: $STANCAL_CXX, else clang++ if on the PATH; None
    for Python's (g++)."""
    named = os.environ.get(COMPILER_VARIABLE, "").strip()
    if named in ("g++", "gcc", "default"):
        return None
    found = shutil.which(named or "clang++")
    if named and found is None:
        logger.warning("%s=%s is not a compiler on the PATH; compiling with g++", COMPILER_VARIABLE, named)
    return found


def compiler_version(compiler: str) -> str:
    done = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=60)
    return done.stdout.strip()


def is_clang(compiler: str) -> bool:
    return "clang" in compiler_version(compiler).lower()


def python_compile_command(compiler: str | None) -> list[str]:
    """The command setuptools starts a C++ compile with (the compiler, then
    Python's CFLAGS and CCSHARED: ``-DNDEBUG -fno-strict-overflow -fPIC``...),
    read from setuptools itself so that the header is built with exactly the
    flags of the compiles that include it."""
    import setuptools  # noqa: F401  (first: it provides distutils)
    from setuptools._distutils.ccompiler import new_compiler
    from setuptools._distutils.sysconfig import customize_compiler

    with Toolchain(compiler).environment():
        built = new_compiler()
        customize_compiler(built)
    return list(built.compiler_so_cxx)


def header_command(compiler: str, macros: Sequence[tuple[str, str | None]], include: Path,
                   args: Sequence[str], output: Path) -> list[str]:
    """The command that precompiles the Stan header: a program's compile
    command (as setuptools composes it: the compiler's flags, macros, include
    folders, stancal's flags) with the header in place of the program."""
    defines = [f"-D{name}" if value is None else f"-D{name}={value}" for name, value in macros]
    return [*python_compile_command(compiler), *defines, f"-I{include}", *args,
            "-x", "c++-header", str(include / MODEL_HEADER),
            "-Xclang", "-fpch-instantiate-templates", "-o", str(output)]


def header_path(store: Path, command: Sequence[str], include: Path) -> Path:
    """Where the header built by ``command`` lives: named by the command
    (its output path left out), the compiler's version and the header's time stamp."""
    identity = [*command[:-1], compiler_version(command[0]), str((include / MODEL_HEADER).stat().st_mtime_ns)]
    return store / f"model_header-{hashlib.sha256(chr(0).join(identity).encode()).hexdigest()[:24]}.pch"


def precompiled_header(store: Path, compiler: str, macros: Sequence[tuple[str, str | None]],
                       include: Path, args: Sequence[str]) -> Path:
    """The precompiled Stan header for these flags, built into ``store`` unless
    there: under a lock (one process builds, the others wait) and atomically
    (a reader sees all of it or nothing)."""
    target = header_path(store, header_command(compiler, macros, include, args, Path("-")), include)
    if target.is_file():
        return target
    store.mkdir(parents=True, exist_ok=True)
    with open(target.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if target.is_file():
            return target
        logger.warning("Precompiling the Stan header with %s (once per machine, under a minute)", compiler)
        with tempfile.TemporaryDirectory(dir=store) as folder:
            staged = Path(folder) / target.name
            done = subprocess.run(header_command(compiler, macros, include, args, staged),
                                  capture_output=True, text=True)
            if done.returncode != 0:
                tail = "\n".join(done.stderr.strip().splitlines()[-10:])
                raise RuntimeError(f"precompiling the Stan header failed:\n{tail}")
            os.replace(staged, target)
    return target


def choose_toolchain(store: Path, macros: Sequence[tuple[str, str | None]], include: Path,
                     args: Sequence[str]) -> Toolchain:
    """clang++ with its precompiled header if the machine has clang++ (about
    half g++'s CPU time per program, docs/benchmarks.md), else Python's g++. A
    compiler that is not clang is used as it is; a clang whose header fails
    to build is left for g++, with a warning."""
    compiler = wanted_compiler()
    if compiler is None:
        return Toolchain()
    try:
        if not is_clang(compiler):
            return Toolchain(compiler)
        return Toolchain(compiler, str(precompiled_header(store, compiler, macros, include, args)))
    except (RuntimeError, OSError, subprocess.SubprocessError) as error:
        logger.warning("%s; compiling with g++ instead", error)
        return Toolchain()
