"""Parameter changes for every camera backend: `Staging.set_params`, `Staging.staged`, `Applied`.

A backend that has ``params(port)`` and implements ``_set_params`` inherits ``set_params``
and ``staged``: the block runs with the settings written, and the previous values come back
afterwards, also after an error, and also when a write fails halfway through several
ports.
"""

from __future__ import annotations

import contextlib
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from elphel_host.errors import CameraClientError, ElphelError

if TYPE_CHECKING:
    from elphel_host.camera.protocol import CameraInterface


@dataclass(frozen=True)
class Applied:
    """Answer to a parameter change: the frame at which it is in effect, and the params."""

    frame: int
    params: dict[str, int]


class Staging(ABC):
    """``set_params`` and ``staged()``, written on the backend's ``params`` and ``_set_params``."""

    def set_params(
        self,
        changes: Mapping[str, int],
        *,
        port: int = 0,
        frame: int | None = None,
        ahead: int | None = None,
    ) -> Applied:
        """Change parameters at frame ``frame`` or ``ahead`` frames on; the frame they take.

        How, and with which guarantees, is the backend's: see its ``_set_params``.
        """
        return self._set_params(changes, port, frame, ahead)

    @abstractmethod
    def _set_params(
        self, changes: Mapping[str, int], port: int, frame: int | None, ahead: int | None
    ) -> Applied:
        """Change ``port``'s parameters at frame ``frame`` or ``ahead`` frames on."""

    @contextlib.contextmanager
    def staged(
        self: CameraInterface,
        changes: Mapping[str, int] | Mapping[int, Mapping[str, int]],
        *,
        port: int = 0,
    ) -> Iterator[dict[int, Applied]]:
        """Apply settings for a block and put the previous values back on exit.

        ``changes`` is a parameter dict for ``port``, or ``{port: {...}, ...}`` for several
        ports. If a port's change fails, the ports already changed are restored before the
        error is raised. Yields ``{port: Applied}``.

        Ports are restored in reverse order, each as soon as the previous one is accepted,
        not once it is in effect. A port in snapshot mode takes a change only at its next
        trigger, so do not restore a common trigger in the same block as the ports that
        wait for it: nest two blocks (trigger outside) and wait in between, as
        ``elphel tp capture`` does.
        """
        per_port = _per_port(changes, port)
        previous: dict[int, dict[str, int]] = {}
        applied: dict[int, Applied] = {}
        try:
            for p, values in per_port.items():
                now = self.params(p)
                previous[p] = {k: now[k] for k in values if k in now}
                applied[p] = self.set_params(values, port=p)
        except BaseException as e:
            try:
                _restore(self, previous, applied)
            except ElphelError as restore_error:
                e.add_note(str(restore_error))
            raise
        try:
            yield applied
        finally:
            _restore(self, previous, applied)


def _restore(
    camera: CameraInterface,
    previous: dict[int, dict[str, int]],
    applied: dict[int, Applied],
) -> None:
    errors = []
    for p in reversed(list(applied)):
        try:
            camera.set_params(previous[p], port=p)
        except ElphelError as e:
            errors.append(f"port {p}: {e}")
    if errors:
        raise CameraClientError("could not restore staged settings: " + "; ".join(errors))


def _per_port(changes: Mapping[Any, Any], port: int) -> dict[int, dict[str, int]]:
    per_port: dict[int, dict[str, int]] = {}
    for key, value in changes.items():
        if isinstance(key, int) and isinstance(value, Mapping):
            per_port[key] = dict(value)
        elif isinstance(key, str) and isinstance(value, int):
            per_port.setdefault(port, {})[key] = value
        else:
            raise ValueError(f"staged(): {key!r}: {value!r}; give NAME=int or port: {{...}}")
    return per_port
