"""The house rules of the source tree, checked on every run.

- the command line is the edge: only CLI modules import CLI modules;
- private names stay private: no module imports a ``_name`` from another module;
- functions stay readable: none over 80 lines, in the sources and the firmware;
- lines are laid out by the formatter: no ``fmt: skip`` packing.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = [REPO / "host" / "src", REPO / "target" / "camera" / "src", REPO / "simulator" / "src"]
PACKAGES = ("elphel_host", "elphel_camd", "elphel_sim")
MAX_FUNCTION_LINES = 80
FIRMWARE = REPO / "target" / "esp8266"


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


def _source_files() -> list[Path]:
    return [path for _, path in MODULES] + sorted(FIRMWARE.glob("*.py"))


SOURCE_FILES = _source_files()
_IDS = [str(path.relative_to(REPO)) for path in SOURCE_FILES]


def _long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    return [
        f"{path.relative_to(REPO)}:{node.lineno} {node.name} has {length} lines"
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and (length := (node.end_lineno or node.lineno) - node.lineno + 1) > MAX_FUNCTION_LINES
    ]


@pytest.mark.parametrize("path", SOURCE_FILES, ids=_IDS)
def test_functions_stay_under_80_lines(path: Path) -> None:
    long = _long_functions(path)
    assert not long, f"at most {MAX_FUNCTION_LINES} lines a function: " + "; ".join(long)


@pytest.mark.parametrize("path", SOURCE_FILES, ids=_IDS)
def test_no_formatter_packing(path: Path) -> None:
    marked = [n for n, line in enumerate(path.read_text().splitlines(), 1) if "fmt: skip" in line]
    assert not marked, f"{path.relative_to(REPO)} packs lines past the formatter at {marked}"
