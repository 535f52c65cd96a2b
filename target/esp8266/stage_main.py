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


def run(config_path=stage_config.CONFIG_FILE):
    cfg = stage_config.load(config_path)
    wdt = machine.WDT() if cfg["watchdog"] else None

    def feed():
        if wdt is not None:
            wdt.feed()

    hw = Hardware(cfg, feed)
    app = StageApp(cfg, hw)
    uart = machine.UART(cfg["uart"]["id"], cfg["uart"]["baud"])
    if cfg["uart"]["detach_repl"]:
        os.dupterm(None, 1)
    poller = select.poll()
    poller.register(uart, select.POLLIN)
    channels = []

    def uart_write(line):
        uart.write(line + "\n")

    uart_ch = Channel("uart", uart_write, app)
    channels.append(uart_ch)
    server = None
    client = None
    client_ch = None
    if cfg["tcp"]["enable"]:
        start_wifi(cfg)
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(socket.getaddrinfo("0.0.0.0", cfg["tcp"]["port"])[0][-1])
        server.listen(1)
        server.setblocking(False)
        poller.register(server, select.POLLIN)

    def push(line):
        for ch in channels:
            ch.write(line)

    app.push = push
    uart_write(banner(hw))

    def drop_client():
        nonlocal client, client_ch
        if client is not None:
            poller.unregister(client)
            client.close()
            channels.remove(client_ch)
        client = None
        client_ch = None

    def client_write(line):
        data = (line + "\n").encode()
        sent = 0
        tries = 0
        while sent < len(data) and client is not None:
            try:
                n = client.send(data[sent:])
            except OSError:
                n = 0
                tries += 1
                if tries > 50:
                    drop_client()
                    return
                time.sleep_ms(2)
            sent += n or 0

    def handle_bytes(ch, data):
        for item in ch.framer.feed(data):
            if isinstance(item, proto.ProtocolError):
                reply = proto.err("?", item.code, item.text)
            elif not item:
                continue
            else:
                reply = app.handle_line(item)
            ch.write(reply)

    while True:
        feed()
        wait_us = app.service()
        if wait_us < 0:
            app.idle_caliper()
            timeout_ms = 20
        else:
            timeout_ms = 0 if wait_us < 2000 else 1
        for obj, _ in poller.poll(timeout_ms):
            if obj is uart:
                data = uart.read(64)
                if data:
                    handle_bytes(uart_ch, data)
            elif obj is server:
                try:
                    sock, _addr = server.accept()
                except OSError:
                    continue
                drop_client()   # a new connection replaces a stale one
                client = sock
                client.setblocking(False)
                poller.register(client, select.POLLIN)
                client_ch = Channel("tcp", client_write, app)
                channels.append(client_ch)
                client_write(banner(hw))
            elif client is not None and obj is client:
                try:
                    data = client.recv(128)
                except OSError:
                    continue
                if not data:
                    drop_client()
                    continue
                handle_bytes(client_ch, data)
