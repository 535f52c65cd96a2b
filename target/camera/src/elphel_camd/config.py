"""Daemon settings: `DaemonSettings`, `load_settings` and the config file they read.

Settings come, strongest first, from the command line, ``ELPHEL_CAMD_*`` environment
variables, the JSON config file (``--config``; ``/etc/elphel-camd/config.json`` when it
exists) and the defaults below. A file key that is no setting is a keyword argument of
the board factory (``board_options``); the factory rejects names it does not take. What
the daemon writes to disk (token file, parameters) is `elphel_camd.store`'s.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from pydantic import Field, SecretStr, ValidationError
from pydantic_settings import (
    BaseSettings,
    InitSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from elphel_camd.errors import ConfigError

__all__ = ["DEFAULT_CONFIG", "ConfigError", "DaemonSettings", "load_settings", "read_config_file"]

DEFAULT_CONFIG = Path("/etc/elphel-camd/config.json")


def default_state_dir() -> Path:
    """Where the daemon keeps its token and parameters.

    systemd's ``StateDirectory=`` (``$STATE_DIRECTORY``), else ``/var/lib/elphel-camd`` for
    root, else ``$XDG_STATE_HOME/elphel-camd`` (``~/.local/state/elphel-camd``).
    """
    if os.environ.get("STATE_DIRECTORY"):
        return Path(os.environ["STATE_DIRECTORY"].split(":")[0])
    if os.geteuid() == 0:
        return Path("/var/lib/elphel-camd")
    xdg = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(xdg) / "elphel-camd"


class DaemonSettings(BaseSettings):
    """Everything the daemon reads at start-up (file keys = field names)."""

    model_config = SettingsConfigDict(
        env_prefix="ELPHEL_CAMD_", extra="forbid", validate_default=True
    )

    host: str = Field("127.0.0.1", description="address to listen on (loopback by default)")
    port: int = Field(8000, ge=0, le=65535, description="TCP port (0 = any free port)")
    board: str | None = Field(None, description="board type (the command line's --board wins)")
    bus_urls: list[str] = Field(
        default_factory=list, description="I2C bus URL per port (i2c board), e.g. /dev/i2c-0"
    )
    video: list[str] = Field(
        default_factory=list,
        description="V4L2 capture node per port (v4l2 board), e.g. /dev/video0",
    )
    sensor: str | None = Field(
        None,
        description="kernel driver of the v4l2 ports' sensor, for its gain laws (e.g. imx219; "
        "default: the node's card name)",
    )
    board_options: dict[str, Any] = Field(
        default_factory=dict, description="keyword arguments of the board factory"
    )
    token: SecretStr | None = Field(
        None, description="bearer token for writes (usually env ELPHEL_CAMD_TOKEN)"
    )
    token_file: Path | None = Field(
        None, description="token file, created 0600 on first start (default STATE_DIR/token)"
    )
    public_reads: bool = Field(
        False, description="answer reads without the token (writes still need it)"
    )
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="host names the Host header may carry besides IP addresses and "
        "localhost (DNS-rebinding guard), e.g. the camera's DNS name; * allows any",
    )
    cors_origins: list[str] = Field(
        default_factory=list, description="origins whose browser pages may call the API"
    )
    tls_cert: Path | None = Field(None, description="TLS certificate (PEM): serve https")
    tls_key: Path | None = Field(None, description="TLS private key (PEM) of tls_cert")
    max_header_bytes: int = Field(
        16384, ge=1024, description="largest request head (request line and headers)"
    )
    state_dir: Path = Field(default_factory=default_state_dir, description="daemon state")
    params_dir: Path | None = Field(
        None, description="per-port parameter files (default STATE_DIR/params)"
    )
    persist_params: bool = Field(True, description="persist accepted parameter changes")
    params_fsync_each: bool = Field(
        False,
        description="fsync each parameter file before answering (else right after, in the "
        "background; a killed daemon keeps every answered change either way)",
    )
    max_body_bytes: int = Field(65536, ge=1024, description="largest request body accepted")
    event_queue: int = Field(256, ge=1, description="events buffered per SSE client")
    stream_idle_s: float = Field(
        300.0,
        gt=0,
        allow_inf_nan=False,
        description="an event stream without an event of its types for this long ends",
    )
    log_level: str = Field("info", pattern="^(critical|error|warning|info|debug)$")
    access_log: bool = Field(True, description="log every request")

    @property
    def token_path(self) -> Path:
        return self.token_file if self.token_file is not None else self.state_dir / "token"

    @property
    def params_path(self) -> Path:
        return self.params_dir if self.params_dir is not None else self.state_dir / "params"

    # The config file's values, weakest of the sources; `load_settings` sets them on a
    # subclass, so plain `DaemonSettings()` reads the command line and environment only.
    file_values: ClassVar[Mapping[str, Any]] = {}

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        file_settings = InitSettingsSource(settings_cls, dict(cls.file_values))
        return (init_settings, env_settings, file_settings)


def read_config_file(path: Path) -> dict[str, Any]:
    """The JSON object of a config file (ConfigError if unreadable or not an object)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read config {path}: {e}") from e
    if not isinstance(data, dict):
        raise ConfigError(f"config {path}: a JSON object is needed, not {type(data).__name__}")
    return data


def load_settings(config: Path | None = None, **overrides: Any) -> DaemonSettings:
    """Settings from overrides (the command line), then environment, then the file.

    Parameters
    ----------
    config
        JSON config file; None reads `DEFAULT_CONFIG` when it exists.
    overrides
        Values that beat every other source (None values are ignored).
    """
    if config is None and DEFAULT_CONFIG.is_file():
        config = DEFAULT_CONFIG
    from_file = read_config_file(config) if config is not None else {}
    # Keys that are not settings are the board factory's keyword arguments (the file's
    # original form, e.g. {"scenario": "default", "seed": 3}); the factory rejects unknown
    # ones when the board is built.
    extra = {k: from_file.pop(k) for k in list(from_file) if k not in DaemonSettings.model_fields}
    if extra:
        from_file["board_options"] = {**extra, **from_file.get("board_options", {})}
    given = {k: v for k, v in overrides.items() if v is not None}

    class _FromFile(DaemonSettings):
        file_values = from_file

    try:
        loaded = _FromFile(**given)
    except ValidationError as e:
        where = f"config {config} or " if config is not None else ""
        raise ConfigError(f"invalid settings ({where}ELPHEL_CAMD_* environment): {e}") from e
    return loaded
