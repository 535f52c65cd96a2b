"""Debian's Firefox ESR started headless for the tests, serving WebDriver BiDi on loopback.

There is no geckodriver on Debian: Firefox itself serves BiDi (``--remote-debugging-port``).
Port 0 lets Firefox pick a free port, which it writes to ``WebDriverBiDiServer.json`` in the
profile. The profile is new for each start, and its prefs stop Firefox's own background
traffic (updates, telemetry, remote settings, safe browsing, ...), so that the only
connections it makes are the ones a test asks for.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

# Background services that would otherwise call Mozilla or Google on start. Checked with
# `strace -f -e trace=connect,sendto`: with these (and MOZ_DISABLE_NONLOCAL_CONNECTIONS,
# which also lets `services.settings.server` be overridden on a release build) Firefox
# makes no DNS lookup and no connection of its own.
PREFS: dict[str, bool | int | str] = {
    "remote.active-protocols": 1,  # WebDriver BiDi only
    "network.proxy.type": 0,  # straight to the camera, whatever the environment says
    "app.update.disabledForTesting": True,
    "app.update.auto": False,
    "app.normandy.enabled": False,
    "app.normandy.api_url": "",
    "app.shield.optoutstudies.enabled": False,
    "messaging-system.rsexperimentloader.enabled": False,
    "services.settings.server": "data:,#remote-settings-dummy/v1",
    "datareporting.policy.dataSubmissionEnabled": False,
    "datareporting.healthreport.uploadEnabled": False,
    "toolkit.telemetry.enabled": False,
    "toolkit.telemetry.unified": False,
    "toolkit.telemetry.archive.enabled": False,
    "toolkit.telemetry.server": "",
    "browser.backup.enabled": False,
    "network.captive-portal-service.enabled": False,
    "network.connectivity-service.enabled": False,
    "network.trr.mode": 5,  # no DNS over HTTPS
    "network.dns.disablePrefetch": True,
    "network.prefetch-next": False,
    "network.http.speculative-parallel-limit": 0,
    "browser.safebrowsing.malware.enabled": False,
    "browser.safebrowsing.phishing.enabled": False,
    "browser.safebrowsing.downloads.enabled": False,
    "browser.safebrowsing.blockedURIs.enabled": False,
    "browser.safebrowsing.update.enabled": False,
    "media.gmp-manager.url": "",
    "media.gmp-manager.chromium-update-url": "",
    "media.gmp-manager.updateEnabled": False,
    "media.gmp-provider.enabled": False,
    "media.gmp-gmpopenh264.enabled": False,
    "media.gmp-widevinecdm.enabled": False,
    "extensions.update.enabled": False,
    "extensions.getAddons.cache.enabled": False,
    "extensions.blocklist.enabled": False,
    "browser.region.update.enabled": False,
    "browser.region.network.url": "",
    "browser.search.update": False,
    "browser.newtabpage.enabled": False,
    "browser.topsites.contile.enabled": False,
    "browser.startup.homepage_override.mstone": "ignore",
    "browser.aboutwelcome.enabled": False,
    "geo.provider.network.url": "",
    "identity.fxaccounts.enabled": False,
    "security.OCSP.enabled": 0,
}

START_TIMEOUT_S = 60.0  # a cold start on a loaded 2-core machine takes 5-20 s
STOP_TIMEOUT_S = 10.0


class FirefoxError(Exception):
    """Firefox did not start, or stopped before it served WebDriver BiDi."""


class FirefoxStartTimeout(FirefoxError, TimeoutError):  # noqa: N818 - like StageTimeout
    """Firefox did not serve WebDriver BiDi within the allowed time."""


class Firefox:
    """A headless Firefox of our own, in its own process group, with a fresh profile.

    Parameters
    ----------
    executable
        The Firefox binary (Debian's ``/usr/bin/firefox-esr``).
    workdir
        An empty directory for the profile and Firefox's output.
    """

    def __init__(self, executable: str, workdir: Path) -> None:
        self.profile = workdir / "profile"
        self.profile.mkdir()
        self.log = workdir / "firefox.log"
        lines = [f"user_pref({json.dumps(k)}, {json.dumps(v)});" for k, v in PREFS.items()]
        (self.profile / "user.js").write_text("\n".join(lines) + "\n")
        env = {**os.environ, "MOZ_DISABLE_NONLOCAL_CONNECTIONS": "1"}
        with self.log.open("wb") as out:
            self.proc = subprocess.Popen(
                [
                    executable,
                    "--headless",
                    "--no-remote",
                    "--remote-debugging-port=0",
                    "--profile",
                    str(self.profile),
                    "about:blank",
                ],
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,  # its own process group, killed whole in stop()
            )
        try:
            self.url = self._wait_for_bidi(executable)
        except BaseException:
            self.stop()
            raise

    def _wait_for_bidi(self, executable: str) -> str:
        server = self.profile / "WebDriverBiDiServer.json"
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise FirefoxError(
                    f"{executable} exited with status {self.proc.returncode} before serving "
                    f"WebDriver BiDi; its output:\n{self.output()}"
                )
            try:
                where = json.loads(server.read_text())
            except (FileNotFoundError, json.JSONDecodeError):  # not written (whole) yet
                time.sleep(0.1)
                continue
            if where["ws_host"] != "127.0.0.1":
                raise FirefoxError(f"Firefox serves BiDi on {where['ws_host']}, not loopback")
            return f"ws://127.0.0.1:{where['ws_port']}/session"
        raise FirefoxStartTimeout(
            f"{executable} did not serve WebDriver BiDi within {START_TIMEOUT_S:.0f} s "
            f"(no {server.name} in its profile); its output:\n{self.output()}"
        )

    def output(self, *, tail: int = 40) -> str:
        """The last lines Firefox wrote to stdout and stderr."""
        text = self.log.read_text(errors="replace") if self.log.exists() else ""
        return "\n".join(text.splitlines()[-tail:])

    def stop(self) -> None:
        """Wait briefly for Firefox to exit (after ``browser.close``), then kill its group.

        The group also holds Firefox's content processes, which outlive a killed parent.
        """
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(STOP_TIMEOUT_S)
        with contextlib.suppress(ProcessLookupError):  # the group is gone already
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
