"""Read the meta-elphel layer the way the tests need: recipes, templates and docs.

A small reader of BitBake assignments, not BitBake: it joins continued lines, keeps
the last plain assignment of each variable (appends are joined on) and expands
``${VAR}`` from the recipe and from the oe-core defaults below. That is enough for the
layer's own recipes, which use no inline Python in the values the tests read.
"""

from __future__ import annotations

import re
import shlex
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LAYER = REPO / "yocto" / "meta-elphel"
CAMERA_PYPROJECT = REPO / "target" / "camera" / "pyproject.toml"
DEPLOY_DOC = REPO / "docs" / "deploy.md"
DAEMON_RECIPE_DIR = LAYER / "recipes-camera" / "elphel-camd"
UNIT_TEMPLATE = DAEMON_RECIPE_DIR / "files" / "elphel-camd.service"
INIT_TEMPLATE = DAEMON_RECIPE_DIR / "files" / "elphel-camd.init"

# oe-core's bitbake.conf values for the paths the layer uses (usrmerge, as on wrynose
# images with systemd; nonarch_base_libdir is /lib without it, which no test relies on).
OE_PATHS = {
    "prefix": "/usr",
    "bindir": "/usr/bin",
    "base_bindir": "/bin",
    "sysconfdir": "/etc",
    "nonarch_base_libdir": "/usr/lib",
    "systemd_system_unitdir": "/usr/lib/systemd/system",
}

_ASSIGN = re.compile(
    r"^(?P<name>[A-Za-z0-9_${}.:\-/+]+?)(?:\[(?P<flag>[^\]]+)\])?\s*"
    r"(?P<op>\?\?=|\?=|:=|\+=|=\+|\.=|=\.|=)\s*\"(?P<value>.*)\"\s*$"
)


def logical_lines(text: str) -> list[tuple[int, str]]:
    """Lines with backslash continuations joined, each with its first line number."""
    out: list[tuple[int, str]] = []
    buf = ""
    start = 0
    for number, raw in enumerate(text.splitlines(), 1):
        if not buf:
            start = number
        if raw.endswith("\\"):
            buf += raw[:-1] + " "
            continue
        out.append((start, buf + raw))
        buf = ""
    if buf:
        out.append((start, buf))
    return out


@dataclass
class Recipe:
    """The variables of one .bb or .conf file, by name (override suffix kept)."""

    path: Path
    values: dict[str, str] = field(default_factory=dict)
    flags: dict[tuple[str, str], str] = field(default_factory=dict)

    @classmethod
    def read(cls, path: Path) -> Recipe:
        recipe = cls(path)
        stem = path.stem
        if "_" in stem and path.suffix == ".bb":
            pn, pv = stem.split("_", 1)
            recipe.values.update(PN=pn, BPN=pn, PV=pv, BP=f"{pn}-{pv}")
        else:
            recipe.values.update(PN=stem, BPN=stem)
        recipe.values["THISDIR"] = str(path.parent)
        recipe.values.setdefault("UNPACKDIR", "${WORKDIR}/sources")
        for _, line in logical_lines(path.read_text()):
            m = _ASSIGN.match(line.strip())
            if not m:
                continue
            name, flag, op, value = m["name"], m["flag"], m["op"], m["value"]
            if flag:
                recipe.flags[(name, flag)] = value
                continue
            old = recipe.values.get(name)
            if op in ("?=", "??=") and old is not None:
                continue
            if op in ("+=", ".=") and old is not None:
                value = old + (" " if op == "+=" else "") + value
            elif op in ("=+", "=.") and old is not None:
                value = value + (" " if op == "=+" else "") + old
            recipe.values[name] = value
        return recipe

    def get(self, name: str) -> str:
        """The expanded value of a variable; KeyError when the recipe does not set it."""
        return self.expand(self.values[name])

    def words(self, name: str) -> list[str]:
        return self.get(name).split()

    def expand(self, value: str, depth: int = 0) -> str:
        if depth > 20:
            raise RecursionError(f"{self.path.name}: cannot expand {value!r}")

        def one(m: re.Match[str]) -> str:
            key = m[1]
            if key in self.values:
                return self.expand(self.values[key], depth + 1)
            if key in OE_PATHS:
                return OE_PATHS[key]
            return m[0]

        return re.sub(r"\$\{([A-Za-z0-9_:\-]+)\}", one, value)


def recipe_files() -> list[Path]:
    return sorted([*LAYER.rglob("*.bb"), *LAYER.rglob("*.bbappend")])


def metadata_files() -> list[Path]:
    """Every file BitBake parses in the layer: recipes, appends, classes, includes, confs."""
    kinds = ("*.bb", "*.bbappend", "*.bbclass", "*.inc", "*.conf")
    return sorted(p for kind in kinds for p in LAYER.rglob(kind))


def daemon_recipe() -> Recipe:
    (path,) = DAEMON_RECIPE_DIR.glob("elphel-camd_*.bb")
    return Recipe.read(path)


def camera_pyproject() -> dict:
    return tomllib.loads(CAMERA_PYPROJECT.read_text())


def render_template(path: Path, recipe: Recipe) -> str:
    """A unit or init script as do_install fills it in (the same four substitutions)."""
    text = path.read_text()
    for token, value in {
        "@BINDIR@": OE_PATHS["bindir"],
        "@SYSCONFDIR@": OE_PATHS["sysconfdir"],
        "@ELPHEL_CAMD_BOARD@": recipe.get("ELPHEL_CAMD_BOARD"),
        "@ELPHEL_CAMD_CONFIG@": recipe.get("ELPHEL_CAMD_CONFIG"),
    }.items():
        text = text.replace(token, value)
    return text


def unit_exec_start(unit_text: str) -> list[str]:
    (line,) = [x for x in unit_text.splitlines() if x.startswith("ExecStart=")]
    return shlex.split(line.removeprefix("ExecStart="))


def init_command(script_text: str) -> list[str]:
    """DAEMON followed by DAEMON_ARGS, as the init script assigns them."""
    found: dict[str, str] = {}
    for line in script_text.splitlines():
        m = re.match(r"^(DAEMON|DAEMON_ARGS)=(.*)$", line)
        if m:
            found[m[1]] = " ".join(shlex.split(m[2]))
    return [found["DAEMON"], *shlex.split(found["DAEMON_ARGS"])]


@dataclass(frozen=True)
class Provider:
    """One row of docs/deploy.md's dependency table."""

    distribution: str
    package: str
    layer: str
    version: str


def documented_release() -> str:
    m = re.search(r"^Supported release: \*\*(\w+)\*\*", DEPLOY_DOC.read_text(), re.M)
    assert m, "docs/deploy.md must name the supported release ('Supported release: **x**')"
    return m[1]


def documented_providers() -> dict[str, Provider]:
    """Yocto package name -> its row in the table under 'Where each runtime dependency'."""
    text = DEPLOY_DOC.read_text()
    section = text.split("### Where each runtime dependency comes from", 1)[1]
    rows: dict[str, Provider] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[1].startswith("python3-"):
            rows[cells[1]] = Provider(*cells)
        elif rows and not line.startswith("|"):
            break
    return rows
