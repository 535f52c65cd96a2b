"""What oelint-adv does not check in meta-elphel: licenses, syntax, files, versions, deps."""

from __future__ import annotations

import hashlib
import importlib.metadata
import inspect
import json
import re
import subprocess
import tomllib
from pathlib import Path

import pytest
from packaging.licenses import InvalidLicenseExpression, canonicalize_license_expression
from packaging.licenses._spdx import LICENSES
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

from elphel_camd.boards import board_factories
from elphel_camd.cli import build_parser
from tests.yocto.layer import (
    INIT_TEMPLATE,
    LAYER,
    OE_PATHS,
    REPO,
    UNIT_TEMPLATE,
    Recipe,
    camera_pyproject,
    daemon_recipe,
    documented_providers,
    documented_release,
    init_command,
    logical_lines,
    metadata_files,
    recipe_files,
    render_template,
    unit_exec_start,
)

RECIPES = recipe_files()
# Yocto's own keyword for software without a license to declare; not an SPDX id.
YOCTO_LICENSE_KEYWORDS = {"CLOSED"}


def _ids(paths: list[Path]) -> list[str]:
    return [str(p.relative_to(LAYER)) for p in paths]


def test_layer_conf_declares_collection_and_series() -> None:
    conf = Recipe.read(LAYER / "conf" / "layer.conf")
    (collection,) = conf.words("BBFILE_COLLECTIONS")
    assert conf.get(f"BBFILE_PATTERN_{collection}") == "^${LAYERDIR}/"
    assert int(conf.get(f"BBFILE_PRIORITY_{collection}")) > 0
    series = conf.words(f"LAYERSERIES_COMPAT_{collection}")
    # The current LTS and the series after it; the docs name the first.
    assert series == ["wrynose", "blacksail"]
    assert documented_release() == series[0]
    assert {"core", "openembedded-layer", "meta-python"} <= set(
        conf.words(f"LAYERDEPENDS_{collection}")
    )


def test_layer_has_every_kind_of_recipe_the_issue_asks_for() -> None:
    names = {p.name.split("_")[0].removesuffix(".bb") for p in RECIPES}
    assert {
        "elphel-camd",
        "python3-tifffile",
        "python3-pydantic-settings",
        "packagegroup-elphel-camd",
        "elphel-camd-image",
    } <= names


@pytest.mark.parametrize("path", RECIPES, ids=_ids(RECIPES))
def test_license_names_are_spdx(path: Path) -> None:
    license_expr = Recipe.read(path).get("LICENSE")
    for name in re.split(r"\s*[&|()]\s*", license_expr):
        if not name or name in YOCTO_LICENSE_KEYWORDS:
            continue
        info = LICENSES.get(name.lower())
        assert info is not None and info["id"] == name, f"{path.name}: {name} is not SPDX"
        assert not info["deprecated"], f"{path.name}: {name} is a deprecated SPDX id"
    spdx = re.sub(r"\s*&\s*", " AND ", re.sub(r"\s*\|\s*", " OR ", license_expr))
    if spdx not in YOCTO_LICENSE_KEYWORDS:
        try:
            assert canonicalize_license_expression(spdx) == spdx
        except InvalidLicenseExpression as e:
            pytest.fail(f"{path.name}: LICENSE {license_expr!r}: {e}")


OLD_OVERRIDE = re.compile(
    r"(?:^|[\s{])(?:[A-Z][A-Z0-9_]*|do_[a-z_]+)_(?:append|prepend|remove)\b"  # FOO_append
    r"|[A-Za-z0-9]_\$\{PN\}"  # RDEPENDS_${PN}
    r"|_(?:pn|class|virtclass)-[a-z]"  # FOO_pn-bar, FOO_class-native
    r"|^[A-Z][A-Z0-9_]*_(?:task|machine|arm|x86|qemuall|libc)-?[a-z0-9]*\s*[?:.+]?="
)


@pytest.mark.parametrize("path", metadata_files(), ids=_ids(metadata_files()))
def test_new_override_syntax_only(path: Path) -> None:
    for number, line in logical_lines(path.read_text()):
        code = line.split("#", 1)[0] if line.lstrip().startswith("#") else line
        assert not OLD_OVERRIDE.search(code), f"{path.name}:{number}: old override: {line}"


def test_old_override_pattern_catches_old_forms() -> None:
    for old in [
        'RDEPENDS_${PN} = "x"',
        'IMAGE_INSTALL_append = " x"',
        "do_install_append() {",
        'FILES_${PN}-dev += "x"',
        'DEPENDS_class-native = "x"',
        'SRC_URI_remove = "x"',
    ]:
        assert OLD_OVERRIDE.search(old), old
    for new in [
        'RDEPENDS:${PN} = "x"',
        'IMAGE_INSTALL:append = " x"',
        "do_install:append() {",
        'PYPI_PACKAGE = "pydantic_settings"',
        'ELPHEL_CAMD_CONFIG = "${sysconfdir}/elphel-camd/config.json"',
    ]:
        assert not OLD_OVERRIDE.search(new), new


def _files_path(recipe: Recipe) -> list[Path]:
    """BitBake's FILESPATH for the recipe: FILESEXTRAPATHS first, then BP/BPN/files."""
    here = recipe.path.parent
    extra = [
        Path(recipe.expand(d)).resolve()
        for d in recipe.values.get("FILESEXTRAPATHS:prepend", "").split(":")
        if d.strip()
    ]
    return [*extra, here / recipe.values.get("BP", ""), here / recipe.get("BPN"), here / "files"]


@pytest.mark.parametrize("path", RECIPES, ids=_ids(RECIPES))
def test_every_local_file_in_src_uri_exists(path: Path) -> None:
    recipe = Recipe.read(path)
    if "SRC_URI" not in recipe.values:
        return  # pypi class recipes, images and packagegroups fetch nothing local
    for item in recipe.words("SRC_URI"):
        if not item.startswith("file://"):
            continue
        name = item.removeprefix("file://").split(";", 1)[0]
        found = [d / name for d in _files_path(recipe) if (d / name).exists()]
        assert found, f"{path.name}: {item} is in none of {_files_path(recipe)}"


def test_daemon_source_is_the_camera_distribution() -> None:
    recipe = daemon_recipe()
    (camera,) = [d / "camera" for d in _files_path(recipe) if (d / "camera").is_dir()]
    assert (camera / "pyproject.toml").resolve() == (
        LAYER.parents[1] / "target" / "camera" / "pyproject.toml"
    )
    assert recipe.values["S"] == "${UNPACKDIR}/camera"
    assert camera_pyproject()["build-system"]["build-backend"] == "setuptools.build_meta"
    assert "python_setuptools_build_meta" in recipe.path.read_text()


def _license_checksums(recipe: Recipe) -> list[tuple[str, str]]:
    out = []
    for item in recipe.words("LIC_FILES_CHKSUM"):
        name, *params = item.removeprefix("file://").split(";")
        md5 = dict(p.split("=", 1) for p in params)["md5"]
        out.append((name, md5))
    return out


LICENSED = [
    p for p in RECIPES if "LIC_FILES_CHKSUM" in Recipe.read(p).values and p != daemon_recipe().path
]
APACHE_2_0_MD5 = "3b83ef96387f14655fc854ddc3c6bd57"  # apache.org's LICENSE-2.0.txt


def test_repository_license_is_the_unmodified_apache_2_0_text() -> None:
    text = (REPO / "LICENSE").read_bytes()
    assert hashlib.md5(text).hexdigest() == APACHE_2_0_MD5
    assert text.lstrip().startswith(b"Apache License\n                           Version 2.0")


def test_every_package_declares_the_repository_license() -> None:
    for folder in ("host", "simulator", "target/camera"):
        with open(REPO / folder / "pyproject.toml", "rb") as f:
            project = tomllib.load(f)
        assert project["project"]["license"] == "Apache-2.0", folder
        # SPDX license expressions in [project] need setuptools 77.
        (req,) = project["build-system"]["requires"]
        assert req == "setuptools>=77", folder


def test_daemon_recipe_license_checksum_matches_its_source_tree() -> None:
    recipe = daemon_recipe()
    assert recipe.get("LICENSE") == "Apache-2.0"
    # LIC_FILES_CHKSUM paths are relative to S, the daemon's folder target/camera.
    (item,) = _license_checksums(recipe)
    name, md5 = item
    source = REPO / "target" / "camera" / name
    assert source.read_bytes() == (REPO / "LICENSE").read_bytes()
    assert hashlib.md5(source.read_bytes()).hexdigest() == md5


@pytest.mark.parametrize("path", LICENSED, ids=_ids(LICENSED))
def test_license_checksum_matches_the_file(path: Path) -> None:
    recipe = Recipe.read(path)
    inherits = path.read_text()
    assert "inherit pypi" in inherits, "only PyPI sources are checked here; add a case"
    dist_name = recipe.values.get("PYPI_PACKAGE", recipe.get("BPN").removeprefix("python3-"))
    # The wheel carries the same LICENSE file as the sdist the recipe fetches.
    try:
        dist = importlib.metadata.distribution(dist_name)
    except importlib.metadata.PackageNotFoundError:
        pytest.skip(f"{dist_name} is not installed here, so its LICENSE cannot be read")
    if Version(dist.version) != Version(recipe.get("PV")):
        pytest.skip(f"{dist_name} {dist.version} is installed, the recipe has {recipe.get('PV')}")
    for name, md5 in _license_checksums(recipe):
        files = [f for f in dist.files or [] if f.name == Path(name).name and "dist-info" in str(f)]
        assert files, f"{dist_name}: no {name} in its dist-info"
        digest = hashlib.md5(files[0].locate().read_bytes()).hexdigest()
        assert digest == md5, f"{path.name}: {name} md5 is {digest}, recipe says {md5}"


def test_recipe_version_is_the_pyproject_version() -> None:
    assert daemon_recipe().get("PV") == camera_pyproject()["project"]["version"]


def test_third_party_recipes_name_their_home() -> None:
    for path in RECIPES:
        if path.name.startswith("python3-"):
            recipe = Recipe.read(path)
            assert recipe.get("HOMEPAGE").startswith("https://"), path.name
            assert re.fullmatch(r"[0-9a-f]{64}", recipe.flags[("SRC_URI", "sha256sum")])


def _expected_command() -> tuple[str, str, str]:
    """(installed console script, board, config path) as the recipe defines them."""
    recipe = daemon_recipe()
    (script,) = [
        name
        for name, target in camera_pyproject()["project"]["scripts"].items()
        if target == "elphel_camd.cli:main"
    ]
    return (
        f"{OE_PATHS['bindir']}/{script}",
        recipe.get("ELPHEL_CAMD_BOARD"),
        recipe.get("ELPHEL_CAMD_CONFIG"),
    )


def _check_command(argv: list[str]) -> None:
    script, board, config = _expected_command()
    assert argv[0] == script
    assert argv[1:] == ["--board", board, "--config", config]
    # The daemon's own parser reads exactly this: the board it knows, the config path.
    args = build_parser().parse_args(argv[1:])
    assert args.board == board
    assert str(args.config) == config


def test_systemd_unit_runs_the_console_script_with_the_config() -> None:
    unit = render_template(UNIT_TEMPLATE, daemon_recipe())
    assert "@" not in unit.split("ExecStart=", 1)[1].splitlines()[0]
    _check_command(unit_exec_start(unit))
    assert re.search(r"^User=elphel-camd$", unit, re.M)


def test_init_script_runs_the_same_command() -> None:
    script = render_template(INIT_TEMPLATE, daemon_recipe())
    assert not re.search(r"@[A-Z_]+@", script)
    _check_command(init_command(script))
    syntax = subprocess.run(["sh", "-n"], input=script, text=True, capture_output=True)
    assert syntax.returncode == 0, syntax.stderr


def test_config_file_is_installed_where_the_command_points_and_kept() -> None:
    recipe = daemon_recipe()
    _, board, config = _expected_command()
    install = recipe.path.read_text()
    assert "${UNPACKDIR}/config.json ${D}${ELPHEL_CAMD_CONFIG}" in install
    assert config in recipe.words("CONFFILES:${PN}")
    assert "/etc/default/elphel-camd" in recipe.words("CONFFILES:${PN}")
    shipped = json.loads((recipe.path.parent / "files" / "config.json").read_text())
    # cli.main passes the JSON object as keyword arguments to the board's factory.
    params = inspect.signature(board_factories()[board]).parameters
    assert set(shipped) <= set(params), f"{board} board takes {list(params)}"


def test_daemon_user_is_a_system_user_in_the_i2c_group() -> None:
    recipe = daemon_recipe()
    assert recipe.words("USERADD_PACKAGES") == [recipe.get("PN")]
    params = recipe.get("USERADD_PARAM:${PN}").split()
    assert params[-1] == "elphel-camd"
    assert "--system" in params
    assert params[params.index("--groups") + 1] == "i2c"
    assert "i2c" in recipe.get("GROUPADD_PARAM:${PN}").split()


def test_every_runtime_dependency_has_a_provider() -> None:
    recipe = daemon_recipe()
    rdepends = set(recipe.words("RDEPENDS:${PN}"))
    providers = documented_providers()
    release = documented_release()
    layer_recipes = {p.name.split("_")[0]: p for p in (LAYER / "recipes-devtools").rglob("*.bb")}
    requirements = [Requirement(r) for r in camera_pyproject()["project"]["dependencies"]]
    # The settings work adds pydantic-settings; the layer packages it ahead of that.
    requirements.append(Requirement("pydantic-settings>=2.0"))
    for req in requirements:
        package = f"python3-{canonicalize_name(req.name)}"
        assert package in rdepends, f"{package} missing from elphel-camd's RDEPENDS"
        assert package in providers, f"docs/deploy.md names no provider for {package}"
        row = providers[package]
        assert req.specifier.contains(row.version), f"{package} {row.version} vs {req}"
        if row.layer == "meta-elphel":
            assert package in layer_recipes, f"no recipe for {package} in the layer"
            assert layer_recipes[package].stem.split("_")[1] == row.version
        else:
            assert row.layer in {"meta-python", "openembedded-core"}, row
            assert package not in layer_recipes, f"{package} is both upstream and ours"
    assert release == "wrynose"
    # Everything else the recipe pulls in is either Python's own or documented.
    for package in rdepends - {f"python3-{canonicalize_name(r.name)}" for r in requirements}:
        assert package in {"python3-core", "python3-json", "python3-logging", "python3-threading"}
