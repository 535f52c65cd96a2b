# Board wiring: pins, UART, WiFi, TCP server, watchdog and the main loop.
# The only firmware module that touches machine/network/socket directly.
import os
import select
import socket
import time

import machine
import network

import stage_config
import stage_protocol as proto
from caliper_read import CaliperReader
from stage_app import VERSION, StageApp


class Hardware:
    def __init__(self, cfg, feed):
        pins = cfg["pins"]
        self.step = machine.Pin(pins["step"], machine.Pin.OUT, value=0)
        self.dir = machine.Pin(pins["dir"], machine.Pin.OUT, value=0)
        self.enable = machine.Pin(pins["enable"], machine.Pin.OUT, value=1 - cfg["enable_active"])
        self.lim_min = self._input(pins["lim_min"])
        self.lim_max = self._input(pins["lim_max"])
        cal = cfg["caliper"]
        fmt = cfg["caliper_format"]
        if fmt["clock"] == "host":
            clk = machine.Pin(pins["cal_clk"], machine.Pin.OUT, value=cal["clk_idle"])
        else:
            clk = machine.Pin(pins["cal_clk"], machine.Pin.IN)
        data = machine.Pin(pins["cal_data"], machine.Pin.IN)
        zero = self._output(pins["cal_zero"], 0)
        power = self._output(pins["cal_power"], 1)
        self.caliper = CaliperReader(cal, fmt, clk, data, zero, power, machine.time_pulse_us,
                                     time.ticks_ms, time.ticks_diff, time.sleep_us, feed)
        self.ticks_us = time.ticks_us
        self.ticks_ms = time.ticks_ms
        self.ticks_diff = time.ticks_diff
        self.ticks_add = time.ticks_add
        self.sleep_us = time.sleep_us
        self.serial = cfg["serial"] or "".join("%02x" % b for b in machine.unique_id())
        self.boot_id = "".join("%02x" % b for b in os.urandom(4))
        self.reset_cause = machine.reset_cause()
        self._up_last = time.ticks_ms()
        self._up_ms = 0

    @staticmethod
    def _input(num):
        if num is None or num < 0:
            return None
        return machine.Pin(num, machine.Pin.IN, machine.Pin.PULL_UP if num != 16 else None)

    @staticmethod
    def _output(num, value):
        if num is None or num < 0:
            return None
        return machine.Pin(num, machine.Pin.OUT, value=value)

    def ticks_ms_total(self):
        # ticks wrap every 2^30 ms-ish; keep a running uptime instead.
        now = time.ticks_ms()
        self._up_ms += time.ticks_diff(now, self._up_last)
        self._up_last = now
        return self._up_ms


class Channel:
    """One byte stream (UART or a TCP client) with its own line framer."""

    def __init__(self, name, write, app):
        self.name = name
        self.write = write
        self.framer = proto.LineFramer(app.halt)


def banner(hw):
    return "# ELPHEL-STAGE %s boot=%s serial=%s" % (VERSION, hw.boot_id, hw.serial)


def start_wifi(cfg):
    w = cfg["wifi"]
    if w["mode"] == "ap":
        ap = network.WLAN(network.AP_IF)
        ap.active(True)
        ap.config(essid=w["ap_ssid"])
        return ap
    sta = network.WLAN(network.STA_IF)
    sta.active(True)
    if w["ssid"] and not sta.isconnected():
        sta.connect(w["ssid"], w["password"])   # connects in the background
    return sta


def open_server(cfg):
    """The TCP server socket (non-blocking, one client at a time) after starting WiFi."""
    start_wifi(cfg)
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(socket.getaddrinfo("0.0.0.0", cfg["tcp"]["port"])[0][-1])
    server.listen(1)
    server.setblocking(False)
    return server


class Links:
    """The UART and at most one TCP client: polled, framed, answered, pushed to."""

    def __init__(self, cfg, app, hw):
        self.app = app
        self.hw = hw
        self.uart = machine.UART(cfg["uart"]["id"], cfg["uart"]["baud"])
        if cfg["uart"]["detach_repl"]:
            os.dupterm(None, 1)
        self.poller = select.poll()
        self.poller.register(self.uart, select.POLLIN)
        self.uart_ch = Channel("uart", self.uart_write, app)
        self.channels = [self.uart_ch]
        self.server = None
        self.client = None
        self.client_ch = None
        if cfg["tcp"]["enable"]:
            self.server = open_server(cfg)
            self.poller.register(self.server, select.POLLIN)

    def uart_write(self, line):
        self.uart.write(line + "\n")

    def push(self, line):
        for ch in self.channels:
            ch.write(line)

    def drop_client(self):
        if self.client is not None:
            self.poller.unregister(self.client)
            self.client.close()
            self.channels.remove(self.client_ch)
        self.client = None
        self.client_ch = None

    def client_write(self, line):
        data = (line + "\n").encode()
        sent = 0
        tries = 0
        while sent < len(data) and self.client is not None:
            try:
                n = self.client.send(data[sent:])
            except OSError:
                n = 0
                tries += 1
                if tries > 50:
                    self.drop_client()
                    return
                time.sleep_ms(2)
            sent += n or 0

    def handle_bytes(self, ch, data):
        for reply in self.app.answers(ch.framer, data):
            ch.write(reply)

    def accept(self):
        try:
            sock, _addr = self.server.accept()
        except OSError:
            return
        self.drop_client()   # a new connection replaces a stale one
        self.client = sock
        sock.setblocking(False)
        self.poller.register(sock, select.POLLIN)
        self.client_ch = Channel("tcp", self.client_write, self.app)
        self.channels.append(self.client_ch)
        self.client_write(banner(self.hw))

    def receive(self):
        try:
            data = self.client.recv(128)
        except OSError:
            return
        if not data:
            self.drop_client()
            return
        self.handle_bytes(self.client_ch, data)

    def poll(self, timeout_ms):
        """Wait up to timeout_ms for bytes or a connection, and handle what came."""
        for obj, _ in self.poller.poll(timeout_ms):
            if obj is self.uart:
                data = self.uart.read(64)
                if data:
                    self.handle_bytes(self.uart_ch, data)
            elif obj is self.server:
                self.accept()
            elif self.client is not None and obj is self.client:
                self.receive()


def run(config_path=stage_config.CONFIG_FILE):
    cfg = stage_config.load(config_path)
    wdt = machine.WDT() if cfg["watchdog"] else None

    def feed():
        if wdt is not None:
            wdt.feed()

    hw = Hardware(cfg, feed)
    app = StageApp(cfg, hw)
    links = Links(cfg, app, hw)
    app.push = links.push
    links.uart_write(banner(hw))
    while True:
        feed()
        wait_us = app.service()
        if wait_us < 0:
            app.idle_caliper()
            timeout_ms = 20
        else:
            timeout_ms = 0 if wait_us < 2000 else 1
        links.poll(timeout_ms)
