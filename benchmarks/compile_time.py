"""Compile time of one Stan program by toolchain and optimisation level, and
the sampling speed of what each builds, as ratios against g++ -O3 (stancal's
build until clang++ was found faster) measured in the same run.

The program is the cooling case study's `koh` program (what `./run demo` and
`./run calibrate` compile first), built into a temporary store, so the
machine's store is neither used nor changed:

- g++ -O3 (the baseline), clang++ -O3, and clang++ -O3 with a precompiled
  Stan header (`-fpch-instantiate-templates`, CmdStan PR #1346), whose own
  build is timed apart (once per machine);
- clang++ with its header at -O2 and -O1.

Each build's wall time and CPU time (the compiler's user + system seconds:
the machine is shared, so CPU time is the steadier figure) are printed with
their ratios to g++ -O3. Then each module samples the cooling case (seed 1,
the same data), in its own process, the variants interleaved `--repeats`
times: θ's bulk ESS per wall second and per CPU second of the sampling
processes, and θ's posterior mean and sd against g++ -O3's (a clang build
must give the same posterior).

    .venv/bin/python benchmarks/compile_time.py [--repeats 2] [--chains 4] [--warmup 1000] [--draws 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

COOLING = ROOT / "case_studies" / "cooling" / "config.toml"


def children_cpu() -> float:
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def timed(action) -> tuple[object, float, float]:
    """``action()``, its wall seconds and its child processes' CPU seconds."""
    wall, cpu = time.perf_counter(), children_cpu()
    value = action()
    return value, time.perf_counter() - wall, children_cpu() - cpu


def cooling_program() -> str:
    from stancal.cli import config_programs
    from stancal.problem.config import load_config

    return config_programs(load_config(COOLING), False)[0].code


def variants(clang: str | None) -> list[tuple[str, bool, str | None, tuple[str, ...]]]:
    """(label, with a precompiled header, compiler (None: g++), flags)."""
    from stancal.stan.backends.pystan_compile import COMPILE_ARGS

    def level(flag: str) -> tuple[str, ...]:
        return (flag, *COMPILE_ARGS[1:])

    rows = [("g++ -O3", False, None, COMPILE_ARGS)]
    if clang:
        rows += [("clang++ -O3", False, clang, COMPILE_ARGS)]
        rows += [(f"clang++ {o} + header", True, clang, level(o)) for o in ("-O3", "-O2", "-O1")]
    return rows


def build_all(code: str, work: Path, clang: str | None, only: list[str]) -> tuple[list[dict], dict[str, Path]]:
    """Build every variant of ``code``; a row per build (and per header build)."""
    from stancal.stan.backends.pystan_compile import STAN_MACROS, build_module, httpstan_include, store_directory
    from stancal.stan.backends.toolchain import Toolchain, precompiled_header

    rows, modules = [], {}
    store_directory().mkdir(parents=True, exist_ok=True)
    for label, with_header, compiler, args in variants(clang):
        if only and label not in only and label != "g++ -O3":  # the baseline always
            continue
        pch = None
        if with_header:
            pch, wall, cpu = timed(lambda a=args: precompiled_header(store_directory(), clang, STAN_MACROS,
                                                                     httpstan_include(), a))
            rows.append({"build": f"header for {label.split(' + ')[0]}", "wall_s": wall, "cpu_s": cpu})
        folder = work / label.replace(" ", "_").replace("+", "")
        folder.mkdir()
        toolchain = Toolchain(compiler, str(pch) if pch else None)
        module, wall, cpu = timed(lambda f=folder, t=toolchain, a=args: build_module(code, f, t, a))
        modules[label] = module
        rows.append({"build": label, "wall_s": wall, "cpu_s": cpu})
        print(f"built {label}: {wall:.0f} s wall, {cpu:.0f} s CPU", file=sys.stderr, flush=True)
    base = next(r for r in rows if r["build"] == "g++ -O3")
    for row in rows:
        row["wall_ratio"] = row["wall_s"] / base["wall_s"]
        row["cpu_ratio"] = row["cpu_s"] / base["cpu_s"]
    return rows, modules


def sample_with(module: Path, args: argparse.Namespace) -> dict:
    """In this process (a fresh one per module): the cooling case sampled
    with ``module`` as its program's build."""
    import httpstan.services_stub

    import stancal
    from stancal.problem.config import load_config
    from stancal.stan.backends.pystan_compile import stored_module

    stored = stored_module(cooling_program())
    stored.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(module, stored)
    problem = load_config(COOLING)
    model = dict(problem.model)
    method = model.pop("method", None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the same fit for every build: its warnings are not what is measured
        result, wall, _ = timed(lambda: stancal.calibrate(
            problem.data, simulator=problem.simulator, method=method, chains=args.chains, warmup=args.warmup,
            draws=args.draws, seed=1, backend="pystan", **model))
        httpstan.services_stub.executor.shutdown(wait=True)  # its processes' CPU time is counted once they end
    if result.timing["compile_s"] > 5:
        raise RuntimeError("the program was compiled again: the module under test was not used")
    (name, theta), = result.theta_summary().items()
    return {"theta": name, "mean": theta["mean"], "sd": theta["sd"], "mcse": theta["sd"] / theta["ess_bulk"] ** 0.5,
            "ess_bulk": theta["ess_bulk"], "sample_s": result.timing["sample_s"],
            "cpu_s": children_cpu(), "divergences": result.diagnostics.divergences}


def sample_all(modules: dict[str, Path], args: argparse.Namespace, store: Path) -> list[dict]:
    """Each module sampled in its own process, the variants interleaved."""
    runs: dict[str, list[dict]] = {label: [] for label in modules}
    for _ in range(args.repeats):
        for label, module in modules.items():
            command = [sys.executable, __file__, "--sample", str(module), "--chains", str(args.chains),
                       "--warmup", str(args.warmup), "--draws", str(args.draws)]
            with tempfile.TemporaryDirectory(dir=store) as cache:
                environment = {**os.environ, "STANCAL_CACHE": cache, "XDG_CACHE_HOME": cache}
                done = subprocess.run(command, env=environment, capture_output=True, text=True, check=True)
            runs[label].append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(f"sampled {label}: {runs[label][-1]['sample_s']:.1f} s", file=sys.stderr, flush=True)
    base = runs["g++ -O3"][0]
    rows = []
    for label, done in runs.items():
        wall = statistics.median(r["sample_s"] for r in done)
        cpu = statistics.median(r["cpu_s"] for r in done)
        first = done[0]
        rows.append({"build": label, "sample_s": wall, "sample_cpu_s": cpu, "ess_bulk": first["ess_bulk"],
                     "ess_per_s": first["ess_bulk"] / wall, "ess_per_cpu_s": first["ess_bulk"] / cpu,
                     f"{first['theta']}_mean": first["mean"], f"{first['theta']}_sd": first["sd"],
                     "mean_diff_in_se": abs(first["mean"] - base["mean"]) / (first["mcse"] ** 2 + base["mcse"] ** 2)
                     ** 0.5,
                     "divergences": first["divergences"]})
    for row in rows:
        row["ess_per_s_ratio"] = row["ess_per_s"] / rows[0]["ess_per_s"]
        row["ess_per_cpu_s_ratio"] = row["ess_per_cpu_s"] / rows[0]["ess_per_cpu_s"]
    return rows


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--no-sampling", action="store_true")
    parser.add_argument("--variants", nargs="*", default=[], help="builds to measure besides g++ -O3, by label")
    parser.add_argument("--sample", type=Path, help=argparse.SUPPRESS)  # a child process: sample one module
    return parser.parse_args()


def main() -> None:
    args = arguments()
    if args.sample:
        print(json.dumps(sample_with(args.sample, args)))
        return
    from stancal.stan.backends.toolchain import is_clang

    clang = shutil.which("clang++")
    clang = clang if clang and is_clang(clang) else None
    with tempfile.TemporaryDirectory(prefix="stancal_compile_time_") as scratch:
        store = Path(scratch)
        os.environ["STANCAL_CACHE"] = str(store / "cache")  # a store of this run's own
        code = cooling_program()
        (store / "builds").mkdir()
        rows, modules = build_all(code, store / "builds", clang, args.variants)
        pd.options.display.float_format = "{:.2f}".format
        print("compiling the cooling koh program (ratios: to g++ -O3 in this run)")
        print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=".2f"))
        if args.no_sampling:
            return
        sampled = {k: v for k, v in modules.items() if k == "g++ -O3" or k.endswith("header")}
        print(f"\nsampling the cooling case, {args.chains} x ({args.warmup} + {args.draws}), seed 1, "
              f"median of {args.repeats}")
        print(pd.DataFrame(sample_all(sampled, args, store)).to_markdown(index=False, floatfmt=".3g"))


if __name__ == "__main__":
    main()
