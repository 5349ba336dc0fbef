"""Driving a viewer page in a real, headless Chromium (informative; tests and screenshots).

Uses the ``playwright`` Python package (``pip install 'lghcc[viewer]'``) with a Chromium the
system provides (Debian: ``apt-get install chromium``; playwright's own browser download is
not used). WebGL2 runs in software (SwiftShader) when there is no GPU: the flags below ask for
it explicitly, as recent Chromium releases only fall back to it when told.

``page_images`` loads a page written by lghcc-view with ``#size=WxH`` (every pane W x H CSS
pixels at device pixel ratio 1, nothing drawn over them), waits for ``window.lghccViewer.ready``
(every pane has drawn a depth-sorted frame), screenshots the canvas and cuts it into panes.
"""

from __future__ import annotations

import io
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")
# Headless, no sandbox (CI runs as root), no GPU process (software WebGL), and no background
# connections (a closed network refuses them, noisily); a fresh profile per launch.
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader")
PANE_GAP = 2  # CSS pixels between panes (viewer/web/viewer.mjs GAP)


def chromium_path() -> str | None:
    """The Chromium to drive: $LGHCC_CHROMIUM, else the first of CHROMIUM_CANDIDATES that exists."""
    env = os.environ.get("LGHCC_CHROMIUM")
    if env:
        return env if Path(env).is_file() else None
    return next((p for p in CHROMIUM_CANDIDATES if Path(p).is_file()), shutil.which("chromium"))


def browser_status() -> tuple[bool, str]:
    """(usable, reason when not): playwright importable and a Chromium binary present."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return False, "the playwright package is not installed (pip install 'lghcc[viewer]')"
    if chromium_path() is None:
        return False, ("no Chromium found at " + ", ".join(CHROMIUM_CANDIDATES)
                       + " (Debian: apt-get install chromium; or set LGHCC_CHROMIUM)")
    return True, ""


class ViewerSession:
    """One headless Chromium with one page of a viewer file; ``with ViewerSession(path, w, h) as s``."""

    def __init__(self, html_path: str | os.PathLike, width: int, height: int, timeout_s: float = 90.0,
                 viewport: tuple[int, int] | None = None):
        """Panes of ``width`` x ``height`` (the page's ``#size`` mode); with ``viewport`` (w, h)
        instead, the page as a visitor sees it in a window of that size (no ``#size``)."""
        self.html_path = Path(html_path).resolve()
        self.width, self.height, self.timeout_ms = int(width), int(height), int(timeout_s * 1000)
        self.viewport = viewport
        self.console: list[str] = []
        self.requests: list[str] = []

    def __enter__(self) -> "ViewerSession":
        from playwright.sync_api import sync_playwright

        self._profile = tempfile.mkdtemp(prefix="lghcc-chromium-")
        self._pw = sync_playwright().start()
        try:
            self._ctx = self._pw.chromium.launch_persistent_context(
                self._profile, executable_path=chromium_path(), args=list(CHROMIUM_FLAGS), headless=True,
                viewport=({"width": self.viewport[0], "height": self.viewport[1]} if self.viewport else
                          {"width": 2 * self.width + PANE_GAP + 64, "height": self.height + 400}),
                device_scale_factor=1)
            self.page = self._ctx.new_page()
            self.page.on("console", lambda m: self.console.append(f"{m.type}: {m.text}"))
            self.page.on("pageerror", lambda e: self.console.append(f"pageerror: {e}"))
            self.page.on("request", lambda r: self.requests.append(r.url))
            self.page.goto(self.html_path.as_uri() + ("" if self.viewport else f"#size={self.width}x{self.height}"))
            self.wait_ready()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        ctx, pw = getattr(self, "_ctx", None), getattr(self, "_pw", None)
        try:
            if ctx is not None:
                ctx.close()
        except Exception:  # noqa: BLE001 - closing a browser that already went away
            pass
        try:
            if pw is not None:
                pw.stop()
        except Exception:  # noqa: BLE001
            pass
        shutil.rmtree(getattr(self, "_profile", ""), ignore_errors=True)

    def _await(self, expr: str) -> None:
        """Evaluate a promise expression in the page; raise RuntimeError with the console on failure."""
        try:
            self.page.evaluate(f"() => Promise.race([{expr}, new Promise((_, rej) => "
                               f"setTimeout(() => rej(new Error('timed out')), {self.timeout_ms}))])")
        except Exception as e:  # noqa: BLE001 - playwright's error types; re-raised with context
            raise RuntimeError(f"viewer page {self.html_path.name}: {e}; console: {self.console[-10:]}") from None

    def wait_ready(self) -> None:
        self._await("window.lghccViewer.ready")

    def set_camera(self, camera: dict) -> None:
        self.page.evaluate("(c) => window.lghccViewer.setCamera(c)", camera)
        self._await("window.lghccViewer.settled()")

    def camera(self) -> dict:
        return self.page.evaluate("() => window.lghccViewer.camera()")

    def drag(self, dx: float, dy: float, steps: int = 8) -> None:
        """Drag with the left mouse button from the middle of the first pane (an orbit)."""
        box = self.page.locator("#lghcc-canvas").bounding_box()
        x, y = box["x"] + self.width / 2, box["y"] + self.height / 2
        self.page.mouse.move(x, y)
        self.page.mouse.down()
        self.page.mouse.move(x + dx, y + dy, steps=steps)
        self.page.mouse.up()
        self._await("window.lghccViewer.settled()")

    def images(self) -> dict[str, np.ndarray]:
        """Screenshot of the canvas, cut into panes: name -> [H, W, 3] float32 in [0, 1]."""
        from PIL import Image

        box = self.page.locator("#lghcc-canvas").bounding_box()
        rects = self.page.evaluate("() => window.lghccViewer.paneRects()")
        full_w = round(box["width"])
        png = self.page.screenshot(clip={"x": box["x"], "y": box["y"], "width": full_w, "height": self.height})
        img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32) / 255.0
        out = {}
        for r in rects:
            x0 = int(round(r["x"]))
            out[r["name"]] = img[:, x0:x0 + self.width]
        return out

    def screenshot(self, path: str | os.PathLike, full_page: bool = False) -> None:
        self.page.screenshot(path=str(path), full_page=full_page)
