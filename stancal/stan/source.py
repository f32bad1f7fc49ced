"""Resolve ``#include`` in Stan programs, exactly as stanc does, and map
lines of the flattened program back to the files they came from.

PyStan takes a program as one string, so stancal flattens it for PyStan; the
same flat text is compiled by cmdstanpy too, so both backends run identical
code and compile errors are mapped back to the user's file in one place.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

_INCLUDE = re.compile(r"^\s*#include\s+[<\"]?([^>\"\s]+)[>\"]?\s*$")
_LINE_REFERENCE = re.compile(r"line (\d+)")
_TEMPORARY_FILE = re.compile(r"in '[^']*(?:string|\.stan)', (?=line)")


class StanProgramError(ValueError):
    """A Stan program that cannot be read, flattened or compiled."""


def shipped_models_dir() -> Path:
    """The ``stan_models`` folder shipped with stancal."""
    source_tree = Path(__file__).resolve().parents[2] / "stan_models"
    if source_tree.is_dir():
        return source_tree
    return Path(str(resources.files("stancal.stan_models")))


@dataclass(frozen=True)
class FlatProgram:
    """A Stan program with every ``#include`` resolved."""

    code: str
    # origin[i] is (file, line) of line i + 1 of ``code``
    origin: tuple[tuple[str, int], ...]

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.code.encode()).hexdigest()[:16]

    def locate(self, flat_line: int) -> tuple[str, int] | None:
        if 1 <= flat_line <= len(self.origin):
            return self.origin[flat_line - 1]
        return None

    def explain(self, message: str) -> str:
        """Rewrite 'line N' references of a stanc message as file:line."""

        def replace(match: re.Match[str]) -> str:
            where = self.locate(int(match.group(1)))
            if where is None:
                return match.group(0)
            return f"line {where[1]} of {where[0]}"

        # the flat program's temporary file name means nothing to the user
        message = _TEMPORARY_FILE.sub("at ", message)
        return _LINE_REFERENCE.sub(replace, message)

    def users_warnings(self, stanc_warnings: str) -> list[str]:
        """stanc's warnings that point into the user's own files, mapped to
        them. Those that point into the shipped programs are known, mostly
        pedantic-mode advice about stancal's own modelling choices."""
        shipped = str(shipped_models_dir())
        blocks = re.split(r"\n(?=Warning)", stanc_warnings.strip()) if stanc_warnings.strip() else []
        mapped = [self.explain(block) for block in blocks]
        return [block for block in mapped if not block.split("\n", 1)[0].count(shipped)]


def flatten(
    program: Path,
    include_dirs: list[Path] | None = None,
    aliases: dict[str, Path] | None = None,
) -> FlatProgram:
    """Inline every ``#include`` of ``program``.

    An include name is looked up first in ``aliases`` (how the user's
    simulator file becomes ``simulator.stan``), then next to the including
    file, then in ``include_dirs`` and the shipped ``functions`` folder.
    """
    aliases = aliases or {}
    search = [*(include_dirs or []), shipped_models_dir() / "functions"]
    lines: list[str] = []
    origin: list[tuple[str, int]] = []

    def resolve(name: str, including: Path) -> Path:
        if name in aliases:
            return aliases[name]
        for folder in [including.parent, *search]:
            candidate = folder / name
            if candidate.is_file():
                return candidate
        raise StanProgramError(
            f"{including}: '#include {name}' not found next to it or in "
            f"{', '.join(str(s) for s in search)}"
        )

    def visit(path: Path, stack: tuple[Path, ...]) -> None:
        resolved = path.resolve()
        if resolved in stack:
            chain = " -> ".join(str(p) for p in (*stack, resolved))
            raise StanProgramError(f"circular #include: {chain}")
        try:
            text = path.read_text()
        except OSError as err:
            raise StanProgramError(f"cannot read Stan file {path}: {err}") from err
        for number, line in enumerate(text.splitlines(), start=1):
            match = _INCLUDE.match(line)
            if match:
                visit(resolve(match.group(1), path), (*stack, resolved))
            else:
                lines.append(line)
                origin.append((str(path), number))

    visit(Path(program), ())
    return FlatProgram(code="\n".join(lines) + "\n", origin=tuple(origin))
