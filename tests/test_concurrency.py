"""Stancal processes side by side on one machine (its own file: it compiles,
and runs apart from the session fits' worker group)."""

import os
import shutil
import subprocess
import sys

from conftest import COOLING


def test_commands_side_by_side_share_one_compile_and_lose_no_fit(tmp_path):
    """Three `stancal calibrate` commands on a program no cache holds, started
    at once with the same seed (so httpstan would give their fits one name):
    all three finish with the same draws, and exactly one of them compiles.
    Each process samples through an httpstan cache of its own, removed at exit."""
    shutil.copytree(COOLING, tmp_path / "cooling")
    store = tmp_path / "store"  # an empty machine store, and empty user caches: no cache holds the program
    environment = {**os.environ, "STANCAL_CACHE": str(store), "XDG_CACHE_HOME": str(tmp_path / "user_cache")}
    command = [sys.executable, "-m", "stancal.cli", "calibrate", str(tmp_path / "cooling" / "config.toml"),
               "--chains", "1", "--warmup", "150", "--draws", "100", "--seed", "5", "--backend", "pystan"]
    processes = [subprocess.Popen([*command, "--out", str(tmp_path / f"out{i}")], env=environment,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in range(3)]
    outputs = [p.communicate(timeout=1200) for p in processes]
    errors = [err for _, err in outputs]
    assert all(p.returncode == 0 for p in processes), [err[-2000:] for err in errors]
    compiled = [err.count("stancal: compiled ") for err in errors]
    waited = [err.count("another process compiled ") for err in errors]
    assert sorted(compiled) == [0, 0, 1] and sum(waited) <= 2, errors
    summaries = [(tmp_path / f"out{i}" / "summary.csv").read_text() for i in range(3)]
    assert summaries[0] == summaries[1] == summaries[2]  # one seed, one program: the same draws
    assert not list((store / "pystan" / "processes").glob("*")), "each process removes its httpstan cache"
