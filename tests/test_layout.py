"""The house rules of the source tree, checked on every run.

- the command line is the edge: only CLI modules import CLI modules;
- private names stay private: no module imports a ``_name`` from another module;
- files stay readable: no source file over 400 lines, register tables excepted.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = [REPO / "host" / "src", REPO / "target" / "camera" / "src", REPO / "simulator" / "src"]
PACKAGES = ("elphel_host", "elphel_camd", "elphel_sim")
MAX_LINES = 400


def _modules() -> list[tuple[str, Path]]:
    found = []
    for src in SOURCES:
        for path in sorted(src.rglob("*.py")):
            parts = list(path.relative_to(src).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found.append((".".join(parts), path))
    return found


MODULES = _modules()


def _is_cli(module: str) -> bool:
    return any(part == "cli" or part.startswith("cli_") for part in module.split("."))


def _imports(path: Path, module: str) -> list[tuple[int, str, str | None]]:
    """(line, module imported from, name or None) for every import of our packages."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[tuple[int, str, str | None]] = []
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            out += [(node.lineno, base, alias.name) for alias in node.names]
    return [imp for imp in out if imp[1].split(".")[0] in PACKAGES]


def test_the_tree_has_modules() -> None:
    assert len(MODULES) > 50


@pytest.mark.parametrize(("module", "path"), MODULES, ids=[m for m, _ in MODULES])
def test_only_cli_modules_import_cli_modules(module: str, path: Path) -> None:
    if _is_cli(module):
        return
    bad = [
        f"{path.name}:{line} imports {base}{'.' + name if name else ''}"
        for line, base, name in _imports(path, module)
        if _is_cli(base) or (name is not None and _is_cli(f"{base}.{name}"))
    ]
    assert not bad, "library code must not import the command line: " + "; ".join(bad)


@pytest.mark.parametrize(("module", "path"), MODULES, ids=[m for m, _ in MODULES])
def test_no_private_names_imported_from_other_modules(module: str, path: Path) -> None:
    bad = []
    for line, base, name in _imports(path, module):
        parts = [*base.split("."), *([name] if name else [])]
        if any(p.startswith("_") and not p.startswith("__") for p in parts):
            bad.append(f"{path.name}:{line} imports {'.'.join(parts)}")
    assert not bad, "; ".join(bad)


def _is_register_table(path: Path) -> bool:
    return "registers" in path.stem or path.parent.name == "registers"


@pytest.mark.parametrize(("module", "path"), MODULES, ids=[m for m, _ in MODULES])
def test_source_files_stay_under_400_lines(module: str, path: Path) -> None:
    if _is_register_table(path):
        return
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_LINES, f"{path.relative_to(REPO)} has {lines} lines (at most {MAX_LINES})"
