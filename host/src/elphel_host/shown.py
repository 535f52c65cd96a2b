"""Text from a device or a file, made safe to print on a terminal.

A camera's error message, an HTML body or a stage's reply may hold escape sequences
(``ESC]0;...BEL`` retitles a terminal, ``ESC[2J`` clears it) or megabytes of text.
`shown` escapes every control character and cuts the text to a length a line can hold.
"""

from __future__ import annotations

SHOWN_CHARS = 300


def shown(text: object, *, limit_chars: int = SHOWN_CHARS) -> str:
    r"""``text`` with control characters escaped (``\x1b``) and cut to ``limit_chars``.

    Printable characters, spaces included, are kept; everything else (C0 and C1
    controls, DEL, line breaks, lone surrogates) appears as a Python escape. A cut text
    ends with ``...(N more chars)``.
    """
    raw = text if isinstance(text, str) else str(text)
    head = raw[: limit_chars * 4]
    out: list[str] = []
    size = 0
    for char in head:
        piece = char if char.isprintable() or char == " " else _escape(char)
        if size + len(piece) > limit_chars:
            break
        out.append(piece)
        size += len(piece)
    else:
        if len(head) == len(raw):
            return "".join(out)
    more = len(raw) - sum(1 for _ in out)
    return "".join(out) + f"...({more} more chars)"


def _escape(char: str) -> str:
    code = ord(char)
    if code <= 0xFF:
        return f"\\x{code:02x}"
    if code <= 0xFFFF:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"
