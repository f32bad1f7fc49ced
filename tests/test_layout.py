"""The package's layout: docs/architecture.md lists every module, folders import only
from the folders before them in the flow, no module imports another's private
name, and nothing outside the registry names a program."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "stancal"
FLOW = ["problem", "numerics", "stan", "results", "fitting", "diagnosing", "designing", "reporting"]


def _modules() -> dict[str, Path]:
    return {".".join(p.relative_to(ROOT).with_suffix("").parts): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path) -> list[ast.ImportFrom]:
    """Module-level imports (function-level ones load late and are not part of the layering)."""
    tree = ast.parse(path.read_text())
    nodes = [n for n in tree.body if isinstance(n, ast.ImportFrom)]
    nodes += [n for block in tree.body if isinstance(block, ast.If) for n in block.body
              if isinstance(n, ast.ImportFrom)]
    return nodes


def test_the_architecture_page_lists_every_module():
    layout = (ROOT / "docs" / "architecture.md").read_text().split("## The package", 1)[1]
    missing = [name for name, path in _modules().items()
               if path.name != "__init__.py" and f"`{path.name}`" not in layout]
    assert not missing, f"docs/architecture.md's layout leaves out {missing}"


def test_folders_import_only_from_earlier_folders_and_no_private_names():
    upward, private = [], []
    for name, path in _modules().items():
        folder = name.split(".")[1] if name.count(".") >= 2 else None
        for node in _imports(path):
            target = (node.module or "").split(".")
            if target[0] != "stancal":
                continue
            if len(target) > 1 and folder in FLOW and target[1] in FLOW and \
                    FLOW.index(target[1]) > FLOW.index(folder):
                upward.append(f"{name} -> {node.module}")
            private += [f"{name} imports {node.module}.{a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not upward, upward
    assert not private, private


def test_no_module_outside_the_registry_names_a_program():
    from stancal.stan.registry import PROGRAMS

    names = "|".join(sorted(PROGRAMS, key=len, reverse=True))
    comparison = re.compile(rf"(==|!=|\bin\b|\bis\b)\s*\(?\s*[\"']({names})[\"']")
    found = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
             for path in PACKAGE.rglob("*.py") if path.name != "registry.py"
             for number, line in enumerate(path.read_text().splitlines(), 1) if comparison.search(line)]
    assert not found, found
