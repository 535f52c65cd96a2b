# Caliper frame acquisition from the clock/data pins. The pins and timing functions are
# passed in, so the same code runs on the board (machine.Pin, machine.time_pulse_us) and
# against test fakes.
#
# ESP8266 MicroPython has no hard pin IRQs and a 4-deep scheduler queue, so edges are
# not taken by interrupt: the reader blocks in time_pulse_us for one frame (a few ms to
# tens of ms), which it only does while the motor is idle.
import caliper_decode


class CaliperError(Exception):
    def __init__(self, code, text):
        super().__init__(text)
        self.code = code
        self.text = text


class CaliperReader:
    def __init__(self, cal_cfg, fmt, clk, data, zero, power, time_pulse_us, ticks_ms,
                 ticks_diff, sleep_us, feed):
        self.cfg = cal_cfg
        self.fmt = fmt
        self.clk = clk
        self.data = data
        self.zero = zero
        self.power = power
        self.tpu = time_pulse_us
        self.ticks_ms = ticks_ms
        self.ticks_diff = ticks_diff
        self.sleep_us = sleep_us
        self.feed = feed
        self.idle = cal_cfg["clk_idle"]
        self.invert = cal_cfg["data_invert"]
        self.powered = True
        self.last_um = None
        self.last_ms = 0
        self.last_error = 0

    def set_power(self, on):
        self.powered = bool(on)
        if self.power is not None:
            self.power.value(1 if on else 0)

    def pulse_zero(self):
        if self.zero is None:
            raise CaliperError(23, "no caliper zero pin configured")
        self.zero.value(1)
        ms = self.cfg["zero_pulse_ms"]
        while ms > 0:
            self.sleep_us(min(ms, 50) * 1000)
            self.feed()
            ms -= 50
        self.zero.value(0)

    def _sample(self):
        return self.data.value() ^ self.invert

    def _device_frame(self, n_bits, need_gap):
        idle = self.idle
        active = 1 - idle
        gap_us = self.cfg["gap_us"]
        start = self.ticks_ms()
        limit_ms = self.cfg["timeout_ms"]
        # Frame sync: an idle stretch of at least gap_us, ended by the clock leaving idle.
        while True:
            left = limit_ms - self.ticks_diff(self.ticks_ms(), start)
            if left <= 0:
                raise CaliperError(20, "no caliper frame within %d ms" % limit_ms)
            d = self.tpu(self.clk, idle, left * 1000)
            if d < 0:
                raise CaliperError(20, "caliper clock %s for %d ms"
                                   % ("idle" if d == -1 else "stuck active", limit_ms))
            if d >= gap_us or not need_gap:
                break
            self.feed()
        frame = 0
        leave = self.cfg["sample"] == "leave"
        for i in range(n_bits):
            if i > 0:
                d = self.tpu(self.clk, idle, gap_us)
                if d < 0:
                    raise CaliperError(21, "caliper frame ended after %d of %d bits" % (i, n_bits))
            if leave:
                bit = self._sample()
            if self.tpu(self.clk, active, gap_us) < 0:
                raise CaliperError(21, "caliper clock stuck active at bit %d" % i)
            if not leave:
                bit = self._sample()
            frame |= bit << i
        # A glitch that adds clock pulses shows up as an edge before the gap.
        if self.tpu(self.clk, idle, gap_us) >= 0:
            raise CaliperError(21, "caliper frame longer than %d bits" % n_bits)
        return frame

    def _host_frame(self, n_bits):
        idle = self.idle
        half = self.cfg["host_half_us"]
        self.clk.value(idle)
        self.sleep_us(self.cfg["gap_us"])
        frame = 0
        for i in range(n_bits):
            self.clk.value(1 - idle)
            self.sleep_us(half)
            frame |= self._sample() << i
            self.clk.value(idle)
            self.sleep_us(half)
        return frame

    def read_frame(self):
        """One raw frame as an int (bit 0 = first data bit), start pulses dropped."""
        if not self.powered:
            raise CaliperError(23, "caliper power is off (CALPWR 1 turns it on)")
        fmt = self.fmt
        n = fmt["skip"] + fmt["bits"]
        clock = fmt["clock"]
        if clock == "host":
            frame = self._host_frame(n)
        elif clock == "request":
            self.zero.value(1)
            try:
                frame = self._device_frame(n, False)
            finally:
                self.zero.value(0)
        else:
            frame = self._device_frame(n, True)
        return frame >> fmt["skip"]

    def read(self):
        """A confirmed reading in um: the mean of `confirm` consecutive frames that agree."""
        readings = []
        tries = 0
        while len(readings) < self.cfg["confirm"]:
            tries += 1
            if tries > 3 * self.cfg["confirm"]:
                self.last_error = 22
                raise CaliperError(22, "caliper readings %s do not agree within %d um"
                                   % (readings, self.cfg["agree_um"]))
            try:
                um = caliper_decode.decode(self.fmt, self.read_frame())
            except caliper_decode.CaliperDecodeError as e:
                self.last_error = 21
                readings = []
                last = CaliperError(21, "caliper frame rejected: %s" % e)
                if tries >= 3 * self.cfg["confirm"]:
                    raise last
                continue
            except CaliperError as e:
                self.last_error = e.code
                raise
            self.feed()
            if readings and not caliper_decode.agree(readings + [um], self.cfg["agree_um"]):
                readings = [um]
            else:
                readings.append(um)
        self.last_um = caliper_decode.mean_um(readings)
        self.last_ms = self.ticks_ms()
        self.last_error = 0
        return self.last_um

    def age_ms(self):
        if self.last_um is None:
            return -1
        return self.ticks_diff(self.ticks_ms(), self.last_ms)
