"""write_design: the design folder made beside --out and renamed onto it,
so that a failure at any point leaves --out as it was (docs/design.md)."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import toy_data

from stancal.designing.loop import design, design_of
from stancal.reporting import design_report
from stancal.reporting.design_report import write_design


@pytest.fixture(scope="module")
def toy_design(toy_match):
    """design(toy_data(), 4, experiments=1, seed=2), on the shared history match."""
    return design_of(toy_match, 4, experiments=1, seed=2)


@pytest.fixture(scope="module")
def other_design():
    """Another seed: every file differs from toy_design's."""
    return design(toy_data(), 4, experiments=1, seed=3)


def contents(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def hidden(parent: Path) -> list[str]:
    return [p.name for p in parent.iterdir() if p.name.startswith(".")]


def test_a_failure_while_the_files_are_made_leaves_no_out_folder(tmp_path, monkeypatch, toy_design):
    def broken(*args, **kwargs):
        raise RuntimeError("the figure failed")

    monkeypatch.setattr(design_report, "plot_proposed_runs", broken)
    with pytest.raises(RuntimeError, match="the figure failed"):
        write_design(toy_design, tmp_path / "design")
    assert not (tmp_path / "design").exists() and not hidden(tmp_path)


def test_a_failure_while_the_files_are_moved_leaves_the_old_folder_whole(tmp_path, monkeypatch, toy_design,
                                                                         other_design):
    """The disk fills after one file has moved: a folder written file by
    file would be half this wave's, half the last's."""
    out = tmp_path / "design"
    write_design(toy_design, out)
    (out / "notes.txt").write_text("the user's own file")
    before = contents(out)
    moved = []

    def staged(path: Path) -> bool:  # the new folder, or a file in it (not the old one set aside)
        return any(p.name.startswith(".design.") and ".old." not in p.name for p in (path, path.parent))

    def filling(move):
        def move_or_fail(source, destination, *args, **kwargs):
            if staged(Path(source)):
                if moved or Path(source).is_dir():
                    raise OSError(28, "No space left on device")
                moved.append(source)
            return move(source, destination, *args, **kwargs)
        return move_or_fail

    monkeypatch.setattr(os, "replace", filling(os.replace))
    monkeypatch.setattr(os, "rename", filling(os.rename))
    with pytest.raises(OSError, match="No space left"):
        write_design(other_design, out)
    monkeypatch.undo()
    assert contents(out) == before and not hidden(tmp_path)


def test_a_new_wave_replaces_the_design_files_and_keeps_the_users(tmp_path, toy_design):
    out = tmp_path / "design"
    write_design(toy_design, out)
    assert (out / "next_experiments.csv").exists()
    mode = out.stat().st_mode
    (out / "notes.txt").write_text("the user's own file")
    write_design(replace(toy_design, next_experiments=None), out)
    assert (out / "notes.txt").read_text() == "the user's own file"
    assert not (out / "next_experiments.csv").exists() and (out / "next_runs.csv").exists()
    assert out.stat().st_mode == mode and not hidden(tmp_path)
