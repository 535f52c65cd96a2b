"""One way for the host's clients and workers to be context managers: ``with`` closes them."""

from __future__ import annotations

from types import TracebackType
from typing import Self


class Closing:
    """Base of objects holding a connection or a thread: leaving ``with`` calls ``close()``.

    Leaving early (an error, Ctrl-C) closes too; ``close()`` must be idempotent.
    """

    def close(self) -> None:
        """Release what the object holds."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
