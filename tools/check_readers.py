"""Real-file check of the readers lghcc shares with splat-transform: compressed PLY, streamed
SOG (lod-meta.json), .splat and .ksplat, each file read by lghcc (lghcc.formats.read_scene)
and by the pinned splat-transform (converted by it to a PLY, read with lghcc.formats.ply3dgs),
value for value.

The files, in a temporary folder, from the shared scenes (--data-root):
- compressed PLY: splat-transform's conversion of the donut and of playbot lod4 (SH degree 2);
- streamed SOG: playbot lod3 (31k Gaussians, level 0) and lod4 (8k, level 1) written by
  splat-transform as one lod-meta.json; each level read (lghcc --lod N, splat-transform -L N);
- .splat (donut) and .ksplat in compression modes 0, 1 and 2 (playbot lod4, SH degree 2, two
  sections, full and partial buckets): splat-transform writes neither, so this tool writes them
  (``splat_bytes``, ``ksplat_bytes``: the layouts its readers read, which tests/ use too).

The table gives, per file, the Gaussians and the largest absolute difference of each field
between the two readings (0: the same float32 values), and how many opacity logits
splat-transform gave as +-inf: lghcc reads alpha 0 and 255 as the finite logits of its other
8-bit formats (formats/opacity.py), and reads splat-transform's +-inf the same way, so those
compare equal too. Exit status 0 when every difference is within --tolerance (default 0),
1 otherwise, 3 when splat-transform or the data are missing.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numpy's threads start: a shared machine

import argparse  # noqa: E402
import datetime
import struct
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real import run_splat_transform, splat_transform_status  # noqa: E402
from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT.parent))
from lghcc.common.scene import GaussianScene  # noqa: E402
from lghcc.formats import read_scene  # noqa: E402
from lghcc.formats.ksplat import MAIN_HEADER, MODES, SECTION, SECTION_HEADER, sh_slots  # noqa: E402
from lghcc.formats.opacity import InfiniteOpacityWarning  # noqa: E402
from lghcc.formats.ply import read_ply  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402

SH_C0 = 0.28209479177387814
FIELDS = ("means", "sh", "opacity", "log_scales", "rotations")
DONUT, LOD3, LOD4 = "donut/donut.ply", "playbot/playbot_lod3_31k.ply", "playbot/playbot_lod4_8k.ply"


# --- writers of the formats splat-transform reads but does not write ------------------------

def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def _rgba(scene: GaussianScene) -> np.ndarray:
    colour = _u8((0.5 + SH_C0 * scene.sh[:, 0].astype(np.float64)) * 255)
    alpha = _u8(255 / (1 + np.exp(-scene.opacity.astype(np.float64))))
    return np.concatenate([colour, alpha[:, None]], axis=1)


def splat_bytes(scene: GaussianScene) -> bytes:
    """antimatter15's .splat: 32 bytes per Gaussian (lghcc.formats.splat's layout); SH beyond DC dropped."""
    n = scene.num_gaussians
    q = scene.rotations / np.linalg.norm(scene.rotations, axis=1, keepdims=True)
    rec = np.zeros(n, [("means", "<f4", 3), ("scales", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
    rec["means"], rec["scales"], rec["rgba"] = scene.means, np.exp(scene.log_scales), _rgba(scene)
    rec["rotation"] = _u8((q + 1) / 2 * 255)
    return rec.tobytes()


def _buckets(means: np.ndarray, block: float, capacity: int) -> tuple[np.ndarray, np.ndarray, list[int], int]:
    """(order of the Gaussians, bucket centres, partial bucket sizes, full buckets): the
    Gaussians grouped by cube of side ``block``, each cube cut into buckets of ``capacity``,
    the full buckets first."""
    lo = means.min(axis=0)
    cell = np.floor((means - lo) / block).astype(np.int64)
    keys, inverse = np.unique(cell, axis=0, return_inverse=True)
    full, partial = [], []
    for k in range(len(keys)):
        members = np.flatnonzero(inverse.ravel() == k)
        for s in range(0, len(members), capacity):
            (full if len(members) - s >= capacity else partial).append((members[s:s + capacity], keys[k]))
    buckets = full + partial
    order = np.concatenate([m for m, _ in buckets])
    centres = np.array([lo + (key + 0.5) * block for _, key in buckets], np.float32)
    return order, centres, [len(m) for m, _ in partial], len(full)


def _records(scene: GaussianScene, mode: int, pos: np.ndarray, sh_range: tuple[float, float], capacity: int) -> bytes:
    d = scene.sh_degree
    pos_t, half, sh_t, _ = MODES[mode]
    k = 3 * (scene.sh.shape[1] - 1)
    dtype = np.dtype([("position", pos_t, 3), ("scale", half, 3), ("rotation", half, 4), ("rgba", "u1", 4)]
                     + ([("sh", sh_t, k)] if k else []))
    rec = np.zeros(capacity, dtype)
    n = scene.num_gaussians
    rec["position"][:n], rec["scale"][:n], rec["rotation"][:n] = pos, np.exp(scene.log_scales), scene.rotations
    rec["rgba"][:n] = _rgba(scene)
    if k:
        coeff, channel = sh_slots(d)
        sh = scene.sh[:, 1 + coeff, channel].astype(np.float64)
        rec["sh"][:n] = _u8((sh - sh_range[0]) / (sh_range[1] - sh_range[0]) * 255) if mode == 2 else sh
    return rec.tobytes()


def _section(scene: GaussianScene, mode: int, sh_range: tuple[float, float], block: float,
             capacity: int) -> tuple[bytes, bytes]:
    """(section header, section data) of one section."""
    n = scene.num_gaussians
    slots = -(-n // 4) * 4  # a multiple of 4: the next section's float32 arrays stay aligned
    qrange = MODES[mode][3]
    if mode == 0:
        head = SECTION.pack(n, slots, 0, 0, 0.0, 0, 0, 0, 0, scene.sh_degree)
        return head, _records(scene, mode, scene.means, sh_range, slots)
    order, centres, partial, full = _buckets(scene.means.astype(np.float64), block, capacity)
    scene = GaussianScene(*(getattr(scene, f)[order] for f in FIELDS))
    bucket_of = np.repeat(np.arange(len(centres)), [capacity] * full + partial)
    step = np.float32(block) / 2.0 / qrange
    pos = np.clip(np.round((scene.means - centres[bucket_of].astype(np.float64)) / step + qrange), 0, 65535)
    head = SECTION.pack(n, slots, capacity, len(centres), block, 12, qrange, full, len(partial), scene.sh_degree)
    data = np.array(partial, "<u4").tobytes() + centres.tobytes() + _records(scene, mode, pos, sh_range, slots)
    return head, data


def ksplat_bytes(scene: GaussianScene, mode: int, sections: int = 2, block: float | None = None,
                 capacity: int = 256) -> bytes:
    """A .ksplat (lghcc.formats.ksplat's layout) in compression ``mode`` of ``sections``
    sections; positions in modes 1 and 2 relative to bucket centres on cubes of side ``block``
    (default: a tenth of the scene's extent). The Gaussians' order within a section follows the
    buckets."""
    if block is None:
        block = float(np.ptp(scene.means, axis=0).max()) / 10 or 1.0
    rest = scene.sh[:, 1:].astype(np.float64)
    sh_range = (float(rest.min()), float(rest.max())) if rest.size and np.ptp(rest) > 0 else (-1.5, 1.5)
    parts = np.array_split(np.arange(scene.num_gaussians), sections)
    header = bytearray(MAIN_HEADER)
    header[0:2] = bytes([0, 1])
    struct.pack_into("<I", header, 4, sections)
    struct.pack_into("<I", header, 16, scene.num_gaussians)
    struct.pack_into("<H", header, 20, mode)
    struct.pack_into("<2f", header, 36, *sh_range)
    heads, datas = [], []
    for idx in parts:
        h, d = _section(GaussianScene(*(getattr(scene, f)[idx] for f in FIELDS)), mode, sh_range, block, capacity)
        heads.append(h.ljust(SECTION_HEADER, b"\0"))
        datas.append(d)
    return bytes(header) + b"".join(heads) + b"".join(datas)


# --- the check -------------------------------------------------------------------------------

def splat_transform_reading(prefix: list[str], path: Path, lod: int | None) -> tuple[GaussianScene, int]:
    """(the scene splat-transform reads from ``path`` at level ``lod``, its +-inf opacity
    logits) via a PLY it writes."""
    ply = path.parent.parent / f"{path.name}.{lod}.st.ply"  # outside a streamed SOG's folder
    run_splat_transform(prefix, [str(path), *([] if lod is None else ["-L", str(lod)]), str(ply)])
    n_inf = int(np.isinf(read_ply(ply)["opacity"]).sum())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InfiniteOpacityWarning)
        return read_3dgs_ply(ply), n_inf


def compare(ours: GaussianScene, theirs: GaussianScene) -> list[float]:
    """The largest absolute difference per field (inf when the shapes differ)."""
    return [float(np.abs(getattr(ours, f).astype(np.float64) - getattr(theirs, f)).max())
            if getattr(ours, f).shape == getattr(theirs, f).shape else float("inf") for f in FIELDS]


def make_files(prefix: list[str], data: Path, work: Path) -> list[tuple[str, str, Path, int | None]]:
    """(format, what it was made from, file, level of detail) of every file checked (the
    streamed SOG's units in their own folder, whose bytes are the file's)."""
    run_splat_transform(prefix, [str(data / DONUT), str(work / "donut.compressed.ply")])
    run_splat_transform(prefix, [str(data / LOD4), str(work / "playbot.compressed.ply")])
    run_splat_transform(prefix, [str(data / LOD3), "-l", "0", str(data / LOD4), "-l", "1",
                                 str(work / "lod" / "lod-meta.json")])
    (work / "donut.splat").write_bytes(splat_bytes(read_3dgs_ply(data / DONUT)))
    lod4 = read_3dgs_ply(data / LOD4)
    for mode in (0, 1, 2):
        (work / f"playbot.mode{mode}.ksplat").write_bytes(ksplat_bytes(lod4, mode))
    return [("compressed PLY", "donut (splat-transform)", work / "donut.compressed.ply", None),
            ("compressed PLY", "playbot lod4 (splat-transform)", work / "playbot.compressed.ply", None),
            ("streamed SOG", "playbot lod3 + lod4 (splat-transform), level 0", work / "lod" / "lod-meta.json", 0),
            ("streamed SOG", "playbot lod3 + lod4 (splat-transform), level 1", work / "lod" / "lod-meta.json", 1),
            (".splat", "donut (this tool)", work / "donut.splat", None),
            *((".ksplat", f"playbot lod4, mode {m} (this tool)", work / f"playbot.mode{m}.ksplat", None)
              for m in (0, 1, 2))]


def check(prefix: list[str], data: Path, work: Path) -> list[tuple]:
    rows = []
    for fmt, made, path, lod in make_files(prefix, data, work):
        size = sum(f.stat().st_size for f in path.parent.rglob("*")) if fmt == "streamed SOG" else path.stat().st_size
        ours = read_scene(path, lod=lod)
        theirs, n_inf = splat_transform_reading(prefix, path, lod)
        rows.append((fmt, made, size, ours.num_gaussians, theirs.num_gaussians, ours.sh_degree,
                     compare(ours, theirs), n_inf))
        print(f"{fmt}, {made}: {ours.num_gaussians:,} Gaussians, largest differences {rows[-1][6]}", flush=True)
    return rows


def table(rows: list[tuple], argv: list[str]) -> list[str]:
    lines = ["# Readers against splat-transform on real files", "",
             f"Command: `{command_line('check_readers.py', argv)}`  ",
             f"Date: {datetime.date.today()}; load average {load_average()}", "",
             "Largest absolute difference per field between lghcc's reading and splat-transform's "
             "(0: the same float32 values). +-inf: the opacity logits splat-transform gave as +-inf "
             "(alpha 255 / 0), which both sides then read as the same finite logits. Bytes: the file's; a "
             "streamed SOG's: lod-meta.json and all its units (both levels).", "",
             "Scenes: playbot by **Stephane Agullo**, CC-BY-4.0 (playbot/LICENSE-playbot.txt); donut: V3DG "
             "project, MIT (donut/LICENSE).", "",
             "| format | file | bytes | Gaussians (lghcc / splat-transform) | SH degree | means | SH | opacity | "
             "log scales | rotations | +-inf opacities |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for fmt, made, size, n_ours, n_theirs, degree, diffs, n_inf in rows:
        cells = " | ".join(f"{d:.3g}" for d in diffs)
        lines.append(f"| {fmt} | {made} | {size:,} | {n_ours:,} / {n_theirs:,} | {degree} | {cells} | {n_inf:,} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--tolerance", type=float, default=0.0, help="largest difference accepted (default 0)")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "readers.md")
    args = ap.parse_args(argv)
    prefix, why = splat_transform_status()
    missing = [p for p in (DONUT, LOD3, LOD4) if not (args.data_root / p).is_file()]
    if prefix is None or missing:
        print(f"check_readers: error: {why or 'missing under ' + str(args.data_root) + ': ' + ', '.join(missing)}",
              file=sys.stderr)
        return 3
    with tempfile.TemporaryDirectory(prefix="lghcc-readers-") as d:
        rows = check(prefix, args.data_root, Path(d))
    write_lines(args.out, table(rows, sys.argv[1:] if argv is None else argv))
    bad = [r for r in rows if r[3] != r[4] or max(r[6]) > args.tolerance]
    print(f"wrote {args.out}; {len(rows) - len(bad)} of {len(rows)} files read alike", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
