#!/usr/bin/env python3
"""lghcc beside SPZ, SOG and PlayCanvas compressed PLY on real 3DGS scenes, at equal PSNR.

For each scene (a plain 3DGS PLY): renders of the source from a fixed orbit (the same cameras
for every codec), then every codec's decoded scene rendered from those cameras and compared with
them (PSNR, SSIM; the way MPEG's Gaussian-splat coding exploration measures):

- SPZ, SOG and compressed PLY, each written and read back with @playcanvas/splat-transform
  (pinned in tools/node/package.json; `make node-tools` installs it into tools/node/);
- an SPZ rate-distortion curve: SPZ of reduced scenes (fewer SH bands; fewer Gaussians by
  importance pruning, by splat-transform's --decimate-adaptive and, on request, its uniform
  -d), whose upper envelope (the best SPZ file at each PSNR) gives every other row its
  "bytes / SPZ bytes at equal PSNR";
- lghcc at each preset (``--presets``; default: the presets ``lghcc-enc --help`` lists less the
  lghcc-* modes, per-scene GG-Conv fits made for trained anchor scenes): the installed
  lghcc-enc on the PLY, then lghcc-dec --export-ply back to a 3DGS PLY (with
  --export-sh-degree at the source's degree when the decoder has that option), both timed as
  subprocesses.

    make node-tools                                     # once: splat-transform into tools/node/
    python tools/bench_real.py donut playbot-lod4 --presets low
    python tools/bench_real.py path/to/scene.ply@-y --append    # a scene by path, -y up
    python tools/bench_real.py --replot                         # redraw the plots from the tables

Scenes: the names donut, playbot-lod4, playbot-lod3, playcanvas-logo (files under --data-root,
default ../shared/data beside the repository) or paths of 3DGS PLYs, ``LABEL=PATH`` to name the
section (default: the file name); ``PATH@UP`` gives a scene's up axis (x, y, z, -x, -y, -z);
``--up`` gives it for every scene. Otherwise the named scenes use their recorded up axis and a
path's is detected: the coordinate axis along which the scene is thinnest (robust 1%-99% box of
the Gaussians with opacity >= 0.05), signed by the usual conventions (+z: Blender and other
z-up tools; -y: COLMAP/OpenCV-derived captures, PlayCanvas and SuperSplat; +x). A guess: it
holds for donut (+z) and playbot (-y) but not for the flat PlayCanvas logo (thinnest along z,
upright with -y), so give the axis when you know it. The table says which was used and how.

Orbit: ``--views`` cameras (default 12) at ``--elevation`` degrees (20) on a circle around the
scene's robust box (render/views.py orbit_cameras), ``--size`` px square (320), 50 degree field
of view, black background; PSNR and SSIM are the means over the views. ``--cameras PATH``
evaluates from those cameras instead (what lghcc's load_capture_cameras reads: an INRIA
cameras.json, a COLMAP sparse folder, a transforms.json), each at ``--size`` squared pixels, for
scenes watched from inside (a room from where its viewers stand); the importance pruning of the
SPZ curve then measures on them too (an oracle: it ranks on the very views it is judged on) unless
``--importance-cameras PATH`` gives others (the capture's own, which an SPZ user has), and
``LABEL=PATH`` names the section apart from the orbit's.

Importance pruning keeps the top x% of Gaussians by contribution (sum over views and pixels of
alpha T, render/importance.py) seen from ``--importance-views`` cameras on a Fibonacci sphere
(encoder/anchors/transcode.py sphere_cameras): not the evaluation orbit.

Equal PSNR: the SPZ envelope is the set of SPZ points no other SPZ point beats in both bytes and
PSNR; between two of them bytes are interpolated linearly in log(bytes) against PSNR. A row
above the envelope's top is compared with the full SPZ file (marked "above SPZ's best"); a row
below its lowest point with the smallest SPZ file (a lower bound, marked ">=").

Decoded PLYs are read with lghcc.formats.ply3dgs; opacity logits of +-inf (splat-transform writes
compressed PLY's 8-bit opacities 0 and 1 back so) are read as opacity 0 and 1 (finite logits,
lghcc.formats.opacity) and counted in the row.

Cache (``--work``, default .bench_real/ in the repository, ignored by git): per scene file the
source renders, the importance scores and every splat-transform row (SPZ, SOG, compressed PLY,
the SPZ curve), keyed by the file's SHA-256, the render settings and the pinned version, so that
re-running with other lghcc presets costs only the lghcc rows (``--fresh`` recomputes).

splat-transform missing: the tool stops with one line and exit status 3 naming what is missing
(node on the PATH, or the pinned package: run `make node-tools`), unless
``--no-splat-transform`` is given; then those rows come from the cache or are left out, and the
section says so. Other exit statuses: 0 done, 1 bad input (a scene that cannot be read), 2 usage.

Results: a markdown section per scene in ``--out`` (default tools/results/real_scenes.md) with
the command that produced it, and a PNG per scene beside it (PSNR against bytes, log x;
matplotlib, ``pip install -e .[tools]``). ``--append`` keeps the other scenes' sections of
--out and replaces those of the scenes run; ``--replot`` only redraws the PNGs from --out.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads on a shared machine

import argparse  # noqa: E402
import datetime
import hashlib
import json
import math
import re
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NODE_DIR = ROOT / "tools" / "node"
PACKAGE = "@playcanvas/splat-transform"
CACHE_VERSION = 1  # bump when what a cached row means changes

# Scenes with a recorded up axis (files under --data-root). The donut's +z reproduces the issue-12
# numbers (SPZ 650,336 B at 49.3 dB, SOG 635,846 B at 63.0 dB); the PlayCanvas scenes are -y up.
SCENES = {
    "donut": ("donut/donut.ply", "z", "donut: V3DG project, MIT (donut/LICENSE)"),
    "playbot-lod4": ("playbot/playbot_lod4_8k.ply", "-y",
                     "playbot scene by **Stephane Agullo**, CC-BY-4.0 (playbot/LICENSE-playbot.txt)"),
    "playbot-lod3": ("playbot/playbot_lod3_31k.ply", "-y",
                     "playbot scene by **Stephane Agullo**, CC-BY-4.0 (playbot/LICENSE-playbot.txt)"),
    "playcanvas-logo": ("playcanvas-logo/playcanvas_logo_307k.ply", "-y",
                        "PlayCanvas logo: PlayCanvas engine examples, MIT (playcanvas-logo/LICENSE)"),
}
AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0),
        "-x": (-1.0, 0.0, 0.0), "-y": (0.0, -1.0, 0.0), "-z": (0.0, 0.0, -1.0)}
CONVENTIONAL_SIGN = {"x": "x", "y": "-y", "z": "z"}
UP_WHY = {"given": "given on the command line", "recorded": "recorded for this scene"}
REDUCERS = ("prune", "decimate-adaptive", "decimate")
DEFAULT_REDUCERS = ("prune", "decimate-adaptive")  # uniform -d: on request (it trailed adaptive where measured)
FORMATS = {"spz": ("SPZ", ".spz"), "sog": ("SOG", ".sog"), "cply": ("compressed PLY", ".compressed.ply")}
MAIN_HEADER = ("| codec | setting | bytes | bits/source Gaussian | Gaussians decoded | PSNR dB | SSIM | encode s | "
               "decode s | bytes / SPZ at equal PSNR |")
CURVE_HEADER = "| SPZ variant | SH degree | Gaussians | bytes | bits/source Gaussian | PSNR dB | SSIM | on envelope |"


def log(msg: str) -> None:
    """A progress line on stderr (flushed, so that it reaches logs as it happens)."""
    print(f"bench_real: {msg}", file=sys.stderr, flush=True)


# --- up axis and cameras --------------------------------------------------------------------

def parse_up(s: str) -> tuple[float, float, float]:
    key = s.strip().lower().lstrip("+")
    if key not in AXES:
        raise ValueError(f"up axis must be one of x, y, z, -x, -y, -z, got {s!r}")
    return AXES[key]


def detect_up(means: np.ndarray, opacity_logits: np.ndarray | None = None) -> tuple[str, str]:
    """(axis, why): the coordinate axis along which the robust box (1%-99% quantiles of the means
    of Gaussians with opacity >= 0.05) is thinnest, signed by convention (+z, -y, +x)."""
    m = np.asarray(means, np.float64)
    if opacity_logits is not None:
        vis = 1 / (1 + np.exp(-np.asarray(opacity_logits, np.float64))) >= 0.05
        if vis.sum() >= 10:
            m = m[vis]
    ext = np.quantile(m, 0.99, axis=0) - np.quantile(m, 0.01, axis=0)
    i = int(np.argmin(ext))
    name = "xyz"[i]
    others = max(float(np.delete(ext, i).min()), 1e-30)
    return CONVENTIONAL_SIGN[name], (f"detected: thinnest along {name} ({ext[i]:.3g} vs {others:.3g}), "
                                     f"signed by convention")


def orbit(means: np.ndarray, views: int, size: int, up: str, elevation: float = 20.0):
    from lghcc.render.views import orbit_cameras

    return orbit_cameras(means, views, width=size, height=size, elevation_deg=elevation, up=parse_up(up))


def evaluation_cameras(args, means: np.ndarray, up: str) -> list:
    """The orbit, or the cameras of ``--cameras``, each at --size squared pixels."""
    if not args.cameras:
        return orbit(means, args.views, args.size, up, args.elevation)
    from lghcc.render.camera import load_capture_cameras

    return [c.scaled(args.size / math.sqrt(c.width * c.height)) for c in load_capture_cameras(args.cameras)]


def importance_text(args) -> str:
    """Which views the SPZ curve's importance pruning ranks the Gaussians on (``SceneRun.importance``)."""
    if args.importance_cameras:
        return f"the cameras of `{args.importance_cameras}` at {args.importance_size} px (not the evaluation's)"
    if args.cameras:
        return "the evaluation cameras themselves (an oracle: ranked on the views it is judged on)"
    return f"{args.importance_views} Fibonacci-sphere views (not the orbit)"


def cameras_digest(path: Path) -> str:
    """SHA-256 of a cameras file, or of a folder's files (names and contents)."""
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")) if path.is_dir() else [path]:
        if p.is_file():
            h.update(str(p.relative_to(path) if path.is_dir() else p.name).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


# --- equal PSNR -----------------------------------------------------------------------------

def envelope(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The upper envelope of (bytes, PSNR) points: those no other point beats or equals in both
    (fewer or equal bytes and higher or equal PSNR), sorted by bytes; PSNR strictly increases."""
    pts = sorted(((float(b), float(p)) for b, p in points if math.isfinite(b) and not math.isnan(p)),
                 key=lambda t: (t[0], -t[1]))
    out: list[tuple[float, float]] = []
    for b, p in pts:
        if not out or p > out[-1][1]:
            if out and out[-1][0] == b:
                out.pop()
            out.append((b, p))
    return out


def bytes_at_psnr(env: list[tuple[float, float]], psnr: float) -> tuple[float | None, str]:
    """SPZ bytes at ``psnr`` on the envelope: (bytes, 'interpolated') between two points (log
    bytes linear in PSNR; exact at the points), (None, 'above') above the top, (bytes of the
    lowest point, 'below') under it."""
    if not env:
        return None, "none"
    if psnr > env[-1][1]:
        return None, "above"
    if psnr < env[0][1]:
        return env[0][0], "below"
    for (b0, p0), (b1, p1) in zip(env, env[1:]):
        if p0 <= psnr <= p1:
            if psnr == p0:
                return b0, "interpolated"
            if psnr == p1 or not math.isfinite(p1):
                return b1, "interpolated"
            t = (psnr - p0) / (p1 - p0)
            return math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0))), "interpolated"
    return env[-1][0], "interpolated"  # psnr == top


def equal_psnr_cell(nbytes: int, psnr: float, env: list[tuple[float, float]], full_spz: int | None) -> str:
    """The 'bytes / SPZ at equal PSNR' cell of a row."""
    if not env:
        return "n/a (no SPZ curve)"
    ref, where = bytes_at_psnr(env, psnr)
    if where == "above":
        if full_spz:
            return f"{nbytes / full_spz:.2f} vs full SPZ (above SPZ's best, {env[-1][1]:.2f} dB)"
        return f"above SPZ's best ({env[-1][1]:.2f} dB)"
    if where == "below":
        return f">= {nbytes / ref:.2f} (below SPZ's lowest, {env[0][1]:.2f} dB)"
    return f"{nbytes / ref:.2f} (SPZ {ref:,.0f} B)"


# --- rows and cache -------------------------------------------------------------------------

@dataclass
class Row:
    codec: str  # "source PLY", "SPZ", "SOG", "compressed PLY", "lghcc", "SPZ curve"
    setting: str
    bytes: int
    gaussians: int
    psnr: float
    ssim: float
    sh_degree: int = -1
    encode_s: float | None = None
    decode_s: float | None = None
    note: str = ""
    extra: dict = field(default_factory=dict)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class SceneCache:
    """Per scene file and render setting: source renders, importance scores and rows (JSON)."""

    def __init__(self, work: Path, slug: str, file_hash: str, render_key: dict, fresh: bool):
        self.base = work / f"{slug}-{file_hash[:12]}"
        rk = hashlib.sha256(json.dumps(render_key, sort_keys=True).encode()).hexdigest()[:12]
        self.dir = self.base / f"r{rk}"
        self.files = self.dir / "files"
        if fresh and self.dir.exists():
            shutil.rmtree(self.dir)
        if fresh:
            for f in self.base.glob("importance_*.npy"):
                f.unlink()
        self.files.mkdir(parents=True, exist_ok=True)
        (self.dir / "key.json").write_text(json.dumps(render_key, indent=1, sort_keys=True))
        self.rows_path = self.dir / "rows.json"
        self.rows: dict = json.loads(self.rows_path.read_text()) if self.rows_path.exists() else {}

    def get(self, key: str) -> Row | None:
        r = self.rows.get(key)
        return Row(**r) if r else None

    def put(self, key: str, row: Row) -> None:
        self.rows[key] = asdict(row)
        tmp = self.rows_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.rows, indent=1, sort_keys=True))
        tmp.replace(self.rows_path)


# --- splat-transform ------------------------------------------------------------------------

def pinned_version(node_dir: Path = NODE_DIR) -> str:
    return json.loads((node_dir / "package.json").read_text())["dependencies"][PACKAGE]


def splat_transform_status(node_dir: Path = NODE_DIR) -> tuple[list[str] | None, str]:
    """(command prefix, '') when node and the pinned splat-transform are installed, else
    (None, one line saying what is missing and what to run)."""
    want = pinned_version(node_dir)
    node = shutil.which("node")
    if node is None:
        return None, (f"node is not on the PATH: install Node.js (20 or later) and run `make node-tools` "
                      f"(installs {PACKAGE} {want} into tools/node/)")
    pkg = node_dir / "node_modules" / "@playcanvas" / "splat-transform"
    try:
        have = json.loads((pkg / "package.json").read_text())["version"]
    except (OSError, ValueError, KeyError):
        return None, f"{PACKAGE} {want} is not installed in {node_dir}: run `make node-tools`"
    if have != want:
        return None, f"{PACKAGE} in {node_dir} is {have}, not the pinned {want}: run `make node-tools`"
    return [node, str(pkg / "bin" / "cli.mjs")], ""


def run_splat_transform(prefix: list[str], args: list[str]) -> float:
    """Run splat-transform quietly on the CPU (-g cpu: decimation otherwise needs a WebGPU adapter;
    SOG bytes are the same either way); returns the wall time. Raises RuntimeError with its
    stderr on failure."""
    cmd = [*prefix, "-q", "-w", "-g", "cpu", *args]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-5:])
        raise RuntimeError(f"splat-transform {' '.join(args)} failed (exit {r.returncode}): {tail}")
    return dt


# --- rendering ------------------------------------------------------------------------------

class Evaluator:
    """Renders scenes from the fixed cameras and compares them with the source renders."""

    def __init__(self, cams, background, refs: np.ndarray | None = None):
        self.cams, self.bg, self.refs = cams, background, refs

    def render(self, scene) -> np.ndarray:
        import torch

        from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs

        g = gaussians_from_scene(scene)
        with torch.no_grad():
            return np.stack([render_3dgs(g, c, background=self.bg).image.clamp(0, 1).numpy() for c in self.cams])

    def compare(self, scene) -> tuple[float, float]:
        """(mean PSNR, mean SSIM) over the views. SSIM is render/metrics.py's (3DGS's) computed in
        float32 (ssim_torch): its float64 ``ssim`` agrees to 1e-7 and takes ~100x longer on a CPU
        (78 s against 0.7 s for 12 views of 320 px)."""
        import torch

        from lghcc.render.metrics import psnr, ssim_torch

        imgs = self.render(scene)
        return (float(np.mean([psnr(a, b) for a, b in zip(imgs, self.refs)])),
                float(np.mean([float(ssim_torch(torch.as_tensor(a), torch.as_tensor(b)))
                               for a, b in zip(imgs, self.refs)])))

    def compare_ply(self, path: Path) -> tuple[float, float, int, int, str]:
        """(PSNR, SSIM, Gaussians, SH degree, note) of a 3DGS PLY (read_back_ply)."""
        s, note = read_back_ply(path)
        p, q = self.compare(s)
        return p, q, s.num_gaussians, s.sh_degree, note


def read_back_ply(path: Path):
    """(GaussianScene, note) of a decoded 3DGS PLY; the note: lghcc's warning when opacity logits
    of +-inf (opacity exactly 1 or 0: splat-transform writes them for compressed PLY, whose
    opacity is 8-bit) were read as finite logits, counting them; any other bad value is an InputError."""
    import warnings

    from lghcc.formats.opacity import InfiniteOpacityWarning
    from lghcc.formats.ply3dgs import read_3dgs_ply

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", InfiniteOpacityWarning)
        scene = read_3dgs_ply(path)
    notes = [str(w.message).split(": ", 1)[-1] for w in caught if issubclass(w.category, InfiniteOpacityWarning)]
    return scene, "; ".join(notes)


# --- one scene ------------------------------------------------------------------------------

@dataclass
class SceneSpec:
    slug: str
    path: Path
    up: str | None  # None: detect
    up_source: str  # "given", "recorded", "" (detect)
    credit: str = ""


def resolve_scene(spec: str, data_root: Path, up_override: str | None) -> SceneSpec:
    """A scene argument: NAME (of SCENES) or [LABEL=]PATH, either with an optional @UP."""
    name, up = spec, None
    m = re.fullmatch(r"(.+)@([+-]?[xyzXYZ])", spec)
    if m:
        name, up = m.group(1), m.group(2).lower().lstrip("+")
    if up_override:
        up = up_override.lower().lstrip("+")
    if name in SCENES:
        rel, rec_up, credit = SCENES[name]
        return SceneSpec(name, data_root / rel, up or rec_up, "given" if up else "recorded", credit)
    label = None
    m = re.fullmatch(r"([A-Za-z0-9_.-]+)=(.+)", name)
    if m:
        label, name = m.group(1), m.group(2)
    p = Path(name)
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "-", label or p.name.removesuffix(".ply")).strip("-") or "scene"
    return SceneSpec(slug, p, up, "given" if up else "")


def spz_variants(sh_degree: int, keeps: list[int], reducers: list[str],
                 sh_mode: str) -> list[tuple[str, int, str, int]]:
    """(key, SH degree, reducer, keep %) of every SPZ curve point: for each SH degree (the
    source's only, or every one down to 0), the full scene and each reducer at each keep %."""
    degrees = [sh_degree] if sh_mode == "source" else list(range(sh_degree, -1, -1))
    out = []
    for d in degrees:
        out.append((f"spz-sh{d}-full", d, "full", 100))
        for red in reducers:
            for k in keeps:
                out.append((f"spz-sh{d}-{red}-{k}", d, red, k))
    return out


def variant_label(reducer: str, keep: int) -> str:
    return "full" if reducer == "full" else {"prune": "importance", "decimate-adaptive": "decimate-adaptive",
                                             "decimate": "decimate"}[reducer] + f" {keep}%"


class SceneRun:
    def __init__(self, spec: SceneSpec, args, st_prefix: list[str] | None, st_why: str):
        from lghcc.formats.ply3dgs import read_3dgs_ply
        from lghcc.render.imageio import background_color

        self.spec, self.args = spec, args
        self.st, self.st_why = st_prefix, st_why
        t0 = time.perf_counter()
        self.scene = read_3dgs_ply(spec.path)
        self.n = self.scene.num_gaussians
        self.deg = self.scene.sh_degree
        if spec.up is None:
            self.up, self.up_why = detect_up(self.scene.means, self.scene.opacity)
        else:
            self.up, self.up_why = spec.up, spec.up_source
        self.file_hash = sha256_file(spec.path)
        key = dict(v=CACHE_VERSION, views=args.views, size=args.size, up=self.up, elevation=args.elevation,
                   background=args.background, splat_transform=pinned_version(),
                   importance=[args.importance_views, args.importance_size])
        if args.cameras:
            key["cameras"] = cameras_digest(Path(args.cameras))
        if args.importance_cameras:
            key["importance_cameras"] = cameras_digest(Path(args.importance_cameras))
        self.cache = SceneCache(Path(args.work), spec.slug, self.file_hash, key, args.fresh)
        self.cams = evaluation_cameras(args, self.scene.means, self.up)
        self.ev = Evaluator(self.cams, background_color(args.background))
        refs_path = self.cache.dir / "source_renders.npy"
        if refs_path.exists():
            self.ev.refs = np.load(refs_path)
            log(f"{spec.slug}: {self.n:,} Gaussians, SH {self.deg}, up {self.up} ({self.up_why}); source renders "
                f"from the cache ({refs_path})")
        else:
            log(f"{spec.slug}: {self.n:,} Gaussians, SH {self.deg}, up {self.up} ({self.up_why}); rendering the "
                f"source, {args.views} views {args.size}x{args.size} ...")
            self.ev.refs = self.ev.render(self.scene)
            np.save(refs_path, self.ev.refs.astype(np.float32))
            log(f"{spec.slug}: source renders done in {time.perf_counter() - t0:.1f} s")
        self.skipped: list[str] = []

    # splat-transform rows ---------------------------------------------------------------

    def cached_or(self, key: str, what: str, fn) -> Row | None:
        row = self.cache.get(key)
        if row is not None:
            log(f"{self.spec.slug}: {what}: cached ({row.bytes:,} B, {row.psnr:.2f} dB)")
            return row
        if self.st is None:
            self.skipped.append(what)
            return None
        from lghcc.common.errors import LghccError

        t0 = time.perf_counter()
        try:
            row = fn()
        except (RuntimeError, LghccError) as e:
            log(f"{self.spec.slug}: {what}: {e}")
            self.skipped.append(f"{what} (failed: {str(e).splitlines()[0]})")
            return None
        self.cache.put(key, row)
        log(f"{self.spec.slug}: {what}: {row.bytes:,} B, {row.gaussians:,} Gaussians, PSNR {row.psnr:.2f} dB, "
            f"SSIM {row.ssim:.4f} ({time.perf_counter() - t0:.1f} s)")
        return row

    def format_row(self, fmt: str) -> Row | None:
        name, ext = FORMATS[fmt]

        def go():
            out = self.cache.files / f"full{ext}"
            back = self.cache.files / f"full_{fmt}.back.ply"
            t_enc = run_splat_transform(self.st, [str(self.spec.path), str(out)])
            t_dec = run_splat_transform(self.st, [str(out), str(back)])
            p, q, n, d, note = self.ev.compare_ply(back)
            back.unlink()
            return Row(name, "full", out.stat().st_size, n, p, q, d, t_enc, t_dec, note)

        return self.cached_or(f"{fmt}-full", name, go)

    def importance(self) -> np.ndarray:
        # named by what it ranks on (kept per scene file, across render settings): a sphere's views,
        # or a cameras file's digest (the evaluation's, or --importance-cameras')
        ranked_on = self.args.importance_cameras or self.args.cameras
        tag = f"{self.args.importance_views}x" if not ranked_on else f"{cameras_digest(Path(ranked_on))[:12]}-"
        path = self.cache.base / f"importance_{tag}{self.args.importance_size}.npy"
        if path.exists():
            return np.load(path)
        from lghcc.encoder.anchors.transcode import sphere_cameras
        from lghcc.render.gaussians3dgs import gaussians_from_scene
        from lghcc.render.importance import gaussian_contributions

        g = gaussians_from_scene(self.scene)
        centre, radius = g.bounds()
        if self.args.importance_cameras:
            from lghcc.render.camera import load_capture_cameras

            size = self.args.importance_size
            cams, what = [c.scaled(size / math.sqrt(c.width * c.height))
                          for c in load_capture_cameras(self.args.importance_cameras)], "--importance-cameras"
        elif self.args.cameras:
            cams, what = self.cams, "evaluation cameras"
        else:
            cams = sphere_cameras(centre, radius, self.args.importance_views, resolution=self.args.importance_size,
                                  prefix="importance")
            what = f"Fibonacci-sphere views {self.args.importance_size}px (not the evaluation orbit)"
        log(f"{self.spec.slug}: importance of each Gaussian from {len(cams)} {what} ...")
        t0 = time.perf_counter()
        c = gaussian_contributions(g.means, g.quats, g.scales, g.opacities, cams)
        np.save(path, c)
        log(f"{self.spec.slug}: importance done in {time.perf_counter() - t0:.1f} s")
        return c

    def curve_point(self, key: str, d: int, reducer: str, keep: int) -> Row | None:
        label = variant_label(reducer, keep)

        def go():
            from lghcc.formats.ply3dgs import write_3dgs_ply

            f = self.cache.files
            src = self.spec.path
            t_red = 0.0
            tmp = f / f"{key}.reduced.ply"
            if reducer == "prune":
                c = self.importance()
                k = max(1, int(round(self.n * keep / 100)))
                idx = np.sort(np.argsort(-c, kind="stable")[:k])
                write_3dgs_ply(tmp, self.scene.subset(idx))
                src = tmp
            elif reducer in ("decimate-adaptive", "decimate"):
                opt = "--decimate-adaptive" if reducer == "decimate-adaptive" else "-d"
                t_red = run_splat_transform(self.st, [str(src), str(tmp), opt, f"{keep}%"])
                src = tmp
            out, back = f / f"{key}.spz", f / f"{key}.back.ply"
            t_enc = run_splat_transform(self.st, [str(src), *(["-H", str(d)] if d < self.deg else []), str(out)])
            t_dec = run_splat_transform(self.st, [str(out), str(back)])
            p, q, n, dd, note = self.ev.compare_ply(back)
            back.unlink()
            tmp.unlink(missing_ok=True)
            return Row("SPZ curve", label, out.stat().st_size, n, p, q, dd, t_red + t_enc, t_dec, note)

        return self.cached_or(key, f"SPZ SH {d} {label}", go)

    # lghcc rows ------------------------------------------------------------------------

    def lghcc_row(self, preset: str, enc: list[str], dec: list[str], dec_help: str) -> Row:
        f = self.cache.files
        stream, back = f / f"lghcc-{preset}.lghcc", f / f"lghcc-{preset}.back.ply"
        for p in (stream, back):
            p.unlink(missing_ok=True)
        env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
        if self.args.lghcc_root:  # another checkout's code, for before/after in one run
            env["PYTHONPATH"] = os.pathsep.join([str(Path(self.args.lghcc_root).resolve()), env.get("PYTHONPATH", "")])
        log(f"{self.spec.slug}: lghcc {preset}: encoding (lghcc-enc's own output follows) ...")
        cmd = [*enc, str(self.spec.path), "-o", str(stream), "--preset", preset, *self.args.enc_args]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, stdout=sys.stderr, env=env)
        t_enc = time.perf_counter() - t0
        if r.returncode != 0:
            log(f"{self.spec.slug}: lghcc {preset}: lghcc-enc failed (exit {r.returncode})")
            return Row("lghcc", preset, 0, 0, math.nan, math.nan, note=f"lghcc-enc failed (exit {r.returncode})")
        sh = ["--export-sh-degree", str(self.deg)] if "--export-sh-degree" in dec_help else []
        cmd = [*dec, str(stream), "--export-ply", str(back), *sh, *self.args.dec_args]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, stdout=sys.stderr, env=env)
        t_dec = time.perf_counter() - t0
        if r.returncode != 0:
            log(f"{self.spec.slug}: lghcc {preset}: lghcc-dec failed (exit {r.returncode})")
            return Row("lghcc", preset, stream.stat().st_size, 0, math.nan, math.nan, encode_s=t_enc,
                       note=f"lghcc-dec failed (exit {r.returncode})")
        from lghcc.common.errors import LghccError

        try:
            p, q, n, d, note = self.ev.compare_ply(back)
        except LghccError as e:
            log(f"{self.spec.slug}: lghcc {preset}: the exported PLY cannot be read: {e}")
            return Row("lghcc", preset, stream.stat().st_size, 0, math.nan, math.nan, encode_s=t_enc, decode_s=t_dec,
                       note=f"exported PLY unreadable: {e}")
        back.unlink()
        row = Row("lghcc", preset, stream.stat().st_size, n, p, q, d, t_enc, t_dec, note)
        log(f"{self.spec.slug}: lghcc {preset}: {row.bytes:,} B, {n:,} Gaussians (SH {d}), PSNR {p:.2f} dB, "
            f"SSIM {q:.4f}, encode {t_enc:.1f} s, decode {t_dec:.1f} s")
        return row


# --- markdown -------------------------------------------------------------------------------

def _s(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None else format(x, fmt)


def _db(x: float) -> str:
    return "n/a" if math.isnan(x) else ("inf" if math.isinf(x) else f"{x:.2f}")


def scene_section(title: str, info: list[str], n_source: int, main: list[Row], curve: list[Row], plot_line: str,
                  notes: list[str]) -> list[str]:
    """One scene's markdown: header lines, the main table, the SPZ curve table, the plot, notes."""
    env = envelope([(r.bytes, r.psnr) for r in curve])
    on_env = {(float(b), float(p)) for b, p in env}
    full_spz = next((r.bytes for r in main if r.codec == "SPZ"), None)
    lines = [f"## {title}", "", *info, "", MAIN_HEADER, "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in main:
        if r.codec in ("source PLY", "SPZ") or not r.bytes or math.isnan(r.psnr):
            eq = "1.00 (itself)" if r.codec == "SPZ" else "-"
        else:
            eq = equal_psnr_cell(r.bytes, r.psnr, env, full_spz)
        if r.note:
            eq = f"{eq}; {r.note}" if eq != "-" else r.note
        lines.append(f"| {r.codec} | {r.setting} | {r.bytes:,} | {8 * r.bytes / n_source:.2f} | {r.gaussians:,} | "
                     f"{_db(r.psnr)} | {_s(r.ssim, '.4f') if not math.isnan(r.ssim) else 'n/a'} | "
                     f"{_s(r.encode_s)} | {_s(r.decode_s)} | {eq} |")
    if curve:
        lines += ["", "SPZ rate-distortion points (the envelope: no other SPZ point has fewer or equal bytes and "
                  "higher or equal PSNR):", "", CURVE_HEADER, "|---|---:|---:|---:|---:|---:|---:|---|"]
        for r in sorted(curve, key=lambda r: r.bytes):
            lines.append(f"| {r.setting} | {r.sh_degree} | {r.gaussians:,} | {r.bytes:,} | "
                         f"{8 * r.bytes / n_source:.2f} | {_db(r.psnr)} | {r.ssim:.4f} | "
                         f"{'yes' if (float(r.bytes), float(r.psnr)) in on_env else ''} |")
    lines += ["", plot_line]
    if notes:
        lines += [""] + notes
    return lines


def parse_section(lines: list[str]) -> dict:
    """Back from a scene section: {'title', 'main': [Row], 'curve': [Row], 'plot': file or None}."""
    title = lines[0][3:].strip()
    main, curve, plot, mode = [], [], None, None

    def num(s):
        s = s.strip().replace(",", "")
        return math.nan if s in ("n/a", "-", "") else float(s)

    for l in lines[1:]:
        if l.startswith(MAIN_HEADER[:20]):
            mode = "main"
            continue
        if l.startswith(CURVE_HEADER[:20]):
            mode = "curve"
            continue
        if not l.startswith("|"):
            mode = None
            m = re.match(r"!\[[^\]]*\]\(([^)]+)\)", l)
            if m:
                plot = m.group(1)
            continue
        if l.startswith("|---"):
            continue
        c = [x.strip() for x in l.strip().strip("|").split("|")]
        if mode == "main":
            main.append(Row(c[0], c[1], int(num(c[2])), int(num(c[4])), num(c[5]), num(c[6])))
        elif mode == "curve":
            curve.append(Row("SPZ curve", c[0], int(num(c[3])), int(num(c[2])), num(c[5]), num(c[6]), int(c[1])))
    return dict(title=title, main=main, curve=curve, plot=plot)


def split_sections(text: str) -> tuple[list[str], list[list[str]]]:
    """(preamble lines, [section lines]) of a results file: sections start at '## '."""
    pre, secs = [], []
    for l in text.rstrip("\n").split("\n"):
        if l.startswith("## "):
            secs.append([l])
        elif secs:
            secs[-1].append(l)
        else:
            pre.append(l)
    return pre, secs


def plot_scene(title: str, main: list[Row], curve: list[Row], path: Path, credit: str = "") -> str:
    """PSNR against bytes (log x) of one scene; returns the markdown line that shows the PNG (or
    says why there is none)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "(matplotlib not installed: no plot; `pip install -e .[tools]`, then `--replot`)"
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    colours = {"importance": "tab:orange", "decimate-adaptive": "tab:purple", "decimate": "tab:olive"}
    ok = [r for r in curve if math.isfinite(r.psnr)]
    fulls = sorted((r for r in ok if r.setting == "full"), key=lambda r: r.bytes)
    fams: dict[tuple[int, str], list[Row]] = {}
    for r in ok:
        if r.setting != "full":
            fams.setdefault((r.sh_degree, r.setting.split(" ")[0]), []).append(r)
    for (d, fam), rs in sorted(fams.items(), key=lambda t: (-t[0][0], t[0][1])):
        rs = sorted(rs + [r for r in fulls if r.sh_degree == d], key=lambda r: r.bytes)
        ax.plot([r.bytes for r in rs], [r.psnr for r in rs], ".", ls=("-", "--", ":", "-.")[d % 4], lw=0.9, ms=3,
                alpha=0.6, color=colours.get(fam, "0.5"), label=f"SPZ SH {d}, {fam}")
    if len(fulls) > 1:
        ax.plot([r.bytes for r in fulls], [r.psnr for r in fulls], "o:", color="0.4", ms=3, lw=0.8,
                label="SPZ, SH degree " + " / ".join(str(r.sh_degree) for r in fulls))
    env = envelope([(r.bytes, r.psnr) for r in curve])
    if env:
        ax.plot([b for b, _ in env], [p for _, p in env], "k-", lw=2, label="SPZ envelope (best SPZ)")
    marks = {"SPZ": ("s", "black"), "SOG": ("D", "tab:blue"), "compressed PLY": ("^", "tab:green")}
    for r in main:
        if not math.isfinite(r.psnr) or not r.bytes:
            continue
        if r.codec in marks:
            m, c = marks[r.codec]
            ax.plot([r.bytes], [r.psnr], m, color=c, ms=8, label=r.codec)
        elif r.codec == "lghcc":
            ax.plot([r.bytes], [r.psnr], "*", color="tab:red", ms=13)
            ax.annotate(f"lghcc {r.setting}", (r.bytes, r.psnr), textcoords="offset points", xytext=(5, -10),
                        fontsize=8, color="tab:red")
    ax.set_xscale("log")
    from matplotlib.ticker import FuncFormatter
    kb = FuncFormatter(lambda x, _: f"{x / 1e6:g} MB" if x >= 1e6 else f"{x / 1e3:g} kB" if x >= 1e3 else f"{x:g} B")
    ax.xaxis.set_major_formatter(kb)
    ax.xaxis.set_minor_formatter(FuncFormatter(lambda x, _: kb(x, _) if str(int(x))[0] in "25" else ""))
    ax.set_xlabel("bytes (log)")
    ax.set_ylabel("PSNR dB against the source renders")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower right")
    if credit:
        fig.text(0.01, 0.01, re.sub(r"\*\*", "", credit), fontsize=7, color="0.3")
    fig.tight_layout(rect=(0, 0.03 if credit else 0, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return f"![PSNR against bytes]({path.name})"


def plot_path(out: Path, slug: str) -> Path:
    return out.with_name(f"{out.stem}_{slug}.png")


def replot(out: Path) -> int:
    if not out.exists():
        raise SystemExit(f"{out}: no results file to replot")
    pre, secs = split_sections(out.read_text())
    new = list(pre)
    for sec in secs:
        d = parse_section(sec)
        slug = d["title"].split(" ")[0]
        line = plot_scene(d["title"], d["main"], d["curve"], plot_path(out, slug),
                          next((l for l in sec if l.startswith("Data credit")), ""))
        new += [line if (l.startswith("![") or l.startswith("(matplotlib not installed")) else l for l in sec]
        log(f"replotted {d['title']}: {line}")
    write_lines(out, new)
    return 0


# --- main -----------------------------------------------------------------------------------

def default_data_root() -> Path:
    for p in (ROOT.parent / "shared" / "data", ROOT.parents[1] / "shared" / "data"):
        if p.is_dir():
            return p
    return ROOT.parent / "shared" / "data"


def lghcc_commands() -> tuple[list[str], list[str]]:
    """lghcc-enc and lghcc-dec of the running Python's environment."""
    bindir = Path(sys.executable).parent
    enc, dec = bindir / "lghcc-enc", bindir / "lghcc-dec"
    if enc.exists() and dec.exists():
        return [str(enc)], [str(dec)]
    return ([sys.executable, "-m", "lghcc.encoder.cli"], [sys.executable, "-m", "lghcc.decoder.cli"])


def help_text(cmd: list[str]) -> str:
    r = subprocess.run([*cmd, "--help"], capture_output=True, text=True, env=dict(os.environ, COLUMNS="200"))
    return r.stdout


def listed_presets(enc_help: str) -> list[str]:
    m = re.search(r"--preset \{([^}]*)\}", enc_help)
    return m.group(1).split(",") if m else []


def default_presets(enc_help: str) -> list[str]:
    """The presets lghcc-enc --help lists, less the lghcc-* modes (per-scene GG-Conv fits made
    for trained anchor scenes: on transcoded 3DGS they saved 0.05%, issue 12)."""
    return [p for p in listed_presets(enc_help) if not p.startswith("lghcc-")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*", default=list(SCENES),
                    help=f"scene names ({', '.join(SCENES)}) or [LABEL=]PATH of 3DGS PLYs, optionally @UP "
                         "(default: all names)")
    ap.add_argument("--up", help="up axis of every scene: x, y, z, -x, -y, -z (default: recorded or detected)")
    ap.add_argument("--presets", default=None,
                    help="comma-separated lghcc presets; 'none' for no lghcc rows, 'all' for every preset "
                         "lghcc-enc lists (default: those it lists less the lghcc-* modes)")
    ap.add_argument("--enc-args", default="", help="extra lghcc-enc arguments (one string, shell-split)")
    ap.add_argument("--dec-args", default="", help="extra lghcc-dec arguments (one string, shell-split)")
    ap.add_argument("--lghcc-root", help="a folder holding another lghcc checkout (a folder named lghcc, e.g. a git "
                                         "worktree of an older commit) whose lghcc-enc and lghcc-dec the lghcc rows run "
                                         "(default: this environment's)")
    ap.add_argument("--views", type=int, default=12, help="orbit views (default 12)")
    ap.add_argument("--size", type=int, default=320, help="render width and height (default 320)")
    ap.add_argument("--elevation", type=float, default=20.0, help="orbit elevation in degrees (default 20)")
    ap.add_argument("--cameras", help="evaluate from these cameras instead of the orbit (an INRIA cameras.json, a "
                                      "COLMAP sparse folder, a transforms.json), each at --size squared pixels")
    ap.add_argument("--background", default="black", choices=("black", "white"))
    ap.add_argument("--formats", default="spz,sog,cply", help="splat-transform formats (default spz,sog,cply)")
    ap.add_argument("--spz-keep", default="90,80,70,60,50,40,30",
                    help="percent of Gaussians kept by the SPZ curve's reducers (default 90,...,30)")
    ap.add_argument("--spz-reducers", default=",".join(DEFAULT_REDUCERS),
                    help=f"how the SPZ curve removes Gaussians, from {', '.join(REDUCERS)} (default "
                         f"{','.join(DEFAULT_REDUCERS)}; 'none': SH bands only)")
    ap.add_argument("--spz-sh", default="all", choices=("all", "source"),
                    help="SH degrees of the SPZ curve: every degree down to 0 (default) or the source's")
    ap.add_argument("--importance-views", type=int, default=24, help="Fibonacci-sphere views for pruning (24)")
    ap.add_argument("--importance-size", type=int, default=256, help="their size in px (256)")
    ap.add_argument("--importance-cameras", help="rank the SPZ curve's importance pruning on these cameras (a file "
                                                 "as --cameras reads, at --importance-size px) instead of the "
                                                 "Fibonacci sphere, or of --cameras, which would be an oracle")
    ap.add_argument("--no-splat-transform", action="store_true",
                    help="never run splat-transform: its rows come from the cache or are left out")
    ap.add_argument("--data-root", type=Path, default=None, help="folder of the named scenes (../shared/data)")
    ap.add_argument("--work", default=str(ROOT / ".bench_real"), help="cache folder (default .bench_real/)")
    ap.add_argument("--fresh", action="store_true", help="ignore the cache of the scenes run (recompute)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads of the renderer (default 2)")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "real_scenes.md")
    ap.add_argument("--append", action="store_true",
                    help="keep the other scenes' sections of --out (those of the scenes run are replaced)")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNGs from the tables in --out")
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.out)

    import shlex

    args.enc_args, args.dec_args = shlex.split(args.enc_args), shlex.split(args.dec_args)
    try:
        keeps = [int(k) for k in args.spz_keep.split(",") if k.strip()]
        reducers = [r for r in args.spz_reducers.split(",") if r.strip() and r != "none"]
        formats = [f for f in args.formats.split(",") if f.strip()]
        if any(not 0 < k < 100 for k in keeps) or any(r not in REDUCERS for r in reducers) or \
                any(f not in FORMATS for f in formats):
            raise ValueError
        if args.up:
            parse_up(args.up)
    except ValueError:
        ap.error("--spz-keep: percents in (0, 100); --spz-reducers: from " + ", ".join(REDUCERS)
                 + "; --formats: from " + ", ".join(FORMATS) + "; --up: x, y, z, -x, -y, -z")
    if "spz" not in formats:
        formats.insert(0, "spz")  # the equal-PSNR column needs the full SPZ file
    st, why = (None, "--no-splat-transform") if args.no_splat_transform else splat_transform_status()
    if st is None and not args.no_splat_transform:
        print(f"bench_real: error: {why}", file=sys.stderr)
        return 3
    enc, dec = lghcc_commands()
    enc_help = help_text(enc) if args.presets in (None, "all") else ""
    if args.presets is None:
        presets = default_presets(enc_help)
    elif args.presets == "none":
        presets = []
    elif args.presets == "all":
        presets = listed_presets(enc_help)
    else:
        presets = [p for p in args.presets.split(",") if p.strip()]
    dec_help = help_text(dec) if presets else ""
    log(f"lghcc presets: {', '.join(presets) or 'none'}")

    import torch

    from lghcc.common.errors import LghccError

    torch.set_num_threads(args.threads)
    data_root = args.data_root or default_data_root()
    cmd = command_line("bench_real.py", argv)
    sections: dict[str, list[str]] = {}
    for spec_str in args.scenes:
        spec = resolve_scene(spec_str, data_root, args.up)
        if not spec.path.is_file():
            print(f"bench_real: error: {spec.path}: no such file" + (f" (scene {spec.slug}; --data-root "
                  f"{data_root})" if spec_str.split('@')[0] in SCENES else ""), file=sys.stderr)
            return 1
        try:
            run = SceneRun(spec, args, st, why)
        except LghccError as e:
            print(f"bench_real: error: {e}", file=sys.stderr)
            return 1
        t_scene = time.perf_counter()
        size = spec.path.stat().st_size
        main_rows = [Row("source PLY", f"SH {run.deg}", size, run.n, math.inf, 1.0, run.deg)]
        for fmt in formats:
            r = run.format_row(fmt)
            if r is not None:
                main_rows.append(r)
        curve = []
        for key, d, red, k in spz_variants(run.deg, keeps, reducers, args.spz_sh):
            if red == "full" and d == run.deg:
                full = next((r for r in main_rows if r.codec == "SPZ"), None)
                if full is not None:
                    curve.append(Row("SPZ curve", "full", full.bytes, full.gaussians, full.psnr, full.ssim, d,
                                     full.encode_s, full.decode_s))
                continue
            r = run.curve_point(key, d, red, k)
            if r is not None:
                curve.append(r)
        for p in presets:
            main_rows.append(run.lghcc_row(p, enc, dec, dec_help))
        title = f"{spec.slug} ({run.n:,} Gaussians, SH degree {run.deg})"
        info = [f"Command: `{cmd}`  ",
                f"Date: {datetime.date.today()}; torch {torch.__version__}, {args.threads} threads; "
                f"{PACKAGE} {pinned_version()} (SPZ v4) on node {node_version()}; shared 2-core VM, load "
                f"{load_average()} at the end (timings are noisy).  ",
                f"Scene: `{display_path(spec)}`, {size:,} B, SHA-256 {run.file_hash[:16]}... "
                + (f"Renders: {args.views} orbit views {args.size}x{args.size}, elevation {args.elevation:g} deg, "
                   "field of view 50 deg, " if not args.cameras else
                   f"Renders: the {len(run.cams)} cameras of `{args.cameras}` at {args.size}^2 pixels each, ")
                + f"{args.background} background, up {run.up} "
                f"({UP_WHY.get(run.up_why, run.up_why)}). "
                "PSNR/SSIM: mean over the views of the decoded scene's renders against the source renders "
                "(render/gaussians3dgs.py, our CPU rasterizer; SSIM as 3DGS, in float32).  ",
                "Encode/decode s: wall time of the subprocess (splat-transform: node start included, ~0.4 s"
                + ("; lghcc: lghcc-enc with its default verification decode, then lghcc-dec --export-ply "
                   + ("with --export-sh-degree at the source's SH degree" if "--export-sh-degree" in dec_help else
                      "at the decoder's default SH degree (it has no --export-sh-degree)")
                   + ", Python and torch start included" if presets else "")
                + "). SPZ curve: SPZ of the scene with fewer "
                f"SH bands (-H) and/or fewer Gaussians: importance = the top x% by contribution over "
                f"{importance_text(args)}, decimate-adaptive / decimate = splat-transform --decimate-adaptive x% / "
                "-d x%."]
        notes = []
        if run.skipped:
            notes.append(f"Not measured ({why or 'failed'}): " + "; ".join(run.skipped) + ".")
        if spec.credit:
            notes.append(f"Data credit: {spec.credit}.")
        line = plot_scene(title, main_rows, curve, plot_path(args.out, spec.slug), spec.credit)
        sections[spec.slug] = scene_section(title, info, run.n, main_rows, curve, line, notes)
        log(f"{spec.slug}: done in {time.perf_counter() - t_scene:.1f} s")
    pre, old = split_sections(args.out.read_text()) if args.append and args.out.exists() else ([], [])
    if not pre:
        pre = ["# Real 3DGS scenes: lghcc beside SPZ, SOG and compressed PLY at equal PSNR", "",
               "Each section is one scene, with the command that produced it (tools/bench_real.py; `--append` "
               "replaces a scene's section and keeps the others). PSNR/SSIM are against renders of the "
               "uncompressed source scene from the same cameras; 'bytes / SPZ at equal PSNR' divides a row's "
               "bytes by the bytes the best SPZ variant needs for the same PSNR (the envelope of the SPZ "
               "curve, interpolated in log bytes).", ""]
    lines = list(pre)
    while lines and not lines[-1].strip():
        lines.pop()
    done = set()
    for sec in old:
        slug = sec[0][3:].split(" ")[0]
        while sec and not sec[-1].strip():
            sec = sec[:-1]
        lines += [""] + (sections[slug] if slug in sections else sec)
        done.add(slug)
    for slug, sec in sections.items():
        if slug not in done:
            lines += [""] + sec
    while lines and not lines[-1].strip():
        lines.pop()
    write_lines(args.out, lines)
    log(f"wrote {args.out}")
    return 0


def node_version() -> str:
    try:
        return subprocess.run(["node", "--version"], capture_output=True, text=True).stdout.strip() or "?"
    except OSError:
        return "n/a"


def display_path(spec: SceneSpec) -> str:
    """A scene's file as the reader can find it: a named scene's path under the data root, a path
    relative to the repository when inside it, else as given."""
    if spec.slug in SCENES:
        return f"shared/data/{SCENES[spec.slug][0]}"
    try:
        return str(spec.path.resolve().relative_to(ROOT))
    except ValueError:
        return str(spec.path)


if __name__ == "__main__":
    sys.exit(main())
