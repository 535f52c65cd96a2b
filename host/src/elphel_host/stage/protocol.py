"""Host side of the stage line protocol (the wire format of docs/stage-protocol.md).

Requests are sealed with a ``*HH`` XOR checksum; replies to sealed requests are sealed
too, so a garbled byte in either direction is detected rather than believed.
"""

from __future__ import annotations

from dataclasses import dataclass

from elphel_host.errors import (
    StageAlarmError,
    StageBusyError,
    StageCaliperError,
    StageCommandError,
    StageLimitError,
    StageNotHomedError,
    StageProtocolError,
)

# Error codes of the firmware and the host exception each maps to.
ERROR_CLASSES: dict[int, type[StageCommandError]] = {
    8: StageBusyError,
    9: StageNotHomedError,
    10: StageAlarmError,
    15: StageLimitError,
    20: StageCaliperError,
    21: StageCaliperError,
    22: StageCaliperError,
    23: StageCaliperError,
}

STATES = ("IDLE", "RUN", "HOME", "ALARM")


def checksum(text: str) -> int:
    c = 0
    for ch in text.encode("ascii", "replace"):
        c ^= ch
    return c


def seal(line: str) -> str:
    return f"{line}*{checksum(line):02X}"


def unseal(line: str) -> str:
    """Return the body of a sealed line, or raise StageProtocolError if it does not verify."""
    star = line.rfind("*")
    if star <= 0 or len(line) - star != 3:
        raise StageProtocolError(f"reply {line!r} has no *HH checksum")
    body, tail = line[:star], line[star + 1 :]
    try:
        got = int(tail, 16)
    except ValueError:
        raise StageProtocolError(f"reply {line!r}: checksum {tail!r} is not hex") from None
    if got != checksum(body):
        raise StageProtocolError(f"reply {line!r}: checksum {got:02X} != {checksum(body):02X}")
    return body


@dataclass(frozen=True)
class Reply:
    keyword: str
    ok: bool
    payload: str = ""
    code: int = 0


def parse_reply(body: str) -> Reply:
    """Parse an unsealed reply body: ``ok KW [payload]`` or ``err KW CODE text``."""
    parts = body.split(" ", 2)
    if len(parts) < 2 or parts[0] not in ("ok", "err"):
        raise StageProtocolError(
            f"reply {body!r} is neither 'ok KEYWORD ...' nor 'err KEYWORD CODE ...'"
        )
    if parts[0] == "ok":
        return Reply(parts[1], True, parts[2] if len(parts) > 2 else "")
    rest = parts[2] if len(parts) > 2 else ""
    code_text, _, text = rest.partition(" ")
    if not code_text.isdigit():
        raise StageProtocolError(f"error reply {body!r} lacks a numeric code")
    return Reply(parts[1], False, text, int(code_text))


def raise_for(reply: Reply, request: str) -> None:
    if reply.ok:
        return
    cls = ERROR_CLASSES.get(reply.code, StageCommandError)
    raise cls(
        f"stage refused {request!r}: error {reply.code}: {reply.payload}",
        code=reply.code,
        keyword=reply.keyword,
    )


@dataclass(frozen=True)
class StageStatus:
    """One STATUS? answer. Positions in steps; caliper in micrometres (None if never read)."""

    state: str
    steps: int
    target_steps: int
    homed: bool
    caliper_um: int | None
    caliper_age_ms: int
    caliper_error: int
    limits: str
    alarm: int

    @property
    def moving(self) -> bool:
        return self.state in ("RUN", "HOME")


def parse_status(payload: str) -> StageStatus:
    fields: dict[str, str] = {}
    for item in payload.split():
        key, sep, value = item.partition("=")
        if not sep:
            raise StageProtocolError(f"status item {item!r} is not key=value")
        fields[key] = value
    try:
        state = fields["st"]
        if state not in STATES:
            raise StageProtocolError(f"status state {state!r}; allowed {STATES}")
        cal = fields["cal_um"]
        return StageStatus(
            state=state,
            steps=int(fields["pos"]),
            target_steps=int(fields["tgt"]),
            homed=fields["homed"] == "1",
            caliper_um=None if cal == "NA" else int(cal),
            caliper_age_ms=int(fields["cal_age_ms"]),
            caliper_error=int(fields["cal_err"]),
            limits=fields["lim"],
            alarm=int(fields["alarm"]),
        )
    except (KeyError, ValueError) as e:
        raise StageProtocolError(f"status {payload!r} is malformed: {e}") from e
