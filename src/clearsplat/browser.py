"""Headless Chromium driven over the DevTools protocol: screenshots of a page once it shows
what is asked for.

The viewer's pages draw what the server sends them over a websocket, after the page has
loaded, and software WebGL on a busy machine may take many seconds. A fixed wait (Chromium's
``--virtual-time-budget``) races that; here the page runs in real time and is photographed
again until a check on the picture holds, or an overall timeout says what never appeared.
Used by the viewer's tests and the screenshot examples; needs Chromium (Debian: ``apt-get
install chromium``) and the ``websockets`` package (installed with the ``viewer`` extra).

Example::

    with HeadlessBrowser(size=(800, 600)) as browser:
        browser.open(viewer.url)
        rgb = browser.wait_until(lambda rgb: (rgb.max(-1) > 40).mean() > 0.2,
                                 what="the scene drawn")
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable

import numpy as np

__all__ = ["HeadlessBrowser", "find_browser"]


def find_browser() -> str | None:
    """The path of a Chromium (or Chrome) executable on this machine, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class HeadlessBrowser:
    """One headless Chromium with software WebGL (SwiftShader) and one page.

    Parameters
    ----------
    executable : str, optional
        Chromium's path; default :func:`find_browser`.
    size : (width, height), default (800, 600)
        The page's viewport in CSS pixels; screenshots are ``(height, width, 3)`` uint8.
    start_timeout : float, default 120
        Seconds for Chromium to start and open its DevTools endpoint.
    """

    def __init__(self, executable: str | None = None, *, size=(800, 600),
                 start_timeout: float = 120.0):
        from websockets.sync.client import connect

        executable = executable or find_browser()
        if executable is None:
            raise FileNotFoundError("no Chromium on this machine (Debian: apt-get install "
                                    "chromium)")
        self.size = (int(size[0]), int(size[1]))
        self._profile = tempfile.TemporaryDirectory(prefix="clearsplat-browser-",
                                                    ignore_cleanup_errors=True)
        self._proc = subprocess.Popen(
            [executable, "--headless", "--no-sandbox", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run",
             "--remote-debugging-port=0", "--remote-allow-origins=*",
             f"--user-data-dir={self._profile.name}",
             f"--window-size={self.size[0]},{self.size[1]}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self._ids = itertools.count(1)
        self._ws = None
        try:
            port = self._devtools_port(start_timeout)
            pages = [t for t in self._targets(port) if t.get("type") == "page"]
            if not pages:
                raise RuntimeError("Chromium started without a page")
            self._ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None,
                               open_timeout=start_timeout)
            self.call("Emulation.setDeviceMetricsOverride", width=self.size[0],
                      height=self.size[1], deviceScaleFactor=1, mobile=False)
        except BaseException:
            self.close()
            raise

    # -- DevTools ----------------------------------------------------------------------------
    def _devtools_port(self, timeout: float) -> int:
        """Chromium writes the port it chose to DevToolsActivePort in its profile."""
        path = os.path.join(self._profile.name, "DevToolsActivePort")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._proc.poll() is not None:
                raise RuntimeError(f"Chromium exited with code {self._proc.returncode} "
                                   "before opening its DevTools port")
            try:
                with open(path) as f:
                    first = f.readline().strip()
                if first:
                    return int(first)
            except (OSError, ValueError):
                pass
            time.sleep(0.1)
        raise TimeoutError(f"Chromium opened no DevTools port within {timeout:.0f} s")

    @staticmethod
    def _targets(port: int) -> list:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=60) as r:
            return json.loads(r.read())

    def call(self, method: str, *, timeout: float = 120.0, **params) -> dict:
        """Send one DevTools command to the page and return its result."""
        key = next(self._ids)
        self._ws.send(json.dumps({"id": key, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"Chromium gave no answer to {method} within {timeout:.0f} s")
            message = json.loads(self._ws.recv(timeout=left))
            if message.get("id") != key:
                continue                        # an event, or an answer to an earlier call
            if "error" in message:
                raise RuntimeError(f"{method}: {message['error'].get('message')}")
            return message.get("result", {})

    # -- the page ----------------------------------------------------------------------------
    def open(self, url: str) -> None:
        """Load ``url`` in the page (returns once the navigation is under way)."""
        self.call("Page.navigate", url=url)

    def screenshot(self, *, timeout: float = 120.0) -> np.ndarray:
        """(H, W, 3) uint8: the page as it is drawn now (Chromium waits for a frame)."""
        from PIL import Image
        data = self.call("Page.captureScreenshot", format="png", timeout=timeout)["data"]
        with Image.open(io.BytesIO(base64.b64decode(data))) as im:
            return np.asarray(im.convert("RGB"))

    def wait_until(self, check: Callable[[np.ndarray], bool], *, what: str,
                   timeout: float = 300.0, settle: bool = True) -> np.ndarray:
        """Photograph the page until ``check(screenshot)`` holds, and return that screenshot.

        With ``settle`` the picture must also be the same in two screenshots in a row (the
        page has finished drawing what it shows). A page still loading is photographed again;
        one busy drawing (a million Gaussians in software WebGL take minutes a frame) is waited
        for. After ``timeout`` seconds a ``TimeoutError``
        names ``what`` never appeared.
        """
        deadline = time.monotonic() + timeout
        last, seen = None, "no screenshot"
        while True:
            left = deadline - time.monotonic()
            try:
                rgb = self.screenshot(timeout=max(1.0, left))
            except (RuntimeError, TimeoutError) as e:   # navigating, or busy drawing
                rgb, seen = None, f"no screenshot ({e})"
            if rgb is not None:
                if check(rgb) and (not settle or (last is not None and check(last)
                                                 and _same(rgb, last))):
                    return rgb
                seen = f"the last screenshot has {100 * (rgb.max(-1) > 40).mean():.1f} % " \
                       "lit pixels"
            if time.monotonic() > deadline:
                raise TimeoutError(f"{what}: not in the page after {timeout:.0f} s ({seen})")
            last = rgb
            time.sleep(0.25)

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        """Stop Chromium and remove its profile."""
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:           # noqa: BLE001 - the browser may be gone already
                pass
            self._ws = None
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._profile.cleanup()

    def __enter__(self) -> HeadlessBrowser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Two screenshots show the same picture (up to a few stray pixels)."""
    return a.shape == b.shape and (np.abs(a.astype(np.int16) - b).max(-1) > 8).mean() < 1e-3
