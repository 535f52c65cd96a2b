"""The simulated stage as a service: firmware on a simulated board, on TCP and a pty.

``SimStage`` writes the board's ``stage.json``, wires `stage_hw` to the board's pins,
boots the unchanged firmware of ``target/esp8266`` and exposes its UART on a pty and its
TCP server on a loopback port. ``sim_state()`` tells the truth the host must measure.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import shutil
import tempfile
import threading
import time
import tty
from pathlib import Path
from typing import Any

from elphel_sim.caliper import CaliperConfig, SimCaliper
from elphel_sim.micropython.esp8266 import SimEsp8266
from elphel_sim.stage_hw import MechanicsConfig, StageHardware, StageMechanics

PINS = {
    "step": 14,
    "dir": 12,
    "enable": 13,
    "lim_min": 4,
    "lim_max": 5,
    "cal_clk": 0,
    "cal_data": 2,
    "cal_zero": 15,
    "cal_power": 16,
}


class SimStage:
    """A simulated stage board served on ``tcp_url`` and ``pty_path``.

    Parameters
    ----------
    world
        Optional world; if it has ``rig.carriage_mm`` that attribute follows the carriage.
    seed
        Seeds every noise source (caliper noise, missed steps, link garbling, boot id).
    tcp_port
        Loopback TCP port for the firmware's server; 0 picks a free port.
    time_scale
        Virtual seconds per real second at most (tests use a large value).
    mechanics, caliper
        Simulated hardware settings; defaults are the burst rig's stage.
    firmware_config
        Entries merged into the board's ``stage.json``.
    """

    def __init__(
        self,
        world: Any = None,
        *,
        seed: int = 0,
        tcp_port: int = 0,
        time_scale: float = 1.0,
        mechanics: MechanicsConfig | None = None,
        caliper: CaliperConfig | None = None,
        firmware_config: dict[str, Any] | None = None,
        pty: bool = True,
    ) -> None:
        self.world = world
        self.seed = seed
        self.mech_cfg = mechanics or MechanicsConfig()
        self.cal_cfg = caliper or CaliperConfig()
        self.fw_extra = firmware_config or {}
        self.want_pty = pty
        self._fs = Path(tempfile.mkdtemp(prefix="elphel-stage-fs-"))
        self.board = SimEsp8266(
            fs_dir=self._fs, time_scale=time_scale, tcp_port=tcp_port, seed=seed
        )
        self.mech = StageMechanics(self.mech_cfg, seed=seed + 1, world=world)
        self.caliper = SimCaliper(self.cal_cfg, self.mech, seed=seed + 2)
        self._link_rng = random.Random(seed + 3)
        self._garble_rate = 0.0
        self.garbled_bytes = 0
        self.tcp_port = 0
        self._master: int | None = None
        self._slave: int | None = None
        self.pty_path: str | None = None
        self._pump: threading.Thread | None = None
        self._closing = False
        self._started = False

    # ---- lifecycle ----------------------------------------------------------------
    def firmware_config(self) -> dict[str, Any]:
        cal = self.cal_cfg
        cfg: dict[str, Any] = {
            "pins": dict(PINS),
            "serial": f"sim{self.seed:05d}",
            "travel_steps": int((self.mech_cfg.lim_max_mm - 1.5) / self.mech_cfg.mm_per_step),
            "caliper": {
                "format": cal.fmt,
                "clk_idle": cal.clk_idle,
                "sample": cal.sample,
                "data_invert": cal.data_invert,
            },
            "tcp": {"enable": True, "port": 23},
        }
        if cal.fmt == "sylvac48":
            cfg["caliper"]["settings"] = {"sign": cal.sign_mode}
        for key, value in self.fw_extra.items():
            if isinstance(value, dict) and isinstance(cfg.get(key), dict):
                cfg[key] = {**cfg[key], **value}
            else:
                cfg[key] = value
        return cfg

    def start(self) -> SimStage:
        if self._started:
            return self
        self._started = True
        (self._fs / "stage.json").write_text(json.dumps(self.firmware_config(), indent=1))
        StageHardware(self.board, self.mech, self.caliper, PINS)
        self.tcp_port = self.board.bind_tcp_now()
        if self.want_pty:
            master, slave = os.openpty()
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.pty_path = os.ttyname(slave)
            self.board.uart_sink = self._uart_out
            self._pump = threading.Thread(target=self._pump_pty, name="sim-stage-pty", daemon=True)
            self._pump.start()
        self.board.garble_in = self._garble
        self.board.garble_out = self._garble
        self.board.start()
        return self

    def __enter__(self) -> SimStage:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        self.board.close()
        if self._pump is not None:
            self._pump.join(timeout=5)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        shutil.rmtree(self._fs, ignore_errors=True)

    @property
    def tcp_url(self) -> str:
        return f"socket://127.0.0.1:{self.tcp_port}"

    def wait_booted(self, timeout_s: float = 10.0) -> None:
        """Block until the firmware has entered its main loop (or raise TimeoutError)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.board.crash is not None:
                raise RuntimeError(
                    f"simulated firmware crashed: {self.board.crash!r}"
                ) from self.board.crash
            if self.board.clock.now_us > 2_100_000:
                return
            time.sleep(0.005)
        raise TimeoutError(f"simulated stage did not boot within {timeout_s} s")

    # ---- pty link -------------------------------------------------------------------
    def _uart_out(self, data: bytes) -> None:
        if self._master is None:
            return
        with contextlib.suppress(OSError):  # nobody reading: bytes are lost, as on a wire
            os.write(self._master, data)

    def _pump_pty(self) -> None:
        import select

        assert self._master is not None
        while not self._closing:
            try:
                ready, _, _ = select.select([self._master], [], [], 0.05)
                if ready:
                    data = os.read(self._master, 256)
                    if data:
                        self.board.uart_feed(data)
            except OSError:
                time.sleep(0.01)

    def _garble(self, data: bytes) -> bytes:
        if self._garble_rate <= 0 or not data:
            return data
        out = bytearray(data)
        for i in range(len(out)):
            if self._link_rng.random() < self._garble_rate:
                out[i] ^= 1 << self._link_rng.randrange(8)
                self.garbled_bytes += 1
        return bytes(out)

    # ---- truth and faults ---------------------------------------------------------
    def sim_state(self) -> dict[str, Any]:
        """The simulator's truth: carriage position and mechanics (`GET {sim_url}/stage`)."""
        m = self.mech
        return {
            "true_mm": float(m.carriage_mm),
            "mm_per_step": float(self.mech_cfg.mm_per_step),
            "backlash_mm": float(self.mech_cfg.backlash_mm),
            "travel_mm": float(self.mech_cfg.travel_mm),
            "caliper_zero_mm": float(self.cal_cfg.zero_mm),
            "steps_taken": m.steps_taken,
            "steps_missed": m.steps_missed,
            "end_stop_hits": m.end_stop_hits,
            "min_mm_seen": float(m.min_mm_seen),
            "max_mm_seen": float(m.max_mm_seen),
            "stalled": m.stalled,
            "link_down": self.board.link_down,
            "resets": self.board.resets,
            "virtual_s": self.board.clock.now_us / 1e6,
        }

    def sim_garble(self, rate: float) -> None:
        """Flip one bit in each byte on the links (both ways) with this probability."""
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"garble rate {rate}; allowed 0..1")
        self._garble_rate = rate

    def sim_drop_connection(self) -> None:
        """Cut the TCP connection(s), as a WiFi drop would."""
        self.board.drop_clients()

    def sim_link_down(self, down: bool = True) -> None:
        """Take the TCP link down (cut it now and every new connection) or bring it back."""
        self.board.link_down = down
        if down:
            self.board.drop_clients()

    @property
    def link_down(self) -> bool:
        """Whether `sim_link_down` holds the TCP link down."""
        return self.board.link_down

    def sim_caliper_glitch(self, count: int = 1, kind: str = "bits") -> None:
        """Corrupt the next `count` caliper frames: 'bits', 'extra' or 'short'."""
        if kind not in ("bits", "extra", "short"):
            raise ValueError(f"glitch kind {kind!r}; allowed bits, extra, short")
        self.caliper.glitches.extend([kind] * count)

    def sim_stall(self, stalled: bool = True) -> None:
        """Stall the motor: step pulses no longer move it."""
        self.mech.stalled = stalled

    def sim_reset(self) -> None:
        """Reset the board (as the reset button or a brown-out would)."""
        self.board.request_reset()
