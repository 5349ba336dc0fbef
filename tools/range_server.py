"""A local HTTP file server that answers Range requests over a throttled link, for the streamed
reader of the JavaScript decoder (js/lghcc-decoder's stream(); tests/test_js_stream.py and
tools/bench_js_stream.py use it). The files whose names end in one of the throttled suffixes
(.lghcc by default) go out in chunks through one shared link of the given rate (every request waits
its turn on it, as on one network link); other files (pages, scripts) go out at once. With
ranges=False it ignores Range headers and answers 200 with the whole file, as a server without
Range support does. It records every throttled request ((path, first byte, last byte + 1, status,
time of its first and of its last byte sent)) and the time the last byte of a throttled file went out.

    .venv/bin/python tools/range_server.py FOLDER --rate 20 [--port 8000] [--no-ranges]

serves FOLDER at http://127.0.0.1:PORT/ with the .lghcc files at 20 Mbit/s until interrupted.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import os
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

CHUNK = 16384  # bytes per write: a throttled file arrives in pieces of this size


@dataclass
class Link:
    """One shared link of `rate` bytes/s (None: unthrottled) and what went over it."""

    rate: float | None
    ranges: bool = True
    chunk: int = CHUNK
    suffixes: tuple[str, ...] = (".lghcc",)
    log: list[tuple[str, int, int, int, float, float]] = field(default_factory=list)
    bytes_sent: int = 0
    last_byte_time: float | None = None  # time.time() when the last byte of a throttled file was sent
    timeline: list[tuple[float, int]] = field(default_factory=list)  # (time.time(), bytes_sent) after each piece
    _free_at: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def sent_by(self, t: float) -> int:
        """Bytes of throttled files sent by time t (time.time())."""
        return max([b for when, b in self.timeline if when <= t], default=0)

    def send(self, n: int) -> None:
        """Wait until n more bytes have crossed the link (the link is shared: requests queue)."""
        if not self.rate:
            return
        with self._lock:
            start = max(time.monotonic(), self._free_at)
            self._free_at = start + n / self.rate
            done = self._free_at
        time.sleep(max(0.0, done - time.monotonic()))


def _byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """[start, end) of a single-range 'bytes=a-b' / 'bytes=a-' / 'bytes=-n' header; None: the whole file."""
    if not header:
        return None
    m = re.fullmatch(r"bytes=(\d*)-(\d*)", header.strip())
    if not m or (not m.group(1) and not m.group(2)):
        return None  # several ranges or a malformed header: answered with the whole file (RFC 9110 allows it)
    if not m.group(1):
        return max(0, size - int(m.group(2))), size
    start = int(m.group(1))
    end = min(size, int(m.group(2)) + 1) if m.group(2) else size
    return start, end


class Handler(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript",
                      ".js": "text/javascript", ".lghcc": "application/octet-stream"}

    def __init__(self, *args, link: Link, **kw):
        self.link = link
        super().__init__(*args, **kw)

    def log_message(self, *args):
        pass

    def do_GET(self):
        path = Path(self.translate_path(self.path))
        if not path.is_file() or not path.name.endswith(self.link.suffixes):
            return super().do_GET()
        data = path.read_bytes()
        rng = _byte_range(self.headers.get("Range"), len(data)) if self.link.ranges else None
        if rng is not None and rng[0] >= len(data):
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{len(data)}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        start, end = rng if rng is not None else (0, len(data))
        self.send_response(206 if rng is not None else 200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(end - start))
        if self.link.ranges:
            self.send_header("Accept-Ranges", "bytes")
        if rng is not None:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{len(data)}")
        self.end_headers()
        self._send_throttled(data, start, end, 206 if rng is not None else 200)
        return None

    def _send_throttled(self, data: bytes, start: int, end: int, status: int) -> None:
        first = last = time.time()
        try:
            for p in range(start, end, self.link.chunk):
                piece = data[p:min(end, p + self.link.chunk)]
                self.link.send(len(piece))
                self.wfile.write(piece)
                self.wfile.flush()
                last = time.time()
                with self.link._lock:
                    self.link.bytes_sent += len(piece)
                    self.link.last_byte_time = last
                    self.link.timeline.append((last, self.link.bytes_sent))
        except (BrokenPipeError, ConnectionResetError):
            pass  # the client stopped reading (an abort)
        with self.link._lock:
            self.link.log.append((self.path, start, end, status, first, last))


def serve(folder: Path | str, rate_bytes: float | None, *, ranges: bool = True, port: int = 0,
          suffixes: tuple[str, ...] = (".lghcc",), chunk: int = CHUNK) -> tuple[http.server.ThreadingHTTPServer, Link]:
    """Start serving folder in a daemon thread, the throttled files at rate_bytes bytes/s (None:
    unthrottled) in pieces of chunk bytes; (the server, its link). server.shutdown() stops it."""
    link = Link(rate_bytes, ranges=ranges, suffixes=suffixes, chunk=chunk)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port),
                                             functools.partial(Handler, link=link, directory=str(folder)))
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, link


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="the folder to serve")
    ap.add_argument("--rate", type=float, default=20.0, help="the link's rate in Mbit/s for .lghcc files (0: unthrottled; default 20)")
    ap.add_argument("--port", type=int, default=8000, help="the port on 127.0.0.1 (default 8000)")
    ap.add_argument("--no-ranges", action="store_true", help="ignore Range headers: answer 200 with the whole file")
    args = ap.parse_args(argv)
    if not args.folder.is_dir():
        ap.error(f"{args.folder}: not a folder")
    server, _ = serve(args.folder, args.rate * 1e6 / 8 or None, ranges=not args.no_ranges, port=args.port)
    print(f"serving {os.path.abspath(args.folder)} at http://127.0.0.1:{server.server_address[1]}/ "
          f"(.lghcc at {args.rate or 'unthrottled'} Mbit/s{', no Range support' if args.no_ranges else ''}); Ctrl-C stops")
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        server.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
