"""The caliper stage as a Micro-Manager focus (Z) stage: µm in the caliper frame.

A position is what the caliper shows there, in micrometres. `set_position_um` starts a
closed-loop move (`Positioner.move_closed_loop`) in a thread and returns at once; the
device is busy until the caliper confirms the target, which is how Micro-Manager's
``waitForDevice`` and the MDA runner expect a stage to behave. A move that fails (a
stall, a limit, a closed-loop miss) is raised by the next ``busy()`` call, so
``waitForDevice`` and the MDA runner see it instead of a silently wrong position.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymmcore_plus.experimental.unicore import StageDevice

from elphel_host.errors import StageBusyError, StageError
from elphel_host.stage.client import MoveStatus, StageClient
from elphel_host.stage.model import StageModel
from elphel_host.stage.positioning import Positioner


class MoveStopped(StageError):  # noqa: N818 - an outcome, like StageTimeout
    """A move or homing was ended by `ElphelStageDevice.stop`."""


class _StoppableClient:
    """The stage client as the positioner sees it: no new motion once a stop was asked."""

    def __init__(self, client: StageClient, stopping: threading.Event) -> None:
        self._client = client
        self._stopping = stopping

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)

    def _check(self) -> None:
        if self._stopping.is_set():
            raise MoveStopped("stopped by the user")

    def move_to_steps(self, target_steps: int) -> MoveStatus:
        self._check()
        return self._client.move_to_steps(target_steps)

    def move_by_steps(self, delta_steps: int) -> MoveStatus:
        self._check()
        return self._client.move_by_steps(delta_steps)


class ElphelStageDevice(StageDevice):
    """The elphel-rig linear stage, closed loop on its caliper (positions in µm).

    Parameters
    ----------
    url
        The stage's pyserial URL (``socket://HOST:PORT``, ``/dev/ttyUSB0``, a pty).
    model_path
        A calibration saved by ``elphel stage calibrate`` (its mm/step and backlash);
        without one the nominal mm/step is used and the closed loop fits the rest.
    home_on_init
        Home the stage when it is loaded and not homed yet (moves need a homed stage).
    tolerance_um
        Extra tolerance of a closed-loop move beyond half a caliper LSB (5 µm).
    move_timeout_s
        Longest a single motion may take.
    """

    def __init__(
        self,
        url: str,
        *,
        model_path: str | Path | None = None,
        home_on_init: bool = True,
        tolerance_um: float = 5.0,
        move_timeout_s: float = 120.0,
    ) -> None:
        super().__init__()
        self.url = url
        self.model_path = Path(model_path) if model_path is not None else None
        self.home_on_init = home_on_init
        self.move_timeout_s = move_timeout_s
        self._client: StageClient | None = None
        self._positioner: Positioner | None = None
        self._stopping = threading.Event()
        self._worker: threading.Thread | None = None
        self._error: BaseException | None = None
        self._position_um: float | None = None  # the last caliper-verified position
        self.register_property("URL", default_value=url, is_read_only=True)
        self.register_property(
            "ToleranceUm",
            default_value=float(tolerance_um),
            limits=(0.0, 100.0),
            property_type=float,
        )
        self.register_property(
            "Steps", property_type=int, getter=type(self)._get_steps, is_read_only=True
        )

    # -- lifecycle ------------------------------------------------------------------------

    def initialize(self) -> None:
        client = StageClient(self.url)
        self._client = client
        model = StageModel.load(self.model_path) if self.model_path else StageModel()
        self._positioner = Positioner(
            _StoppableClient(client, self._stopping),  # type: ignore[arg-type]
            model,
            move_timeout_s=self.move_timeout_s,
        )
        if self.home_on_init and not client.status().homed:
            client.home().wait(self.move_timeout_s)
        if client.status().homed:
            self._position_um = self._positioner.read_mm() * 1000.0

    def shutdown(self) -> None:
        if self._worker is not None and self._worker.is_alive():
            self.stop()
            self._worker.join(self.move_timeout_s)
        if self._client is not None:
            self._client.close()
            self._client = None

    @property
    def client(self) -> StageClient:
        if self._client is None:
            raise StageError(f"stage {self.url!r} is not initialised (load it into a core)")
        return self._client

    @property
    def positioner(self) -> Positioner:
        if self._positioner is None:
            raise StageError(f"stage {self.url!r} is not initialised (load it into a core)")
        return self._positioner

    # -- motion in a worker thread --------------------------------------------------------

    def _start(self, what: str, work: Callable[[], float | None]) -> None:
        if self._worker is not None and self._worker.is_alive():
            raise StageBusyError(
                f"stage {self.url!r} is still moving; wait for it or stop it before {what}",
                code=8,
                keyword="MOVE",
            )
        self._stopping.clear()
        self._error = None
        self._position_um = None

        def run() -> None:
            try:
                self._position_um = work()
            except MoveStopped:
                self._position_um = None
            except StageError as e:
                # A stop asked for ends the motion under way with an error of its own.
                if not self._stopping.is_set():
                    self._error = e
                self._position_um = None
            except BaseException as e:
                self._error = e

        self._worker = threading.Thread(target=run, name=f"elphel-stage {what}", daemon=True)
        self._worker.start()

    def set_position_um(self, val: float) -> None:
        """Start a closed-loop move to ``val`` µm (caliper frame); busy until it ends."""
        target_mm = float(val) / 1000.0
        tolerance_mm = float(self.get_property_value("ToleranceUm")) / 1000.0

        def move() -> float:
            result = self.positioner.move_closed_loop(target_mm, tolerance_mm=tolerance_mm)
            return result.caliper_mm * 1000.0

        self._start(f"moving to {val} µm", move)

    def get_position_um(self) -> float:
        """The last caliper-verified position; while moving, the step model's estimate."""
        if self._position_um is not None:
            return self._position_um
        st = self.client.status()
        model = self.positioner.model
        if st.moving and model.offset_mm is not None:
            return model.mm_at(st.steps) * 1000.0
        if st.moving:
            return float("nan")  # no reference yet: the first reading comes after the move
        position = self.positioner.read_mm() * 1000.0
        if self._worker is None or not self._worker.is_alive():
            self._position_um = position
        return position

    def busy(self) -> bool:
        """Whether a move or homing is running; raises the error a finished move ended in."""
        if self._worker is not None and self._worker.is_alive():
            return True
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        return False

    def home(self) -> None:
        """Home onto the min limit switch (busy until done); the step frame starts again."""

        def run() -> None:
            self.client.home().wait(self.move_timeout_s)
            self._forget_reference()

        self._start("homing", lambda: run())

    def stop(self) -> None:
        """Stop now: no further motion of a running move, and the motor stopped."""
        self._stopping.set()
        self.client.stop()

    def set_origin(self) -> None:
        """Zero the caliper here: this position becomes 0 µm."""
        if self.busy():
            raise StageBusyError(
                f"stage {self.url!r} is moving; stop it before zeroing", code=8, keyword="ZERO"
            )
        self.client.zero_caliper()
        self._forget_reference()
        self._position_um = self.positioner.read_mm() * 1000.0

    def _forget_reference(self) -> None:
        # Homing re-zeroes the steps and zeroing the caliper moves the caliper frame:
        # the step-to-caliper offset and the last verified reading no longer hold.
        pos = self.positioner
        pos.model.offset_mm = None
        pos.last_dir = 0
        pos._verified = None

    def _get_steps(self) -> int:
        return self.client.status().steps
