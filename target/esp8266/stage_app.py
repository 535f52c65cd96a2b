# The stage itself: motion state machine, soft limits, homing and command handling.
# Hardware comes in through `hw` (pins and time functions), so this module holds no
# port-specific code. Positions on the wire are user steps = machine steps - origin.
import stage_protocol as proto
from caliper_read import CaliperError
from stage_ramp import RampPlan

MAKER = "elphel-rig"
MODEL = "esp8266-stage"
VERSION = "1.0.0"

IDLE = "IDLE"
RUN = "RUN"
HOME = "HOME"
ALARM = "ALARM"

ALARM_LIMIT = 1       # a limit switch closed during a move
ALARM_HOME_FAIL = 2   # homing found no switch within the travel

# commands handled by StageApp._setting and StageApp._caliper
SETTINGS = ("POS", "LIM?", "LIM", "SPEED?", "SPEED")
CALIPER = ("CAL?", "CALZERO", "CALPWR")


class StageApp:
    def __init__(self, cfg, hw):
        self.cfg = cfg
        self.hw = hw
        self.state = IDLE
        self.pos = 0            # machine steps
        self.origin = 0         # machine steps of user position 0
        self.target = 0         # machine steps
        self.homed = False
        self.alarm = 0
        self.lim_lo = 0
        self.lim_hi = cfg["travel_steps"]
        self.max_hz = cfg["max_hz"]
        self.accel = cfg["accel_hz_per_s"]
        self.plan = None
        self.dir = 1
        self.i = 0
        self.n = 0
        self.due = 0
        self.home_phase = 0
        self.push = None        # set by the main loop: function(line) to every channel
        self.caliper_next_ms = 0
        hw.enable.value(cfg["enable_active"])

    # ---- motion -------------------------------------------------------------------
    def _limit(self, pin):
        return pin is not None and pin.value() == self.cfg["limit_active"]

    def _start(self, steps, start_hz, max_hz):
        """Start moving by `steps` machine steps (sign = direction)."""
        hw = self.hw
        self.dir = 1 if steps > 0 else -1
        self.n = steps if steps > 0 else -steps
        self.i = 0
        level = self.cfg["dir_positive"]
        hw.dir.value(level if self.dir > 0 else 1 - level)
        hw.sleep_us(self.cfg["dir_setup_us"])
        self.plan = RampPlan(self.n, start_hz, max_hz, self.accel)
        self.due = hw.ticks_us()

    def _finish(self):
        self.plan = None
        if self.state == HOME:
            if self.home_phase == 1:
                self.home_phase = 0
                travel = self.cfg["travel_steps"]
                return self._alarm(ALARM_HOME_FAIL, "no min switch within %d steps" % (travel + travel // 5))
            return self._home_next()
        self.state = IDLE
        self.target = self.pos

    def halt(self):
        """Stop issuing steps now (the realtime stop and STOP)."""
        if self.state in (RUN, HOME):
            if self.state == HOME:
                self.homed = False
            self.state = IDLE
        self.plan = None
        self.target = self.pos

    def _alarm(self, code, text):
        self.plan = None
        self.state = ALARM
        self.alarm = code
        self.target = self.pos
        if self.push:
            self.push("# ALARM %d %s pos=%d" % (code, text, self.pos - self.origin))

    def service(self, budget_us=3000):
        """Issue the steps that are due; return microseconds until the next one (or -1)."""
        hw = self.hw
        t0 = hw.ticks_us()
        pulse_us = self.cfg["step_pulse_us"]
        step = hw.step
        while self.plan is not None:
            now = hw.ticks_us()
            wait = hw.ticks_diff(self.due, now)
            if wait > 0:
                if wait > 1500 or hw.ticks_diff(now, t0) + wait > budget_us:
                    return wait
                hw.sleep_us(wait)
            if self.dir < 0 and self._limit(hw.lim_min):
                if self.state == HOME and self.home_phase == 1:
                    self.plan = None
                    self._home_next()
                    continue
                self._alarm(ALARM_LIMIT, "min limit switch")
                return -1
            if self.dir > 0 and self._limit(hw.lim_max):
                self._alarm(ALARM_LIMIT, "max limit switch")
                return -1
            if self.state == HOME and self.home_phase == 2 and not self._limit(hw.lim_min):
                # Released: the back-off after release is the last homing leg.
                self.plan = None
                self._home_next()
                continue
            step.value(1)
            hw.sleep_us(pulse_us)
            step.value(0)
            self.pos += self.dir
            self.i += 1
            if self.i >= self.n:
                self._finish()
                continue
            self.due = hw.ticks_add(self.due, self.plan.interval_us(self.i))
            if hw.ticks_diff(hw.ticks_us(), self.due) > 20000:
                self.due = hw.ticks_us()   # far behind (caliper read, WiFi): restart timing
        return -1

    def _home_next(self):
        hz = self.cfg["home_hz"]
        travel = self.cfg["travel_steps"]
        if self.home_phase == 1:
            # Switch found: creep off it.
            self.home_phase = 2
            self._start(travel // 10 + self.cfg["home_backoff_steps"], hz // 2 or 1, hz // 2 or 1)
            return
        if self.home_phase == 2:
            if self._limit(self.hw.lim_min):
                self.home_phase = 0
                return self._alarm(ALARM_HOME_FAIL, "min switch did not release")
            self.home_phase = 3
            self._start(self.cfg["home_backoff_steps"], hz, hz)
            return
        if self.home_phase == 3:
            self.home_phase = 0
            self.pos = 0
            self.origin = 0
            self.target = 0
            self.homed = True
            self.alarm = 0
            self.state = IDLE
            return

    def start_home(self):
        self.state = HOME
        self.homed = False
        self.alarm = 0
        travel = self.cfg["travel_steps"]
        if self._limit(self.hw.lim_min):
            self.home_phase = 1
            self._home_next()
        else:
            self.home_phase = 1
            self._start(-(travel + travel // 5), self.cfg["home_hz"], self.cfg["home_hz"])

    # ---- commands -----------------------------------------------------------------
    def status_payload(self):
        cal = self.hw.caliper
        lim = ("L" if self._limit(self.hw.lim_min) else "") + ("H" if self._limit(self.hw.lim_max) else "")
        um = "NA" if cal.last_um is None else str(cal.last_um)
        return "st=%s pos=%d tgt=%d homed=%d cal_um=%s cal_age_ms=%d cal_err=%d lim=%s alarm=%d" % (
            self.state, self.pos - self.origin, self.target - self.origin, 1 if self.homed else 0,
            um, cal.age_ms(), cal.last_error, lim or "-", self.alarm)

    def _check_move(self, kw, target_user):
        if self.state == ALARM:
            raise proto.ProtocolError(10, "alarm %d active; HOME or POS clears it" % self.alarm, kw)
        if self.cfg["home_required"] and not self.homed:
            raise proto.ProtocolError(9, "position unknown; HOME or POS first", kw)
        m = target_user + self.origin
        if not self.lim_lo <= m <= self.lim_hi:
            raise proto.ProtocolError(15, "target %d outside soft limits %d..%d"
                                      % (target_user, self.lim_lo - self.origin, self.lim_hi - self.origin), kw)
        if self.state != IDLE:
            if self.state == RUN and m == self.target:
                return None     # the same move again (a retry after a lost reply)
            raise proto.ProtocolError(8, "%s in progress; STOP first" % self.state, kw)
        return m

    def _move_to(self, kw, target_user):
        m = self._check_move(kw, target_user)
        if m is not None:
            self.target = m
            if m != self.pos:
                self.state = RUN
                self._start(m - self.pos, self.cfg["start_hz"], self.max_hz)
        return proto.ok(kw, str(target_user))

    def _need_idle(self, kw):
        if self.state in (RUN, HOME):
            raise proto.ProtocolError(8, "%s in progress; STOP first" % self.state, kw)

    def handle(self, kw, args):
        """Execute one parsed command; return the reply line or raise ProtocolError."""
        hw = self.hw
        if kw == "STATUS?":
            return proto.ok(kw, self.status_payload())
        if kw == "MOVE":
            return self._move_to(kw, args[0])
        if kw == "MOVER":
            base = (self.target if self.state == RUN else self.pos) - self.origin
            if self.state == RUN:
                raise proto.ProtocolError(8, "RUN in progress; STOP first", kw)
            return self._move_to(kw, base + args[0])
        if kw == "STOP":
            self.halt()
            return proto.ok(kw, str(self.pos - self.origin))
        if kw == "*IDN?":
            return proto.ok(kw, "%s,%s,%s,%s" % (MAKER, MODEL, hw.serial, VERSION))
        if kw == "BOOT?":
            return proto.ok(kw, "id=%s up_ms=%d cause=%d" % (hw.boot_id, hw.ticks_ms_total(), hw.reset_cause))
        if kw == "HOME":
            self._need_idle(kw)
            self.start_home()
            return proto.ok(kw)
        if kw == "ZERO":
            self._need_idle(kw)
            self.origin = self.pos
            self.target = self.pos
            return proto.ok(kw)
        if kw in SETTINGS:
            return self._setting(kw, args)
        if kw in CALIPER:
            return self._caliper(kw, args)
        raise proto.ProtocolError(1, "command %s has no handler" % kw, kw)

    def _setting(self, kw, args):
        """POS, LIM?, LIM, SPEED? and SPEED: the position, soft limits and speed."""
        if kw == "POS":
            self._need_idle(kw)
            self.pos = args[0] + self.origin
            self.target = self.pos
            self.homed = True
            self.alarm = 0
            self.state = IDLE
            return proto.ok(kw, str(args[0]))
        if kw == "LIM?":
            return proto.ok(kw, "%d %d" % (self.lim_lo - self.origin, self.lim_hi - self.origin))
        if kw == "LIM":
            lo, hi = args[0] + self.origin, args[1] + self.origin
            if not 0 <= lo < hi <= self.cfg["travel_steps"]:
                raise proto.ProtocolError(15, "limits %d..%d must satisfy %d <= min < max <= %d"
                                          % (args[0], args[1], -self.origin,
                                             self.cfg["travel_steps"] - self.origin), kw)
            self._need_idle(kw)
            self.lim_lo, self.lim_hi = lo, hi
            return proto.ok(kw, "%d %d" % (args[0], args[1]))
        if kw == "SPEED?":
            return proto.ok(kw, "%d %d" % (self.max_hz, self.accel))
        # SPEED: the last of SETTINGS
        cap = self.cfg["max_hz_cap"]
        if not self.cfg["start_hz"] <= args[0] <= cap or not 1 <= args[1] <= 1000000:
            raise proto.ProtocolError(2, "speed %d Hz accel %d Hz/s; allowed %d..%d Hz, 1..1000000 Hz/s"
                                      % (args[0], args[1], self.cfg["start_hz"], cap), kw)
        self._need_idle(kw)
        self.max_hz, self.accel = args[0], args[1]
        return proto.ok(kw, "%d %d" % (args[0], args[1]))

    def _caliper(self, kw, args):
        """CAL?, CALZERO and CALPWR: read, zero and power the caliper."""
        hw = self.hw
        if kw == "CAL?":
            self._need_idle(kw)
            try:
                um = hw.caliper.read()
            except CaliperError as e:
                raise proto.ProtocolError(e.code, e.text, kw)
            return proto.ok(kw, "%d %d" % (um, hw.caliper.age_ms()))
        if kw == "CALZERO":
            self._need_idle(kw)
            try:
                hw.caliper.pulse_zero()
            except CaliperError as e:
                raise proto.ProtocolError(e.code, e.text, kw)
            return proto.ok(kw)
        # CALPWR: the last of CALIPER
        hw.caliper.set_power(args[0])
        return proto.ok(kw, str(args[0]))

    def handle_line(self, line):
        """One request line in, one reply line out (sealed if the request was)."""
        sealed = False
        try:
            kw, args, sealed = proto.parse(line)
            reply = self.handle(kw, args)
        except proto.ProtocolError as e:
            reply = proto.err(e.keyword, e.code, e.text)
            sealed = sealed or e.sealed
        return proto.seal(reply) if sealed else reply

    def answers(self, framer, data):
        """The reply to each request line that ``data`` completes in ``framer``."""
        for item in framer.feed(data):
            if isinstance(item, proto.ProtocolError):
                yield proto.err("?", item.code, item.text)
            elif item:
                yield self.handle_line(item)

    def idle_caliper(self):
        """Background caliper reading while the motor is idle, every poll_ms."""
        hw = self.hw
        poll_ms = self.cfg["caliper"]["poll_ms"]
        if self.plan is not None or poll_ms <= 0 or not hw.caliper.powered:
            return
        now = hw.ticks_ms()
        if hw.ticks_diff(now, self.caliper_next_ms) < 0:
            return
        self.caliper_next_ms = hw.ticks_add(now, poll_ms)
        try:
            hw.caliper.read()
        except CaliperError:
            pass    # kept in caliper.last_error, shown by STATUS?
