"""Decoder fuzzing: mutate conformance streams and check that the decoder ends every case in
``LghccError`` or a valid decode, within a time bound and without a huge allocation.

The mutation engine (``Mutator``) works at three depths:

* raw bytes of the whole stream: bit flips, truncation, inserted / deleted / overwritten bytes,
  pure random data (CRCs usually stop these in the container layer);
* data units, re-framed with valid CRC-32s so that the damage reaches the payload parsers:
  payload bit flips, truncation, insertions, deletions, 4-byte extreme values, shuffled,
  dropped or duplicated units, units spliced from another stream, and a unit_payload_size
  that disagrees with the payload (0, +-1, swallowing its CRC or the next unit, 2^31,
  2^32 - 1 ...) with a CRC-32 that is valid for the bytes that size delimits;
* syntax elements: every element of every parsed header (sps, render model, geometry,
  context model, attribute unit with its chunk sizes, hash unit) can be rewritten with an
  extreme value of its descriptor (0, 1, the largest value of its width, 2^k +- 1 up to 2^64,
  NaN / Inf / denormal floats ...), re-coded in place (Exp-Golomb lengths change), CRCs fixed.

Cases run in a forked worker process with an address-space limit (``RLIMIT_AS``), so an
allocation beyond it raises MemoryError there (reported as a bug) instead of exhausting the
machine; a case that runs past the time bound is killed and reported as a bug (timeout), and
the worker is restarted. The worker measures each case's peak resident memory (the kernel's
VmHWM, reset before the case through /proc/self/clear_refs). This module never imports the encoder.

Two drivers: ``run_campaign`` (random.Random, seeded; the long runs of tools/fuzz_decoder.py)
and ``mutation_programs`` (a hypothesis strategy: seed stream, then one or two mutation steps
whose choices hypothesis draws, so that it can shrink a failure; tests/test_fuzz.py).
"""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import random
import re
import resource
import zlib
import time
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common.container import DataUnit, UnitType, read_container, write_container
from ..common.errors import LghccError

# --- seeds -------------------------------------------------------------------------------------


def load_seeds(streams_dir: Path | None = None, max_bytes: int = 200_000) -> dict[str, bytes]:
    """The conformance streams that decode (expect: decode), by id; larger ones left out."""
    from .runner import STREAMS_DIR, load_cases

    seeds = {}
    for case in load_cases(Path(streams_dir) if streams_dir else STREAMS_DIR):
        if case.meta.get("expect", "decode") == "decode":
            data = case.stream.read_bytes()
            if len(data) <= max_bytes:
                seeds[case.id] = data
    return seeds


# --- syntax elements of a stream -----------------------------------------------------------------

@dataclass(frozen=True)
class Element:
    unit: int  # index of the data unit
    bit: int  # bit position in the unit payload
    nbits: int  # coded length
    name: str
    descriptor: str
    value: object


_STRUCTURE_UNIT = {"scene_parameter_set": UnitType.SCENE_PARAMETER_SET,
                   "gaussian_parameter_set": UnitType.GAUSSIAN_PARAMETER_SET,
                   "render_model_unit": UnitType.RENDER_MODEL, "render_mlp_header": UnitType.RENDER_MODEL,
                   "geometry_header": UnitType.GEOMETRY, "context_model_unit": UnitType.CONTEXT_MODEL,
                   "int_array_header": UnitType.CONTEXT_MODEL, "attribute_unit_header": UnitType.ATTRIBUTE,
                   "decoded_scene_hash_unit": UnitType.DECODED_SCENE_HASH}


def _ue_bits(v: int) -> str:
    x = v + 1
    return "0" * (x.bit_length() - 1) + format(x, "b")


def _se_code(v: int) -> int:
    return 2 * v - 1 if v > 0 else -2 * v


def code_bits(descriptor: str, value: int) -> str:
    """The bits of ``value`` coded with ``descriptor`` (u(n), ue(v), se(v), f(32) as its bits)."""
    if descriptor == "ue(v)":
        return _ue_bits(value)
    if descriptor == "se(v)":
        return _ue_bits(_se_code(value))
    n = 32 if descriptor == "f(32)" else int(descriptor[2:-1])
    return format(value & ((1 << n) - 1), f"0{n}b")


def stream_elements(data: bytes) -> list[Element]:
    """Every syntax element of a decodable stream, located in its unit (from the decoder's trace)."""
    from ..common.syntax import f32_bits
    from ..decoder.decode import decode_stream

    units = read_container(data).units
    trace = decode_stream(data, trace=True).trace
    # units of each type in stream order; a structure's entries belong to the next unit of its type
    # when its first element reappears (two attribute units in a hierarchy)
    by_type: dict[int, list[int]] = {}
    for i, u in enumerate(units):
        by_type.setdefault(u.unit_type, []).append(i)
    taken: dict[int, int] = {}
    first_name: dict[int, str] = {}
    out = []
    for e in trace:
        struct = e.name.split(".")[0]
        t = _STRUCTURE_UNIT.get(struct)
        if t is None or t not in by_type:
            continue
        if first_name.get(t) is None:
            first_name[t] = e.name
            taken[t] = 0
        elif e.name == first_name[t]:
            taken[t] += 1
        idx = by_type[t][min(taken[t], len(by_type[t]) - 1)]
        if e.descriptor.startswith("b("):
            continue  # byte strings are mutated as bytes
        value = f32_bits(e.value) if e.descriptor == "f(32)" else int(e.value)
        out.append(Element(idx, e.bit_position, len(code_bits(e.descriptor, value)), e.name, e.descriptor,
                           value))
    return out


def replace_element(payload: bytes, el: Element, value: int) -> bytes:
    """Re-code one element with a new value; later bits move with it; zero-padded to bytes."""
    total = 8 * len(payload)
    whole = int.from_bytes(payload, "big")
    after = total - el.bit - el.nbits  # bits after the element
    code = code_bits(el.descriptor, value)
    head = whole >> (total - el.bit)
    tail = whole & ((1 << after) - 1) if after > 0 else 0
    n = el.bit + len(code) + max(after, 0)
    new = (((head << len(code)) | int(code, 2)) << max(after, 0)) | tail
    pad = -n % 8
    return (new << pad).to_bytes((n + pad) // 8, "big") if n else b""


_EXTREME_F32 = [0x00000000, 0x80000000, 0x7F800000, 0xFF800000, 0x7FC00000, 0x00000001, 0x7F7FFFFF,
                0xFF7FFFFF, 0x3F800000, 0xBF800000, 0x00800000]


def extreme_values(el: Element, rng: random.Random) -> int:
    d = el.descriptor
    if d == "f(32)":
        return rng.choice(_EXTREME_F32 + [rng.getrandbits(32)])
    if d.startswith("u("):
        n = int(d[2:-1])
        return rng.choice([0, 1, (1 << n) - 1, 1 << (n - 1), rng.getrandbits(n), el.value ^ 1])
    k = rng.choice([1, 2, 7, 8, 15, 16, 23, 24, 30, 31, 32, 40, 52, 62, 63, 64])
    big = rng.choice([(1 << k) - 1, 1 << k, (1 << k) + 1])
    v = int(el.value)
    if d == "ue(v)":
        return rng.choice([0, 1, max(v - 1, 0), v + 1, 2 * v + 1, big, rng.randrange(0, 1 << 20)])
    return rng.choice([0, 1, -1, v + 1, v - 1, -v, big, -big])


# --- the mutator -----------------------------------------------------------------------------------

class Mutator:
    """Seeded mutations of seed streams. ``case(rng)`` -> (bytes, description)."""

    RAW = ("raw_bitflip", "raw_truncate", "raw_insert", "raw_delete", "raw_overwrite", "random_bytes",
           "random_after_header")
    UNIT = ("payload_bitflip", "payload_truncate", "payload_insert", "payload_delete", "payload_extreme4",
            "shuffle_units", "drop_unit", "duplicate_unit", "splice_unit", "unit_size")
    FIELD = ("field_extreme", "field_extreme_multi")

    def __init__(self, seeds: dict[str, bytes]):
        if not seeds:
            raise LghccError("no seed streams to mutate")
        self.seeds = dict(seeds)  # add_seed grows the mutator's copy, not the caller's
        self.ids = sorted(seeds)
        self._units = {k: [DataUnit(u.unit_type, u.payload) for u in read_container(v).units]
                       for k, v in seeds.items()}
        self._elements: dict[str, list[Element]] = {}
        self.ops = self.RAW + self.UNIT + self.FIELD + self.FIELD  # syntax-aware mutations twice as often
        self.weights: dict[str, float] | None = None  # seed choice weights (None: uniform), see weigh_by_time

    def weigh_by_time(self, seconds: dict[str, float], floor: float = 0.002) -> None:
        """Draw each seed with probability inversely proportional to its decode time (``seconds``:
        CPU seconds per seed; at least ``floor``): a 0.2 s GG-Conv seed is mutated a hundredth as
        often as a 2 ms one, so that a long run spends its time on many cases rather than on the
        slowest seeds, and still mutates every seed."""
        self.weights = {sid: 1.0 / max(seconds.get(sid, floor), floor) for sid in self.ids}

    def add_seed(self, sid: str, data: bytes, seconds: float | None = None) -> None:
        """One more stream to mutate (a fresh one from the scene generator of tools/fuzz_scenes.py)."""
        self.seeds[sid] = data
        if self.weights is not None:
            self.weights[sid] = 1.0 / max(seconds or 0.002, 0.002)
        self._units[sid] = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
        if sid not in self.ids:
            self.ids.append(sid)

    def drop_seed(self, sid: str) -> None:
        self.seeds.pop(sid, None)
        self._units.pop(sid, None)
        self._elements.pop(sid, None)
        if self.weights is not None:
            self.weights.pop(sid, None)
        if sid in self.ids:
            self.ids.remove(sid)

    def elements(self, sid: str) -> list[Element]:
        if sid not in self._elements:
            try:
                self._elements[sid] = stream_elements(self.seeds[sid])
            except LghccError:  # a seed this decoder rejects (e.g. a suite newer than the decoder)
                self._elements[sid] = []
        return self._elements[sid]

    def case(self, rng: random.Random) -> tuple[bytes, str]:
        sid = rng.choice(self.ids) if self.weights is None else \
            rng.choices(self.ids, [self.weights[i] for i in self.ids])[0]
        op = rng.choice(self.ops)
        data, what = getattr(self, "_" + op)(rng, sid)
        return data, f"{sid}: {op}: {what}"

    @classmethod
    def of_bytes(cls, data: bytes) -> "Mutator":
        """A mutator of one (already mutated) stream, for a further step: raw mutations, and unit
        mutations when its container still parses. Field mutations need the decoder's trace of a
        valid stream, which a mutated stream need not have, so they are left out (and nothing is
        decoded in this process)."""
        m = cls.__new__(cls)
        m.seeds, m.ids, m._elements = {"step": data}, ["step"], {"step": []}
        try:
            m._units = {"step": [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]}
            m.ops = cls.RAW + (cls.UNIT if m._units["step"] else ())
        except LghccError:
            m._units, m.ops = {}, cls.RAW
        if len(data) == 0:
            m.ops = ("random_bytes",)
        return m

    # raw -----------------------------------------------------------------------------------------
    def _raw_bitflip(self, rng, sid):
        b = bytearray(self.seeds[sid])
        pos = [rng.randrange(8 * len(b)) for _ in range(rng.randint(1, 8))]
        for p in pos:
            b[p >> 3] ^= 0x80 >> (p & 7)
        return bytes(b), f"bits {pos}"

    def _raw_truncate(self, rng, sid):
        n = rng.randrange(len(self.seeds[sid]))
        return self.seeds[sid][:n], f"first {n} bytes"

    def _raw_insert(self, rng, sid):
        b = self.seeds[sid]
        i = rng.randrange(len(b) + 1)
        ins = rng.randbytes(rng.randint(1, 16))
        return b[:i] + ins + b[i:], f"{len(ins)} bytes at {i}"

    def _raw_delete(self, rng, sid):
        b = self.seeds[sid]
        i, n = rng.randrange(len(b)), rng.randint(1, 16)
        return b[:i] + b[i + n:], f"{n} bytes at {i}"

    def _raw_overwrite(self, rng, sid):
        b = bytearray(self.seeds[sid])
        i = rng.randrange(len(b))
        v = rng.choice([b"\x00" * 4, b"\xff" * 4, b"\x7f\xff\xff\xff", b"\x80\x00\x00\x00"])
        b[i:i + 4] = v
        return bytes(b[:len(self.seeds[sid])]), f"{v.hex()} at {i}"

    def _random_bytes(self, rng, sid):
        n = rng.randint(0, 512)
        return rng.randbytes(n), f"{n} random bytes"

    def _random_after_header(self, rng, sid):
        n = rng.randint(0, 512)
        return self.seeds[sid][:8] + rng.randbytes(n), f"container header + {n} random bytes"

    # units -----------------------------------------------------------------------------------------
    def _pick_unit(self, rng, sid) -> tuple[list[DataUnit], int]:
        units = list(self._units[sid])
        return units, rng.randrange(len(units))

    def _with_payload(self, units, j, payload) -> bytes:
        units[j] = DataUnit(units[j].unit_type, bytes(payload))
        return write_container(units)

    def _payload_bitflip(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        b = bytearray(units[j].payload)
        if not b:
            return write_container(units), f"unit {j} empty"
        pos = [rng.randrange(8 * len(b)) for _ in range(rng.randint(1, 4))]
        for p in pos:
            b[p >> 3] ^= 0x80 >> (p & 7)
        return self._with_payload(units, j, b), f"unit {j} bits {pos}"

    def _payload_truncate(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        n = rng.randint(0, len(units[j].payload))
        return self._with_payload(units, j, units[j].payload[:n]), f"unit {j} first {n} bytes"

    def _payload_insert(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        p = units[j].payload
        i = rng.randint(0, len(p))
        ins = rng.randbytes(rng.randint(1, 8))
        return self._with_payload(units, j, p[:i] + ins + p[i:]), f"unit {j}: {len(ins)} bytes at {i}"

    def _payload_delete(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        p = units[j].payload
        i, n = rng.randint(0, max(len(p) - 1, 0)), rng.randint(1, 8)
        return self._with_payload(units, j, p[:i] + p[i + n:]), f"unit {j}: {n} bytes deleted at {i}"

    def _payload_extreme4(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        b = bytearray(units[j].payload)
        i = rng.randint(0, max(len(b) - 1, 0))
        v = rng.choice([b"\x00\x00\x00\x00", b"\xff\xff\xff\xff", b"\x00\x00\x00\x01", b"\x80\x00\x00\x00"])
        b[i:i + 4] = v
        return self._with_payload(units, j, b[:max(len(units[j].payload), 1)]), f"unit {j}: {v.hex()} at {i}"

    def _shuffle_units(self, rng, sid):
        units = list(self._units[sid])
        order = list(range(len(units)))
        rng.shuffle(order)
        return write_container([units[i] for i in order]), f"order {order}"

    def _drop_unit(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        del units[j]
        return write_container(units), f"unit {j} dropped"

    def _duplicate_unit(self, rng, sid):
        units, j = self._pick_unit(rng, sid)
        k = rng.randint(0, len(units))
        units.insert(k, units[j])
        return write_container(units), f"unit {j} repeated at {k}"

    def _splice_unit(self, rng, sid):
        """A unit of the same type from another stream: consistent alone, inconsistent together."""
        units, j = self._pick_unit(rng, sid)
        other = rng.choice(self.ids)
        same = [u for u in self._units[other] if u.unit_type == units[j].unit_type]
        if not same:
            return write_container(units), "no unit to splice"
        units[j] = rng.choice(same)
        return write_container(units), f"unit {j} from {other}"

    def _unit_size(self, rng, sid):
        """unit_payload_size of one unit changed, the unit's CRC-32 made valid for the bytes the new
        size delimits (the bytes after them follow unchanged): the container layer accepts the unit
        and the payload parser, or the framing of the next units, meets the mismatch."""
        units, j = self._pick_unit(rng, sid)
        data = write_container(units)
        pos = read_container(data).units[j].offset
        n = len(units[j].payload)
        nxt = units[j + 1].size if j + 1 < len(units) else 0
        size = rng.choice([0, 1, max(n - 1, 0), n + 1, n + 4, n + 4 + nxt, n + 4 + max(nxt - 4, 0), 1 << 31,
                           (1 << 32) - 1, rng.randrange(0, len(data) - pos + 16)])
        hdr = bytes([units[j].unit_type]) + size.to_bytes(4, "big")
        tail = data[pos + 5:]
        if size > len(tail):  # the stream ends inside the declared payload
            return data[:pos] + hdr + tail, f"unit {j}: size {size} (payload {n}), beyond the end"
        crc = zlib.crc32(hdr + tail[:size]).to_bytes(4, "big")
        return data[:pos] + hdr + tail[:size] + crc + tail[size:], f"unit {j}: size {size} (payload {n})"

    # syntax elements ---------------------------------------------------------------------------------
    def _field_extreme(self, rng, sid, count: int = 1):
        units = list(self._units[sid])
        els = self.elements(sid)
        changes = []
        # distinct units; within a unit, from the last element backwards so positions stay valid
        picked = sorted(rng.sample(els, min(count, len(els))), key=lambda e: (e.unit, -e.bit))
        done = set()
        for el in picked:
            if (el.unit, el.bit) in done:
                continue
            done.add((el.unit, el.bit))
            v = extreme_values(el, rng)
            units[el.unit] = DataUnit(units[el.unit].unit_type, replace_element(units[el.unit].payload, el, v))
            changes.append(f"{el.name}={v}")
        return write_container(units), ", ".join(changes)

    def _field_extreme_multi(self, rng, sid):
        return self._field_extreme(rng, sid, rng.randint(2, 4))


# --- hypothesis-driven mutation programs ------------------------------------------------------------

def mutation_programs(mutator: Mutator, max_steps: int = 2):
    """A hypothesis strategy of mutation programs: (seed id, [(op, rng), ...]). The first step is any
    mutation of the seed stream; later steps mutate the result (raw and unit mutations, see
    ``Mutator.of_bytes``). Every choice inside a step comes from the step's hypothesis-controlled
    Random, so that hypothesis can replay, shrink and derandomize programs. Needs hypothesis."""
    from hypothesis import strategies as st

    steps = st.lists(st.tuples(st.sampled_from(mutator.ops), st.randoms(use_true_random=False)),
                     min_size=1, max_size=max_steps)
    return st.tuples(st.sampled_from(mutator.ids), steps)


def apply_program(mutator: Mutator, program) -> tuple[bytes, str]:
    """The stream a mutation program makes, and a description of its steps."""
    sid, steps = program
    op, rng = steps[0]
    data, what = getattr(mutator, "_" + op)(rng, sid)
    desc = [f"{sid}: {op}: {what}"]
    for op, rng in steps[1:]:
        m = Mutator.of_bytes(data)
        if op not in m.ops:  # e.g. a field mutation as a second step: a raw one of the same rank instead
            op = m.ops[Mutator.RAW.index(op) % len(m.ops)] if op in Mutator.RAW else m.ops[len(op) % len(m.ops)]
        data, what = getattr(m, "_" + op)(rng, "step")
        desc.append(f"then {op}: {what}")
    return data, "; ".join(desc)


# --- running cases ---------------------------------------------------------------------------------

VALID = "valid decode"


# the decoder's memory bound in the worker (decoder/limits.py): half the address space the sandbox
# gives a case, so that a stream the plan admits cannot reach the sandbox's limit (a MemoryError
# there is a bug: the plan undercounted)
_MAX_MEMORY: list[int | None] = [None]


def classify(data: bytes, options: dict | None = None) -> tuple[str, str]:
    """Decode in this process: (kind, detail). kind: VALID, 'error: <class>' or 'BUG: <class>'.
    ``options``: decode_stream's box, max_level, jobs and exact_jobs (a partial decode, or tiles
    decoded by worker processes); a box decode must output the full decode's points of the tiles
    it selects, row for row."""
    from ..decoder.decode import decode_stream
    from ..decoder.limits import DEFAULT_MAX_MEMORY

    try:
        res = decode_stream(data, max_memory=_MAX_MEMORY[0] or DEFAULT_MAX_MEMORY, **(options or {}))
        if res.scene.num_points < 1 and not (options or {}).get("box"):
            return "BUG: empty scene", "a valid decode with no anchors or Gaussians"
        if (options or {}).get("box") and (options or {}).get("max_level", 2) == 2:
            wrong = partial_mismatch(data, options["box"], res.scene)
            if wrong:
                return "BUG: box decode differs from the full decode", wrong
        return VALID, ""
    except LghccError as e:
        if not str(e):
            return "BUG: error without message", type(e).__name__
        return f"error: {type(e).__name__}", str(e)[:200]
    except MemoryError:
        return "BUG: MemoryError", traceback.format_exc()
    except Exception as e:  # noqa: BLE001 - every other exception is a decoder bug
        return f"BUG: {type(e).__name__}", traceback.format_exc()


# the arrays of a decoded scene with one row per point (anchor or explicit-Gaussian scene)
_ROW_ARRAYS = ("coords", "features", "scalings", "offsets", "offset_mask", "sh", "opacity", "log_scales", "rotations")


def partial_mismatch(data: bytes, box, part) -> str:
    """'' when ``part`` (a box decode of ``data``) holds exactly the full decode's rows of the tiles
    the box selects (clause 13.3), else what differs."""
    from ..decoder.decode import decode_stream, parse_stream, selected_tiles

    s = parse_stream(data)
    starts = np.concatenate([[0], np.cumsum([t.num_points for t in s.tiles])]).astype(np.int64)
    sel = selected_tiles(s.tiles, s.ps, box)
    rows = np.concatenate([np.arange(starts[t], starts[t + 1]) for t in sel]) if sel else np.zeros(0, np.int64)
    full = decode_stream(data, max_memory=_MAX_MEMORY[0]).scene
    for name in _ROW_ARRAYS:
        a, b = getattr(full, name, None), getattr(part, name, None)
        if (a is None) != (b is None) or (a is not None and not np.array_equal(a[rows], b, equal_nan=True)):
            return f"{name}: the box decode's {len(sel)} tiles differ from the full decode's"
    return ""


def _worker(conn, memory_bytes: int | None, threads: int, max_memory: int | None = None, judge=None) -> None:
    """Decodes the parent's cases one at a time with ``judge`` (default ``classify``)."""
    import signal

    import torch

    # a case may decode its tiles in worker processes (decode_stream's jobs): this process, which the
    # sandbox kills itself, may have children
    mp.current_process().daemon = False

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the campaign (the parent), not a case
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's handler is not the worker's

    torch.set_num_threads(threads)
    from ..common import knn

    knn.set_candidate_threads(threads)  # a thread pool per k-NN query costs more than small cases' queries
    _MAX_MEMORY[0] = max_memory
    judge = judge or classify
    from ..decoder import decode  # noqa: F401 - imported before the clock of the first case starts

    if memory_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    conn.send("ready")
    while True:
        try:
            data, options = conn.recv()
        except EOFError:
            return
        base_kib = _reset_peak_rss()
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            kind, detail = judge(data) if options is None else judge(data, options)
        except Exception as e:  # noqa: BLE001 - e.g. MemoryError while handling another error
            kind, detail = f"BUG: {type(e).__name__}", traceback.format_exc()
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        peak_kib = _status_kib("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        conn.send((kind, detail, dt, peak_kib, max(peak_kib - base_kib, 0), cpu))


def _status_kib(key: str) -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _reset_peak_rss() -> int:
    """Reset the kernel's peak-RSS mark (VmHWM) to the current RSS; returns the current RSS (KiB).
    Without /proc/self/clear_refs the peak is the process's peak so far (an upper bound)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass
    return _status_kib("VmRSS")


def _vm_size_bytes() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class CaseResult(tuple):
    """(kind, detail, seconds, peak_kib, growth_kib, cpu_seconds) with names: ``seconds`` is wall
    time, ``cpu_seconds`` the worker's CPU time for the case (on a shared machine a niced run's wall
    time says little about the decoder; its CPU time does)."""

    def __new__(cls, kind: str, detail: str, seconds: float, peak_kib: int = 0, growth_kib: int = 0,
                cpu_seconds: float = 0.0):
        return super().__new__(cls, (kind, detail, seconds, peak_kib, growth_kib, cpu_seconds))

    kind = property(lambda self: self[0])
    detail = property(lambda self: self[1])
    seconds = property(lambda self: self[2])
    cpu_seconds = property(lambda self: self[5])
    peak_kib = property(lambda self: self[3])
    growth_kib = property(lambda self: self[4])


class Sandbox:
    """A forked worker that decodes cases one at a time, with an address-space limit of the
    parent's current size plus ``memory_mb`` and a wall-clock bound per case. ``judge(data, options)``
    -> (kind, detail) decodes a case in the worker (default ``classify``; the differential fuzzer's
    also returns the decoded scene's hash, conformance/differential.py)."""

    def __init__(self, timeout: float = 5.0, memory_mb: int | None = 2048, threads: int = 1, judge=None):
        self.timeout = timeout
        self.memory_bytes = _vm_size_bytes() + memory_mb * (1 << 20) if memory_mb else None
        self.max_memory = memory_mb * (1 << 19) if memory_mb else None  # the decoder's own bound: half of it
        self.threads = threads
        self.judge = judge
        self._ctx = mp.get_context("fork")
        self._proc = None
        self._conn = None
        self._t0 = 0.0

    def _start(self) -> None:
        parent, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_worker, daemon=True,
                                       args=(child, self.memory_bytes, self.threads, self.max_memory, self.judge))
        self._proc.start()
        child.close()
        self._conn = parent
        if not parent.poll(120) or parent.recv() != "ready":
            raise RuntimeError("the fuzz worker process did not start")

    def _stop(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.join()
            self._conn.close()
        self._proc = self._conn = None

    def run(self, data: bytes, options: dict | None = None) -> "CaseResult":
        """Decode one case in the worker (``options``: see classify): (kind, detail, seconds, peak
        RSS KiB, peak above the RSS before the case KiB); the memory figures are 0 when the worker
        timed out or died."""
        self.submit(data, options)
        return self.collect()

    def submit(self, data: bytes, options: dict | None = None) -> None:
        """Hand the worker one case and return at once (``collect`` waits for its result): the
        caller may do other work meanwhile (the differential fuzzer runs the JavaScript decoder)."""
        if self._proc is None or not self._proc.is_alive():
            self._start()
        self._t0 = time.perf_counter()
        self._conn.send((data, options))

    def collect(self) -> "CaseResult":
        """The result of the case ``submit`` handed over, within ``timeout`` of its submission."""
        t0 = self._t0
        if not self._conn.poll(max(self.timeout - (time.perf_counter() - t0), 0.0)):
            self._stop()
            return CaseResult("BUG: timeout", f"no result after {self.timeout:g} s", time.perf_counter() - t0)
        try:
            kind, detail, seconds, peak_kib, growth_kib, cpu = self._conn.recv()
        except (EOFError, OSError):
            code = self._proc.exitcode if self._proc else None
            self._stop()
            return CaseResult("BUG: worker died", f"exit code {code}", time.perf_counter() - t0)
        return CaseResult(kind, detail, seconds, peak_kib, growth_kib, cpu)

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        if self._proc is not None:
            self._proc.join(timeout=2)
            if self._proc.is_alive():
                self._proc.kill()
        self._proc = self._conn = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def message_prefix(message: str, words: int = 8) -> str:
    """A message's first words with numbers and hex digests replaced by '#': groups errors by reason."""
    m = re.sub(r"0x[0-9a-fA-F]+|\b[0-9a-f]{8,}\b|-?\d+(\.\d+)?(e[+-]?\d+)?", "#",
               message.strip().splitlines()[0] if message else "")
    return " ".join(m.split()[:words])


@dataclass
class Summary:
    cases: int = 0
    seconds: float = 0.0
    outcomes: Counter = field(default_factory=Counter)
    reasons: Counter = field(default_factory=Counter)  # (kind, message prefix) of the errors
    slowest: tuple[float, str] = (0.0, "")  # wall seconds
    slowest_cpu: tuple[float, str] = (0.0, "")  # the worker's CPU seconds
    slow_cpu_s: float = 5.0
    slow: int = 0  # cases that took more than slow_cpu_s of CPU (reported, not bugs: a hang is a timeout)
    stopped: bool = False  # the run was stopped before its budget (its figures are those of the cases done)
    peak_kib: list[int] = field(default_factory=list)  # per case: the worker's peak RSS
    growth_kib: list[int] = field(default_factory=list)  # per case: peak RSS above the RSS before the case
    largest: tuple[int, str] = (0, "")  # the largest growth and its case
    failures: list[tuple[str, str, str, bytes]] = field(default_factory=list)  # kind, what, detail, data

    def add(self, res: "CaseResult", what: str, data: bytes, failures_dir: Path | None = None) -> None:
        self.cases += 1
        self.outcomes[res.kind] += 1
        if res.kind.startswith("error"):
            self.reasons[(res.kind[len("error: "):], message_prefix(res.detail))] += 1
        if res.seconds > self.slowest[0]:
            self.slowest = (res.seconds, what)
        if res.cpu_seconds > self.slowest_cpu[0]:
            self.slowest_cpu = (res.cpu_seconds, what)
        if res.cpu_seconds > self.slow_cpu_s:
            self.slow += 1
        if res.peak_kib:
            self.peak_kib.append(res.peak_kib)
            self.growth_kib.append(res.growth_kib)
            if res.growth_kib > self.largest[0]:
                self.largest = (res.growth_kib, what)
        if res.kind.startswith("BUG"):
            self.failures.append((res.kind, what, res.detail, data))
            if failures_dir is not None:
                save_failure(Path(failures_dir), res.kind, what, res.detail, data)

    @property
    def bugs(self) -> int:
        return sum(n for k, n in self.outcomes.items() if k.startswith("BUG"))

    @property
    def cases_per_minute(self) -> float:
        return 60.0 * self.cases / self.seconds if self.seconds else 0.0

    def memory_text(self) -> str:
        if not self.peak_kib:
            return "peak memory: not measured"
        peaks, growth = sorted(self.peak_kib), sorted(self.growth_kib)

        def q(a, f):
            return a[min(int(f * len(a)), len(a) - 1)] / 1024
        return (f"peak RSS per case: median {q(peaks, 0.5):.0f} MiB, max {peaks[-1] / 1024:.0f} MiB; above the "
                f"worker's RSS before the case: median {q(growth, 0.5):.1f} MiB, 99th percentile "
                f"{q(growth, 0.99):.1f} MiB, max {growth[-1] / 1024:.1f} MiB ({self.largest[1][:100]})")

    def text(self, top_reasons: int = 15) -> str:
        lines = [f"cases: {self.cases} in {self.seconds:.1f} s ({self.cases_per_minute:.0f} cases/min)",
                 "outcomes:"]
        for k, n in sorted(self.outcomes.items(), key=lambda kv: (not kv[0].startswith("BUG"), -kv[1])):
            lines.append(f"  {n:>7}  {k}")
        if self.reasons:
            lines.append(f"errors by reason (class, message prefix; {len(self.reasons)} distinct, "
                         f"top {min(top_reasons, len(self.reasons))}):")
            for (kind, prefix), n in self.reasons.most_common(top_reasons):
                lines.append(f"  {n:>7}  {kind}: {prefix}")
        lines.append(f"slowest case: {self.slowest[0]:.3f} s wall ({self.slowest[1][:120]}); most CPU: "
                     f"{self.slowest_cpu[0]:.3f} s ({self.slowest_cpu[1][:120]}); cases above {self.slow_cpu_s:g} s "
                     f"of CPU: {self.slow}")
        lines.append(self.memory_text())
        lines.append(f"bugs: {self.bugs}")
        return "\n".join(lines)


def save_failure(folder: Path, kind: str, what: str, detail: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    tag = kind.split(":")[-1].strip().replace(" ", "_")
    name = f"{tag}_{hashlib.sha256(data).hexdigest()[:12]}"
    (folder / f"{name}.lghcc").write_bytes(data)
    (folder / f"{name}.txt").write_text(f"{kind}\n{what}\n\n{detail}\n")
    return folder / f"{name}.lghcc"


SCENE_VALID = "scene: valid round trip"
SCENE_REFUSED = "scene: refused by the encoder (InputError)"
SCENE_PARTIAL = "scene: valid box, preview or worker decode"


def scene_outcome(res: "CaseResult", valid: str = SCENE_VALID) -> "CaseResult":
    """A fresh stream from the scene generator must decode to its own hash (and its box, preview
    and worker decodes must succeed: ``valid`` SCENE_PARTIAL): anything else is a bug."""
    if res.kind == VALID:
        return CaseResult(valid, "", res.seconds, res.peak_kib, res.growth_kib, res.cpu_seconds)
    kind = "BUG: round trip" if not res.kind.startswith("BUG") else f"BUG: round trip ({res.kind[5:]})"
    return CaseResult(kind, f"{res.kind}: {res.detail}", res.seconds, res.peak_kib, res.growth_kib, res.cpu_seconds)


def run_campaign(mutator: Mutator, *, seed: int = 0, cases: int | None = None, seconds: float | None = None,
                 timeout: float = 5.0, memory_mb: int | None = 2048, threads: int = 1,
                 failures_dir: Path | None = None, progress=None, scene_source=None,
                 mutations_per_scene: int = 30, pool_size: int = 32, slow_cpu_s: float = 5.0) -> Summary:
    """Run cases until ``cases`` are done or ``seconds`` have passed (whichever first).

    ``scene_source(rng)``: a structure-aware generator (tools/fuzz_scenes.py ``scene_case``:
    an object with ``data``, ``what``, ``refused``, ``bug``). With it, every
    ``mutations_per_scene`` mutation cases one scene case is generated: a new stream that must
    decode to its own hash (``scene_outcome``); each valid one joins the mutator's seeds (the
    ``pool_size`` newest), so that byte, unit and field mutations reach the geometry, hierarchy
    and context models it carries. A refused scene counts as a case (SCENE_REFUSED); a generator
    exception is a bug ('BUG: encoder')."""
    if cases is None and seconds is None:
        raise ValueError("give cases or seconds")
    rng = random.Random(seed)
    scene_rng = random.Random(f"scenes-{seed}")
    summary = Summary(slow_cpu_s=slow_cpu_s)
    t0 = time.perf_counter()
    with Sandbox(timeout, memory_mb, threads) as box:
        try:
            _campaign_loop(summary, mutator, box, rng, scene_rng, cases, seconds, t0, failures_dir, progress,
                           scene_source, mutations_per_scene, pool_size)
        except KeyboardInterrupt:  # stopped from outside (Ctrl-C, SIGTERM): keep what was measured
            summary.stopped = True
    summary.seconds = time.perf_counter() - t0
    return summary


def _campaign_loop(summary, mutator, box, rng, scene_rng, cases, seconds, t0, failures_dir, progress, scene_source,
                   mutations_per_scene, pool_size) -> None:
    """run_campaign's cases, one at a time, into ``summary``."""
    pool: list[str] = []
    since_scene = mutations_per_scene
    while (cases is None or summary.cases < cases) and (seconds is None or time.perf_counter() - t0 < seconds):
        if scene_source is not None and since_scene >= mutations_per_scene:
            since_scene = 0
            sc = scene_source(scene_rng)
            what = f"scene {summary.cases}: {sc.what}"
            if sc.bug:
                summary.add(CaseResult("BUG: encoder", sc.bug, 0.0), what, b"", failures_dir)
            elif sc.data is None:
                summary.add(CaseResult(SCENE_REFUSED, sc.refused, 0.0), what, b"")
            else:
                res = scene_outcome(box.run(sc.data))
                summary.add(res, what, sc.data, failures_dir)
                for opts in getattr(sc, "decodes", ()) if res.kind == SCENE_VALID else ():
                    summary.add(scene_outcome(box.run(sc.data, opts), SCENE_PARTIAL), f"{what}; decode {opts}",
                                sc.data, failures_dir)
                if res.kind == SCENE_VALID:
                    sid = f"scene{summary.cases}"
                    mutator.add_seed(sid, sc.data, res.cpu_seconds)
                    pool.append(sid)
                    if len(pool) > pool_size:
                        mutator.drop_seed(pool.pop(0))
        else:
            since_scene += 1
            data, what = mutator.case(rng)
            summary.add(box.run(data), what, data, failures_dir)
        if progress is not None:
            progress(summary)
