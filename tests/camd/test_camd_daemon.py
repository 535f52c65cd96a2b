"""`elphel-camd` as a process: settings, the token file, and parameters that survive kill -9."""

import json
import os
import random
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from elphel_camd import store
from elphel_camd.cli import build_parser, build_service, settings_from_args
from elphel_camd.config import ConfigError, DaemonSettings, load_settings
from elphel_camd.store import (
    ParamStore,
    last_journal_line,
    load_or_create_token,
    new_token,
    write_atomic,
)

REPO = Path(__file__).resolve().parents[2]
LAYER_CONFIG = REPO / "yocto/meta-elphel/recipes-camera/elphel-camd/files/config.json"


def test_settings_come_from_cli_then_environment_then_file(tmp_path, monkeypatch):
    cfg = tmp_path / "config.json"
    cfg.write_text(json.dumps({"host": "0.0.0.0", "port": 9000, "public_reads": True}))
    monkeypatch.setenv("ELPHEL_CAMD_PORT", "9100")
    monkeypatch.setenv("ELPHEL_CAMD_TOKEN", "from-env")
    s = load_settings(cfg)
    assert (s.host, s.port, s.public_reads) == ("0.0.0.0", 9100, True)
    assert s.token is not None and s.token.get_secret_value() == "from-env"
    args = build_parser().parse_args(["--board", "sim", "--config", str(cfg), "--port", "9200"])
    assert settings_from_args(args).port == 9200
    assert s.token_path == s.state_dir / "token"


def test_unknown_or_invalid_settings_are_rejected(tmp_path, monkeypatch):
    cfg = tmp_path / "config.json"
    cfg.write_text(json.dumps({"hots": "0.0.0.0"}))
    settings = load_settings(cfg)  # not a setting: a board option, which the board rejects
    assert settings.board_options == {"hots": "0.0.0.0"}
    with pytest.raises(ConfigError, match=r"hots.*allowed: noise, scenario, seed"):
        build_service(settings.model_copy(update={"board": "sim"}))
    cfg.write_text(json.dumps({"scenario": "default", "seed": 3}))  # the file's first form
    assert load_settings(cfg).board_options == {"scenario": "default", "seed": 3}
    cfg.write_text("[1]")
    with pytest.raises(ConfigError, match="JSON object"):
        load_settings(cfg)
    monkeypatch.setenv("ELPHEL_CAMD_PORT", "70000")
    with pytest.raises(ConfigError, match="port"):
        load_settings(None)


def test_the_yocto_layer_config_file_is_valid_and_runs_the_i2c_board():
    s = load_settings(LAYER_CONFIG)
    assert s.bus_urls == ["/dev/i2c-0", "/dev/i2c-1", "/dev/i2c-2", "/dev/i2c-3"]
    args = build_parser().parse_args(["--board", "i2c", "--config", str(LAYER_CONFIG)])
    assert settings_from_args(args).board == "i2c"


def test_board_options_reach_the_board(tmp_path):
    s = DaemonSettings(board="sim", board_options={"seed": 4, "noise": False}, state_dir=tmp_path)
    camera = build_service(s)
    try:
        assert camera.board.seed == 4 and camera.board.noise is False
        assert camera.store is not None and camera.store.directory == tmp_path / "params"
    finally:
        camera.close()


def test_token_file_is_created_0600_once_and_reused(tmp_path):
    path = tmp_path / "state" / "token"
    token = load_or_create_token(path)
    assert len(token) >= 24
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert load_or_create_token(path) == token


def test_new_tokens_never_start_with_a_dash(monkeypatch):
    # A token starting with "-" is taken for an option in `elphel ... --token T`.
    drawn = iter(["-starts-like-an-option", "-again", "fine-token"])
    monkeypatch.setattr(store.secrets, "token_urlsafe", lambda n: next(drawn))
    assert new_token() == "fine-token"


def test_atomic_write_leaves_old_or_new_file_and_store_ignores_bad_files(tmp_path):
    target = tmp_path / "p.json"
    write_atomic(target, b'{"a": 1}')
    write_atomic(target, b'{"a": 2}')
    assert json.loads(target.read_text()) == {"a": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["p.json"]
    (tmp_path / ".p.json.x.tmp").write_text("half")  # what a kill leaves behind
    store = ParamStore(tmp_path)
    assert not list(tmp_path.glob(".*.tmp"))
    store.path(0).write_text("{garbage")
    assert store.load(0, "MT9P006") is None
    store.save(0, "MT9P006", {"EXPOS": 5})
    assert store.load(0, "MT9P006") == {"EXPOS": 5}
    assert store.load(0, "MT9F002") is None
    store.close()


def test_journal_keeps_the_last_intact_line_and_compacts(tmp_path):
    store = ParamStore(tmp_path)
    store.save(0, "MT9P006", {"EXPOS": 5})
    store.save(0, "MT9P006", {"EXPOS": 6})
    store.close()
    journal = tmp_path / "port0.log"
    intact = journal.read_bytes()
    # A power loss may leave a partial line or zeros at the end: skipped, not fatal.
    for tail in (b'{"version":1,"port":0,"sensor":"MT9P006","params":{"EXPOS":7}}\t0', b"\0" * 40):
        journal.write_bytes(intact + tail)
        with ParamStore(tmp_path) as fresh:
            assert fresh.load(0, "MT9P006") == {"EXPOS": 6}
    # A line whose CRC does not match is not trusted either.
    journal.write_bytes(intact.replace(b'"EXPOS":6', b'"EXPOS":9'))
    with ParamStore(tmp_path) as fresh:
        assert fresh.load(0, "MT9P006") == {"EXPOS": 5}

    for sync_each in (False, True):
        store = ParamStore(tmp_path / str(sync_each), sync_each=sync_each)
        store.compact_bytes = 2000
        for i in range(200):
            store.save(1, "MT9F002", {"EXPOS": i})
        store.close()
        journal = store.journal_path(1)
        assert journal.stat().st_size <= 2000 + 200  # emptied as it grew
        assert json.loads(store.path(1).read_text())["params"]["EXPOS"] >= 150
        with ParamStore(store.directory) as fresh:
            assert fresh.load(1, "MT9F002") == {"EXPOS": 199}
        # The snapshot alone (journal lost or emptied) is a valid state too.
        journal.write_bytes(b"")
        with ParamStore(store.directory) as fresh:
            assert fresh.load(1, "MT9F002") is not None


def test_a_save_during_compaction_is_kept(tmp_path, monkeypatch):
    from elphel_camd import store as store_module

    store = ParamStore(tmp_path, sync_each=True)
    store.compact_bytes = 200
    real = store_module.write_atomic
    raced = []

    def write_then_race(path, data, **kw):
        real(path, data, **kw)
        if not raced:  # another request's save lands while the snapshot is written
            raced.append(1)
            limit, store.compact_bytes = store.compact_bytes, 1 << 30  # no compaction of its own
            store.save(0, "MT9P006", {"EXPOS": 99})
            store.compact_bytes = limit

    monkeypatch.setattr(store_module, "write_atomic", write_then_race)
    i = 0
    while not raced:  # until the journal is long enough to be compacted
        store.save(0, "MT9P006", {"EXPOS": i})
        i += 1
    # The snapshot holds the state before the race; the raced save's line was not thrown
    # away with the journal, and it is what a restart restores.
    assert json.loads(store.path(0).read_text())["params"] == {"EXPOS": i - 1}
    assert b'"EXPOS":99' in store.journal_path(0).read_bytes()
    store.close()
    with ParamStore(tmp_path) as fresh:
        assert fresh.load(0, "MT9P006") == {"EXPOS": 99}


# -- the daemon as a process -----------------------------------------------------------------


class Daemon:
    """`elphel-camd --board sim` in a subprocess, its log in a file of its own."""

    starts = 0

    def __init__(self, state: Path, env: dict[str, str]) -> None:
        Daemon.starts += 1
        self.log = state / f"daemon{Daemon.starts}.log"
        config = state / "config.json"
        config.write_text(
            json.dumps(
                {
                    "state_dir": str(state),
                    "board_options": {"seed": 1},
                    "access_log": False,
                    "log_level": "warning",
                }
            )
        )
        command = [sys.executable, "-m", "elphel_camd.cli", "--board", "sim"]
        command += ["--config", str(config), "--port", "0"]
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(
                command, stdout=subprocess.DEVNULL, stderr=log, env={**os.environ, **env}
            )
        self.url = self._wait_for_url()

    def _wait_for_url(self) -> str:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            text = self.log.read_text()
            if "listening on http://" in text:
                return text.split("listening on ", 1)[1].split()[0]
            if self.proc.poll() is not None:
                pytest.fail(f"elphel-camd exited {self.proc.returncode}: {text}")
            time.sleep(0.05)
        self.kill()
        pytest.fail("elphel-camd did not start listening in 60 s")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()


def exposure(i: int) -> int:
    return 1000 + 301 * i


def test_kill_9_during_200_writes_restarts_with_the_last_acknowledged_state(tmp_path):
    env = {"ELPHEL_CAMD_TOKEN": ""}  # no token configured: the daemon makes the token file
    rng = random.Random(8)
    writes, acked, restarts = 0, None, 0
    token, pending = None, None
    window = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1000, "WOI_TOP": 800}
    while writes < 200:
        daemon = Daemon(tmp_path, env)
        restarts += 1
        token_file = tmp_path / "token"
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        if token is None:
            token = token_file.read_text().strip()
        assert token_file.read_text().strip() == token  # reused across restarts
        with httpx.Client(
            base_url=daemon.url + "/api/v1",
            headers={"Authorization": f"Bearer {token}"},
            timeout=20,
        ) as http:
            now = http.get("/ports/0/params").json()
            if acked is not None:
                restored = {k: now[k] for k in acked}
                assert restored == acked or restored == in_flight_expect(now, pending), (
                    restored,
                    acked,
                    pending,
                )
                line = last_journal_line(tmp_path / "params" / "port0.log")
                assert line is not None
                saved = json.loads(line)
                assert saved["params"]["EXPOS"] == now["EXPOS"]
            assert http.patch("/ports/0/params", json={"EXPOS": 5}).status_code in (200, 422)
            unauth = httpx.patch(daemon.url + "/api/v1/ports/0/params", json={"EXPOS": 5000})
            assert unauth.status_code == 401
            # Kill at a random moment after a random number of writes: mid-request, while
            # saving, or between two requests.
            kill_after = writes + rng.randint(45, 65)
            killer = threading.Timer(3600, daemon.kill)
            try:
                while writes < 200:
                    if writes == kill_after:
                        killer = threading.Timer(rng.uniform(0, 0.02), daemon.kill)
                        killer.start()
                    pending = {**window, "EXPOS": exposure(writes), "FLIPH": writes % 2}
                    writes += 1
                    try:
                        r = http.patch("/ports/0/params", json=pending)
                    except httpx.HTTPError:
                        break
                    assert r.status_code == 200, r.text
                    acked = {k: r.json()["params"][k] for k in pending}
                    pending = None
            finally:
                killer.cancel()
                daemon.kill()
    assert restarts >= 3
    final = Daemon(tmp_path, env)
    try:
        now = httpx.get(
            final.url + "/api/v1/ports/0/params",
            headers={"Authorization": f"Bearer {token}"},
            timeout=20,
        ).json()
        restored = {k: now[k] for k in acked}
        assert restored == acked or restored == in_flight_expect(now, pending)
    finally:
        final.kill()


def in_flight_expect(now: dict, pending: dict | None) -> dict | None:
    """The state if the write in flight at the kill was saved but not acknowledged."""
    if pending is None:
        return None
    got = {k: now[k] for k in pending}
    same = all(got[k] == v for k, v in pending.items() if k != "EXPOS")
    close = abs(got["EXPOS"] - pending["EXPOS"]) < 150  # EXPOS is rounded to whole rows
    return got if same and close else pending
