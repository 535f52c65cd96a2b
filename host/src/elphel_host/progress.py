"""The progress line of long-running programs: a bar, the rate and the time left.

`ProgressLine` draws on a stream (stderr by default) one updating line with a rich bar
when the stream is a terminal, else one plain line per update. It is for programs' edges
only, the `elphel` CLI and the simulator's demo; library code reports progress through
callbacks and never draws.
"""

from __future__ import annotations

import io
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

BAR_WIDTH = 24


def format_rate(per_second: float, unit: str = "") -> str:
    """A rate for people: ``"1,470/s"``, ``"14.7 mm/s"``, ``"0.52/s"`` (3 digits, no exponent)."""
    if per_second >= 100:
        number = f"{per_second:,.0f}"
    elif per_second >= 10:
        number = f"{per_second:.1f}"
    else:
        number = f"{per_second:.2g}" if per_second < 0.01 else f"{per_second:.2f}".rstrip("0")
        number = number.rstrip(".")
    return f"{number} {unit}/s" if unit else f"{number}/s"


def _clock(seconds: float) -> str:
    m, sec = divmod(round(seconds), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class ProgressLine:
    """Progress of a long command on stderr: one updating line on a terminal, else a line each.

    Given ``done`` and ``total``, the line carries the rate and the time left; on a
    terminal, rich draws a bar before it. stdout stays for the result (one JSON object
    with --json), so progress never mixes with it.
    """

    def __init__(
        self, stream: TextIO | None = None, *, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._open = False
        self._clock = clock
        self._start: tuple[float, float] = (clock(), 0.0)

    def restart(self, done: float = 0.0) -> None:
        """Count the rate from now and from ``done`` (work resumed with ``done`` already done)."""
        self._start = (self._clock(), done)

    def rate_text(self, done: float, total: float, unit: str = "") -> str:
        """``"2/s, 0:04 left"``: the rate since the line was made (or `restart`).

        The time left is at that rate; the text is empty until something is done.
        """
        now = self._clock()
        if done < self._start[1]:
            self._start = (now, done)
        t0, d0 = self._start
        if now <= t0 or done <= d0:
            return ""
        rate = (done - d0) / (now - t0)
        return f"{format_rate(rate, unit)}, {_clock(max(total - done, 0) / rate)} left"

    def _bar(self, done: float, total: float) -> str:
        """The progress bar of rich, ``BAR_WIDTH`` cells, as terminal text (colours included)."""
        from rich.console import Console
        from rich.progress_bar import ProgressBar

        console = Console(
            file=io.StringIO(), force_terminal=True, color_system="standard", width=BAR_WIDTH
        )
        with console.capture() as captured:
            console.print(
                ProgressBar(total=total, completed=min(max(done, 0), total), width=BAR_WIDTH),
                end="",
            )
        return captured.get()

    def update(
        self,
        text: str,
        *,
        done: float | None = None,
        total: float | None = None,
        unit: str = "",
        detail: str = "",
    ) -> None:
        """Show ``text`` as the current state (replacing the previous one on a terminal).

        With ``done`` of ``total`` (``text`` names the counts, in ``unit`` if they are
        not a count of things), the rate and the time left follow it, and a terminal
        shows a bar before it. ``detail`` comes last, after the rate (e.g. the progress
        of one step of the counted whole).
        """
        if done is not None and total:
            rate = self.rate_text(done, total, unit)
            if rate:
                text = f"{text} ({rate})"
            if self.tty:
                text = f"{self._bar(done, total)} {text}"
        if detail:
            text = f"{text} · {detail}"
        if self.tty:
            self.stream.write(f"\r{text}\x1b[K")
            self._open = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    @contextmanager
    def ticking(self, text: str, *, every_s: float = 1.0) -> Iterator[None]:
        """Show ``text`` while the block runs: a step that reports nothing itself.

        A terminal redraws it every ``every_s`` with the seconds elapsed; a pipe gets
        ``text`` once. The line stays open for what comes next.
        """
        t0 = self._clock()
        self.update(text)
        if not self.tty:
            yield
            return
        stop = threading.Event()

        def tick() -> None:
            while not stop.wait(every_s):
                self.update(f"{text} ({self._clock() - t0:.0f} s)")

        thread = threading.Thread(target=tick, name="progress-tick", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    def end(self) -> None:
        """Finish the updating line (a no-op when not on a terminal)."""
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False

    def say(self, prefix: str) -> Callable[[str], None]:
        """A callback printing ``prefix + message`` as a line of its own."""

        def print_line(message: str) -> None:
            self.end()
            self.stream.write(f"{prefix}{message}\n")
            self.stream.flush()

        return print_line
