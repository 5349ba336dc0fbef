#!/usr/bin/env python3
"""lghcc at the scale of real captures: time per Gaussian, memory, bytes and PSNR against N.

Scenes of about 100k, 300k, 1M and 3M Gaussians of real content, built deterministically from
the shared donut, playbot lod3 and PlayCanvas logo scenes (tools/scale_scenes.py says exactly
how: whole copies side by side on a grid, none overlapping, and a spatial slab of the last one)
and written as 3DGS PLYs into --work. Per size and preset:

- encode: the installed lghcc-enc on the PLY (``--jobs`` worker processes, default 2; its own
  verification decode off: decoding is measured on its own), wall time, time per Gaussian,
  each stage's share (lghcc-enc --json stage_times_s; "load and start" is the rest of the wall
  time: Python, torch, reading the PLY), peak memory;
- decode: lghcc-dec --export-ply with 1 and with 2 worker processes, wall time and peak memory;
- bytes, PSNR of the decoded scene against renders of the source (bench_real's orbit: --views
  cameras of --size px, up -y) and bytes / SPZ at equal PSNR (bench_real's envelope of SPZ files
  of the scene and of splat-transform --decimate-adaptive reductions; needs `make node-tools`,
  else the column says n/a).

Memory: every encoder and decoder runs in its own subprocess. "peak RSS" is the kernel's maximum
resident set of that process (GNU time's %M); with worker processes, "tree peak" is the
largest sum of the proportional set sizes (PSS: pages shared after fork counted once) of the
process and its descendants, sampled every 0.2 s (or 20x a sample's own time, when reading
PSS of a process of several GiB takes longer: the sampler keeps to about 5% of a core).

``--scene objects-sh3``: the same scenes at SH degree 3, the 59 values per Gaussian of real
captures (tools/scale_scenes.py with_sh3_content: bands 1-2 playbot lod3's, laid out in space as
on playbot, band 3 modelled from them), into tools/results/scale_sh3.md with issue 53's targets (encoder and decoder memory per
Gaussian, `fast` and `medium` time per Gaussian, 6M decoded in 60 s).

``--scene room``: the same for rooms watched from inside (formats/procedural.py make_room_scene of
each size, tools/make_room.py's room), PSNR and bytes / SPZ on 18 views from where a person stands
in it (room_inside_cameras, seed 7: views none of the encoder's stages used; its own views it places
itself, ``--views auto``), into tools/results/scale_inside.md.

Presets: any lghcc-enc preset, and ``plain``: preset low's steps without the render-based
preparation (--psnr 0 --lambda 0 and prune_share 0: no renders, no search), the encoder's
coding alone.

    python tools/bench_scale.py --sizes 100k,300k --presets plain,low     # minutes
    python tools/bench_scale.py                                           # 100k-3M x low, medium: hours
    python tools/bench_scale.py --scene room --sizes 100k,300k            # rooms from inside
    python tools/bench_scale.py --scene objects-sh3 --sizes 1M,3M,6M --presets fast,low,medium
                                                                          # issue 53's SH-3 rows: a day

Results: --out (default tools/results/scale.md) and a PNG of time per Gaussian against N beside
it (matplotlib, `pip install -e .[tools]`; skipped with a message without it). Exit status: 0
done, 1 a scene source missing, 2 usage.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads on a shared machine

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict, dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real as br  # noqa: E402
import scale_scenes  # noqa: E402
from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SIZES = "100k,300k,1M,3M"
UP = {"objects": "-y", "objects-sh3": "-y", "room": "z"}  # the copies stand along -y (tools/scale_scenes.py); the room's floor is z = 0
OUT = {"objects": "scale.md", "objects-sh3": "scale_sh3.md", "room": "scale_inside.md"}
SLUG = {"objects": "scale", "objects-sh3": "scale-sh3", "room": "room"}
ROOM_EVAL_SEED = 7  # the room's evaluation cameras (tools/results/views.md (b)): not the encoder's
PLAIN_YAML = "prune_share: 0\nfit_iterations: 0\n"
STAGES = ("prepare", "geometry", "quantization", "attributes", "tiles and hash")


def log(msg: str) -> None:
    print(f"bench_scale: {msg}", file=sys.stderr, flush=True)


def parse_size(text: str) -> int:
    """100k, 1M, 2.5M, 300000 -> a count of Gaussians."""
    t = text.strip().lower()
    mult = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    try:
        n = int(round(float(t[:-1] if mult > 1 else t) * mult))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a size such as 100k, 1M or 300000, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"a size must be at least 1, got {text!r}")
    return n


def label(n: int) -> str:
    return f"{n / 1e6:g}M" if n >= 1_000_000 else f"{n / 1e3:g}k" if n >= 1000 else str(n)


# --- measuring a subprocess ------------------------------------------------------------------

def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for t in os.listdir(f"/proc/{p}/task"):
                todo += [int(c) for c in open(f"/proc/{p}/task/{t}/children").read().split()]
        except OSError:
            pass
    return out


def _pss(pid: int) -> int:
    try:
        for line in open(f"/proc/{pid}/smaps_rollup"):
            if line.startswith("Pss:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


@dataclass
class Measured:
    rc: int
    wall_s: float
    peak_rss: int  # bytes, the process itself
    tree_peak: int  # bytes, sampled sum of PSS over the process tree (0: not sampled)


SAMPLE_S = 0.2  # the tree peak's sampling period, at least
TIME = "/usr/bin/time"  # GNU time: forks from its own small process, so the child's peak is its own


def measured(cmd: list[str], env: dict, scratch: Path) -> Measured:
    """Run ``cmd`` (its stdout to our stderr) and measure its wall time and memory (module doc).
    The peak RSS comes from GNU time (-f %M): Linux keeps a process's RSS high-water mark across
    exec, so a child forked straight from this process, which holds the renders and torch, would
    report this process's peak as its own. Without /usr/bin/time the column is left empty."""
    out = scratch / "maxrss.txt"
    out.unlink(missing_ok=True)
    wrap = [TIME, "-f", "%M", "-o", str(out)] if os.path.exists(TIME) else []
    t0 = time.perf_counter()
    p = subprocess.Popen([*wrap, *cmd], stdout=sys.stderr, env=env)
    peak = [0]
    done = threading.Event()

    def sample() -> None:
        # reading PSS walks the page tables: for a process of several GiB a sample takes tens of ms,
        # so the pause grows with it and the sampler keeps to about 5% of a core
        wait = SAMPLE_S
        while not done.wait(wait):
            t = time.perf_counter()
            peak[0] = max(peak[0], sum(_pss(q) for q in _descendants(p.pid)))
            wait = max(SAMPLE_S, 20 * (time.perf_counter() - t))
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    p.wait()
    wall = time.perf_counter() - t0
    done.set()
    th.join()
    rss = 0
    if wrap and out.exists():
        lines = [ln for ln in out.read_text().split() if ln.isdigit()]
        rss = int(lines[-1]) * 1024 if lines else 0
    return Measured(p.returncode, wall, rss, peak[0])


# --- rows ------------------------------------------------------------------------------------

@dataclass
class ScaleRow:
    n: int
    preset: str
    bytes: int = 0
    psnr: float = math.nan
    encode: dict = field(default_factory=dict)  # Measured as a dict
    stages: dict = field(default_factory=dict)  # stage -> seconds
    decode: dict = field(default_factory=dict)  # "1", "2" -> Measured as a dict
    spz_cell: str = "n/a"
    note: str = ""
    memory_estimate: int = 0  # lghcc-enc --max-memory's estimate (bytes)
    gaussians_decoded: int = 0  # 0: not recorded (rows of runs before it was)
    measured_at: str = ""  # UTC time and load average when the row started (rows of several runs differ)
    options: str = ""  # the run's options that change a row (measured_options); "": rows of runs before it was recorded


def encode_row(run, n: int, preset: str, args, enc: list[str], dec: list[str], work: Path) -> ScaleRow:
    """One preset on one scene: encode, decode with 1 and 2 workers, PSNR (module doc)."""
    row = ScaleRow(n, preset, measured_at=f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
                                          f"load {load_average()}", options=measured_options(args))
    stream, js = work / f"{run.spec.slug}-{preset}.lghcc", work / f"{run.spec.slug}-{preset}.json"
    opts = ["--preset", preset]
    if preset == "plain":
        plain = work / "plain.yaml"
        plain.write_text(PLAIN_YAML)
        opts = ["--preset", "low", "--psnr", "0", "--lambda", "0", "--config", str(plain)]
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE", LGHCC_PROGRESS_INTERVAL="60")
    log(f"{label(n)} {preset}: encoding ...")
    m = measured([*enc, str(run.spec.path), "-o", str(stream), "-y", *opts, "--jobs", str(args.jobs), "--no-verify",
                  "--json", str(js), *args.enc_args], env, work)
    row.encode = asdict(m)
    if m.rc != 0:
        row.note = f"lghcc-enc failed (exit {m.rc})"
        return row
    stats = json.loads(js.read_text())["stats"]
    row.bytes = stream.stat().st_size
    row.stages = dict(stats.get("stage_times_s", {}))
    back = work / f"{run.spec.slug}-{preset}.back.ply"
    for jobs in (1, 2):
        log(f"{label(n)} {preset}: decoding with {jobs} worker(s) ...")
        d = measured([*dec, str(stream), "--export-ply", str(back), "-y", "--jobs", str(jobs), "-q"], env, work)
        row.decode[str(jobs)] = asdict(d)
        if d.rc != 0:
            row.note = f"lghcc-dec --jobs {jobs} failed (exit {d.rc})"
            return row
    row.psnr, _, row.gaussians_decoded, _, _ = run.ev.compare_ply(back)
    back.unlink()
    log(f"{label(n)} {preset}: {row.bytes:,} B, PSNR {row.psnr:.2f} dB, encode {m.wall_s:.1f} s "
        f"({1e6 * m.wall_s / n:.0f} us per Gaussian), peak {m.peak_rss / 2**20:.0f} MiB")
    return row


def spz_envelope(run, keeps: list[int]) -> tuple[list, int | None]:
    """The SPZ envelope of the scene (full SPZ and --decimate-adaptive reductions) and the full
    file's bytes; ([], None) without splat-transform."""
    full = run.format_row("spz")
    points = [] if full is None else [(full.bytes, full.psnr)]
    for k in keeps:
        r = run.curve_point(f"spz-sh{run.deg}-decimate-adaptive-{k}", run.deg, "decimate-adaptive", k)
        if r is not None:
            points.append((r.bytes, r.psnr))
    return br.envelope(points), None if full is None else full.bytes


# --- the scenes ------------------------------------------------------------------------------

def scene_file(n: int, kind: str, sources: list, work: Path, playbot=None) -> tuple[Path, str, object]:
    """The PLY of the scene of ``n`` Gaussians of ``kind`` (written once into ``work``), how it is
    built, the scene. ``playbot``: playbot lod3 as read (SH 2), the SH content of objects-sh3."""
    from lghcc.formats.ply3dgs import write_3dgs_ply

    if kind == "room":
        from lghcc.formats.procedural import make_room_scene

        scene, text = make_room_scene(n), f"make_room_scene({n}): the room of tools/make_room.py --gaussians {n}"
        path = work / f"room-{label(n)}.ply"
    else:
        scene, pieces = scale_scenes.build_scene(n, sources)
        text, path = scale_scenes.describe(pieces), work / f"{SLUG[kind]}-{label(n)}.ply"
        if kind == "objects-sh3":
            scene = scale_scenes.with_sh3_content(scene, playbot)
            text += ("; SH degree 3 (bands 1-2 of playbot lod3's Gaussian nearest in the unit box, band 3 modelled "
                     "from the second nearest: scale_scenes.with_sh3_content)")
    if not path.exists():
        write_3dgs_ply(path, scene)
    return path, text, scene


def room_evaluation_cameras(work: Path, size: int) -> Path:
    """The room's evaluation cameras as an INRIA cameras.json in ``work`` (not named cameras.json:
    lghcc-enc would find it beside the scene and measure from the very views it is judged on)."""
    from lghcc.formats.procedural import room_inside_cameras
    from make_room import cameras_json

    path = work / f"room-evaluation-cameras-{size}px.json"
    cams = room_inside_cameras(None, 18, size=size, seed=ROOM_EVAL_SEED)
    path.write_text(json.dumps(cameras_json(cams)) + "\n")
    return path


def memory_estimate(scene, preset: str, jobs: int) -> int:
    """lghcc-enc --max-memory's estimate for the scene and preset (encoder/stream/memory.py)."""
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.memory import encode_memory
    from lghcc.encoder.stream.tile_workers import TileWorkers

    over = {"target_psnr": 0.0, "rd_lambda": 0.0, "prune_share": 0.0, "fit_iterations": 0} if preset == "plain" else {}
    cfg = load_config("low" if preset == "plain" else preset, None, over, kind="gaussians")
    return encode_memory(scene, cfg, TileWorkers(jobs=jobs)).total


def scene_run(path: Path, n: int, args, st, why):
    cameras = str(room_evaluation_cameras(args.work, args.size)) if args.scene == "room" else None
    ns = argparse.Namespace(views=args.views, size=args.size, elevation=20.0, background="black",
                            importance_views=24, importance_size=256, work=str(args.work), fresh=False,
                            enc_args=[], dec_args=[], cameras=cameras, importance_cameras=None)
    slug = f"{SLUG[args.scene]}-{label(n)}"
    return br.SceneRun(br.SceneSpec(slug, path, UP[args.scene], "given"), ns, st, why)


# --- the report ------------------------------------------------------------------------------

def _mib(b: int) -> str:
    return f"{b / 2**20:,.0f}" if b else "-"


def stage_cell(r: ScaleRow) -> str:
    wall = r.encode.get("wall_s", 0.0)
    if not wall or not r.stages:
        return "-"
    parts = [f"{s} {100 * r.stages[s] / wall:.0f}%" for s in STAGES if s in r.stages]
    rest = wall - sum(r.stages.values())
    return ", ".join(parts + [f"load and start {100 * rest / wall:.0f}%"])


def table(rows: list[ScaleRow], jobs: int) -> list[str]:
    out = ["| preset | Gaussians | encode s | us / Gaussian | us / Gaussian, stages only | encoder stages (share of "
           f"the wall time) | encoder peak RSS MiB | encoder tree peak MiB ({jobs} jobs) | --max-memory estimate MiB | bytes | bits / Gaussian | "
           "PSNR dB | bytes / SPZ at equal PSNR | decode s (1 / 2 workers) | decoder peak RSS MiB (1 / 2 workers) |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---:|"]
    for r in rows:
        e, d1, d2 = r.encode, r.decode.get("1", {}), r.decode.get("2", {})
        if r.note:
            out.append(f"| {r.preset} | {r.n:,} | {e.get('wall_s', 0):.1f} | - | - | {r.note} | | | | | | | | | |")
            continue
        out.append(f"| {r.preset} | {r.n:,} | {e['wall_s']:.1f} | {1e6 * e['wall_s'] / r.n:.0f} | "
                   f"{1e6 * sum(r.stages.values()) / r.n:.0f} | {stage_cell(r)} | {_mib(e['peak_rss'])} | "
                   f"{_mib(e['tree_peak'])} | {_mib(r.memory_estimate)} | {r.bytes:,} | {8 * r.bytes / r.n:.2f} | {r.psnr:.2f} | {r.spz_cell} | "
                   f"{d1['wall_s']:.1f} / {d2['wall_s']:.1f} | {_mib(d1['peak_rss'])} / {_mib(d2['peak_rss'])} |")
    return out


def plot(rows: list[ScaleRow], path: Path) -> str:
    """Time per Gaussian against N, one line per preset (log x); a message without matplotlib."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        msg = "plot skipped: matplotlib is not installed (pip install -e .[tools])"
        log(msg)
        return msg
    fig, ax = plt.subplots(figsize=(6, 4))
    for preset in dict.fromkeys(r.preset for r in rows):
        done = sorted((r for r in rows if r.preset == preset and not r.note), key=lambda r: r.n)
        if done:
            line, = ax.plot([r.n for r in done], [1e6 * r.encode["wall_s"] / r.n for r in done], marker="o",
                            label=f"{preset} (wall time)")
            ax.plot([r.n for r in done], [1e6 * sum(r.stages.values()) / r.n for r in done], marker="o",
                    linestyle="--", color=line.get_color(), label=f"{preset} (stages, without start and read)")
    ax.set_xscale("log")
    ax.set_xlabel("Gaussians")
    ax.set_ylabel("encode time per Gaussian (us)")
    ax.set_ylim(bottom=0)
    ax.set_title("lghcc-enc: time per Gaussian against scene size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return f"![time per Gaussian]({path.name})"


def _near(rows: list[ScaleRow], n: int, preset: str | None = None) -> ScaleRow | None:
    """The row of the size nearest ``n`` (within 10%) and the preset (None: any), measured."""
    ok = [r for r in rows if not r.note and abs(r.n - n) <= 0.1 * n and (preset is None or r.preset == preset)]
    return ok[0] if ok else None


def _verdict(value: float | None, limit: float, unit: str) -> str:
    if value is None:
        return "not measured in this run"
    if value <= limit:
        return f"met: {value:,.1f} {unit} (target {limit:,.1f})"
    return f"MISSED by {100 * (value / limit - 1):.0f}%: {value:,.1f} {unit} (target {limit:,.1f})"


def targets(rows: list[ScaleRow]) -> list[str]:
    """Issue 32's targets that these rows measure, each met or missed by how much."""
    gib = 2 ** 30
    m1 = _near(rows, 10 ** 6, "medium")
    out = ["Targets (issue 32; 2 cores):", "",
           f"- 1M Gaussians at medium encoded in <= 10 min: {_verdict(m1 and m1.encode['wall_s'] / 60, 10, 'min')}"]
    for preset in dict.fromkeys(r.preset for r in rows):
        a, b = _near(rows, 3 * 10 ** 5, preset), _near(rows, 3 * 10 ** 6, preset)
        per = (lambda r: 1e6 * r.encode["wall_s"] / r.n)
        out.append(f"- {preset}: time per Gaussian at 3M no higher than at 300k: "
                   + (_verdict(per(b), per(a), "us") if a and b else "not measured in this run (needs 300k and 3M)"))
    for n, limit in ((10 ** 6, 4), (3 * 10 ** 6, 10)):
        peaks = [r.encode["peak_rss"] / gib for r in rows if not r.note and abs(r.n - n) <= 0.1 * n]
        out.append(f"- encoder peak memory at {label(n)} <= {limit} GiB (largest over the presets): "
                   + _verdict(max(peaks) if peaks else None, limit, "GiB"))
    # streams that hold about 1M Gaussians: a preset that prunes decodes fewer (plain never prunes)
    d1 = [r.decode["2"]["wall_s"] for r in rows if not r.note and abs(r.n - 10 ** 6) <= 10 ** 5
          and (r.gaussians_decoded >= 0.9 * r.n or (not r.gaussians_decoded and r.preset == "plain"))]
    out.append("- 1M Gaussians decoded in <= 10 s with 2 workers (streams of >= 0.9M Gaussians): "
               + _verdict(min(d1) if d1 else None, 10, "s"))
    return out


def targets_sh3(rows: list[ScaleRow]) -> list[str]:
    """Issue 53's targets at SH degree 3 that these rows measure, each met or missed by how much."""
    mib = 2 ** 20
    out = ["Targets (issue 53, SH degree 3; 2 cores):", ""]
    for r in (r for r in rows if not r.note):
        enc_limit = (2 ** 30 + 1024 * r.n) / mib
        out.append(f"- {r.preset} {label(r.n)}: encoder peak RSS <= 1 GiB + 1 KB per Gaussian: "
                   + _verdict(r.encode["peak_rss"] / mib, enc_limit, "MiB"))
        per = {"fast": 20.0, "medium": 200.0}.get(r.preset)
        if per is not None:
            out.append(f"- {r.preset} {label(r.n)}: <= {per:g} us per Gaussian: "
                       + _verdict(1e6 * r.encode["wall_s"] / r.n, per, "us"))
        dec_limit = (300 * mib + 400 * r.n) / mib
        peaks = [r.decode[j]["peak_rss"] / mib for j in ("1", "2") if j in r.decode]
        out.append(f"- {r.preset} {label(r.n)}: decoder peak RSS <= 300 MiB + 400 B per Gaussian (largest of 1 and 2 "
                   "workers): " + _verdict(max(peaks) if peaks else None, dec_limit, "MiB"))
        if abs(r.n - 6 * 10 ** 6) <= 6 * 10 ** 5 and "2" in r.decode:
            out.append(f"- {r.preset} {label(r.n)}: decoded in <= 60 s with 2 workers: "
                       + _verdict(r.decode["2"]["wall_s"], 60, "s"))
    return out


def measured_when(rows: list[ScaleRow]) -> list[str]:
    """When each row was measured and at what load (a --resume table holds rows of several runs)."""
    out = [f"{r.preset} {label(r.n)} {r.measured_at}" for r in rows if r.measured_at]
    return ["Rows measured (start, load average 1/5/15 min): " + "; ".join(out) + ".", ""] if out else []


def report(rows: list[ScaleRow], built: dict[int, str], args, argv, plot_line: str, spz_note: str) -> list[str]:
    import torch

    room = args.scene == "room"
    where = {"room": " from inside", "objects-sh3": " at SH degree 3"}.get(args.scene, "")
    lines = [f"# Scale{where}: time, memory and bytes against the number of Gaussians", "",
             f"Command: `{command_line('bench_scale.py', argv)}`  ",
             f"Date: {datetime.date.today()}; torch {torch.__version__}; {os.cpu_count()} CPUs; load "
             f"{load_average()} at the end (a shared machine: timings are noisy).", "",
             "Scenes (formats/procedural.py make_room_scene: a closed 6 x 5 x 3 room with furniture, SH degree 0, "
             "watched from inside; lghcc-enc decides where to look from itself):" if room else
             "Scenes (tools/scale_scenes.py: each source scaled to a unit box and cut to SH degree 0, the "
             f"copies on a grid of {scale_scenes.CELL:g}-unit cells in the x-z plane, none overlapping; the "
             "last copy a slab of its lowest-x Gaussians"
             + ("; then at SH degree 3 as with_sh3_content says):" if args.scene == "objects-sh3" else "):"), ""]
    views = (f"the 18 views of {args.size} px from where a person stands in the room (room_inside_cameras, seed "
             f"{ROOM_EVAL_SEED}, 90-degree field of view: views no encoder stage used)" if room else
             f"{args.views} orbit views of {args.size} px (tools/bench_real.py's cameras, up {UP['objects']})")
    lines += [f"- {n:,}: {text}" for n, text in built.items()]
    lines += ["", f"Encode: lghcc-enc --jobs {args.jobs} --no-verify (the verification decode off; decoding is "
              "timed below), wall time of the subprocess with Python's and torch's start and the PLY read. Stage "
              "shares from lghcc-enc --json stage_times_s. Decode: lghcc-dec --export-ply --jobs 1 and --jobs 2. "
              f"PSNR: mean over {views} of the decoded scene against the source's renders. {spz_note} Memory: peak RSS of the "
              "process (GNU time's %M; with workers, the largest process), tree peak: the largest sum of PSS over the process and "
              "its workers, sampled every 0.2 s or 20x a sample's own time (it can miss a short peak). us / Gaussian, stages only: the "
              "encoder's stages without the start and the PLY read.",
              "", *table(rows, args.jobs), "", *measured_when(rows), plot_line, "",
              *(targets_sh3(rows) if args.scene == "objects-sh3" else targets(rows)), "",
              "What runs in parallel: the tiles (geometry, attributes and hash of each; --jobs, --ray). The "
              "whole-scene stages run in one process before them: the render-based preparation (contributions, "
              "sensitivities, the settings search, the fit), the grid and normative order, the rate-distortion "
              "optimized quantization on the whole scene's neighbour graph, and the choice of the stream's "
              "neighbour_prediction unit (a k-NN graph of the whole scene); the per Gaussian cost of a preset "
              "that prepares is mostly theirs."]
    return lines


def measured_options(args) -> str:
    """The options a row's numbers depend on besides its size and preset (--resume keeps only rows of the same)."""
    return (f"--scene {args.scene} --jobs {args.jobs} --views {args.views} --size {args.size} "
            f"--enc-args '{' '.join(args.enc_args)}'")


def resumed_rows(path: Path, options: str) -> dict[tuple[str, int], ScaleRow]:
    """The measured rows of an earlier run's rows.json by (preset, size), those measured with ``options``
    (or before rows recorded them); rows that failed or had other options are measured again."""
    if not path.exists():
        log(f"--resume: no {path}: measuring every row")
        return {}
    rows = [ScaleRow(**r) for r in json.loads(path.read_text())]
    other = [f"{r.preset} {label(r.n)}" for r in rows if r.options not in ("", options)]
    if other:
        log(f"--resume: measuring again {', '.join(other)}: measured with other options than {options}")
    return {(r.preset, r.n): r for r in rows if not r.note and r.options in ("", options)}


PRESET_ORDER = ("plain", "fast", "web", "low", "medium", "high")  # the table's order of presets


def with_other_kept(rows: list[ScaleRow], kept: dict[tuple[str, int], ScaleRow]) -> list[ScaleRow]:
    """This run's rows and the kept rows of presets or sizes it did not ask for (--resume adds rows to a
    table and drops none), by preset (PRESET_ORDER) and size."""
    done = {(r.preset, r.n) for r in rows}
    order = {p: i for i, p in enumerate(PRESET_ORDER)}
    every = rows + [r for key, r in kept.items() if key not in done]
    return sorted(every, key=lambda r: (order.get(r.preset, len(order)), r.n))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default=DEFAULT_SIZES, help=f"scene sizes (default {DEFAULT_SIZES})")
    ap.add_argument("--presets", default="low,medium", help="lghcc-enc presets, or plain (default low,medium)")
    ap.add_argument("--jobs", type=int, default=2, help="lghcc-enc --jobs (default 2)")
    ap.add_argument("--enc-args", default="", help="extra lghcc-enc arguments (one string, shell-split)")
    ap.add_argument("--views", type=int, default=12, help="orbit views for PSNR (default 12)")
    ap.add_argument("--size", type=int, default=320, help="their width and height in px (default 320)")
    ap.add_argument("--spz-keep", default="75,50,25", help="--decimate-adaptive percents of the SPZ curve")
    ap.add_argument("--no-splat-transform", action="store_true", help="no SPZ rows (the column says n/a)")
    ap.add_argument("--data-root", type=Path, default=None, help="the shared scenes (default ../shared/data)")
    ap.add_argument("--work", type=Path, default=ROOT / ".bench_scale", help="scenes, streams, renders (ignored)")
    ap.add_argument("--scene", default="objects", choices=tuple(UP),
                    help="objects: copies of the shared scenes, from an orbit (default); objects-sh3: the same "
                         "scenes at SH degree 3 (issue 53: real captures' 59 values per Gaussian); room: rooms of each size, "
                         "from inside")
    ap.add_argument("--out", type=Path, default=None,
                    help="the report (default tools/results/scale.md, scale_inside.md for --scene room)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the rows of --work's rows.json (rows-room.json) of an earlier run that stopped part way, measured with the same "
                         "--jobs, --views, --size and --enc-args, and measure only the size and preset pairs it lacks; "
                         "the report lists when each row was measured")
    args = ap.parse_args(argv)
    args.out = args.out or ROOT / "tools" / "results" / OUT[args.scene]
    import shlex

    try:
        sizes = [parse_size(s) for s in args.sizes.split(",") if s.strip()]
        keeps = [int(k) for k in args.spz_keep.split(",") if k.strip()]
    except (argparse.ArgumentTypeError, ValueError) as e:
        ap.error(str(e))
    args.enc_args = shlex.split(args.enc_args)
    presets = [p for p in args.presets.split(",") if p.strip()]
    data_root = args.data_root or br.default_data_root()
    objects = args.scene != "room"  # the rooms are made from nothing
    missing = [rel for _, rel in scale_scenes.SOURCES if objects and not (data_root / rel).is_file()]
    if missing:
        print(f"bench_scale: error: missing under {data_root}: {', '.join(missing)} (--data-root)", file=sys.stderr)
        return 1
    st, why = (None, "--no-splat-transform") if args.no_splat_transform else br.splat_transform_status()
    spz_note = ("bytes / SPZ: against the envelope of SPZ of the scene and of splat-transform --decimate-adaptive "
                f"{','.join(map(str, keeps))}% (SPZ v4, splat-transform {br.pinned_version()})." if st else
                f"No SPZ column: {why}.")
    import torch

    torch.set_num_threads(2)
    args.work.mkdir(parents=True, exist_ok=True)
    sources = scale_scenes.load_sources(data_root) if objects else []
    playbot = scale_scenes.read_source(data_root, "playbot-lod3") if args.scene == "objects-sh3" else None
    enc, dec = br.lghcc_commands()
    rows, built, runs = [], {}, {}
    rows_json = args.work / ("rows.json" if args.scene == "objects" else f"rows-{args.scene}.json")
    kept = resumed_rows(rows_json, measured_options(args)) if args.resume else {}
    for n in sizes:  # the scenes, their renders and SPZ rows first (cached in --work)
        path, built[n], scene = scene_file(n, args.scene, sources, args.work, playbot)
        run = scene_run(path, n, args, st, why)
        runs[n] = (run, *(spz_envelope(run, keeps) if st else ([], None)), scene)
    for preset in presets:  # every size of a preset before the next, slower preset
        for n in sizes:
            run, env, full, scene = runs[n]
            row = kept.get((preset, n))
            if row is None:
                row = encode_row(run, n, preset, args, enc, dec, args.work)
                if not row.note and st:
                    row.spz_cell = br.equal_psnr_cell(row.bytes, row.psnr, env, full)
            else:
                log(f"{label(n)} {preset}: kept from {rows_json} (--resume)")
            row.memory_estimate = memory_estimate(scene, preset, args.jobs)  # this code's estimate, kept rows too
            rows.append(row)
            table_rows = with_other_kept(rows, kept)
            rows_json.write_text(json.dumps([asdict(r) for r in table_rows], indent=1))
            # written after every row: a run stopped part way keeps what it measured, and says so
            left = len(sizes) * len(presets) - len(rows)
            lines = report(table_rows, built, args, argv, plot(table_rows, args.out.with_suffix(".png")), spz_note)
            if left:
                lines[3:3] = [f"Part of the run: {len(rows)} of {len(rows) + left} rows measured when this was "
                              "written.", ""]
            write_lines(args.out, lines)
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
