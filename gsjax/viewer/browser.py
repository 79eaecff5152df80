"""Headless Chromium for the browser tests (``tests/viewer/test_ui_browser.py``), ``experiments/screenshots.py`` and
``experiments/bench_viewer.py`` (it needs the test extra's Playwright):
Debian's ``chromium`` driven by Playwright, with what a page logs, throws and requests recorded, a test for a blank
screenshot, and gsjax commands in a subprocess whose output lines are watched.

``make test`` installs the ``chromium`` package when it is missing; without it the tests fail saying so (set
``GSJAX_SKIP_BROWSER_TESTS=1`` to skip them instead). ``GSJAX_CHROMIUM`` names another Chromium binary.
"""

from __future__ import annotations

import dataclasses
import os
import queue
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import cv2
import numpy as np

# Headless on a machine with no GPU and no network: WebGL through SwiftShader, and none of Chromium's own
# connections (they are refused here and would only add noise and delay).
FLAGS = ("--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic")

# Messages of the page's own libraries, not of gsjax, that are not failures of the page:
# - viser's Gaussian-splat quad has a 2-component "position" attribute (viser/client/src/Splatting/
#   GaussianSplatsHelpers.ts), so three.js's bounding-sphere check reads a missing z and logs this although
#   every value is finite (viser 1.1.1).
KNOWN_LIBRARY_ERRORS = ('THREE.BufferGeometry.computeBoundingSphere(): Computed radius is NaN. The "position" '
                        "attribute is likely to have NaN values.",)


def chromium_path() -> str | None:
    """The Chromium binary to use, or None when there is none."""
    named = os.environ.get("GSJAX_CHROMIUM")
    if named:
        return named if os.path.isfile(named) else None
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    return None


def launch(playwright):
    """A headless Chromium browser (Playwright ``Browser``)."""
    return playwright.chromium.launch(executable_path=chromium_path(), headless=True, args=list(FLAGS))


@dataclasses.dataclass
class PageLog:
    """What a page did: console errors, uncaught exceptions, and requests beyond the ``allowed`` prefixes."""

    allowed: tuple[str, ...]
    errors: list[str] = dataclasses.field(default_factory=list)
    exceptions: list[str] = dataclasses.field(default_factory=list)
    outside: list[str] = dataclasses.field(default_factory=list)
    messages: list[str] = dataclasses.field(default_factory=list)

    def problems(self) -> list[str]:
        """Everything that counts against the page (known library messages left out)."""
        errors = [e for e in self.errors if not e.startswith(KNOWN_LIBRARY_ERRORS)]
        return ([f"console error: {e}" for e in errors] + [f"exception: {e}" for e in self.exceptions]
                + [f"request outside the page: {u}" for u in self.outside])


def open_page(browser, url: str, allowed: tuple[str, ...], width: int = 1280, height: int = 860):
    """(page, log): ``url`` opened in a fresh context; requests that do not start with one of ``allowed`` are
    recorded and aborted."""
    context = browser.new_context(viewport={"width": width, "height": height}, device_scale_factor=1)
    page = context.new_page()
    log = PageLog(allowed=allowed)

    def on_console(message):
        log.messages.append(f"{message.type}: {message.text}")
        if message.type == "error":
            log.errors.append(message.text)

    def on_route(route):
        if route.request.url.startswith(allowed):
            route.continue_()
        else:
            log.outside.append(route.request.url)
            route.abort()

    page.on("console", on_console)
    page.on("pageerror", lambda error: log.exceptions.append(str(error)))
    page.route("**/*", on_route)
    page.goto(url, wait_until="load")
    return page, log


def decode(png: bytes) -> np.ndarray:
    """PNG bytes -> BGR uint8 image."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "not a PNG"
    return image


def drawn_fraction(image: np.ndarray) -> float:
    """The fraction of pixels that differ (by more than 8 levels in a channel) from the image's most common
    colour, its background: 0 for a blank image."""
    pixels = image.reshape(-1, image.shape[-1]).astype(np.int16)
    colours, counts = np.unique(pixels, axis=0, return_counts=True)
    background = colours[np.argmax(counts)]
    return float(np.mean(np.abs(pixels - background).max(axis=1) > 8))


def wait_until(condition: Callable[[], object], timeout_s: float, what: str, poll_s: float = 0.5):
    """Poll ``condition`` until it returns something truthy (returned); AssertionError naming ``what`` on time-out."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(poll_s)


class Process:
    """A gsjax command in a subprocess, its output lines collected as they come."""

    def __init__(self, args: list[str]):
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.popen = subprocess.Popen([sys.executable, "-m", "gsjax", *args], stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, env=env)
        self.lines: list[str] = []
        self._queue: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.popen.stdout:
            self._queue.put(line.rstrip("\n"))
        self._queue.put(None)

    def wait_for(self, pattern: str, timeout_s: float) -> re.Match:
        """The first output line matching ``pattern`` (waiting for it); AssertionError with the output otherwise."""
        deadline = time.monotonic() + timeout_s
        for line in self.lines:
            if match := re.search(pattern, line):
                return match
        while time.monotonic() < deadline:
            try:
                line = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            if line is None:
                break
            self.lines.append(line)
            if match := re.search(pattern, line):
                return match
        raise AssertionError(f"no line matching {pattern!r}; output so far:\n" + "\n".join(self.lines))

    def seen(self, pattern: str) -> bool:
        """Whether an output line so far matches ``pattern`` (without waiting)."""
        while True:
            try:
                line = self._queue.get_nowait()
            except queue.Empty:
                break
            if line is None:
                self._queue.put(None)  # the end stays visible to wait_for and finish
                break
            self.lines.append(line)
        return any(re.search(pattern, line) for line in self.lines)

    def finish(self, timeout_s: float | None = None) -> int:
        """The exit status, once the process has ended and all its output is in ``lines``."""
        code = self.popen.wait(timeout=timeout_s)
        while (line := self._queue.get(timeout=30)) is not None:
            self.lines.append(line)
        return code

    def stop(self, signum: int, timeout_s: float = 30.0) -> int:
        """Send ``signum``; then :meth:`finish`."""
        self.popen.send_signal(signum)
        return self.finish(timeout_s)

    def kill(self):
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait()
