"""Stage client: commands, status, moves returning a status handle, re-connection."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from serial import SerialBase

from elphel_host.errors import (
    StageBusyError,
    StageCommandError,
    StageConnectionError,
    StageError,
    StageProtocolError,
    StageResetError,
    StageTimeout,
)
from elphel_host.limits import HostLimits
from elphel_host.shown import shown
from elphel_host.stage.protocol import (
    Reply,
    StageStatus,
    parse_reply,
    parse_status,
    raise_for,
    seal,
    unseal,
)
from elphel_host.stage.transport import LineLink, open_link

log = logging.getLogger(__name__)

BANNER_PREFIX = "# ELPHEL-STAGE"
STOP_BYTE = b"!"
NOMINAL_MM_PER_STEP = 0.008778
# Reply deadlines (s). CAL? may wait for two caliper frames; the others answer at once
# (a background caliper read can delay them by a few hundred ms).
REPLY_TIMEOUT_S = {"CAL?": 3.0, "CALZERO": 2.0}
DEFAULT_REPLY_TIMEOUT_S = 1.5


@dataclass(frozen=True)
class Identity:
    maker: str
    model: str
    serial: str
    firmware: str


class StageClient:
    """A connection to one stage board over a pyserial URL.

    Every command gets exactly one reply; idempotent commands are retried when the
    request or the reply was damaged on the link. Positions the client returns as
    measured come from the caliper, never from the step counter alone.
    """

    def __init__(
        self,
        url: str,
        *,
        retries: int = 4,
        open_timeout_s: float = 5.0,
        opener: Callable[[str], SerialBase] = open_link,
        reply_timeout_s: float | None = None,
    ) -> None:
        self.url = url
        # None: the per-command defaults for a real board; a simulator running faster
        # than real time can use a shorter deadline so a lost line costs less.
        self.reply_timeout_s = reply_timeout_s
        self.opener = opener
        self.retries = retries
        self.open_timeout_s = open_timeout_s
        self.boot_id: str | None = None
        self.resets_seen = 0
        self._lock = threading.RLock()
        self._link: LineLink | None = None
        self.connect()

    # ---- connection -----------------------------------------------------------------
    def connect(self) -> None:
        """Open the link and learn the board's boot id (raises StageResetError on a change)."""
        with self._lock:
            if self._link is not None:
                self._link.close()
            self._link = LineLink(
                self.opener(self.url),
                self.url,
                line_limit_bytes=HostLimits.from_env().stage_line_bytes,
            )
            self._link.drain(0.05)
            deadline = time.monotonic() + self.open_timeout_s
            while True:
                try:
                    boot = self.command("BOOT?")
                    break
                except (StageProtocolError, StageTimeout):
                    if time.monotonic() > deadline:
                        raise
            self._note_boot(_boot_id(boot))

    def _note_boot(self, boot_id: str) -> None:
        old, self.boot_id = self.boot_id, boot_id
        if old is not None and old != boot_id:
            self.resets_seen += 1
            raise StageResetError(
                f"stage board reset (boot id {old} -> {boot_id}); "
                "its step position is lost: home or re-sync from the caliper"
            )

    def reconnect(self, timeout_s: float = 10.0) -> None:
        """Re-open the link after a drop, retrying until `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.connect()
                return
            except StageConnectionError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def close(self) -> None:
        with self._lock:
            if self._link is not None:
                self._link.close()
                self._link = None

    def __enter__(self) -> StageClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def link(self) -> LineLink:
        if self._link is None:
            raise StageConnectionError(f"stage link {self.url!r} is closed")
        return self._link

    # ---- commands -------------------------------------------------------------------
    def _exchange(self, line: str, keyword: str, timeout_s: float) -> Reply | None:
        link = self.link
        link.drain()
        link.write_line(seal(line))
        deadline = time.monotonic() + timeout_s
        while True:
            raw = link.read_line(deadline)
            if raw is None:
                return None
            if raw.startswith(BANNER_PREFIX):
                boot = dict(item.partition("=")[::2] for item in raw.split()[3:])
                if "boot" in boot:
                    self._note_boot(boot["boot"])
                continue
            if raw.startswith("#"):
                log.info("stage: %s", raw)
                continue
            try:
                reply = parse_reply(unseal(raw))
            except StageProtocolError as e:
                if raw.startswith("err ? "):
                    return Reply("?", False, raw, 4)  # our line arrived damaged
                log.info("stage reply damaged: %s", e)
                return Reply("?", False, raw, -1)
            if reply.keyword == keyword:
                return reply
            log.info("stage: stale reply %r while waiting for %s", raw, keyword)

    def command(self, line: str, *, timeout_s: float | None = None, retry: bool = True) -> str:
        """Send one command line; return the ok payload or raise the mapped error."""
        keyword = line.split()[0].upper()
        timeout = (
            timeout_s
            or self.reply_timeout_s
            or REPLY_TIMEOUT_S.get(keyword, DEFAULT_REPLY_TIMEOUT_S)
        )
        attempts = self.retries + 1 if retry else 1
        last = ""
        with self._lock:
            for _ in range(attempts):
                reply = self._exchange(line, keyword, timeout)
                if reply is None:
                    last = f"no reply within {timeout} s"
                    continue
                if reply.keyword == "?":
                    last = f"damaged exchange ({reply.payload!r})"
                    continue
                raise_for(reply, line)
                return reply.payload
        if last.startswith("no reply"):
            raise StageTimeout(f"stage {self.url!r}: {line!r}: {last} after {attempts} attempt(s)")
        raise StageProtocolError(
            f"stage {self.url!r}: {line!r}: {last} after {attempts} attempt(s)"
        )

    def identify(self) -> Identity:
        fields = self.command("*IDN?").split(",")
        if len(fields) != 4:
            raise StageProtocolError(f"*IDN? answer {fields!r} does not have 4 fields")
        return Identity(*fields)

    def status(self) -> StageStatus:
        return parse_status(self.command("STATUS?"))

    def limits_steps(self) -> tuple[int, int]:
        lo, hi = self.command("LIM?").split()
        return int(lo), int(hi)

    def set_limits_steps(self, min_steps: int, max_steps: int) -> None:
        self.command(f"LIM {min_steps} {max_steps}")

    def speed(self) -> tuple[int, int]:
        hz, acc = self.command("SPEED?").split()
        return int(hz), int(acc)

    def set_speed(self, max_hz: int, accel_hz_per_s: int) -> None:
        self.command(f"SPEED {max_hz} {accel_hz_per_s}")

    def read_caliper_um(self) -> int:
        """A fresh confirmed caliper reading in micrometres (motor must be idle)."""
        um, _age = self.command("CAL?").split()
        return int(um)

    def read_caliper_mm(self) -> float:
        return self.read_caliper_um() / 1000.0

    def zero(self) -> None:
        """Make the current position step 0 (soft limits keep their physical place)."""
        self.command("ZERO")

    def zero_caliper(self) -> None:
        self.command("CALZERO")

    def caliper_power(self, on: bool) -> None:
        self.command(f"CALPWR {1 if on else 0}")

    def declare_position_steps(self, steps: int) -> None:
        self.command(f"POS {steps}")

    def stop(self) -> int:
        """Stop at once: the realtime stop byte, then STOP for a confirmed position."""
        with self._lock:
            with contextlib.suppress(StageConnectionError):
                self.link.write_raw(STOP_BYTE)
            return int(self.command("STOP"))

    # ---- motion ---------------------------------------------------------------------
    def move_to_steps(self, target_steps: int) -> MoveStatus:
        """Start a move to an absolute step position; return its status handle."""
        self.command(f"MOVE {int(target_steps)}")
        return MoveStatus(self, target_steps, kind="move")

    def move_by_steps(self, delta_steps: int) -> MoveStatus:
        """Relative move, sent as an absolute MOVE so a retried request cannot repeat it."""
        st = self.status()
        if st.moving:
            raise StageBusyError(
                f"stage is {st.state}; stop it before a relative move", code=8, keyword="MOVE"
            )
        return self.move_to_steps(st.steps + int(delta_steps))

    def home(self) -> MoveStatus:
        try:
            self.command("HOME")
        except StageBusyError:
            if self.status().state != "HOME":  # a retried HOME finds its own homing running
                raise
        return MoveStatus(self, 0, kind="home")


class MoveStatus:
    """Handle of a running move or homing: `done`, `wait(timeout)`, callbacks.

    Ctrl-C inside `wait` stops the stage before the KeyboardInterrupt propagates.
    """

    def __init__(
        self, client: StageClient, target_steps: int, *, kind: str, poll_s: float = 0.01
    ) -> None:
        self.client = client
        self.target_steps = target_steps
        self.kind = kind
        self.poll_s = poll_s
        self.final: StageStatus | None = None
        self.error: BaseException | None = None
        self._callbacks: list[Callable[[MoveStatus], None]] = []
        self.started = time.monotonic()

    def add_callback(self, fn: Callable[[MoveStatus], None]) -> None:
        """Call fn(self) once the move has finished (at once if it already has)."""
        if self.final is not None or self.error is not None:
            fn(self)
        else:
            self._callbacks.append(fn)

    def _finish(self, final: StageStatus | None, error: BaseException | None) -> None:
        self.final, self.error = final, error
        callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            fn(self)

    def _poll(self) -> bool:
        st = self.client.status()
        if st.moving:
            return False
        if st.state == "ALARM":
            from elphel_host.errors import StageAlarmError

            self._finish(
                st,
                StageAlarmError(
                    f"stage alarm {st.alarm} during {self.kind} "
                    f"at step {st.steps} (limits {st.limits})",
                    code=10,
                    keyword="STATUS?",
                ),
            )
        elif self.kind == "home" and not st.homed:
            self._finish(st, StageError("homing was interrupted; the stage is not homed"))
        elif self.kind == "move" and st.steps != self.target_steps:
            self._finish(
                st,
                StageError(f"move to step {self.target_steps} ended at step {st.steps} (stopped)"),
            )
        else:
            self._finish(st, None)
        return True

    @property
    def done(self) -> bool:
        if self.final is not None or self.error is not None:
            return True
        return self._poll()

    def wait(self, timeout: float | None = 60.0) -> StageStatus:
        """Block until the move ends; return the final status or raise its error."""
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            while not self.done:
                if deadline is not None and time.monotonic() > deadline:
                    raise StageTimeout(
                        f"{self.kind} to step {self.target_steps} not finished within {timeout} s"
                    )
                time.sleep(self.poll_s)
        except KeyboardInterrupt:
            with contextlib.suppress(StageError):
                self.client.stop()
            raise
        if self.error is not None:
            raise self.error
        assert self.final is not None
        return self.final


__all__ = ["Identity", "MoveStatus", "StageClient", "StageCommandError"]


def _boot_id(reply: str) -> str:
    """The ``id=`` of a ``BOOT?`` reply; `StageProtocolError` naming the reply without one."""
    fields = dict(item.partition("=")[::2] for item in reply.split())
    if not fields.get("id"):
        raise StageProtocolError(
            f"BOOT? answered '{shown(reply, limit_chars=80)}'; allowed: a reply with id=..."
        )
    return fields["id"]
