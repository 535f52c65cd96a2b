"""Atomic writes: a file (or a directory) appears whole or not at all.

Every writer of a burst manifest, a fused image, a DSI or a quad directory goes through
here, so a crash or Ctrl-C never leaves a half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


def partial_path(path: Path, *, keep_suffix: bool = False) -> Path:
    """The temporary name a file is written under before it is renamed into place.

    ``keep_suffix`` keeps the file's suffix last (``.fused.part.tif``), for writers that
    choose the format by it (tifffile, PIL).
    """
    if keep_suffix:
        return path.with_name(f".{path.stem}.part{path.suffix}")
    return path.with_name(f".{path.name}.part")


def _sync(path: Path) -> None:
    with open(path, "rb+") as f:
        os.fsync(f.fileno())


def write_atomic(path: str | Path, data: bytes, *, sync: bool = False) -> Path:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    path = Path(path)
    tmp = partial_path(path)
    with open(tmp, "wb") as f:
        f.write(data)
        if sync:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


@contextlib.contextmanager
def replacing(path: str | Path, *, sync: bool = False, keep_suffix: bool = False) -> Iterator[Path]:
    """Yield a temporary name to write ``path``'s content to; rename it into place on success.

    On an exception the temporary file is removed and ``path`` is left as it was.
    ``sync``: the file is on disk before the rename makes it visible; ``keep_suffix`` as
    for :func:`partial_path`.
    """
    path = Path(path)
    tmp = partial_path(path, keep_suffix=keep_suffix)
    try:
        yield tmp
        if sync and tmp.is_file():
            _sync(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            if tmp.is_dir():
                shutil.rmtree(tmp)
            else:
                tmp.unlink()


def _umask() -> int:
    """The process's umask (read by setting it and putting it back at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def replacing_directory(path: str | Path) -> Iterator[Path]:
    """Yield a new empty directory beside ``path``; on success it replaces ``path`` by a rename.

    Whatever stands at ``path`` (a directory, a file, a link) is set aside first and removed
    once the new directory is in place, or put back if the rename fails. On an exception
    the temporary directory is removed and ``path`` is left as it was. Whether replacing is
    allowed is the caller's decision: check it inside the block (as late as possible).
    """
    target = Path(path)
    parent = target.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=parent))
    # mkdtemp makes the directory 0700; the result is an ordinary directory the lab
    # shares, so it gets the mode mkdir would give it under the process's umask.
    os.chmod(tmp, 0o777 & ~_umask())
    aside: Path | None = None
    try:
        yield tmp
        if target.exists() or target.is_symlink():
            aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.rename(target, aside / "old")
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if aside is not None and (aside / "old").exists() and not target.exists():
            os.rename(aside / "old", target)  # put the old one back
        raise
    finally:
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)
