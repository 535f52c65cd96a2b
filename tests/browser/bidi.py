"""A small WebDriver BiDi client: what the Firefox tests need, and no more.

`Session` is one WebSocket to the browser: commands wait for their answer (by id) while a
reader thread passes events to listeners. `Tab` is a top-level browsing context in a user
context of its own (its storage is not shared with other tabs, like a Playwright context)
that records console and script errors, failed responses and the requests it makes.

Protocol: https://w3c.github.io/webdriver-bidi/
"""

from __future__ import annotations

import base64
import contextlib
import itertools
import json
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from pathlib import Path
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

COMMAND_TIMEOUT_S = 30.0
ENTER = "\ue007"  # WebDriver's key value for Enter

Listener = Callable[[str, dict[str, Any]], None]


class BidiError(Exception):
    """The browser answered a command with an error."""

    def __init__(self, method: str, error: str, message: str) -> None:
        super().__init__(f"{method}: {error}: {message}")
        self.method = method
        self.error = error


class BidiTimeout(BidiError, TimeoutError):  # noqa: N818 - like StageTimeout
    """No answer to a command, or a condition in the page not met, in the time allowed."""


class ScriptError(BidiError):
    """A script run in the page threw."""


class Session:
    """One WebDriver BiDi session over the WebSocket at ``url`` (``ws://.../session``)."""

    def __init__(self, url: str) -> None:
        self._stack = contextlib.ExitStack()
        # max_size: screenshots are megabytes of base64. No pings: Firefox answers every
        # command, and a long screenshot must not read as a dead connection.
        self._ws = self._stack.enter_context(
            connect(url, max_size=None, ping_interval=None, proxy=None, open_timeout=30)
        )
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._waiting: dict[int, tuple[str, Future[dict[str, Any]]]] = {}
        self._listeners: list[Listener] = []
        self._reader = threading.Thread(target=self._read, name="bidi-reader", daemon=True)
        self._reader.start()
        self.capabilities = self.command("session.new", {"capabilities": {}})["capabilities"]

    def command(
        self, method: str, params: dict[str, Any], *, timeout_s: float = COMMAND_TIMEOUT_S
    ) -> dict[str, Any]:
        """Send ``method`` and return its result; raise `BidiError` if it failed."""
        answer: Future[dict[str, Any]] = Future()
        with self._lock:
            ident = next(self._ids)
            self._waiting[ident] = (method, answer)
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        try:
            return answer.result(timeout_s)
        except FutureTimeout:
            raise BidiTimeout(method, "timeout", f"no answer in {timeout_s:.0f} s") from None
        finally:
            with self._lock:
                self._waiting.pop(ident, None)

    def listen(self, listener: Listener) -> None:
        """Call ``listener(method, params)`` for every event (from the reader thread)."""
        self._listeners.append(listener)

    def unlisten(self, listener: Listener) -> None:
        self._listeners.remove(listener)

    def _read(self) -> None:
        try:
            for text in self._ws:
                message = json.loads(text)
                if message.get("type") == "event":
                    for listener in list(self._listeners):
                        listener(message["method"], message["params"])
                    continue
                with self._lock:
                    method, answer = self._waiting.pop(message.get("id"), ("", None))
                if answer is None:
                    continue  # an answer nobody waits for any more (it timed out)
                if message.get("type") == "success":
                    answer.set_result(message["result"])
                else:
                    answer.set_exception(
                        BidiError(method, message.get("error", "?"), message.get("message", ""))
                    )
        except ConnectionClosed:
            pass
        with self._lock:
            pending = list(self._waiting.values())
            self._waiting.clear()
        for method, answer in pending:
            answer.set_exception(BidiError(method, "closed", "the browser closed the connection"))

    def close_browser(self) -> None:
        """Ask the browser to close (it ends the session), then close the connection."""
        try:
            self.command("browser.close", {}, timeout_s=10)
        except BidiError:
            pass  # closed before it answered: what was asked
        finally:
            self._stack.close()
            self._reader.join(10)


def _remote(value: Any) -> dict[str, Any]:
    """A Python value as a BiDi LocalValue (shared references pass through)."""
    if isinstance(value, dict) and "sharedId" in value:
        return {"sharedId": value["sharedId"]}
    if value is None:
        return {"type": "null"}
    if isinstance(value, bool):
        return {"type": "boolean", "value": value}
    if isinstance(value, int | float):
        return {"type": "number", "value": value}
    if isinstance(value, str):
        return {"type": "string", "value": value}
    if isinstance(value, list | tuple):
        return {"type": "array", "value": [_remote(v) for v in value]}
    raise TypeError(f"cannot pass {value!r} ({type(value).__name__}) to the page")


def _python(remote: dict[str, Any]) -> Any:
    """A BiDi RemoteValue as a Python value (nodes stay references, for `Tab.call`)."""
    kind = remote["type"]
    if kind in ("undefined", "null"):
        return None
    if kind in ("string", "boolean"):
        return remote["value"]
    if kind == "number":
        v = remote["value"]
        return float(v) if isinstance(v, str) else v  # "NaN", "Infinity", "-0"
    if kind in ("array", "set"):
        return [_python(v) for v in remote.get("value", [])]
    if kind == "object":
        return {k: _python(v) for k, v in remote.get("value", [])}
    return remote  # node, window, function, ...: kept as the reference it is


class Tab:
    """A new tab in its own user context, at ``width`` x ``height`` CSS pixels.

    ``errors`` collects console errors, uncaught script errors, answers with an HTTP error
    status and failed requests (except those the page aborted itself); ``requests`` the
    (method, URL) of every request the tab made.
    """

    EVENTS = (
        "log.entryAdded",
        "network.beforeRequestSent",
        "network.responseCompleted",
        "network.fetchError",
    )

    def __init__(self, session: Session, *, width: int, height: int) -> None:
        self.session = session
        self.errors: list[str] = []
        self.requests: list[tuple[str, str]] = []
        self.user_context = session.command("browser.createUserContext", {})["userContext"]
        self.context = session.command(
            "browsingContext.create", {"type": "tab", "userContext": self.user_context}
        )["context"]
        session.listen(self._event)
        self.subscription = session.command(
            "session.subscribe", {"events": list(self.EVENTS), "contexts": [self.context]}
        )["subscription"]
        session.command(
            "browsingContext.setViewport",
            {"context": self.context, "viewport": {"width": width, "height": height}},
        )

    def _event(self, method: str, params: dict[str, Any]) -> None:
        context = params.get("context") or params.get("source", {}).get("context")
        if context != self.context:
            return
        if method == "log.entryAdded" and params.get("level") == "error":
            self.errors.append(f"{params['type']}: {params.get('text')}")
        elif method == "network.beforeRequestSent":
            self.requests.append((params["request"]["method"], params["request"]["url"]))
        elif method == "network.responseCompleted" and params["response"]["status"] >= 400:
            self.errors.append(f"HTTP {params['response']['status']}: {params['request']['url']}")
        elif method == "network.fetchError" and "ABORT" not in params["errorText"]:
            self.errors.append(f"{params['errorText']}: {params['request']['url']}")

    def navigate(self, url: str) -> None:
        """Go to ``url`` and wait for its load event."""
        self.session.command(
            "browsingContext.navigate", {"context": self.context, "url": url, "wait": "complete"}
        )

    def _script(self, method: str, params: dict[str, Any]) -> Any:
        params = {
            **params,
            "target": {"context": self.context},
            "awaitPromise": True,
            "resultOwnership": "none",
        }
        answer = self.session.command(method, params)
        if answer["type"] == "exception":
            details = answer["exceptionDetails"]
            raise ScriptError(method, "exception", details.get("text", str(details)))
        return _python(answer["result"])

    def evaluate(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (promises are awaited)."""
        return self._script("script.evaluate", {"expression": expression})

    def call(self, function: str, *args: Any) -> Any:
        """Call a JavaScript function declaration with ``args`` (values or node references)."""
        return self._script(
            "script.callFunction",
            {"functionDeclaration": function, "arguments": [_remote(a) for a in args]},
        )

    def element(self, selector: str) -> dict[str, Any]:
        """A reference to the first element matching the CSS ``selector``."""
        node = self.call("(s) => document.querySelector(s)", selector)
        if node is None:
            raise BidiError("element", "no such element", f"nothing matches {selector!r}")
        return node

    def attribute(self, selector: str, name: str) -> str | None:
        return self.call(
            "(s, n) => document.querySelector(s)?.getAttribute(n) ?? null", selector, name
        )

    def wait_for(self, expression: str, *, timeout_s: float = 30.0) -> Any:
        """Poll a JavaScript expression until it is truthy; return its value."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise BidiTimeout(
                    "wait_for", "timeout", f"{expression} still {value!r} after {timeout_s:.0f} s"
                )
            time.sleep(0.1)

    def _actions(self, *sources: dict[str, Any]) -> None:
        self.session.command(
            "input.performActions", {"context": self.context, "actions": list(sources)}
        )

    def click(self, selector: str) -> None:
        """A real mouse click at the middle of the element (which must be in view)."""
        origin = {"type": "element", "element": self.element(selector)}
        self._actions(
            {
                "type": "pointer",
                "id": "mouse",
                "parameters": {"pointerType": "mouse"},
                "actions": [
                    {"type": "pointerMove", "x": 0, "y": 0, "origin": origin},
                    {"type": "pointerDown", "button": 0},
                    {"type": "pointerUp", "button": 0},
                ],
            }
        )

    def type(self, text: str) -> None:
        """Key presses for each character of ``text``, into the focused element."""
        keys: list[dict[str, Any]] = []
        for ch in text:
            keys += [{"type": "keyDown", "value": ch}, {"type": "keyUp", "value": ch}]
        self._actions({"type": "key", "id": "keyboard", "actions": keys})

    def screenshot(self, path: Path) -> bytes:
        """The whole document as PNG, written to ``path``."""
        answer = self.session.command(
            "browsingContext.captureScreenshot", {"context": self.context, "origin": "document"}
        )
        png = base64.b64decode(answer["data"])
        path.write_bytes(png)
        return png

    def close(self) -> None:
        self.session.unlisten(self._event)
        with contextlib.suppress(BidiError):
            self.session.command("session.unsubscribe", {"subscriptions": [self.subscription]})
        self.session.command("browsingContext.close", {"context": self.context})
        self.session.command("browser.removeUserContext", {"userContext": self.user_context})
