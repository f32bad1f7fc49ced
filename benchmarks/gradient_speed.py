"""Seconds per gradient of one program built by two compilers: the modules
two stores hold for the same program (a store built by g++, one built by
clang++ with its precompiled header), timed in one process, interleaved,
at the same posterior draws, as a ratio to the first store's.

A fit's wall time mixes the gradient's cost with the number of leapfrog
steps, which differs between builds (their rounding differs, so their
chains do); the gradient's cost is what the compiler changes.

The program and data are a case study's: the script calibrates it briefly
(2 x (150 + 50), with the first store) to get the program, its data and
posterior draws, then loads both stores' modules of that program directly
(their file name is the store's key for the program) and times
``log_prob_grad`` at the draws.

    .venv/bin/python benchmarks/gradient_speed.py CONFIG --method koh \
        --baseline ~/.cache/stancal --other /work/clangstore [--repeats 5]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np


def captured_fit(config: str, method: str):
    """(program, Stan data, draws) of a short calibration of the config."""
    import stancal
    from stancal.problem.config import load_config
    from stancal.stan.backends.pystan_backend import PyStanBackend

    seen = {}
    original = PyStanBackend.sample

    def recording(self, program, data, **kwargs):
        output = original(self, program, data, **kwargs)
        seen.update(program=program, data=data, draws=output.draws)
        return output

    problem = load_config(config)
    PyStanBackend.sample = recording
    try:
        stancal.calibrate(problem.data, simulator=problem.simulator, method=method or problem.model.get("method"),
                          chains=2, warmup=150, draws=50, seed=1)
    finally:
        PyStanBackend.sample = original
    return seen["program"], seen["data"], seen["draws"]


def stored_module_file(store: Path, code: str) -> Path:
    from stancal.stan.backends import pystan_compile

    return store / "pystan" / pystan_compile.store_directory().name / pystan_compile.stored_module(code).name


def services(path: Path):
    spec = importlib.util.spec_from_file_location("stan_services", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def plain(data: dict) -> dict:
    """The data as the services functions take them: lists and numbers."""
    return json.loads(json.dumps(data, default=lambda v: np.asarray(v).tolist()))


def unconstrained_points(module, data: dict, draws: dict, count: int) -> list[list[float]]:
    chains, per_chain = next(iter(draws.values())).shape[:2]
    points = []
    for i in range(count):
        c, d = i % chains, (i // chains) % per_chain
        draw = {k: np.asarray(v[c, d]).tolist() for k, v in draws.items()}
        points.append(module.transform_inits(data, draw))
    return points


def seconds_per_gradient(module, data: dict, points: list[list[float]]) -> float:
    started = time.perf_counter()
    for point in points:
        module.log_prob_grad(data, point, True)
    return (time.perf_counter() - started) / len(points)


def compilers(path: Path) -> str:
    import subprocess

    comment = subprocess.run(["readelf", "-p", ".comment", str(path)], capture_output=True, text=True).stdout
    return "clang++" if "clang" in comment.lower() else "g++"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config")
    parser.add_argument("--method", default=None)
    parser.add_argument("--baseline", type=Path, required=True, help="STANCAL_CACHE of the baseline store")
    parser.add_argument("--other", type=Path, required=True, help="STANCAL_CACHE of the other store")
    parser.add_argument("--points", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    os.environ["STANCAL_CACHE"] = str(args.baseline.expanduser())
    program, data, draws = captured_fit(args.config, args.method)
    files = [stored_module_file(store.expanduser(), program.code) for store in (args.baseline, args.other)]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        sys.exit(f"no module for the program in {', '.join(missing)}")
    modules = [services(f) for f in files]
    data = plain(data)
    points = unconstrained_points(modules[0], data, draws, args.points)
    times: list[list[float]] = [[], []]
    for _ in range(args.repeats):
        for i, module in enumerate(modules):
            times[i].append(seconds_per_gradient(module, data, points))
    medians = [statistics.median(t) for t in times]
    for label, file, median in zip(("baseline", "other"), files, medians, strict=True):
        print(f"{label}: {compilers(file)} {file.name}: {median * 1e6:.1f} µs per gradient "
              f"(repeats {', '.join(f'{t * 1e6:.1f}' for t in times[0 if label == 'baseline' else 1])})")
    print(f"ratio other / baseline: {medians[1] / medians[0]:.3f}")


if __name__ == "__main__":
    main()
