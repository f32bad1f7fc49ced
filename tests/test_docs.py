"""The docs as a newcomer uses them: every Python and shell example in the
README and docs/ runs as written, on the shipped case studies; the config
files the docs show are the shipped ones; the site builds with
``mkdocs build --strict``; and the documented Python API holds
(``write_calibration(result, "some/new/folder")``).

An example is skipped only through a visible marker on the line before its
block, ``<!-- no-test: reason -->``, kept for the set-up commands that take
minutes (``./run demo``, ``./run tests``, ``./run docs``) and for commands
that start long-running services."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pytest

import stancal

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUNNABLE = {"python": "python", "bash": "bash", "sh": "bash"}
SKIP_MARKER = re.compile(r"<!--\s*no-test:\s*(?P<reason>.*?)\s*-->")
FENCE = re.compile(r"^(?P<indent>\s*)```(?P<lang>[\w+-]*)\s*$")
# the pages worth a newcomer's first minute: their examples run in the default test run
QUICK_START = {"README.md"}


@dataclass(frozen=True)
class Example:
    page: str
    line: int
    lang: str
    code: str
    skip: str | None

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def examples(path: Path) -> list[Example]:
    """The fenced blocks of one Markdown page, with the no-test reason of the
    line before each (indented blocks in lists are dedented)."""
    lines = path.read_text().splitlines()
    found, i = [], 0
    while i < len(lines):
        fence = FENCE.match(lines[i])
        if not fence or not fence["lang"]:
            i += 1
            continue
        indent, start = len(fence["indent"]), i
        end = next(j for j in range(i + 1, len(lines)) if lines[j].strip() == "```")
        before = next((lines[j] for j in range(start - 1, -1, -1) if lines[j].strip()), "")
        marker = SKIP_MARKER.search(before)
        code = "\n".join(line[indent:] for line in lines[start + 1:end]) + "\n"
        found.append(Example(str(path.relative_to(ROOT)), start + 1, fence["lang"], code,
                             marker["reason"] if marker else None))
        i = end + 1
    return found


ALL = [e for page in PAGES for e in examples(page)]
RUN = [e for e in ALL if e.lang in RUNNABLE]


def _params(blocks: list[Example]):
    return [pytest.param(e, id=e.id, marks=[] if e.page in QUICK_START else [pytest.mark.slow]) for e in blocks]


def _environment() -> dict[str, str]:
    """`stancal` and `python` on the PATH are the ones running the tests, and
    they import this checkout."""
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["PYTHONPATH"] = os.pathsep.join(p for p in [str(ROOT), env.get("PYTHONPATH", "")] if p)
    env["MPLBACKEND"] = "Agg"
    return env


def run_example(example: Example, folder: Path) -> subprocess.CompletedProcess:
    """One example in a fresh folder where `case_studies/` is the repository's."""
    (folder / "case_studies").symlink_to(ROOT / "case_studies")
    script = folder / ("example.py" if example.lang == "python" else "example.sh")
    script.write_text(example.code)
    command = [sys.executable, script.name] if example.lang == "python" else \
        ["bash", "-e", "-o", "pipefail", script.name]
    return subprocess.run(command, cwd=folder, env=_environment(), capture_output=True, text=True, timeout=900)


@pytest.mark.parametrize("example", _params(RUN))
def test_the_example_runs_as_written(example: Example, tmp_path: Path):
    if example.skip:
        pytest.skip(f"marked no-test in {example.id}: {example.skip}")
    done = run_example(example, tmp_path)
    assert done.returncode == 0, f"{example.id} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"


def test_examples_are_skipped_only_with_a_reason_and_only_a_few():
    skipped = [e for e in RUN if e.skip is not None]
    assert all(e.skip for e in skipped), [e.id for e in skipped if not e.skip]
    # the set-up commands, the site's build and the cluster's services: nothing that a test could run
    assert len(skipped) <= 6, [f"{e.id}: {e.skip}" for e in skipped]
    assert len(RUN) - len(skipped) >= 10, "the docs should show runnable examples"


def test_the_readme_starts_with_the_two_commands_and_stays_short():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    first = next(e for e in examples(ROOT / "README.md") if e.lang in RUNNABLE)
    assert first.code.split()[:2] == ["./run", "demo"] and "./run tests" in first.code


def test_config_blocks_parse_and_shown_files_are_the_shipped_ones():
    """A TOML block parses; a block whose first line names a shipped file
    (``# case_studies/...`` or ``// case_studies/...``) is that file, word for word."""
    for e in ALL:
        first, _, rest = e.code.partition("\n")
        named = re.fullmatch(r"(#|//)\s*(?P<path>[\w./-]+\.(toml|stan|csv))", first.strip())
        if named and (ROOT / named["path"]).exists():
            assert rest == (ROOT / named["path"]).read_text(), f"{e.id} differs from {named['path']}"
        if e.lang == "toml":
            try:
                tomllib.loads(e.code)
            except tomllib.TOMLDecodeError as err:
                raise AssertionError(f"{e.id}: {err}") from err


def test_the_site_builds_strictly(tmp_path: Path):
    pytest.importorskip("mkdocs", reason="mkdocs is in the docs extra: ./run docs installs it")
    pytest.importorskip("material", reason="mkdocs-material is in the docs extra: ./run docs installs it")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").exists()


def test_write_calibration_takes_a_string_and_makes_the_folder(tmp_path: Path, monkeypatch):
    """As the README writes it: a str path to a folder that does not exist
    yet, no list of warnings (the result's own sampler checks are listed)."""
    cooling = ROOT / "case_studies" / "cooling"
    data = stancal.CalibrationData(pd.read_csv(cooling / "physical.csv"), ["t", "T0"], "temperature",
                                   {"k": (0.01, 0.2)})
    # short on purpose: the sampler's warnings are what the report must list
    with pytest.warns(stancal.SamplerWarning):
        result = stancal.calibrate(data, simulator=cooling / "simulator.stan", chains=2, warmup=100, draws=100,
                                   seed=1)
    assert result.diagnostics.messages
    monkeypatch.chdir(tmp_path)
    summary = stancal.write_calibration(result, "some/new/folder")
    folder = tmp_path / "some" / "new" / "folder"
    assert {"summary.json", "summary.csv", "report.md", "theta.png"} <= {p.name for p in folder.iterdir()}
    assert summary["warnings"] == result.diagnostics.messages
    assert json.loads((folder / "summary.json").read_text())["warnings"] == result.diagnostics.messages
    assert stancal.write_calibration(result, folder / "quiet", [])["warnings"] == []
