"""pytest plugin: the ``elphel_rig`` fixture, a simulated rig served by ``elphel-sim up``.

Installed with elphel-sim (entry point ``pytest11``), so any project's tests can ask
for ``elphel_rig``. Each test gets its own rig on free loopback ports, stopped after
the test. Choose the scenario, seed and firmware with a marker::

    @pytest.mark.elphel_rig(scenario="default", seed=3)
    def test_my_script(elphel_rig): ...

or with an indirect parameter (a dict of the same keywords)::

    @pytest.mark.parametrize("elphel_rig", [{"seed": 1}, {"seed": 2}], indirect=True)
"""

from __future__ import annotations

import json
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from elphel_sim.scenarios import SCENARIOS

RIG_OPTIONS = ("scenario", "seed", "firmware")
FIRMWARES = ("camd", "elphel")


class RigStartError(RuntimeError):
    """``elphel-sim up`` did not announce a running rig."""


@dataclass(frozen=True)
class Rig:
    """A running simulated rig, as ``elphel-sim up --json`` announced it.

    Attributes
    ----------
    camera_url, token
        The camera's REST URL and its token (``None`` for the stock NC393 firmware).
    stage_url, stage_pty
        The stage's TCP URL and its pseudo-terminal.
    sim_url
        The simulator's truth URL (``{sim_url}/stage``, ``{sim_url}/world``...) and its
        fault hooks (``{sim_url}/faults``: `fault`, `faults`, `clear_faults`).
    scenario, seed, firmware
        What the rig was started with.
    camera_urls, tokens
        Every camera's URL and token: one per camera on a rig with a daemon per camera
        (pi-pair), else ``camera_url`` and ``token`` alone.
    lepton_urls, lepton_tokens
        A lepton-board daemon per Lepton port (mixed), reading the port's frames as VoSPI
        bytes; empty without Lepton ports.
    """

    camera_url: str
    token: str | None
    stage_url: str
    stage_pty: str | None
    sim_url: str
    scenario: str
    seed: int
    firmware: str
    camera_urls: tuple[str, ...] = ()
    tokens: tuple[str | None, ...] = ()
    lepton_urls: tuple[str, ...] = ()
    lepton_tokens: tuple[str, ...] = ()

    def fault(self, kind: str, **options: int) -> list[dict[str, Any]]:
        """Inject a fault into the running rig; return the faults now in effect.

        ``kind`` is one of `~elphel_sim.faults.FAULT_KINDS`:

        * ``"i2c_nak"`` (``port=0``, ``count=2``): the next ``count`` I2C transfers on
          that sensor port's bus are not acknowledged. elphel-camd tries each transfer
          twice, so the default 2 fails one access (1 is absorbed by its retry).
        * ``"motor_stall"``: the stage motor stops following its step pulses.
        * ``"stage_link_drop"``: the stage's TCP link goes down (the open connection is
          cut, new ones too) until `clear_faults`.

        Raises
        ------
        ValueError
            An unknown kind or option, or a value the fault does not allow (the
            simulator's message says which and what is allowed).
        """
        answer = self._faults_request("POST", json={"kind": kind, **options})
        return list(answer["faults"])

    def faults(self) -> list[dict[str, Any]]:
        """The faults in effect (an ``i2c_nak``'s ``count`` is what is left of it)."""
        return list(self._faults_request("GET")["faults"])

    def clear_faults(self) -> None:
        """Clear every fault: the buses answer, the motor moves, the stage link is back.

        A stage client whose link was cut must reconnect (``StageClient.reconnect``).
        """
        self._faults_request("DELETE")

    def _faults_request(self, method: str, **kwargs: Any) -> dict[str, Any]:
        import httpx

        r = httpx.request(method, f"{self.sim_url}/faults", timeout=10, **kwargs)
        if r.status_code in (404, 422):
            detail = r.json().get("detail")
            if isinstance(detail, list):  # pydantic's errors: name the first
                first = detail[0]
                where = ".".join(str(x) for x in first.get("loc", ())[1:])
                detail = f"{where or 'fault'}: {first.get('msg')}"
            raise ValueError(f"elphel_rig fault {kwargs.get('json')}: {detail}")
        r.raise_for_status()
        answer: dict[str, Any] = r.json()
        return answer


@dataclass(frozen=True)
class RigProcess:
    """A rig and the ``elphel-sim up`` process serving it."""

    rig: Rig
    proc: subprocess.Popen[str]


def start_rig(
    *,
    scenario: str = "default",
    seed: int = 0,
    firmware: str = "camd",
    timeout: float = 60.0,
    public_reads: bool = False,
) -> RigProcess:
    """Start ``elphel-sim up --json`` on free ports and wait for its announcement.

    ``public_reads`` starts it with ``--public-reads`` (reads answered without the token).

    Raises
    ------
    ValueError
        An unknown scenario or firmware.
    RigStartError
        The process printed no announcement within ``timeout`` seconds.
    """
    if scenario not in SCENARIOS:
        allowed = ", ".join(sorted(SCENARIOS))
        raise ValueError(f"elphel_rig scenario {scenario!r}; allowed {allowed}")
    if firmware not in FIRMWARES:
        raise ValueError(f"elphel_rig firmware {firmware!r}; allowed {', '.join(FIRMWARES)}")
    cmd = [sys.executable, "-m", "elphel_sim.cli", "up", "--json"]
    cmd += ["--scenario", scenario, "--seed", str(int(seed)), "--firmware", firmware]
    if public_reads:
        cmd.append("--public-reads")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = ""
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not line and proc.poll() is None:
            if sel.select(timeout=0.5):
                line = proc.stdout.readline()
    if not line:
        stderr = stop_rig(proc)
        raise RigStartError(f"elphel-sim up printed no JSON line; stderr: {stderr.strip()}")
    a = json.loads(line)
    rig = Rig(
        camera_url=a["camera_url"],
        token=a["token"],
        stage_url=a["stage_url"],
        stage_pty=a.get("stage_pty"),
        sim_url=a["sim_url"],
        scenario=scenario,
        seed=int(seed),
        firmware=firmware,
        camera_urls=tuple(a.get("camera_urls", [a["camera_url"]])),
        tokens=tuple(a.get("tokens", [a["token"]])),
        lepton_urls=tuple(a.get("lepton_urls", [])),
        lepton_tokens=tuple(a.get("lepton_tokens", [])),
    )
    return RigProcess(rig=rig, proc=proc)


def stop_rig(proc: subprocess.Popen[str], *, timeout: float = 20.0) -> str:
    """Stop ``elphel-sim up`` (SIGTERM, then SIGKILL); return what it wrote on stderr."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    stderr = proc.stderr.read() if proc.stderr is not None else ""
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()
    return stderr


def rig_options(request: pytest.FixtureRequest) -> dict[str, Any]:
    """The test's rig options: its ``elphel_rig`` marker, then an indirect parameter."""
    options: dict[str, Any] = {}
    marker = request.node.get_closest_marker("elphel_rig")
    if marker is not None:
        if marker.args:
            raise pytest.UsageError("@pytest.mark.elphel_rig takes keywords only")
        options.update(marker.kwargs)
    param = getattr(request, "param", None)
    if param is not None:
        if not isinstance(param, dict):
            raise pytest.UsageError(f"elphel_rig parameter {param!r}; allowed a dict")
        options.update(param)
    unknown = sorted(set(options) - set(RIG_OPTIONS))
    if unknown:
        raise pytest.UsageError(
            f"elphel_rig options {', '.join(unknown)}; allowed {', '.join(RIG_OPTIONS)}"
        )
    return options


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "elphel_rig(scenario='default', seed=0, firmware='camd'): the simulated rig of the "
        "elphel_rig fixture",
    )


@pytest.fixture
def elphel_rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    """A simulated rig served by ``elphel-sim up`` for this test, stopped after it."""
    try:
        started = start_rig(**rig_options(request))
    except (ValueError, RigStartError) as e:
        pytest.fail(str(e), pytrace=False)
    try:
        yield started.rig
    finally:
        stderr = stop_rig(started.proc)
        if started.proc.returncode not in (0, -signal.SIGTERM):
            pytest.fail(f"elphel-sim up exited {started.proc.returncode}: {stderr}", pytrace=False)
