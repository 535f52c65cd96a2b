"""Elphel recordings on disk: which files to convert and what their names say.

The camera's recorder names each frame ``<seconds>_<microseconds>_<channel>.jp4`` (the
frame's timestamp and its sensor port); imgsrv's downloads are named the same way, with
an ``elphelimg_`` prefix unless asked for ``timestamp_name``.
`find_inputs` expands files and directories into the frames to convert; `recorded_name`
reads a name; `quad_groups` and `burst_groups` group named frames into quad sets (one
timestamp, channels 0..3) and per-channel sequences.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

SUFFIXES = (".jp4", ".jp46", ".jpg", ".jpeg")
_NAME = re.compile(r"(?:elphelimg_)?(\d+)_(\d{1,6})_(\d+)")
QUAD_CHANNELS = (0, 1, 2, 3)


@dataclass(frozen=True)
class RecordedName:
    """What a recorder's file name says: the frame's timestamp and its channel (port)."""

    seconds: int
    microseconds: int
    channel: int

    @property
    def timestamp_ns(self) -> int:
        return self.seconds * 1_000_000_000 + self.microseconds * 1000

    @property
    def instant(self) -> str:
        """``<seconds>_<microseconds>`` as the recorder writes it: a quad directory's name."""
        return f"{self.seconds}_{self.microseconds:06d}"


def recorded_name(path: Path) -> RecordedName | None:
    """The timestamp and channel in ``[elphelimg_]<sec>_<usec>_<channel>.<ext>``, else None."""
    match = _NAME.fullmatch(path.stem)
    if match is None:
        return None
    sec, usec, channel = (int(g) for g in match.groups())
    return RecordedName(sec, usec, channel)


@dataclass(frozen=True)
class Inputs:
    """The frames found (in order, each once) and the paths that could not be used."""

    files: tuple[Path, ...]
    missing: tuple[tuple[Path, str], ...]


def find_inputs(paths: Iterable[str | Path]) -> Inputs:
    """Files named on the command line, and the frames in directories named there.

    A directory contributes its files ending in .jp4, .jp46, .jpg or .jpeg (any case,
    not recursing), sorted by name; a file is taken whatever its name. A path that does
    not exist is reported with the reason.
    """
    files: list[Path] = []
    missing: list[tuple[Path, str]] = []
    seen: set[Path] = set()
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = sorted(
                p for p in path.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES
            )
            if not found:
                missing.append((path, f"no {', '.join(SUFFIXES)} files in this directory"))
        elif path.is_file():
            found = [path]
        else:
            missing.append((path, "no such file or directory"))
            found = []
        for p in found:
            key = p.resolve()
            if key not in seen:
                seen.add(key)
                files.append(p)
    return Inputs(tuple(files), tuple(missing))


@dataclass(frozen=True)
class Group:
    """Frames that become one directory: a quad set (by channel) or a burst (by time)."""

    name: str
    files: tuple[Path, ...]


NOT_NAMED = (
    "not named [elphelimg_]<seconds>_<microseconds>_<channel> as Elphel's recorder and "
    "imgsrv name frames"
)


def _named(
    files: Sequence[Path],
) -> tuple[list[tuple[Path, RecordedName]], list[tuple[Path, str]]]:
    """The files named as the recorder names them, and the others with the reason."""
    named, rejected = [], []
    for path in files:
        name = recorded_name(path)
        if name is None:
            rejected.append((path, NOT_NAMED))
        else:
            named.append((path, name))
    return named, rejected


def quad_groups(files: Sequence[Path]) -> tuple[list[Group], list[tuple[Path, str]]]:
    """Quad sets: frames of one timestamp on channels 0..3, cam0..cam3 in channel order.

    Returns the complete groups (sorted by time) and, with the reason, the files that
    belong to none: unnamed files, a channel twice, an incomplete set.
    """
    by_instant: dict[tuple[int, int], dict[int, Path]] = {}
    named, rejected = _named(files)
    for path, name in named:
        channels = by_instant.setdefault((name.seconds, name.microseconds), {})
        if name.channel in channels:
            rejected.append((path, f"channel {name.channel} again (also {channels[name.channel]})"))
            continue
        channels[name.channel] = path
    groups = []
    for (sec, usec), channels in sorted(by_instant.items()):
        instant = f"{sec}_{usec:06d}"
        if sorted(channels) != list(QUAD_CHANNELS):
            reason = f"quad {instant} has channels {sorted(channels)}; a quad set needs 0, 1, 2, 3"
            rejected.extend((p, reason) for p in channels.values())
            continue
        groups.append(Group(instant, tuple(channels[c] for c in QUAD_CHANNELS)))
    return groups, rejected


def burst_groups(files: Sequence[Path]) -> tuple[list[Group], list[tuple[Path, str]]]:
    """One burst per channel (directory ``channel<N>``), frames in time order."""
    by_channel: dict[int, list[tuple[int, Path]]] = {}
    named, rejected = _named(files)
    for path, name in named:
        by_channel.setdefault(name.channel, []).append((name.timestamp_ns, path))
    groups = [
        Group(f"channel{channel}", tuple(p for _, p in sorted(frames)))
        for channel, frames in sorted(by_channel.items())
    ]
    return groups, rejected
