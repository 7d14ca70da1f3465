"""Open a page in Debian's headless chromium and report what a reader would see.

Driven through the DevTools protocol over ``--remote-debugging-pipe`` (JSON messages,
each ended by a NUL byte, on file descriptors 3 and 4 of the browser), so no driver
package and no browser download is needed.
"""

from __future__ import annotations

import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--remote-debugging-pipe",
)

_INSPECT_PAGE = """
(async () => {
  const images = Array.from(document.images);
  const loaded = await Promise.all(images.map(i => i.decode().then(() => i.naturalWidth > 0, () => false)));
  const tables = {};
  for (const heading of document.querySelectorAll("h2")) {
    const table = heading.nextElementSibling;
    if (table && table.tagName === "TABLE") {
      tables[heading.id] = Array.from(table.querySelectorAll("tbody tr")).map(
        row => Array.from(row.cells).map(cell => cell.textContent));
    }
  }
  return {
    title: document.title,
    n_images: images.length,
    broken: images.filter((_, k) => !loaded[k]).map(i => i.getAttribute("alt") || i.src.slice(0, 60)),
    links: Array.from(document.links).map(a => a.getAttribute("href")),
    tables: tables,
    text: document.body.innerText,
  };
})()
"""


def chromium() -> str:
    """The browser's path; a missing browser fails the test (it must not be skipped)."""
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    pytest.fail(
        "chromium is not installed, so report.html cannot be opened: run `make test` as root "
        "(scripts/sysdeps.sh installs it) or `sudo apt-get install chromium`"
    )


@dataclass
class PageReport:
    """What the page showed: its console errors, its images that did not load, its DOM."""

    console_errors: list[str] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    n_images: int = 0
    title: str = ""
    links: list[str] = field(default_factory=list)
    tables: dict[str, list[list[str]]] = field(default_factory=dict)
    """Rows of the table right after each ``<h2>``, by the heading's id."""
    text: str = ""


class _Pipe:
    """The DevTools protocol over two pipes."""

    def __init__(self, to_browser: int, from_browser: int) -> None:
        self._write, self._read = to_browser, from_browser
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout: float = 30.0) -> dict[str, Any]:
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        while True:
            reply = self._receive(timeout)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_for(self, method: str, timeout: float = 30.0) -> dict[str, Any]:
        for event in self.events:
            if event.get("method") == method:
                return event
        while True:
            event = self._receive(timeout)
            self.events.append(event)
            if event.get("method") == method:
                return event

    def _receive(self, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._read], [], [], left)[0]:
                raise TimeoutError("chromium did not answer")
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)


def open_page(path: Path, timeout: float = 60.0) -> PageReport:
    """Load ``path`` in headless chromium and inspect it after its load event."""
    browser = chromium()
    commands_read, commands_write = _high(os.pipe())
    replies_read, replies_write = _high(os.pipe())

    # DevTools reads commands from fd 3 and writes replies to fd 4: bash puts the pipes there
    # (not sh: dash takes single-digit descriptors only)
    placed = f'exec "$@" 3<&{commands_read} 4>&{replies_write}'
    with tempfile.TemporaryDirectory(prefix="slamfront-chromium-") as profile:
        process = subprocess.Popen(
            ["bash", "-c", placed, "bash", browser, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(commands_read, replies_write),
        )
        os.close(commands_read)
        os.close(replies_write)
        pipe = _Pipe(commands_write, replies_read)
        try:
            target = pipe.send("Target.createTarget", {"url": "about:blank"}, timeout=timeout)["targetId"]
            session = pipe.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                pipe.send(f"{domain}.enable", session=session)
            pipe.send("Page.navigate", {"url": path.resolve().as_uri()}, session=session)
            pipe.wait_for("Page.loadEventFired", timeout)
            found = pipe.send("Runtime.evaluate", {"expression": _INSPECT_PAGE, "awaitPromise": True,
                                                   "returnByValue": True}, session=session, timeout=timeout)
            value = found["result"]["value"]
            pipe.send("Browser.close")
        finally:
            os.close(commands_write)
            os.close(replies_read)
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    return PageReport(
        console_errors=_errors(pipe.events), broken_images=value["broken"], n_images=value["n_images"],
        title=value["title"], links=value["links"], tables=value["tables"], text=value["text"],
    )


def _high(pipe: tuple[int, int]) -> tuple[int, int]:
    """The pipe's ends moved to descriptors above 9, clear of the 3 and 4 the browser gets."""
    moved = tuple(fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in pipe)
    for fd in pipe:
        os.close(fd)
    return moved[0], moved[1]


def _errors(events: list[dict[str, Any]]) -> list[str]:
    """Console errors, uncaught exceptions and the browser's own error log entries."""
    errors = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            errors.append(" ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", [])))
        elif method == "Runtime.exceptionThrown":
            errors.append(params.get("exceptionDetails", {}).get("text", "exception"))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            entry = params["entry"]
            errors.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())
    return errors
