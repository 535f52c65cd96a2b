"""Elphel recordings (JP4, JP46, JPEG frames) to the project's 16-bit TIFFs, quads and bursts.

`convert` decodes each frame (`elphel_host.camera.jp4`) and writes, under ``out``:

- ``files``: ``<stem>.tif`` per input, its capture metadata as JSON in ImageDescription
  (as an elphel-camd capture carries it);
- ``quad``: one quad directory ``<sec>_<usec>/`` per timestamp whose channels 0..3 are
  all there (``quad.json`` through `elphel_host.tp.io`, cam0..cam3 = channels 0..3);
- ``burst``: one burst directory ``channel<N>/`` per channel, frames in time order
  (``manifest.json`` through `elphel_host.burst.manifest`, frames ``frames/<stem>.tif``).

A bad file is reported with the reason and skipped; the others are converted. Every file
and directory appears whole or not at all (`elphel_host.fileio`), and a re-run skips
outputs that are complete, so an interrupted conversion loses nothing already written.
Frames are converted on every core (threads: the JPEG decoding and the NumPy steps
release the GIL).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from elphel_host.burst.manifest import MANIFEST as BURST_MANIFEST
from elphel_host.burst.manifest import FrameEntry, Manifest, write_manifest
from elphel_host.errors import ElphelError
from elphel_host.fileio import replacing_directory
from elphel_host.parallel import THREADS
from elphel_host.recordings.frames import (
    complete_tiff_metadata,
    read_recording,
    tiff_bytes,
    write_frame_tiff,
)
from elphel_host.recordings.names import Group, burst_groups, find_inputs, quad_groups
from elphel_host.tp.io import MANIFEST as QUAD_MANIFEST
from elphel_host.tp.io import QuadManifest, quad_cameras, write_quad_dir

LAYOUTS = ("files", "quad", "burst")
QUAD_POSITIONS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))
Progress = Callable[[int, int, str], None]
_CAMERA_FIELDS = ("port", "frame", "timestamp_ns", "recorded_file")


@dataclass(frozen=True)
class Converted:
    """A frame written (or found complete from an earlier run: ``skipped``)."""

    source: Path
    output: Path
    skipped: bool = False


@dataclass(frozen=True)
class Failure:
    """A frame not converted, and why (the message names the file)."""

    source: Path
    reason: str


@dataclass(frozen=True)
class ConvertResult:
    """What `convert` did: frames converted, frames that failed, directories made."""

    converted: tuple[Converted, ...]
    failed: tuple[Failure, ...]
    directories: tuple[Path, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "converted": [
                {"file": str(c.source), "output": str(c.output), "skipped": c.skipped}
                for c in self.converted
            ],
            "failed": [{"file": str(f.source), "error": f.reason} for f in self.failed],
            "directories": [str(d) for d in self.directories],
        }


def _failure(path: Path, e: Exception) -> Failure:
    text = str(e)
    return Failure(path, text if text.startswith(str(path)) else f"{path}: {text}")


def _convert_one(source: Path, target: Path) -> Converted | Failure:
    try:
        image, meta = read_recording(source)
        write_frame_tiff(target, image, meta)
    except (ElphelError, OSError) as e:
        return _failure(source, e)
    return Converted(source, target)


def _write_quad(group: Group, target: Path) -> list[Converted | Failure]:
    frames = []
    for path in group.files:
        try:
            frames.append(read_recording(path))
        except (ElphelError, OSError) as e:
            bad = _failure(path, e)
            others = [
                Failure(p, f"{p}: quad {group.name} not written: {path.name} failed")
                for p in group.files
                if p != path
            ]
            return [bad, *others]
    shapes = {image.shape for image, _ in frames}
    bayers = {meta.get("bayer") for _, meta in frames}
    if len(shapes) > 1 or len(bayers) > 1:
        what = (
            f"sizes {sorted(shapes)}"
            if len(shapes) > 1
            else f"Bayer order {sorted(map(str, bayers))}"
        )
        return [
            Failure(p, f"{p}: quad {group.name}: the cameras differ in {what}") for p in group.files
        ]
    manifest = QuadManifest(
        cameras=quad_cameras(
            QUAD_POSITIONS,
            [{k: meta[k] for k in _CAMERA_FIELDS if k in meta} for _, meta in frames],
        ),
        bayer=frames[0][1].get("bayer"),
        full_scale_dn=int(frames[0][1].get("full_scale_dn", 65535)),
    )
    with replacing_directory(target) as tmp:
        write_quad_dir(tmp, manifest, [tiff_bytes(image, meta) for image, meta in frames])
    return [
        Converted(p, target / cam.file)
        for p, cam in zip(group.files, manifest.cameras, strict=True)
    ]


def _burst_frame(source: Path, target: Path) -> tuple[Converted | Failure, dict[str, Any] | None]:
    meta = complete_tiff_metadata(target)
    if meta is not None:
        return Converted(source, target, skipped=True), meta
    try:
        image, meta = read_recording(source)
        write_frame_tiff(target, image, meta)
    except (ElphelError, OSError) as e:
        return _failure(source, e), None
    return Converted(source, target), meta


def _shape(key: tuple[Any, ...]) -> str:
    return f"bayer {key[0]}, {key[1]}x{key[2]}"


def _finish_burst(
    root: Path, group: Group, results: dict[Path, tuple[Converted | Failure, Any]]
) -> list[Converted | Failure]:
    outcomes: list[Converted | Failure] = []
    entries: list[FrameEntry] = []
    first: tuple[Any, ...] | None = None
    for path in group.files:
        outcome, meta = results[path]
        if isinstance(outcome, Failure):
            outcomes.append(outcome)
            continue
        key = (meta.get("bayer"), meta.get("WOI_WIDTH"), meta.get("WOI_HEIGHT"))
        first = first or key
        if key != first:  # a frame that does not fit the burst is not kept in it
            outcome.output.unlink(missing_ok=True)
            outcomes.append(
                Failure(path, f"{path}: {_shape(key)}; the burst's first frame: {_shape(first)}")
            )
            continue
        entries.append(
            FrameEntry(
                file=outcome.output.relative_to(root).as_posix(),
                frame=meta.get("frame"),
                timestamp_ns=meta.get("timestamp_ns"),
                index=len(entries),
                extra={"recorded_file": path.name},
            )
        )
        outcomes.append(outcome)
    if entries and first is not None:
        write_manifest(root, Manifest(frames=tuple(entries), bayer=first[0]))
    return outcomes


def _sort_outcome(
    outcome: Converted | Failure, done: list[Converted], failed: list[Failure]
) -> None:
    if isinstance(outcome, Failure):
        failed.append(outcome)
    else:
        done.append(outcome)


def _run(
    tasks: Sequence[tuple[str, Callable[[], Any]]], workers: int, progress: Progress | None
) -> list[Any]:
    """Run ``tasks`` (label, function) on ``workers`` threads; results in task order.

    On an interrupt (or an error) the tasks not started are cancelled and the ones
    running finish their (atomic) writes before it propagates.
    """
    results: list[Any] = [None] * len(tasks)
    pool = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        futures = {pool.submit(fn): i for i, (_, fn) in enumerate(tasks)}
        for done, future in enumerate(as_completed(futures), start=1):
            i = futures[future]
            results[i] = future.result()
            if progress is not None:
                progress(done, len(tasks), tasks[i][0])
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return results


def convert(
    paths: Iterable[str | Path],
    out: str | Path,
    *,
    layout: str = "files",
    workers: int | None = None,
    progress: Progress | None = None,
) -> ConvertResult:
    """Convert recorded frames to 16-bit TIFFs, quad directories or burst directories.

    Parameters
    ----------
    paths
        Frame files and directories of them (``.jp4``, ``.jp46``, ``.jpg``, ``.jpeg``).
    out
        Output directory (created).
    layout
        ``files`` (``<stem>.tif`` each), ``quad`` or ``burst`` (see the module).
    workers
        Threads (default: every core).
    progress
        Called as ``progress(done, total, name)`` after each frame or quad set.

    Returns
    -------
    ConvertResult
        Converted and failed frames (each failure names the file and the reason) and the
        directories made.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout={layout!r}; allowed: {', '.join(LAYOUTS)}")
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    inputs = find_inputs(paths)
    failed = [Failure(p, f"{p}: {why}") for p, why in inputs.missing]
    run = _Run(root, failed, THREADS if workers is None else workers, progress)
    if layout == "files":
        return _convert_files(inputs.files, run)
    grouping = quad_groups if layout == "quad" else burst_groups
    groups, rejected = grouping(inputs.files)
    failed += [Failure(p, f"{p}: {why}") for p, why in rejected]
    if layout == "quad":
        return _convert_quads(groups, run)
    return _convert_bursts(groups, run)


@dataclass(frozen=True)
class _Run:
    """Where a conversion writes, the failures it collects, its threads and progress."""

    root: Path
    failed: list[Failure]
    threads: int
    progress: Progress | None


def _convert_files(files: Sequence[Path], run: _Run) -> ConvertResult:
    root, failed, threads, progress = run.root, run.failed, run.threads, run.progress
    done: list[Converted] = []
    tasks: list[tuple[str, Callable[[], Any]]] = []
    owner: dict[Path, Path] = {}
    for source in files:
        target = root / f"{source.stem}.tif"
        if target in owner:
            failed.append(
                Failure(source, f"{source}: its output {target} is also {owner[target]}'s")
            )
            continue
        owner[target] = source
        if complete_tiff_metadata(target) is not None:
            done.append(Converted(source, target, skipped=True))
            continue
        tasks.append((source.name, functools.partial(_convert_one, source, target)))
    for outcome in _run(tasks, threads, progress):
        _sort_outcome(outcome, done, failed)
    return ConvertResult(tuple(done), tuple(failed))


def _convert_quads(groups: Sequence[Group], run: _Run) -> ConvertResult:
    root, failed, threads, progress = run.root, run.failed, run.threads, run.progress
    done: list[Converted] = []
    tasks: list[tuple[str, Callable[[], Any]]] = []
    dirs: list[Path] = []
    for group in groups:
        target = root / group.name
        if (target / QUAD_MANIFEST).is_file():
            done += [
                Converted(p, target / f"cam{i}.tif", skipped=True)
                for i, p in enumerate(group.files)
            ]
            dirs.append(target)
            continue
        tasks.append((group.name, functools.partial(_write_quad, group, target)))
    for (_, _), outcomes in zip(tasks, _run(tasks, threads, progress), strict=True):
        for outcome in outcomes:
            _sort_outcome(outcome, done, failed)
        if outcomes and isinstance(outcomes[0], Converted):
            dirs.append(outcomes[0].output.parent)
    return ConvertResult(tuple(done), tuple(failed), tuple(sorted(dirs)))


def _convert_bursts(groups: Sequence[Group], run: _Run) -> ConvertResult:
    root, failed, threads, progress = run.root, run.failed, run.threads, run.progress
    done: list[Converted] = []
    dirs: list[Path] = []
    tasks: list[tuple[str, Callable[[], Any]]] = []
    pending: list[Group] = []
    for group in groups:
        target = root / group.name
        if (target / BURST_MANIFEST).is_file():
            done += [
                Converted(p, target / "frames" / f"{p.stem}.tif", skipped=True) for p in group.files
            ]
            dirs.append(target)
            continue
        (target / "frames").mkdir(parents=True, exist_ok=True)
        pending.append(group)
        for p in group.files:
            frame = target / "frames" / f"{p.stem}.tif"
            tasks.append((p.name, functools.partial(_burst_frame, p, frame)))
    sources = [p for group in pending for p in group.files]
    results = dict(zip(sources, _run(tasks, threads, progress), strict=True))
    for group in pending:
        for outcome in _finish_burst(root / group.name, group, results):
            _sort_outcome(outcome, done, failed)
        if (root / group.name / BURST_MANIFEST).is_file():
            dirs.append(root / group.name)
    return ConvertResult(tuple(done), tuple(failed), tuple(sorted(dirs)))
