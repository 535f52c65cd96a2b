"""Paths a directory's manifest names, kept inside that directory.

A burst's ``manifest.json`` or a quad's ``quad.json`` names its files relative to its own
directory. A name that is absolute, climbs out with ``..``, or reaches a symbolic link
pointing elsewhere would make a reader open files the directory does not hold.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from elphel_host.errors import InputFormatError


def check_relative(name: object, *, where: str) -> str:
    """``name`` if it is a relative path without ``..``, else `InputFormatError` at ``where``."""
    if not isinstance(name, str) or not name:
        raise InputFormatError(f"{where}={name!r}; allowed: a relative path inside the directory")
    parts = PurePosixPath(name.replace("\\", "/")).parts
    if Path(name).is_absolute() or name.startswith(("/", "\\")) or ".." in parts:
        raise InputFormatError(f"{where}={name!r}; allowed: a path inside the directory")
    return name


def inside(root: Path, name: str, *, where: str) -> Path:
    """``root / name``, refused when it (through symbolic links too) leaves ``root``.

    Raises
    ------
    InputFormatError
        Naming ``where``, the name and where it leads.
    """
    check_relative(name, where=where)
    path = root / name
    real_root = root.resolve()
    target = path.resolve()
    if not target.is_relative_to(real_root):
        raise InputFormatError(
            f"{where}={name!r} leads to {target}, outside {real_root}; "
            "allowed: a file inside the directory (no links out of it)"
        )
    return path
