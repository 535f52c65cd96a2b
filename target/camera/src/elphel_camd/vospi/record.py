"""Recording a Lepton's VoSPI stream to a file that replays into the same frames.

The recording holds exactly the bytes the reader consumed (`VoSPIReader` ``record``), so
``elphel-camd --board lepton --vospi FILE`` reads the same frames from it, bit for bit.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from elphel_camd.vospi.reader import VoSPIReader
from elphel_camd.vospi.sources import MAX_CLOCK_HZ, ByteSource, open_source


def record_stream(
    path: str,
    out: Path,
    *,
    frames: int | None = None,
    seconds: float | None = None,
    clock_hz: int = MAX_CLOCK_HZ,
    timeout_s: float = 10.0,
    source: ByteSource | None = None,
) -> dict[str, Any]:
    """Record the stream of ``path`` into ``out`` until ``frames`` frames or ``seconds``.

    Parameters
    ----------
    path
        The spidev node (or file or FIFO) to record.
    out
        The recording to write.
    frames
        Stop after this many whole frames.
    seconds
        Stop after this long (the source's clock).
    clock_hz
        SPI clock for a spidev node.
    timeout_s
        Give up (`VoSPITimeoutError`) when no frame comes for this long.
    source
        A byte source to read instead of opening ``path``.

    Returns
    -------
    dict
        ``path``, ``out``, ``frames``, ``bytes``, ``seconds`` and the reader's counts
        (``resyncs``, ``crc_errors``).
    """
    if frames is None and seconds is None:
        raise ValueError("give frames or seconds (or both) to end the recording")
    byte_source = source if source is not None else open_source(path, clock_hz=clock_hz)
    started = time.monotonic()
    try:
        with out.open("wb") as f:
            reader = VoSPIReader(byte_source, record=f)
            try:
                _read_until(reader, frames=frames, seconds=seconds, timeout_s=timeout_s)
            finally:
                reader.close_record()
    finally:
        byte_source.close()
    return {
        "path": path,
        "out": str(out),
        "frames": reader.frames,
        "bytes": out.stat().st_size,
        "seconds": round(time.monotonic() - started, 3),
        "resyncs": reader.counts.resyncs,
        "crc_errors": reader.counts.crc_errors,
    }


def _read_until(
    reader: VoSPIReader, *, frames: int | None, seconds: float | None, timeout_s: float
) -> None:
    """Read whole frames until enough, or long enough, or the end of a file."""
    start_ns = reader.source.now_ns()
    while frames is None or reader.frames < frames:
        try:
            reader.read_frame(timeout_s=timeout_s)
        except EOFError:
            return
        if seconds is not None and reader.source.now_ns() - start_ns >= seconds * 1e9:
            return
