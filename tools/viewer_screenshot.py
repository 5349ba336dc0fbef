"""A screenshot of a page written by lghcc-view, as a visitor's browser shows it: headless
Chromium (lghcc.viewer.browser; Debian's chromium and the playwright package), after the first
depth-sorted frame of every pane.

    python tools/viewer_screenshot.py scene.html docs/viewer.png [--window 1000x520] [--colors 256]

--colors N writes an N-colour palette PNG (much smaller; 0 keeps full RGB).
"""

from __future__ import annotations

import argparse
import io
import re
import sys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("page", help="an HTML file written by lghcc-view")
    p.add_argument("png", help="the screenshot to write")
    p.add_argument("--window", default="1000x520", help="browser window size WxH (default 1000x520)")
    p.add_argument("--colors", type=int, default=256, help="palette colours (default 256; 0: full RGB)")
    args = p.parse_args(argv)
    from PIL import Image

    from lghcc.app.fileio import atomic_output
    from lghcc.viewer.browser import ViewerSession, browser_status

    ok, why = browser_status()
    if not ok:
        print(f"viewer_screenshot: error: {why}", file=sys.stderr)
        return 1
    m = re.fullmatch(r"(\d+)x(\d+)", args.window)
    if not m:
        print(f"viewer_screenshot: error: --window must be WxH, got {args.window!r}", file=sys.stderr)
        return 1
    with ViewerSession(args.page, 0, 0, viewport=(int(m.group(1)), int(m.group(2)))) as s:
        png = s.page.screenshot()
        offline = all(r.startswith(("file:", "blob:", "data:")) for r in s.requests)
    img = Image.open(io.BytesIO(png)).convert("RGB")
    if args.colors:
        img = img.quantize(colors=args.colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    with atomic_output(args.png) as f:
        img.save(f, format="PNG", optimize=True)
    print(f"wrote {args.png} ({img.width}x{img.height}); the page made "
          + ("no network request" if offline else "network requests!"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
