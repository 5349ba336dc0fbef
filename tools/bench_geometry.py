#!/usr/bin/env python
"""Benchmark of lossless geometry coding (informative).

For the garden SfM points and the donut Gaussian centres voxelized on 10-, 12- and 14-bit
grids (longest bounding-box side -> 2^bits cells, duplicates removed), for a closed
surface cloud of 10k / 100k / 1M voxels (densely sampled surfaces, every surface voxel
kept), and for the anchors of the procedural scene (common/procedural.py
make_procedural_scene, seed 0, the scene of lghcc-enc --procedural and of the codec
benchmark: voxels drawn at random from sparsely sampled surfaces) at the same sizes: bits
per voxel, encode and decode time of lghcc.common.geometry, beside zstd (level 19) of the
Morton-sorted coordinates (int32 little-endian, and Morton-delta varints) and beside G-PCC's
octree coder (TMC13 v23, lossless, planar and IDCM on) run on the same voxel positions: each
set is written as a PLY, encoded AND decoded with tmc3, and the decoded positions are checked
against the input (a mismatch stops the benchmark). Small coarse sets (garden and donut on
6- and 8-bit grids) are included by default. Writes a markdown table (default
tools/results/geometry.md).

tmc3 comes from --tmc13 PATH, else $TMC3, else the build of ../shared/tools/tmc13/build.sh
(/tmp/tmc13-v23/...); when none is found the tool says so in one line and the G-PCC columns
show "-" (the reason is in the table's header text).

Data comes from ../shared/data (see its README); a data set that is missing is reported
and skipped, never silently replaced.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse
import datetime
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lghcc.formats.procedural import make_procedural_scene, surface_points
from lghcc.common.geometry import (IDCM_ISOLATED, decode_geometry, encode_geometry,
                                   normative_order)

from benchutil import command_line  # noqa: E402  (tools/ is on the path when run as a script)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data"
DEFAULT_TMC3 = Path("/tmp/tmc13-v23/mpeg-pcc-tmc13/build/tmc3/tmc3")
# Lossless octree geometry, planar + IDCM on: ../shared/tools/tmc13/README.md
TMC3_ENCODE_ARGS = ["--mode=0", "--positionQuantizationScale=1", "--trisoupNodeSizeLog2=0",
                    "--mergeDuplicatedPoints=0", "--neighbourAvailBoundaryLog2=8",
                    "--intra_pred_max_node_size_log2=6", "--inferredDirectCodingMode=1",
                    "--maxNumQtBtBeforeOt=4", "--minQtbtSizeLog2=0", "--planarEnabled=1",
                    "--planarModeIdcmUse=0", "--disableAttributeCoding=1"]
PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1",
             "uint8": "u1", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4"}


def read_ply_xyz(path: Path) -> np.ndarray:
    """x, y, z (float64) of a binary little-endian PLY whose vertex properties are all scalars of
    the types in PLY_TYPES (the shared data sets, and tmc3's reconstructions)."""
    with open(path, "rb") as f:
        header = _ply_header(f, path)
        count, props = _ply_vertex_layout(header)
        dtype = np.dtype(props)
        data = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
    return np.stack([data["x"], data["y"], data["z"]], axis=1).astype(np.float64)


def _ply_header(f, path: Path) -> list[str]:
    header = []
    while True:
        line = f.readline()
        if not line:
            raise SystemExit(f"{path}: no end_header")
        line = line.decode("ascii").strip()
        header.append(line)
        if line == "end_header":
            break
    if "format binary_little_endian 1.0" not in header:
        raise SystemExit(f"{path}: only binary little-endian PLY is supported")
    return header


def _ply_vertex_layout(header: list[str]) -> tuple[int, list[tuple[str, str]]]:
    count, props, in_vertex = 0, [], False
    for line in header:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            count, in_vertex = int(parts[2]), True
        elif parts[:1] == ["element"]:
            in_vertex = False
        elif parts[:1] == ["property"] and in_vertex:
            props.append((parts[2], PLY_TYPES[parts[1]]))
    return count, props


def write_ply_positions(path: Path, coords: np.ndarray) -> None:
    """Non-negative integer positions < 2^24 as a binary little-endian PLY of float32 x, y, z, no
    attributes (exact; tmc3 reads 4-byte binary positions as float32 whatever their declared type)."""
    if coords.min() < 0 or coords.max() >= 1 << 24:
        raise ValueError("positions must lie in [0, 2^24) to be exact as float32")
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {coords.shape[0]}\n"
            "property float x\nproperty float y\nproperty float z\nend_header\n")
    with open(path, "wb") as f:
        f.write(head.encode("ascii"))
        f.write(np.ascontiguousarray(coords, dtype="<f4").tobytes())


# --- G-PCC (TMC13) ------------------------------------------------------------------------------

def find_tmc3(arg: str | None) -> tuple[Path | None, str]:
    """tmc3 from --tmc13, else $TMC3, else the default build; (path, '') or (None, why not)."""
    for source, cand in (("--tmc13", arg), ("$TMC3", os.environ.get("TMC3")), ("default", str(DEFAULT_TMC3))):
        if not cand:
            continue
        path = Path(cand)
        if path.is_file() and os.access(path, os.X_OK):
            return path, ""
        if source != "default":
            return None, f"tmc3 not found at {path} (from {source})"
    return None, (f"tmc3 not found (no --tmc13, no $TMC3, no {DEFAULT_TMC3}; "
                  "build it with ../shared/tools/tmc13/build.sh)")


def tmc3_version(tmc3: Path) -> str:
    """What tmc3 prints after 'version' in its help text (empty in a build from a tarball)."""
    out = subprocess.run([str(tmc3), "--help"], capture_output=True, text=True).stdout
    for line in out.splitlines():
        if "tmc3 version" in line:
            return line.split("version", 1)[1].strip()
    return ""


def gpcc_bits(tmc3: Path, name: str, coords: np.ndarray) -> tuple[int, float, float]:
    """Encode ``coords`` (unique int voxels) with tmc3, decode, check the reconstruction.
    Returns (compressed size in bits, encode s, decode s); a mismatch stops the benchmark."""
    with tempfile.TemporaryDirectory(prefix="gpcc-") as tmp:
        src, bin_, rec = Path(tmp, "in.ply"), Path(tmp, "out.bin"), Path(tmp, "dec.ply")
        write_ply_positions(src, coords - coords.min(axis=0))
        t_enc = _run_tmc3(tmc3, name, TMC3_ENCODE_ARGS + [f"--uncompressedDataPath={src}",
                                                          f"--compressedStreamPath={bin_}"])
        t_dec = _run_tmc3(tmc3, name, ["--mode=1", f"--compressedStreamPath={bin_}",
                                       f"--reconstructedDataPath={rec}", "--outputBinaryPly=1"])
        dec = read_ply_xyz(rec)
        nbits = 8 * bin_.stat().st_size
    check_gpcc_lossless(name, coords - coords.min(axis=0), dec)
    return nbits, t_enc, t_dec


def _run_tmc3(tmc3: Path, name: str, args: list[str]) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([str(tmc3), *args], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{name}: tmc3 {args[0]} failed (exit {r.returncode}):\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
    return time.perf_counter() - t0


def check_gpcc_lossless(name: str, coords: np.ndarray, dec: np.ndarray) -> None:
    """The decoded positions must be the input set exactly (as sets: tmc3 reorders points)."""
    di = np.rint(dec).astype(np.int64)
    ok = dec.shape == coords.shape and np.array_equal(di, dec) and di.min() >= 0
    if ok:
        ok = np.array_equal(unique_voxels(di), unique_voxels(coords))
    if not ok:
        raise SystemExit(f"*** {name}: G-PCC (tmc3) decoded positions differ from the input set "
                         f"({dec.shape[0]} decoded, {coords.shape[0]} input): not lossless ***")


def voxelize(xyz: np.ndarray, bits: int) -> np.ndarray:
    """Integer voxel coordinates: the longest bounding-box side spans 2^bits cells; unique."""
    lo = xyz.min(axis=0)
    side = float((xyz.max(axis=0) - lo).max())
    return unique_voxels(np.floor((xyz - lo) / side * ((1 << bits) - 1) + 0.5).astype(np.int64))


def surface_cloud(n: int, seed: int = 0) -> np.ndarray:
    """About n unique voxels of densely sampled surfaces (torus, sphere, wavy ground plane):
    the grid resolution is chosen so that the voxelized surfaces hold about n voxels; the
    surfaces are sampled 8 times more densely than that, so the voxelization is closed."""
    rng = np.random.default_rng(seed)
    pts = surface_points(rng, 8 * n)
    res = np.sqrt(n / 12.0)
    for _ in range(2):  # calibrate the resolution on the voxel count
        res *= np.sqrt(n / unique_voxels(np.floor((pts + 1) * res).astype(np.int64)).shape[0])
    return unique_voxels(np.floor((pts + 1) * res).astype(np.int64))


def procedural_coords(n: int, seed: int = 0) -> np.ndarray:
    """The anchor coordinates of make_procedural_scene(n, seed), without generating its
    attributes (minutes at 1M): the same random draws, in the same order, as its first steps.
    main() checks the equality on the smallest size."""
    rng = np.random.default_rng(seed)
    voxel = float(np.sqrt(8.6 / n))
    pts = surface_points(rng, 4 * n + 16)
    coords = np.unique(np.floor(pts / voxel).astype(np.int64), axis=0)
    if coords.shape[0] > n:
        coords = coords[np.sort(rng.choice(coords.shape[0], n, replace=False))]
    return coords


def unique_voxels(v: np.ndarray) -> np.ndarray:
    """Unique rows of non-negative int coordinates < 2^21, sorted by (x, y, z)."""
    key = np.unique((v[:, 0] << 42) | (v[:, 1] << 21) | v[:, 2])
    return np.stack([key >> 42, (key >> 21) & 0x1FFFFF, key & 0x1FFFFF], axis=1)


def varint_bytes(values: np.ndarray) -> bytes:
    """LEB128 varints of non-negative integers < 2^63, vectorized."""
    v = values.astype(np.uint64)
    nbytes = np.maximum(1, (np.floor(np.log2(np.maximum(v, 1).astype(np.float64))).astype(np.int64) // 7) + 1)
    nbytes = np.where(v == 0, 1, nbytes)
    total = int(nbytes.sum())
    out = np.zeros(total, dtype=np.uint8)
    pos = np.concatenate(([0], np.cumsum(nbytes)[:-1]))
    for i in range(int(nbytes.max())):
        sel = nbytes > i
        byte = (v[sel] >> np.uint64(7 * i)) & np.uint64(0x7F)
        more = (nbytes[sel] > i + 1).astype(np.uint64) << np.uint64(7)
        out[pos[sel] + i] = (byte | more).astype(np.uint8)
    return out.tobytes()


def zstd_sizes(coords: np.ndarray) -> tuple[int, int | None]:
    import zstandard

    c = coords[normative_order(coords)]
    off = c - c.min(axis=0)
    z = zstandard.ZstdCompressor(level=19)
    raw = len(z.compress(off.astype("<i4").tobytes()))
    depth = max(int(off[:, a].max()).bit_length() for a in range(3))
    if depth > 21:
        return raw, None
    from lghcc.common.geometry import _morton21

    keys = _morton21(off.astype(np.uint64)).astype(np.int64)
    deltas = np.diff(keys, prepend=0)
    return raw, len(z.compress(varint_bytes(deltas)))


def bench_one(name: str, bits: int | None, coords: np.ndarray, repeat: int, tmc3: Path | None) -> dict:
    n = coords.shape[0]
    t_enc = t_dec = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        payload = encode_geometry(coords)
        t_enc = min(t_enc, time.perf_counter() - t0)
        t0 = time.perf_counter()
        out = decode_geometry(payload, n)
        t_dec = min(t_dec, time.perf_counter() - t0)
    if not np.array_equal(out, coords[normative_order(coords)]):
        raise SystemExit(f"{name}: decoded geometry differs from the input")
    zraw, zvar = zstd_sizes(coords)
    gpcc = None if tmc3 is None else gpcc_bits(tmc3, f"{name} {bits or ''}".strip(), coords)[0] / n
    return dict(name=name, bits=bits, n=n, bpv=8 * len(payload) / n, enc=t_enc, dec=t_dec,
                zraw=8 * zraw / n, zvar=None if zvar is None else 8 * zvar / n, gpcc=gpcc)


def load_sets(data_dir: Path, grids: list[int], sizes: list[int]) -> tuple[list, list[str]]:
    sets, missing = [], []
    garden = data_dir / "garden" / "test_garden.npz"
    donut = data_dir / "donut" / "donut.ply"
    if garden.exists():
        xyz = np.load(garden)["means3d"].astype(np.float64)
        sets += [("garden", b, voxelize(xyz, b)) for b in grids]
    else:
        missing.append(str(garden))
    if donut.exists():
        xyz = read_ply_xyz(donut)
        sets += [("donut", b, voxelize(xyz, b)) for b in grids]
    else:
        missing.append(str(donut))
    sets += [(f"surface cloud {n // 1000}k", None, surface_cloud(n)) for n in sizes]
    if sizes:
        n = min(sizes)
        if not np.array_equal(procedural_coords(n), make_procedural_scene(n, seed=0).coords):
            raise SystemExit("procedural_coords() no longer matches make_procedural_scene(); update it")
    sets += [(f"procedural scene {n // 1000}k", None, procedural_coords(n)) for n in sizes]
    return sets, missing


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder (default: %(default)s)")
    p.add_argument("--grids", type=int, nargs="+", default=[6, 8, 10, 12, 14],
                   help="voxel grid bits of garden and donut (6 and 8: small coarse sets)")
    p.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000],
                   help="sizes of the surface clouds and procedural scenes (anchors)")
    p.add_argument("--repeat", type=int, default=1, help="timing repetitions (best is reported)")
    p.add_argument("--tmc13", default=None,
                   help=f"tmc3 binary (default: $TMC3, else {DEFAULT_TMC3} when it exists)")
    p.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "geometry.md",
                   help="markdown output (default: %(default)s); '-' for stdout only")
    return p


def main(argv: list[str] | None = None) -> int:
    args = setup_args().parse_args(argv)
    tmc3, why = find_tmc3(args.tmc13)
    if tmc3 is None:
        print(f"G-PCC columns left empty: {why}", file=sys.stderr)
    sets, missing = load_sets(args.data, args.grids, args.sizes)
    for m in missing:
        print(f"missing data, skipped: {m}", file=sys.stderr)
    rows = []
    for name, bits, coords in sets:
        r = bench_one(name, bits, coords, args.repeat, tmc3)
        rows.append(r)
        gp = "-" if r["gpcc"] is None else f"{r['gpcc']:7.2f} ({r['bpv'] / r['gpcc']:.3f}x)"
        print(f"{name:22s} {str(bits or '-'):>4s} {r['n']:>9d} {r['bpv']:7.2f} bpv  enc {r['enc']:6.2f} s  "
              f"dec {r['dec']:6.2f} s  zstd {r['zraw']:6.2f}  G-PCC {gp}", flush=True)
    gpcc_text = (f"G-PCC: TMC13 tmc3 `{tmc3}` (version string '{tmc3_version(tmc3)}'; "
                 "../shared/tools/tmc13/build.sh builds v23.0-rc2), octree + planar + IDCM, lossless "
                 f"(`tmc3 {' '.join(TMC3_ENCODE_ARGS)}`), run on the same voxel positions (offsets from "
                 "their minimum, float32 PLY); every stream was decoded and its positions checked equal to "
                 "the input set; bpv = 8 * stream bytes / voxels (the whole stream, headers included); "
                 "ratio = lghcc bpv / G-PCC bpv." if tmc3 is not None else f"G-PCC: not run ({why}).")
    lines = table_header(command_line("bench_geometry.py", argv), gpcc_text) + [table_row(r) for r in rows]
    if missing:
        lines += ["", "Missing data (skipped): " + ", ".join(missing)]
    text = "\n".join(lines) + "\n"
    if str(args.out) == "-":
        print(text)
    else:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
        print(f"wrote {args.out}")
    return 0


def table_header(cmd: str, gpcc_text: str) -> list[str]:
    return [
        "# Geometry coding benchmark",
        "",
        f"Command: `{cmd.strip()}`  ",
        f"Date: {datetime.date.today().isoformat()}; machine: {os.cpu_count()} cores shared with other jobs "
        f"({platform.machine()}; times are noisy; one run each unless --repeat).  ",
        f"Codec: lghcc.common.geometry, geom_idcm_mode={IDCM_ISOLATED}. bpv = bits per voxel (unique voxel "
        "after voxelization), whole payload including its header. zstd: level 19 on the coordinates "
        "relative to the bounding-box minimum in normative (Morton) order, as int32 little-endian, and as "
        "LEB128 varints of Morton-key deltas.  ",
        gpcc_text + "  ",
        "Rows: *garden*, *donut* = the garden SfM points and the donut Gaussian centres voxelized so that "
        "the longest bounding-box side spans 2^bits cells, duplicates removed (6 and 8 bits: small coarse "
        "sets); *surface cloud N* = a closed surface (torus, sphere, wavy plane) sampled 8x denser than its "
        "voxels, every surface voxel kept (`surface_cloud`); *procedural scene N* = the anchors of "
        "`make_procedural_scene(N, seed=0)` (`lghcc-enc --procedural N`, the codec benchmark's scene): "
        "the same surfaces sampled 4 points per anchor and subsampled at random to N, so sparser and "
        "less regular; its bpv is the geometry bits per anchor.",
        "",
        "| data | grid bits | voxels | lghcc bpv | enc s | dec s | zstd int32 bpv | zstd Morton-delta bpv "
        "| G-PCC bpv | lghcc / G-PCC |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]


def table_row(r: dict) -> str:
    zvar = "-" if r["zvar"] is None else f"{r['zvar']:.2f}"
    gpcc = "-" if r["gpcc"] is None else f"{r['gpcc']:.2f}"
    ratio = "-" if r["gpcc"] is None else f"{r['bpv'] / r['gpcc']:.3f}"
    return (f"| {r['name']} | {r['bits'] or '-'} | {r['n']:,} | {r['bpv']:.2f} | {r['enc']:.2f} | "
            f"{r['dec']:.2f} | {r['zraw']:.2f} | {zvar} | {gpcc} | {ratio} |")


if __name__ == "__main__":
    sys.exit(main())
