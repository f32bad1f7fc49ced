"""Compiling Stan programs for PyStan: once per machine, several at a time.

httpstan keys its cache by the program *and* the Python executable, so every
new virtual environment (every fresh clone) would compile every program
again, with g++'s debug information (``-g`` from Python's CFLAGS), which
costs a third of the time and most of the 90 MB of each module. stancal
builds the extension module itself, as httpstan.models.build_services_extension_module
does but without debug information, keeps a copy in a store shared by all
environments of this machine (keyed by program, httpstan and Python
version), and installs it into httpstan's cache on demand. The compiler is
clang++ with a precompiled Stan header where the machine has clang++, else g++
(toolchain.py); a module built by either is valid, so the store's key leaves
the compiler out.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import hashlib
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

from stancal.stan.backends.base import StanRuntimeError, cache_root
from stancal.stan.backends.toolchain import Toolchain, choose_toolchain
from stancal.stan.progress import ticking
from stancal.stan.source import FlatProgram, shipped_models_dir

logger = logging.getLogger("stancal")

# httpstan's own flags, and -g0: Python's CFLAGS add -g, which slows g++ by half
COMPILE_ARGS = ("-O3", "-std=c++17", "-Wno-sign-compare", "-g0")
STAN_MACROS = (
    ("BOOST_DISABLE_ASSERTS", None), ("BOOST_PHOENIX_NO_VARIADIC_EXPRESSION", None),
    ("STAN_THREADS", None), ("_REENTRANT", None), ("_GLIBCXX_USE_CXX11_ABI", "0"),
)


# httpstan.compile.compile gives stanc one second, which a busy machine exceeds
# (a stanc of koh_latent.stan took longer while two compiles ran beside it)
STANC_TIMEOUT_S = 300


def stanc_binary() -> Path:
    """The stanc that ships with httpstan (the Stan version PyStan runs)."""
    import httpstan

    return Path(httpstan.__file__).parent / "stanc"


def stanc(code: str, name: str) -> tuple[str, str]:
    """httpstan's stanc on ``code``: (C++ code, warnings), as
    httpstan.compile.compile gives them, with a timeout a loaded machine meets.
    Raises ValueError with stanc's message for a program with an error."""
    with tempfile.TemporaryDirectory(prefix="stancal_stanc_") as folder:
        path = Path(folder) / f"{name}.stan"
        path.write_text(code)
        done = subprocess.run([stanc_binary(), "--name", name, "--warn-pedantic", "--print-cpp", str(path)],
                              capture_output=True, timeout=STANC_TIMEOUT_S)
    stderr = done.stderr.decode().strip()
    if done.returncode != 0:
        raise ValueError(stderr)
    return done.stdout.decode().strip(), stderr


def store_directory() -> Path:
    """The machine's store of compiled modules ($STANCAL_CACHE, else the user cache)."""
    import httpstan

    tag = f"httpstan-{httpstan.__version__}-py{sys.version_info[0]}{sys.version_info[1]}"
    return cache_root() / "pystan" / tag


def stored_module(code: str) -> Path:
    key = hashlib.sha256("\0".join([code, *COMPILE_ARGS]).encode()).hexdigest()[:24]
    return store_directory() / f"{key}{EXTENSION_SUFFIXES[0]}"


def model_name(code: str) -> str:
    import httpstan.models

    return httpstan.models.calculate_model_name(code)


def is_compiled(code: str) -> bool:
    """httpstan's cache holds the program's module (so stan.build will not compile)."""
    import httpstan.cache

    try:
        folder = httpstan.cache.model_directory(model_name(code))
        return any(p.suffix in EXTENSION_SUFFIXES for p in folder.iterdir())
    except OSError:
        return False


def _shared_libraries() -> Path:
    """httpstan's shared libraries (TBB), copied into the store, so that a
    stored module still loads after the environment that built it is gone."""
    import httpstan

    target = store_directory() / "lib"
    if not target.is_dir():
        staging = Path(tempfile.mkdtemp(dir=store_directory()))
        for library in (Path(httpstan.__file__).parent / "lib").glob("*.so*"):
            shutil.copy2(library, staging)
        with contextlib.suppress(OSError):  # another process got there first
            staging.rename(target)
        shutil.rmtree(staging, ignore_errors=True)
    return target


PYTHONS_COMPILER = Toolchain()  # g++, as httpstan builds


def httpstan_include() -> Path:
    """httpstan's headers (Stan, Stan Math, Eigen, Boost)."""
    import httpstan

    return Path(httpstan.__file__).parent / "include"


def prepare_toolchain() -> Toolchain:
    """The compiler for this machine's builds, its precompiled header built
    into the store if it needs one (once per machine)."""
    return choose_toolchain(store_directory(), STAN_MACROS, httpstan_include(), COMPILE_ARGS)


def build_module(code: str, folder: Path, toolchain: Toolchain = PYTHONS_COMPILER,
                 compile_args: tuple[str, ...] = COMPILE_ARGS) -> Path:
    """Build the program's extension module into ``folder`` (a setuptools
    build, as httpstan does) with ``toolchain`` and return its path."""
    import httpstan
    import httpstan.build_ext
    import setuptools

    package = Path(httpstan.__file__).parent
    stan_name = f"model_{model_name(code).split('/')[1]}"
    cpp, _ = stanc(code, stan_name)
    source = folder / f"{stan_name}.cpp"
    source.write_text(cpp)
    libraries = ["sundials_cvodes", "sundials_idas", "sundials_nvecserial", "tbb"]
    if sys.platform == "darwin":  # pragma: no cover
        libraries += ["tbbmalloc", "tbbmalloc_proxy"]
    extension = setuptools.Extension(
        f"stan_services_{stan_name}", language="c++", sources=[str(source)],
        define_macros=list(STAN_MACROS), include_dirs=[str(folder), str(httpstan_include())],
        library_dirs=[str(package / "lib")], libraries=libraries,
        extra_compile_args=[*compile_args, *toolchain.extra_args()],
        extra_link_args=[f"-Wl,-rpath,{_shared_libraries()}", f"-Wl,-rpath,{package / 'lib'}"],
        extra_objects=[str(package / "stan_services.o")],
    )
    with toolchain.environment():
        httpstan.build_ext.run_build_ext([extension], str(folder))
    return next(p for p in folder.iterdir() if p.suffix in EXTENSION_SUFFIXES and p.name.startswith("stan_services"))


def _install(code: str, module: Path) -> None:
    """Put a built module where httpstan looks for the program. stanc's
    warnings are left out: stancal shows them itself, with the user's file
    and line (PyStanBackend.check), and holds back what stan.build prints."""
    import httpstan.cache

    name = model_name(code)
    httpstan.cache.delete_model_directory(name)
    folder = httpstan.cache.model_directory(name)
    folder.mkdir(parents=True)
    httpstan.cache.dump_stanc_warnings("", name)
    httpstan.cache.dump_services_extension_module_compiler_output("", name)
    target = folder / f"stan_services_model_{name.split('/')[1]}{EXTENSION_SUFFIXES[0]}"
    try:
        os.link(module, target)  # one copy on disk; either name may be deleted
    except OSError:  # another file system
        shutil.copy2(module, target)


def build_if_absent(code: str, toolchain: Toolchain = PYTHONS_COMPILER) -> bool:
    """Build the program's module into the store unless it is there; True if
    this process built it. Processes that ask at once (Dask workers, two
    commands) take a lock per program: one builds, the others wait and find
    it built."""
    stored = stored_module(code)
    if stored.is_file():
        return False
    stored.parent.mkdir(parents=True, exist_ok=True)
    with open(stored.parent / f"{stored.name.split('.')[0]}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if stored.is_file():
            return False
        logger.info("building %s", stored.name)
        with tempfile.TemporaryDirectory(dir=stored.parent) as folder:
            built = build_module(code, Path(folder), toolchain)
            os.replace(built, stored)  # atomic: a reader without the lock sees all or nothing
    return True


def use_private_httpstan_cache(folder: Path) -> None:
    """Give this process's httpstan a cache of its own. Processes that share
    one race: each deletes the fits that appeared while it sampled
    (_sampling_output), which may be another process's fit not read yet
    ("Fit ... not found"), and two fits with the same seed and data share
    one name. Modules still come from the machine's store, by hard link, so
    nothing is compiled again."""
    import httpstan.cache

    global _private_folder
    folder.mkdir(parents=True, exist_ok=True)
    httpstan.cache.cache_directory = lambda: folder  # httpstan looks it up at every use
    _private_folder = folder


def release_private_httpstan_cache(folder: Path) -> None:
    """Undo use_private_httpstan_cache when a process (a Dask worker) stops:
    its sampling processes would otherwise hold the exit back."""
    import httpstan.services_stub

    httpstan.services_stub.executor.shutdown(wait=False, cancel_futures=True)
    shutil.rmtree(folder, ignore_errors=True)


_private_folder: Path | None = None
_held_lock = None  # this process's lock on its folder, held until it exits


def _sweep_abandoned(root: Path) -> None:
    """Remove the folders of processes that died without cleaning up (killed,
    or out of memory): a folder whose lock no process holds."""
    for lock_path in root.glob("*.lock"):
        try:
            if time.time() - lock_path.stat().st_mtime < 60:
                continue  # perhaps made a moment ago, and not locked yet by its process
        except FileNotFoundError:
            continue  # another process swept it
        with open(lock_path, "a") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue  # its process is alive
            shutil.rmtree(lock_path.with_suffix(""), ignore_errors=True)
            lock_path.unlink(missing_ok=True)


def ensure_private_httpstan_cache() -> Path:
    """This process's own httpstan cache, made on first use, so that any
    number of stancal processes of one machine (commands, scripts, notebooks,
    Dask workers) sample side by side without touching each other's fits.
    The folder lives under the machine's cache, locked by this process while
    it runs, and is removed at exit (or by the next process, after a kill)."""
    global _held_lock
    if _private_folder is not None:
        return _private_folder
    root = cache_root() / "pystan" / "processes"
    root.mkdir(parents=True, exist_ok=True)
    _sweep_abandoned(root)
    folder = root / f"{os.getpid()}-{os.urandom(6).hex()}"
    _held_lock = open(folder.with_suffix(".lock"), "w")  # held for the process's life
    fcntl.flock(_held_lock, fcntl.LOCK_EX)
    use_private_httpstan_cache(folder)
    atexit.register(_remove_own_folder, folder, os.getpid())
    return folder


def _remove_own_folder(folder: Path, owner: int) -> None:
    if os.getpid() == owner:  # not in a forked child (httpstan's sampling processes)
        shutil.rmtree(folder, ignore_errors=True)
        folder.with_suffix(".lock").unlink(missing_ok=True)
        if _held_lock is not None:
            _held_lock.close()


@contextlib.contextmanager
def held_output(descriptors: bool = True):
    """Hold back what a build or a run prints: PyStan's stanc warnings about the flat
    program and its messages while sampling (print, sys.stderr) and, with
    ``descriptors``, g++'s pages of warnings (a subprocess writing to file
    descriptors 1 and 2). Shown only if it fails. Sampling holds Python's
    streams only, so that stancal's log lines (its progress among them) still
    reach the terminal while a fit runs."""
    with tempfile.TemporaryFile(mode="w+b") as held, \
            contextlib.redirect_stdout(io.StringIO()) as printed, contextlib.redirect_stderr(printed):
        fds = (1, 2) if descriptors else ()
        saved = [os.dup(fd) for fd in fds]
        try:
            for fd in fds:
                os.dup2(held.fileno(), fd)
            yield
        except Exception:
            for fd, copy in zip(fds, saved, strict=True):
                os.dup2(copy, fd)
            held.seek(0)
            tail = (printed.getvalue() + held.read().decode(errors="replace")).strip().splitlines()[-20:]
            if tail:
                logger.warning("before failing, it printed:\n%s", "\n".join(tail))
            raise
        finally:
            for fd, copy in zip(fds, saved, strict=True):
                os.dup2(copy, fd)
                os.close(copy)


def _compile_in_subprocess(program: FlatProgram, toolchain: Toolchain) -> bool:
    """One build into the store in its own Python process (its g++ output held back), so
    that several run side by side; a subprocess rather than multiprocessing,
    which would re-import the user's script in every worker. True if it built
    the program, False if another process had built it meanwhile."""
    script = ("import json, sys; from stancal.stan.backends.pystan_compile import build_if_absent; "
              "from stancal.stan.backends.toolchain import Toolchain; "
              "print(int(build_if_absent(sys.stdin.read(), Toolchain(**json.loads(sys.argv[1])))))")
    done = subprocess.run([sys.executable, "-c", script, json.dumps(toolchain.__dict__)], input=program.code,
                          capture_output=True, text=True)
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-20:])
        hint = "\n(to compile with g++ instead: STANCAL_CXX=g++)" if toolchain.compiler else ""
        raise StanRuntimeError(f"compiling {program_file(program)} with {toolchain.describe()} failed:\n{tail}{hint}")
    return done.stdout.strip().splitlines()[-1] == "1"


def program_file(program: FlatProgram) -> str:
    """The program's file name, for progress and messages, with the user's
    files it includes (a simulator): a gap's variants differ only there."""
    if not program.origin:
        return "the program"
    files = dict.fromkeys(Path(file) for file, _ in program.origin)
    main, *included = files
    shipped = shipped_models_dir().resolve()
    users = [path.name for path in included if not path.resolve().is_relative_to(shipped)]
    return f"{main.name} with {', '.join(users)}" if users else main.name


def compile_programs(programs: list[FlatProgram]) -> float:
    """Compile (or fetch from the store) the programs this process's httpstan
    cache lacks, one per core at a time. Another process compiling the same
    program at the same moment is waited for, not repeated. Returns the
    seconds spent building: 0.0 when every program was built earlier."""
    ensure_private_httpstan_cache()
    todo = {p.code: p for p in programs if not is_compiled(p.code)}
    if not todo:
        return 0.0
    building = [p for p in todo.values() if not stored_module(p.code).is_file()]
    workers = max(1, min(len(building), os.cpu_count() or 1))
    started = time.perf_counter()
    toolchain = prepare_toolchain() if building else Toolchain()
    if building:
        logger.warning("Compiling %d Stan program%s with PyStan and %s, %d at a time (%s); each takes one to "
                       "four minutes on a 2-core machine, once per machine.",
                       len(building), "s" if len(building) > 1 else "", toolchain.describe(), workers,
                       ", ".join(program_file(p) for p in building))
    names = [f"{program_file(p)} ({i + 1}/{len(building)})" for i, p in enumerate(building)]
    built = {}  # name -> True if this process built it, False if another did meanwhile
    with ticking(names) as ticker, ThreadPoolExecutor(max_workers=workers) as pool:  # a thread waits on a subprocess
        failed = threading.Event()  # after a failure, the programs still queued do not start

        def build_one(program: FlatProgram, name: str) -> bool | None:
            if failed.is_set():
                return None
            ticker.start(name)  # queued until a core is free
            try:
                return _compile_in_subprocess(program, toolchain)
            except BaseException:
                failed.set()
                ticker.failed(name)
                raise

        builds = {pool.submit(build_one, p, name): name for p, name in zip(building, names, strict=True)}
        for build in as_completed(builds):
            if (by_us := build.result()) is not None:  # a failure is raised here, once the running builds end
                built[builds[build]] = by_us
                ticker.done(builds[build])
    for code in todo:  # into this process's httpstan cache
        _install(code, stored_module(code))
    for whose, here in (("compiled", True), ("another process compiled", False)):
        which = [name for name, by_us in built.items() if by_us is here]
        if which:  # each one's own time is in its progress line
            logger.info("%s %s: %.0f s in all", whose, ", ".join(which), time.perf_counter() - started)
    return time.perf_counter() - started if building else 0.0
