"""Running a sweep: which cells are left, where they run (Ray or this process), what is kept.

The output folder:

    cells/<cell>.json      one per cell: status ok (its result) or failed (its error), and the
                           fingerprint of the settings it was run with
    streams/<cell>.lghcc   the stream of each finished cell
    prepared/<scene>.tar   each prepared scene (batch/work.py), kept so that a rerun with more
                           presets neither trains nor transcodes again
    results.md, results.json, rd_<scene>.png   the report (batch/report.py)

Resuming: a cell whose JSON says ok with the same fingerprint (its scene, lambda, preset and
the sweep's encoder, transcode and evaluation settings) is not run again; a failed cell is
(the next run retries it). One cell's failure is recorded in its JSON and does not stop the
others; the run ends with a non-zero status when any cell failed.

On Ray, each prepared scene is one task and each cell one task depending on it (Ray passes the
prepared bytes through its object store: workers need not share a filesystem with the driver,
but they read the scenes' input paths and must have lghcc installed). The driver writes every
file; progress goes to the log as plain lines, one per finished step.
"""

from __future__ import annotations

import hashlib
import json
import time
import traceback
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from .sweep import CellKey, PrepKey, Sweep
from ..app.cluster import ClusterError, check_reachable, init_ray, one_line, parse_address  # noqa: F401 (batch's API)
from ..app.fileio import atomic_write_bytes

CELL_FORMAT = 1


def _fingerprint(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def prep_fingerprint(sweep: Sweep, p: PrepKey) -> str:
    s = sweep.scenes[p.scene]
    return _fingerprint({"scene": asdict(s), "lambda": p.lam, "transcode": sweep.transcode if s.kind == "path" else {},
                         "evaluation": asdict(sweep.evaluation)})


def cell_fingerprint(sweep: Sweep, c: CellKey) -> str:
    return _fingerprint({"prep": prep_fingerprint(sweep, c.prep), "preset": c.preset, "encoder": sweep.encoder})


class Store:
    """The output folder (module doc)."""

    def __init__(self, root: Path):
        self.root = Path(root)

    def cell_json(self, c: CellKey) -> Path:
        return self.root / "cells" / f"{c.id}.json"

    def stream(self, c: CellKey) -> Path:
        return self.root / "streams" / f"{c.id}.lghcc"

    def prepared(self, p: PrepKey) -> Path:
        return self.root / "prepared" / f"{p.id}.tar"

    def done(self, sweep: Sweep, c: CellKey) -> dict | None:
        """The stored result of a cell finished with the same settings, else None."""
        try:
            rec = json.loads(self.cell_json(c).read_text())
        except (OSError, ValueError):
            return None
        if rec.get("status") == "ok" and rec.get("fingerprint") == cell_fingerprint(sweep, c) \
                and self.stream(c).is_file():
            return rec
        return None

    def load_prepared(self, sweep: Sweep, p: PrepKey) -> tuple[bytes, dict] | None:
        try:
            info = json.loads(self.prepared(p).with_suffix(".json").read_text())
            if info.get("fingerprint") != prep_fingerprint(sweep, p):
                return None
            return self.prepared(p).read_bytes(), info
        except (OSError, ValueError):
            return None

    def save_prepared(self, sweep: Sweep, p: PrepKey, tar: bytes, info: dict) -> None:
        atomic_write_bytes(self.prepared(p), tar)
        atomic_write_bytes(self.prepared(p).with_suffix(".json"),
                           json.dumps(dict(info, fingerprint=prep_fingerprint(sweep, p)), indent=2).encode())

    def save_cell(self, sweep: Sweep, c: CellKey, result: dict | None, stream: bytes | None,
                  error: BaseException | str | None = None) -> dict:
        rec = {"format": CELL_FORMAT, "cell": c.id, "scene": c.prep.scene, "lambda": c.prep.lam, "preset": c.preset,
               "fingerprint": cell_fingerprint(sweep, c)}
        if error is None:
            atomic_write_bytes(self.stream(c), stream)
            rec.update(status="ok", stream=str(self.stream(c).relative_to(self.root)), **result)
        else:
            rec.update(status="failed", error=error if isinstance(error, str) else one_line(error),
                       traceback=None if isinstance(error, str) else "".join(
                           traceback.format_exception(type(error), error, error.__traceback__)))
        atomic_write_bytes(self.cell_json(c), (json.dumps(rec, indent=2) + "\n").encode())
        return rec


# ---------------------------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------------------------

# ---------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------

class Progress:
    """Plain progress lines (a log, not a terminal bar): one per finished step."""

    def __init__(self, total: int, say: Callable[[str], None]):
        self.total, self.done, self.say, self.t0 = total, 0, say, time.perf_counter()

    def cell(self, rec: dict) -> None:
        self.done += 1
        head = f"[{self.done}/{self.total}] {rec['cell']}"
        if rec["status"] == "ok":
            self.say(f"{head}: {rec['bytes']:,} bytes, {rec['bits_per_anchor']:.1f} bits/anchor, PSNR "
                     f"{rec['psnr']:.2f} dB, SSIM {rec['ssim']:.4f}; encode {rec['encode_s']:.1f} s, decode "
                     f"{rec['decode_s']:.2f} s ({rec.get('host', '?')}, {time.perf_counter() - self.t0:.0f} s elapsed)")
        else:
            self.say(f"{head}: FAILED: {rec['error']}")


def _done_and_todo(store: Store, sweep: Sweep, cells: list[CellKey], redo: bool) -> tuple[dict[str, dict], list[CellKey]]:
    """The records of the cells already finished (none with ``redo``), and the cells to run."""
    records: dict[str, dict] = {}
    todo: list[CellKey] = []
    for c in cells:
        rec = None if redo else store.done(sweep, c)
        if rec is not None:
            records[c.id] = rec
        else:
            todo.append(c)
    return records, todo


def _run_locally(sweep: Sweep, store: Store, preps: dict, cpus_per_cell: int, record, prepared_note) -> None:
    """Every scene prepared (or its stored preparation read), then its cells, in this process."""
    from . import work

    ev, enc, tr = sweep.evaluation, sweep.encoder, sweep.transcode
    for p, its in preps.items():
        got = store.load_prepared(sweep, p)
        if got is None:
            try:
                got = work.prepare(sweep.scenes[p.scene], p.lam, ev, tr, threads=cpus_per_cell)
            except Exception as e:  # noqa: BLE001 - any failure is this scene's, recorded
                for c in its:
                    record(c, error=f"preparing {p.id} failed: {one_line(e)}")
                continue
            store.save_prepared(sweep, p, *got)
            prepared_note(p, got[1])
        for c in its:
            try:
                result, stream = work.run_cell(got[0], c.preset, ev, enc, threads=cpus_per_cell)
            except Exception as e:  # noqa: BLE001
                record(c, error=e)
                continue
            record(c, result, stream)


def run_sweep(sweep: Sweep, *, local: bool = False, address: str | None = None, num_cpus: int | None = None,
              cpus_per_cell: int = 1, connect_timeout_s: float = 15.0, say: Callable[[str], None] = print,
              heartbeat_s: float = 60.0, redo: bool = False) -> list[dict]:
    """Run every cell not finished yet (module doc; ``redo``: every cell, its files replaced);
    return every cell's record, in sweep order."""
    store = Store(sweep.output)
    cells = sweep.cells()
    records, todo = _done_and_todo(store, sweep, cells, redo)
    say(f"{sweep.file}: {len(cells)} cells ({len(sweep.scenes)} scenes x {len(sweep.presets)} presets"
        + (f", lambdas {', '.join(f'{x:g}' for x in sweep.lambdas)}" if sweep.lambdas else "")
        + f"), {len(records)} already done, {len(todo)} to run; results in {sweep.output}")
    if not todo:
        return [records[c.id] for c in cells]
    ray = None if local else init_ray(address, num_cpus, connect_timeout_s)  # a cluster error comes before any file
    sweep.output.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(sweep.output / "sweep.yaml", sweep.file.read_bytes())
    preps: dict[PrepKey, list[CellKey]] = {}
    for c in todo:
        preps.setdefault(c.prep, []).append(c)
    progress = Progress(len(todo), say)

    def record(c: CellKey, result=None, stream=None, error=None) -> None:
        rec = store.save_cell(sweep, c, result, stream, error)
        records[c.id] = rec
        progress.cell(rec)

    def prepared_note(p: PrepKey, info: dict) -> None:
        say(f"prepared {p.id}: {info.get('num_anchors', 0):,} anchors in {info.get('prepare_s', 0):.1f} s "
            f"({info.get('host', '?')})")

    if local:
        _run_locally(sweep, store, preps, cpus_per_cell, record, prepared_note)
    else:
        _run_on_ray(ray, sweep, store, preps, address, cpus_per_cell, say, record, prepared_note, heartbeat_s)
    return [records[c.id] for c in cells]


def _cell_failure(ray, c: CellKey, e: Exception, failed_preps: dict, prep_refs: dict):
    """What a failed cell records: its scene's failed preparation where that was the cause, else
    its own error."""
    if c.prep not in failed_preps and c.prep in prep_refs:  # was it the scene's preparation?
        try:
            ray.get(prep_refs[c.prep])
        except Exception as pe:  # noqa: BLE001
            failed_preps[c.prep] = one_line(pe)
    if c.prep in failed_preps:
        return f"preparing {c.prep.id} failed: {failed_preps[c.prep]}"
    return e


def _run_on_ray(ray, sweep, store, preps, address, cpus_per_cell, say, record, prepared_note, heartbeat_s) -> None:
    from . import work

    try:
        res = ray.cluster_resources()
        say(f"Ray: {'cluster at ' + address if address else 'local'}, {int(res.get('CPU', 0))} CPUs, "
            f"{len(ray.nodes())} node(s); {cpus_per_cell} CPU(s) per task")
        prepare_task = ray.remote(num_cpus=cpus_per_cell, max_retries=0)(work.prepare)
        cell_task = ray.remote(num_cpus=cpus_per_cell, max_retries=0)(work.run_cell)
        ev, enc, tr = sweep.evaluation, sweep.encoder, sweep.transcode
        pending: dict = {}  # ObjectRef -> ("prep", PrepKey, tar_ref) | ("cell", CellKey)
        failed_preps: dict[PrepKey, str] = {}
        prep_refs: dict[PrepKey, object] = {}
        for p, its in preps.items():
            got = store.load_prepared(sweep, p)
            if got is not None:
                tar_ref = ray.put(got[0])
            else:
                tar_ref, info_ref = prepare_task.options(num_returns=2).remote(
                    sweep.scenes[p.scene], p.lam, ev, tr, cpus_per_cell)
                pending[info_ref] = ("prep", p, tar_ref)
                prep_refs[p] = info_ref
            for c in its:
                pending[cell_task.remote(tar_ref, c.preset, ev, enc, cpus_per_cell)] = ("cell", c)
        last = time.perf_counter()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=heartbeat_s)
            if not ready:
                n = sum(1 for v in pending.values() if v[0] == "cell")
                say(f"... {n} cell(s) still running or queued ({time.perf_counter() - last:.0f} s since the last "
                    "one finished)")
                continue
            last = time.perf_counter()
            ref = ready[0]
            kind = pending.pop(ref)
            if kind[0] == "prep":
                p, tar_ref = kind[1], kind[2]
                try:
                    info = ray.get(ref)
                    store.save_prepared(sweep, p, ray.get(tar_ref), info)
                    prepared_note(p, info)
                except Exception as e:  # noqa: BLE001 - the scene's cells fail with it (below)
                    failed_preps[p] = one_line(e)
                    say(f"preparing {p.id} FAILED: {failed_preps[p]}")
                continue
            c = kind[1]
            try:
                result, stream = ray.get(ref)
            except Exception as e:  # noqa: BLE001 - RayTaskError, WorkerCrashedError, ...
                record(c, error=_cell_failure(ray, c, e, failed_preps, prep_refs))
                continue
            record(c, result, stream)
    finally:
        ray.shutdown()
