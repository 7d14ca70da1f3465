"""``slamfront run --live``: the run served over the Foxglove WebSocket protocol as it happens.

A :class:`LiveView` is a :class:`~slamfront.mcaplog.writer.LogSink`: every channel the
run's log opens becomes a channel of a Foxglove WebSocket server (the ``foxglove-sdk``
package, MIT, Foxglove's own implementation of the protocol), with the same topic,
schema and message encoding, and every message the log stores is sent with the same
bytes and log time. So Foxglove (*Open connection* -> *Foxglove WebSocket*,
``ws://localhost:8765``) shows exactly what the log will hold, while the log is written
as usual.

The WebSocket protocol sends a client only messages of channels it has subscribed to,
and a channel is announced when the run first writes to it; ``wait_s`` holds the run
before its first message until a client has subscribed (so a viewer started after the
run sees it from the start), and once a client is subscribed each new channel waits a
moment (``subscribe_wait_s``) for its subscription, so its first message is not missed.
"""

from __future__ import annotations

import importlib
import sys
import threading
import time
from pathlib import Path
from types import ModuleType, TracebackType
from typing import Any

from slamfront.errors import SlamfrontError

DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""


def foxglove_sdk() -> ModuleType:
    """The ``foxglove`` module of the ``foxglove-sdk`` distribution.

    A source checkout has a folder of Foxglove layouts named ``foxglove`` at its top
    level; run from there (``python -m``), it would hide the SDK, so the SDK is then
    loaded from its installed files.

    :raises SlamfrontError: the SDK is not installed.
    """
    try:
        module = importlib.import_module("foxglove")
    except ImportError:
        module = None
    if module is not None and hasattr(module, "start_server"):
        return module
    from importlib import metadata, util

    try:
        init = Path(str(metadata.distribution("foxglove-sdk").locate_file("foxglove/__init__.py")))
    except metadata.PackageNotFoundError:
        raise SlamfrontError("--live needs the foxglove-sdk package (pip install foxglove-sdk)") from None
    spec = util.spec_from_file_location("foxglove", init, submodule_search_locations=[str(init.parent)])
    if spec is None or spec.loader is None or not init.exists():
        raise SlamfrontError(f"--live: the foxglove-sdk installation is incomplete ({init} is missing)")
    sdk = util.module_from_spec(spec)
    sys.modules["foxglove"] = sdk
    spec.loader.exec_module(sdk)
    return sdk


class LiveView:
    """A Foxglove WebSocket server mirroring a run's log; use as a context manager.

    :param port: TCP port (0: any free one; :attr:`port` says which).
    :param host: address to listen on (``127.0.0.1``: this machine only; ``0.0.0.0``: all).
    :param wait_s: before the run's first message, wait up to this long for a client to subscribe.
    :param subscribe_wait_s: once a client has subscribed, a new channel's first message
        waits up to this long for the subscription to it.
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", wait_s: float = 0.0,
                 subscribe_wait_s: float = 0.05) -> None:
        self.requested_port = port
        self.host = host
        self.wait_s = wait_s
        self.subscribe_wait_s = subscribe_wait_s
        self.port: int | None = None
        self.n_messages = 0
        self._sdk: ModuleType | None = None
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[int, Any] = {}
        self._first_message: set[int] = set()
        self._subscribed: dict[str, int] = {}
        self._changed = threading.Condition()
        self._waited = False

    # --- server -------------------------------------------------------------------------

    def start(self) -> LiveView:
        sdk = foxglove_sdk()
        self._sdk = sdk
        self._context = sdk.Context()
        view = self

        class Listener(sdk.websocket.ServerListener):  # type: ignore[name-defined,misc]
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view._on_subscribe(channel.topic, +1)

            def on_unsubscribe(self, client: Any, channel: Any) -> None:
                view._on_subscribe(channel.topic, -1)

        try:
            self._server = sdk.start_server(
                name="slamfront", host=self.host, port=self.requested_port, context=self._context,
                server_listener=Listener(),
            )
        except Exception as exc:  # noqa: BLE001 (the SDK reports a taken port as a plain error)
            raise SlamfrontError(f"--live: cannot serve on {self.host}:{self.requested_port} ({exc})") from None
        self.port = int(self._server.port)
        return self

    @property
    def url(self) -> str:
        host = "localhost" if self.host in ("127.0.0.1", "0.0.0.0", "::") else self.host
        return f"ws://{host}:{self.port}"

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> LiveView:
        return self.start() if self._server is None else self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _on_subscribe(self, topic: str, change: int) -> None:
        with self._changed:
            self._subscribed[topic] = max(0, self._subscribed.get(topic, 0) + change)
            self._changed.notify_all()

    def _wait_for(self, ready: Any, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        with self._changed:
            while not ready() and (left := deadline - time.monotonic()) > 0:
                self._changed.wait(left)

    # --- LogSink ------------------------------------------------------------------------

    def channel(self, channel_id: int, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes,
                message_encoding: str) -> None:
        assert self._sdk is not None, "start() the live view before the run"
        schema = self._sdk.Schema(name=schema_name, encoding=schema_encoding, data=schema_data) if schema_name else None
        self._channels[channel_id] = self._sdk.Channel(
            topic, schema=schema, message_encoding=message_encoding, context=self._context
        )
        self._first_message.add(channel_id)

    def message(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        channel = self._channels.get(channel_id)
        if channel is None:
            return
        if channel_id in self._first_message:
            self._first_message.discard(channel_id)
            if not self._waited:
                self._waited = True
                self._wait_for(lambda: any(self._subscribed.values()), self.wait_s)
            if any(self._subscribed.values()):
                self._wait_for(lambda: self._subscribed.get(channel.topic, 0) > 0, self.subscribe_wait_s)
        channel.log(bytes(data), log_time=log_time_ns)
        self.n_messages += 1
