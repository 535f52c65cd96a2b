# The stage line protocol: command table, line framing, parsing and reply formatting.
# Pure logic (no hardware); docs/stage-protocol.md describes the same table for users.
#
# Wire rules: ASCII lines ending in LF (CR before it ignored). One reply line per
# command line: "ok KEYWORD[ payload]" or "err KEYWORD CODE text". An optional "*HH"
# suffix (XOR of all bytes before '*', two hex digits) protects a line; replies to a
# protected line carry one too. The single byte '!' is the immediate stop: acted on when
# read, never queued, no reply. Lines starting with '#' come only from the board
# (banner, pushed events) and are not replies.

MAX_LINE = 64
STOP_BYTE = 0x21  # '!'

# code: short name. Texts on the wire add the value and what is allowed.
ERRORS = {
    1: "unknown command",
    2: "bad argument",
    3: "line too long",
    4: "bad bytes",
    5: "checksum mismatch",
    8: "busy",
    9: "not homed",
    10: "alarm",
    15: "beyond soft limit",
    20: "caliper timeout",
    21: "caliper decode",
    22: "caliper unstable",
    23: "caliper off",
}

# keyword: (argument kinds, meaning). Argument kinds: "i" integer, "b" 0 or 1.
COMMANDS = {
    "*IDN?": ("", "identify: maker,model,serial,firmware"),
    "BOOT?": ("", "boot id (changes at every reset), uptime ms, reset cause"),
    "STATUS?": ("", "state, position, target, homed, last caliper reading and age"),
    "MOVE": ("i", "start a move to an absolute position in steps"),
    "MOVER": ("i", "start a move by a signed number of steps"),
    "STOP": ("", "stop now; reply with the position in steps"),
    "HOME": ("", "start homing onto the min limit switch; position 0 there"),
    "ZERO": ("", "make the current position 0 (soft limits keep their place)"),
    "POS": ("i", "declare the current position in steps (re-sync); sets homed"),
    "LIM?": ("", "soft limits in steps"),
    "LIM": ("ii", "set soft limits in steps (inside the configured travel)"),
    "SPEED?": ("", "max step rate (Hz) and acceleration (Hz/s)"),
    "SPEED": ("ii", "set max step rate (Hz) and acceleration (Hz/s)"),
    "CAL?": ("", "read the caliper now: micrometres and age in ms"),
    "CALZERO": ("", "pulse the caliper zero line"),
    "CALPWR": ("b", "caliper power off (0) or on (1)"),
}


class ProtocolError(Exception):
    def __init__(self, code, text, keyword="?"):
        super().__init__(text)
        self.code = code
        self.text = text
        self.keyword = keyword
        self.sealed = False     # the failing line carried a valid checksum


def checksum(data):
    """XOR of the bytes (or str characters) of data, 0..255."""
    c = 0
    for ch in data:
        c ^= ch if isinstance(ch, int) else ord(ch)
    return c


def seal(line):
    """Append the *HH checksum suffix to a line (without newline)."""
    return "%s*%02X" % (line, checksum(line))


def _int(text, keyword):
    t = text[1:] if text[:1] in ("-", "+") else text
    if not t or not t.isdigit() or len(t) > 9:
        raise ProtocolError(2, "%s argument %r is not an integer of at most 9 digits" % (keyword, text), keyword)
    return int(text)


def parse(line):
    """Parse one line (str, no newline) into (keyword, args, sealed).

    Raises ProtocolError for a bad checksum, unknown keyword or bad arguments.
    """
    sealed = False
    star = line.rfind("*")
    if star > 0 and len(line) - star == 3:
        body = line[:star]
        try:
            want = int(line[star + 1:], 16)
        except ValueError:
            raise ProtocolError(5, "checksum %r is not two hex digits" % line[star + 1:])
        if checksum(body) != want:
            raise ProtocolError(5, "checksum %02X does not match line (expected %02X)"
                                % (want, checksum(body)))
        line = body
        sealed = True
    try:
        return _parse_body(line, sealed)
    except ProtocolError as e:
        e.sealed = sealed
        raise


def _parse_body(line, sealed):
    words = line.split()
    if not words:
        raise ProtocolError(2, "empty line")
    keyword = words[0].upper()
    spec = COMMANDS.get(keyword)
    if spec is None:
        raise ProtocolError(1, "unknown command %r" % keyword[:16], keyword[:16])
    kinds = spec[0]
    if len(words) - 1 != len(kinds):
        raise ProtocolError(2, "%s takes %d argument(s), got %d" % (keyword, len(kinds), len(words) - 1), keyword)
    args = []
    for kind, word in zip(kinds, words[1:]):
        v = _int(word, keyword)
        if kind == "b" and v not in (0, 1):
            raise ProtocolError(2, "%s argument %d; allowed 0 or 1" % (keyword, v), keyword)
        args.append(v)
    return keyword, args, sealed


def ok(keyword, payload=None):
    return "ok " + keyword if payload is None else "ok %s %s" % (keyword, payload)


def err(keyword, code, text):
    return "err %s %d %s" % (keyword, code, text)


class LineFramer:
    """Bytes in, complete lines out; watches for the realtime stop byte.

    feed() returns a list of items: a str line, or a ProtocolError for a line that was
    too long or held bytes outside printable ASCII. on_stop() is called as soon as the
    stop byte is seen, before any line that is still waiting.
    """

    def __init__(self, on_stop):
        self.on_stop = on_stop
        self.buf = bytearray()
        self.bad = 0
        self.overflow = False

    def feed(self, data):
        out = []
        for b in data:
            if b == STOP_BYTE:
                self.on_stop()
            elif b == 10:
                out.append(self._finish())
            elif b == 13:
                pass
            elif b < 32 or b > 126:
                self.bad += 1
            elif len(self.buf) >= MAX_LINE:
                self.overflow = True
            else:
                self.buf.append(b)
        return out

    def _finish(self):
        line = bytes(self.buf).decode()
        self.buf = bytearray()
        bad, overflow = self.bad, self.overflow
        self.bad = 0
        self.overflow = False
        if overflow:
            return ProtocolError(3, "line longer than %d bytes" % MAX_LINE)
        if bad:
            return ProtocolError(4, "%d byte(s) outside printable ASCII" % bad)
        return line
