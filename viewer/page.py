"""The viewer page: one self-contained HTML file (informative).

The page is ``web/page.html`` filled in one pass: the stream's numbers (in HTML), the camera
and settings (JSON), per pane a base64 3DGS PLY or the base64 .lghcc stream itself (explicit-Gaussian
streams, decoded in the page by ``js/lghcc-decoder`` (the npm package lghcc-decoder) in a Web Worker: ``assets/lghcc-decoder-worker.js``,
inlined as text), and the JavaScript bundle (``assets/
lghcc-viewer.js``: ``web/viewer.mjs`` with the PlayCanvas engine, built once at set-up time by
``make viewer-bundle``, never at view time). Nothing in the page names a network address.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.errors import LghccError

HERE = Path(__file__).resolve().parent
TEMPLATE = HERE / "web" / "page.html"
BUNDLE = HERE / "assets" / "lghcc-viewer.js"
WORKER = HERE / "assets" / "lghcc-decoder-worker.js"  # js/lghcc-decoder's Web Worker, built beside BUNDLE
# The renderer the bundle is built from: tools/node/package.json pins it (a test checks the two agree).
ENGINE_NAME = "playcanvas"
ENGINE_VERSION = "2.23.3"

PANE_LABELS = {"decoded": "decoded", "source": "source"}


def bundle_js() -> str:
    """The built JavaScript bundle; a clear error when the set-up step has not been run."""
    try:
        js = BUNDLE.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise LghccError(f"the viewer's JavaScript bundle {BUNDLE} is missing: build it once with `make viewer-bundle` "
                         "(needs Node.js and npm; installs the pinned renderer from tools/node/package-lock.json)") \
            from None
    # "</script" cannot appear inside an inline script; "<\/script" means the same in JavaScript
    return js.replace("</script", "<\\/script")


def worker_js() -> str:
    """The stream decoder's Web Worker (js/lghcc-decoder, built with the bundle); a clear error when
    the set-up step has not been run."""
    try:
        js = WORKER.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise LghccError(f"the viewer's decoder worker {WORKER} is missing: build it once with `make viewer-bundle`") \
            from None
    return js.replace("</script", "<\\/script")


@dataclass
class Pane:
    name: str  # "decoded" or "source": element ids lghcc-label-<name>, lghcc-ply-<name> or lghcc-stream-<name>
    label: str  # shown over the pane
    ply: bytes | None = None  # INRIA 3DGS PLY
    stream: bytes | None = None  # or an .lghcc stream the page decodes itself (explicit-Gaussian profile)


def _fill(template: str, values: dict[str, str]) -> str:
    """Replace every {{KEY}} in one pass (a value's own text is never searched for keys)."""
    def sub(m: re.Match) -> str:
        if m.group(1) not in values:
            raise KeyError(f"page template: no value for {{{{{m.group(1)}}}}}")
        return values[m.group(1)]
    return re.sub(r"\{\{([A-Z_]+)\}\}", sub, template)


def _json_script(obj) -> str:
    # JSON inside <script>: "<" escaped so that no "</script>" can end the element early
    return json.dumps(obj, separators=(",", ":")).replace("<", "\\u003c")


def build_page(*, title: str, panes: list[Pane], meta: dict, summary_html: str, details_html: str,
               note: str = "") -> str:
    """The page's HTML text. ``meta``: camera {eye, target, up, fov_x_deg, near, far} and
    background [3]; the pane names are added. ``note`` (plain text, e.g. the data's credit) stays
    visible under the panes."""
    if not panes:
        raise ValueError("build_page: no pane")
    from .. import __version__

    meta = dict(meta, panes=[p.name for p in panes])
    pane_html = "\n".join(
        [f'  <div class="label" id="lghcc-label-{p.name}">{html.escape(p.label)}</div>' for p in panes]
        + [f'  <div class="divider" id="lghcc-divider-{i}"></div>' for i in range(len(panes) - 1)])
    ply_scripts = "\n".join(
        f'<script id="lghcc-{"stream" if p.stream is not None else "ply"}-{p.name}" type="application/octet-stream">'
        f'{base64.b64encode(p.stream if p.stream is not None else p.ply).decode("ascii")}</script>' for p in panes)
    return _fill(TEMPLATE.read_text(encoding="utf-8"), {
        "VERSION": __version__, "ENGINE_VERSION": ENGINE_VERSION, "TITLE": html.escape(title),
        "SUMMARY": summary_html, "NUM_PANES": str(len(panes)), "PANES": pane_html, "DETAILS": details_html,
        "NOTE": f" · {html.escape(note)}" if note else "",
        "SYNC_HELP": " · the panes share one camera" if len(panes) > 1 else "",
        "META": _json_script(meta), "PLY_SCRIPTS": ply_scripts, "WORKER": worker_js(), "BUNDLE": bundle_js()})


# ---------------------------------------------------------------------------------------------
# The numbers on the page
# ---------------------------------------------------------------------------------------------

def fmt_db(x: float | None) -> str:
    if x is None:
        return "—"
    return "∞ (identical)" if math.isinf(x) else f"{x:.2f} dB"


def size_table_html(bytes_by_part: dict[str, int], num_anchors: int | None, num_gaussians: int) -> str:
    """Bytes of each part of the stream, in bits per anchor (anchor streams) and per Gaussian
    shown."""
    total = sum(bytes_by_part.values())
    head = "<tr><th>part</th><th>bytes</th>" + ("<th>bits/anchor</th>" if num_anchors else "") + \
        "<th>bits/Gaussian</th><th>share</th></tr>"
    rows = []
    for part, b in list(bytes_by_part.items()) + [("total", total)]:
        cells = [html.escape(part), f"{b:,}"]
        if num_anchors:
            cells.append(f"{8 * b / num_anchors:.2f}")
        cells += [f"{8 * b / max(num_gaussians, 1):.3f}", f"{100 * b / max(total, 1):.1f}%"]
        tag = "th" if part == "total" else "td"
        rows.append("<tr>" + "".join(f"<{tag}>{c}</{tag}>" for c in cells) + "</tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def mean_metrics(images_a: list[np.ndarray], images_b: list[np.ndarray]) -> dict:
    """Mean PSNR (dB, of the mean squared error per view) and SSIM over views (lghcc.render.metrics)."""
    from ..render.metrics import psnr, ssim

    ps = [psnr(a, b) for a, b in zip(images_a, images_b)]
    return {"psnr": float(np.mean(ps)), "psnr_views": [float(p) for p in ps],
            "ssim": float(np.mean([ssim(a, b) for a, b in zip(images_a, images_b)]))}
