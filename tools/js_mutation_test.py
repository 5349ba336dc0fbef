#!/usr/bin/env python3
"""Mutation testing of the JavaScript decoder (js/lghcc-decoder) against the conformance suite,
as tools/mutation_test.py does for the reference decoder (issue 56, item 3).

Each mutation below is one careless implementer's mistake in one normative operation of the
JavaScript decoder: a skipped check of a condition of spec clause 8.2, a bound off by one, a
wrong rounding, a swapped order. It is applied to a copy of the decoder in a temporary folder (a
mutation of wasm/decoder.ts rebuilds the copy's WebAssembly with the pinned AssemblyScript of
tools/node, as tools/node/build-wasm.mjs does), then the copy's own conformance run
(`node conformance.mjs`: every stream of the explicit-Gaussian profile, decoded to its hash or
rejected) must fail: the mutation is *killed*. One that passes the whole run *survives*, and names
a stream the suite lacks. One whose text no longer occurs exactly once in its file is *stale*.

    python tools/js_mutation_test.py              # all, one line each
    python tools/js_mutation_test.py container.   # those whose id starts with this
    python tools/js_mutation_test.py --report     # also rewrite the section of tools/results/conformance.md
    python tools/js_mutation_test.py --differential 400 --report   # and does the differential fuzzer catch
                                                  # each survivor (400 mutated streams to both decoders)?

Needs node; the WebAssembly mutations need `make node-tools` (skipped, as stale, without it).
Exit status: 0 every mutation killed, 1 one survived or is stale, 2 usage error.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DECODER = ROOT / "js" / "lghcc-decoder"
STREAMS = ROOT / "conformance" / "streams"
NODE_TOOLS = ROOT / "tools" / "node"
REPORT = ROOT / "tools" / "results" / "conformance.md"
BEGIN, END = "<!-- js-mutations:begin -->", "<!-- js-mutations:end -->"


@dataclass(frozen=True)
class JsMutation:
    id: str
    path: str  # relative to js/lghcc-decoder
    old: str  # occurs exactly once in the file
    new: str
    why: str


M = JsMutation
MUTATIONS: list[JsMutation] = [
    # container (clause 6)
    M("container.no_magic_check", "container.mjs", "if (magic !== MAGIC) throw", "if (false) throw", "E2 skipped"),
    M("container.version_2_accepted", "container.mjs", "if (major !== 1) throw", "if (major !== 1 && major !== 2) throw",
      "E3: a major version 2 decoded"),
    M("container.profile_0_accepted", "container.mjs", "if (bytes[6] !== 1) throw", "if (bytes[6] > 1) throw", "E4 off by one"),
    M("container.no_reserved_check", "container.mjs", "if (bytes[7] !== 0) throw", "if (false) throw", "E5 skipped"),
    M("container.unit_type_0_ok", "container.mjs", "if (type === 0) throw", "if (false) throw", "E7 skipped"),
    M("container.size_off_by_one", "container.mjs", "if (size + 9 > left)", "if (size + 8 > left)", "E8 off by one"),
    M("container.no_crc_check", "container.mjs", "unitCrc32(bytes, pos, end) !== stored", "false", "E9 skipped"),
    M("container.unknown_critical_ok", "container.mjs", "u.type > LAST_KNOWN_CRITICAL)", "u.type > LAST_KNOWN_CRITICAL + 1)",
      "E10: the first undefined critical type taken for known"),
    M("container.no_unit_kind_check", "container.mjs", "if (!kinds.has(t)) throw", "if (false) throw", "E13 skipped"),
    M("container.flags_before_step_adjust", "container.mjs",
      "            if (peek() === UNIT.STEP_ADJUST_FLAGS) s.sf = critical[i++];\n        }",
      "        }\n        if (peek() === UNIT.STEP_ADJUST_FLAGS) s.sf = critical[i++];",
      "E14: a step_adjust_flags unit accepted without its step_adjust unit"),
    # syntax elements (clause 7)
    M("bitreader.ue_33_zeros", "bitreader.mjs", "if (zeros >= 32)", "if (zeros >= 33)", "E18 off by one"),
    M("bitreader.se_sign_swapped", "bitreader.mjs", "(k + 1) / 2 : -(k / 2)", "-((k + 1) / 2) : k / 2", "se(v) mapping"),
    M("bitreader.infinity_ok", "bitreader.mjs", "if (!Number.isFinite(v)) throw", "if (Number.isNaN(v)) throw",
      "f(32): an infinity accepted"),
    M("bitreader.no_alignment_check", "bitreader.mjs", "if (this.u(1, 'byte_alignment') !== 0)",
      "if (this.u(1, 'byte_alignment') !== 0 && false)", "E20 skipped"),
    M("bitreader.one_trailing_byte_ok", "bitreader.mjs", "if (endByte < this.bytes.length)",
      "if (endByte + 1 < this.bytes.length)", "trailing bytes (clause 6.4) off by one"),
    M("units.zero_step_ok", "bitreader.mjs", "if (!(v > 0)) throw", "if (!(v >= 0)) throw", "a step of 0 accepted"),
    M("units.num_gaussians_2_24", "units.mjs", "'num_gaussians_minus1'), 0, 2 ** 24 - 1)",
      "'num_gaussians_minus1'), 0, 2 ** 24)", "num_gaussians_minus1 range off by one"),
    M("units.tile_scale_range", "units.mjs", "r.ue('tile_scale_minus1'), 0, 2 ** 20 - 1)",
      "r.ue('tile_scale_minus1'), 0, 2 ** 20)", "tile_scale_minus1 range off by one"),
    M("units.ps_trailing_ok", "units.mjs", "    r.expectEnd(true);\n", "", "whole bytes after the parameter set accepted"),
    M("units.equal_cells_ok", "units.mjs", "!lexLess(tiles[t - 1].cell, cell)", "lexLess(cell, tiles[t - 1].cell)",
      "E56: two tiles of one cell accepted"),
    M("units.no_cell_order_check", "units.mjs", "if (t > 0 && !lexLess(tiles[t - 1].cell, cell)) {", "if (false) {",
      "E56 skipped"),
    M("units.fewer_points_ok", "units.mjs", "if (total !== N) throw", "if (total > N) throw", "E57 one-sided"),
    M("units.hash_type_0_ok", "units.mjs", "r.u(8, 'hash_type'), 1, 1)", "r.u(8, 'hash_type'), 0, 1)", "E19: hash_type 0"),
    M("units.hash_trailing_byte_ok", "units.mjs", "if (payload.length > 33) throw", "if (payload.length > 34) throw",
      "E21 off by one"),
    M("units.source_equal_target_ok", "units.mjs", "if (s >= t) throw", "if (s > t) throw", "E48 off by one"),
    M("units.repeated_prediction_ok", "units.mjs", "s > h.predSource[i - 1]", "s >= h.predSource[i - 1]",
      "E49: a repeated (target, source) pair"),
    M("units.weight_max_refused", "units.mjs", "-(2 ** 15), 2 ** 15)", "-(2 ** 15), 2 ** 15 - 1)",
      "pred_weight's range one short"),
    M("units.rows_per_chunk_range", "units.mjs", "r.ue('rows_per_chunk_minus1'), 0, h.numRows - 1)",
      "r.ue('rows_per_chunk_minus1'), 0, h.numRows)", "rows_per_chunk_minus1 range off by one"),
    M("units.adjust_level_with_flags_ok", "units.mjs", "(h.adjustMean || h.adjustLevel)", "(h.adjustMean)",
      "E67 half checked"),
    M("units.short_chunks_ok", "units.mjs", "if (total !== payload.length - h.dataOffset)",
      "if (total > payload.length - h.dataOffset)", "E50 one-sided"),
    M("units.step_flag_frequency", "units.mjs", "r.u(12, `step_flag_prob[${i}]`) + 2048",
      "r.u(12, `step_flag_prob[${i}]`) + 2047", "7.3.16: a flag's frequency off by one"),
    M("units.lod_sizes_floor", "units.mjs", "Math.ceil(a / 2 ** t)", "Math.floor(a / 2 ** t)",
      "LoD sizes of clause 7.3.12 rounded down"),
    # geometry header (G.3)
    M("geometry.bbox_min_2_31_ok", "geometry.mjs", "if (!sign && abs > 2 ** 31 - 1)", "if (!sign && abs > 2 ** 31)",
      "E26 off by one"),
    M("geometry.box_capacity_doubled", "geometry.mjs", "if (n > 2 ** (bitDepth[0] + bitDepth[1] + bitDepth[2]))",
      "if (n > 2 * 2 ** (bitDepth[0] + bitDepth[1] + bitDepth[2]))", "E27 off by a factor"),
    M("geometry.depth0_data_ok", "geometry.mjs", "Math.max(...bitDepth) === 0 && dataOffset < payload.length",
      "false", "E28 skipped"),
    # the decoding process (clause 13), tiles, hash
    M("decoder.index_without_flag_ok", "decoder.mjs", "if (!!s.ti !== !!ps.tilesEnabled)",
      "if (!s.ti && ps.tilesEnabled)", "E54 one-sided"),
    M("decoder.tile_size_unchecked", "decoder.mjs", "tile.start !== pos || tile.end !== pos + t.size",
      "tile.start !== pos", "E55: tile_data_size not checked"),
    M("decoder.cell_off_by_one", "decoder.mjs", "coords.max[a] > hi)", "coords.max[a] > hi + 1)", "E58 off by one"),
    M("decoder.fewer_rows_ok", "decoder.mjs", "if (h.numRows !== n) throw", "if (h.numRows > n) throw", "E59 one-sided"),
    M("decoder.no_hash_check", "decoder.mjs", "if (toHex(digest) !== out.sceneHash) throw", "if (false) throw", "E53 skipped"),
    M("decoder.digest_tile_major", "decoder.mjs", "for (let j = 0; j < 5; j++) for (const p of parts) h.update(p[j]);",
      "for (const p of parts) for (let j = 0; j < 5; j++) h.update(p[j]);",
      "clause 12: a tiled scene serialized tile by tile, not part by part"),
    M("decoder.box_open_faces", "decoder.mjs", "if (lo > box[a + 3] || hi < box[a]) return false;",
      "if (lo >= box[a + 3] || hi <= box[a]) return false;", "clause 13.3: a box on a cell's face misses it"),
    # attributes (clause 11)
    M("attributes.extent_off_by_one", "attributes.mjs", "if (e > MAX_EXTENT) throw", "if (e > MAX_EXTENT + 1) throw",
      "E64 off by one"),
    M("attributes.step_factor_one_ulp", "attributes.mjs", "1.18920708,", "1.1892072,",
      "STEP_ADJUST_FACTORS[1] one binary32 ulp high"),
    M("attributes.half_words_ok", "attributes.mjs", "if (bytes.length % 4) throw", "if (bytes.length % 2) throw",
      "E35: chunks of whole 16-bit words"),
    # the WebAssembly module (rebuilt)
    M("wasm.q_limit_off_by_one", "wasm/decoder.ts", "if (v > Q_LIMIT || v < -Q_LIMIT)",
      "if (v > Q_LIMIT || v < -Q_LIMIT - 1)", "E51 off by one (negative side)"),
    M("wasm.prediction_rounding", "wasm/decoder.ts", "((pr + 128) >> 8));\n    }\n}\n\n@inline function storeValue",
      "((pr + 127) >> 8));\n    }\n}\n\n@inline function storeValue",
      "cross-channel prediction rounds halves down (rows of every SH degree)"),
    M("wasm.coded_channel_prediction_kept", "wasm/decoder.ts", "            if (<u32>(s - e) < gap) continue;\n", "",
      "11.9: an uncoded channel (q = 0) still gives a prediction term"),
    M("wasm.length_index_off_by_one", "wasm/decoder.ts", "if (k < 0 || k > <i64>maxIndex)",
      "if (k < 0 || k > <i64>maxIndex + 1)", "E66 off by one"),
    M("wasm.step_index_off_by_one", "wasm/decoder.ts", "if (!(a >= 0 && a <= max))", "if (!(a >= 0 && a <= max + 1))",
      "E65 off by one"),
    M("wasm.coordinate_max_off_by_one", "wasm/decoder.ts", "if (<i64>mx + <i64>bmin > 0x7FFFFFFF)",
      "if (<i64>mx + <i64>bmin > 0x80000000)", "E34 off by one"),
    M("wasm.prior_mean_truncated", "wasm/decoder.ts", "floorDiv(p * 4096 + (F >> 1), F)", "floorDiv(p * 4096, F)",
      "the adjusted prior mean truncated, not rounded (11.8)"),
    M("wasm.one_word_left_ok", "wasm/decoder.ts", "if (rPos < rWords ||", "if (rPos + 1 < rWords ||",
      "E38: one word of data left over accepted"),
    # the SH rest as transform coefficients (version 1.6, clause 11.11)
    M("wasm.sh_transform_no_rounding", "wasm/decoder.ts", "const v = (u + half) >> <i64>shift;", "const v = u >> <i64>shift;",
      "11.11: the shift without its rounding offset"),
    M("wasm.sh_transform_transposed", "wasm/decoder.ts", "u += i64At(row, load<i32>(nzIdx + (<usize>m << 2)))",
      "u += i64At(T + (<usize>(load<i32>(nzIdx + (<usize>m << 2)) * nRest) << 3), j)", "11.11: T read column-major"),
    M("wasm.sh_transform_limit_skipped", "wasm/decoder.ts", "if (v < -Q_LIMIT || v > Q_LIMIT) { errWide",
      "if (false) { errWide", "E68 skipped"),
    M("units.sh_transform_entries_unsigned", "units.mjs", "BigInt(r.u(bits, `sh_transform_coeff[${i}]`) - offset)",
      "BigInt(r.u(bits, `sh_transform_coeff[${i}]`))", "7.3.17: the entries without their offset"),
    M("container.sh_transform_repeated", "container.mjs", "    if (peek() === UNIT.SH_TRANSFORM) s.st = critical[i++];\n",
      "    while (peek() === UNIT.SH_TRANSFORM) s.st = critical[i++];\n", "E14: two sh_transform units accepted"),
]


class Stale(Exception):
    """The mutation's text does not occur exactly once in its file."""


def mutated_copy(m: JsMutation, into: Path) -> Path:
    """A copy of the decoder with ``m`` applied, in ``into``/js/lghcc-decoder (a WebAssembly
    mutation rebuilt there by a copy of tools/node/build-wasm.mjs). Raises Stale."""
    target = into / "js" / "lghcc-decoder"
    shutil.copytree(DECODER, target)
    f = target / m.path
    text = f.read_text()
    if text.count(m.old) != 1:
        raise Stale(f"{m.path}: the text occurs {text.count(m.old)} times")
    f.write_text(text.replace(m.old, m.new))
    if m.path.startswith("wasm/"):
        if not (NODE_TOOLS / "node_modules" / "assemblyscript").exists():
            raise Stale("AssemblyScript is not installed (make node-tools)")
        (into / "tools" / "node").mkdir(parents=True)
        shutil.copy(NODE_TOOLS / "build-wasm.mjs", into / "tools" / "node")
        (into / "tools" / "node" / "node_modules").symlink_to(NODE_TOOLS / "node_modules")
        build = subprocess.run(["node", str(into / "tools" / "node" / "build-wasm.mjs")], capture_output=True, text=True,
                               timeout=300)
        if build.returncode:
            raise Stale(f"the mutated module does not build: {build.stderr.strip()[-200:]}")
    return target


def run_one(m: JsMutation, timeout: float) -> tuple[str, str]:
    """(status, note): 'killed' with the first failing stream, 'survived', or 'stale'."""
    with tempfile.TemporaryDirectory(prefix="lghcc-js-mutant-") as tmp:
        try:
            target = mutated_copy(m, Path(tmp))
        except Stale as e:
            return "stale", str(e)
        try:
            run = subprocess.run(["node", str(target / "conformance.mjs"), "--streams", str(STREAMS), "--timeout", "20"],
                                 capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return "killed", f"(hang: no end within {timeout:g} s)"
    if run.returncode == 0:
        return "survived", run.stdout.strip().splitlines()[-1] if run.stdout.strip() else ""
    fails = [line for line in run.stdout.splitlines() if line.startswith("FAIL")]
    return "killed", (f"{len(fails)} streams fail, first " + fails[0][5:160]) if fails else \
        f"exit {run.returncode}: {(run.stderr.strip().splitlines() or [''])[-1][:160]}"


def differential_verdict(m: JsMutation, mutator, cases: int) -> str:
    """Whether the differential fuzzer (lghcc/conformance/differential.py) catches a mutation the suite
    does not: ``cases`` mutations of the conformance streams (seed 56) to the reference and the mutant."""
    from lghcc.conformance.differential import run_differential

    with tempfile.TemporaryDirectory(prefix="lghcc-js-mutant-") as tmp:
        try:
            target = mutated_copy(m, Path(tmp))
        except Stale as e:
            return f"stale: {e}"
        s = run_differential(mutator, seed=56, cases=cases, timeout=60.0, decoder_dir=target)
    if not s.disagreements:
        return f"not caught in {s.cases} cases"
    label, what, ref, js = s.disagreements[0]
    return f"caught: {s.bugs} of {s.cases} cases disagree; first {label} ({what[:70]}; JS: {js[:70]})"


def profile_streams() -> set[str]:
    """The ids of the conformance streams of the explicit-Gaussian profile (conformance.mjs --list)."""
    out = subprocess.run(["node", str(DECODER / "conformance.mjs"), "--streams", str(STREAMS), "--list"],
                         capture_output=True, text=True, check=True).stdout
    return {line.split()[1] for line in out.splitlines() if line.startswith("in ")}


# Survivors that no stream can kill under the rejection protocol (a conforming stream that such a
# decoder gets wrong does not exist, or it is rejected anyway, for another condition):
# mutation -> why. Conditions of clause 8.2 that cannot be isolated at all are in
# conformance/conditions.py NOT_ISOLATED and need no entry here.
EQUIVALENT: dict[str, str] = {
    "container.unknown_critical_ok": "a critical unit of type 0x0F, undefined, also breaks the unit order of clause "
                                     "6.3 (E14): every stream with one is rejected by a decoder that takes it for known",
    "wasm.coordinate_max_off_by_one": "the decoder holds coordinates as int32: a coordinate of 2^31 (x053) wraps to "
                                      "-2^31, so its decoded scene differs from the one the stream's hash covers (E53)",
    "decoder.index_without_flag_ok": "a tile_index unit with tiles_enabled_flag 0 has cells without a size "
                                     "(tile_scale is not coded): its points lie outside them (E58) in every such stream",
    "decoder.fewer_rows_ok": "x035 (E59, 299 rows of 300) is isolated (spec 8.2), but this decoder plans an attribute "
                             "unit's chunks from num_rows_minus1: it meets E38 first, a conforming rejection",
}


def missing_stream(m: JsMutation, isolated: dict[str, list[str]], in_profile: set[str]) -> tuple[bool, str]:
    """(equivalent, why) for a surviving mutation: equivalent under the rejection protocol (no stream
    can kill it), or what the suite lacks to kill it: for a condition of clause 8.2, an
    explicit-Gaussian stream that breaks it at the mutated bound."""
    from lghcc.conformance.conditions import NOT_ISOLATED

    if m.id in EQUIVALENT:
        return True, EQUIVALENT[m.id]
    cond = re.search(r"\bE[0-9]+\b", m.why)
    if cond is None:
        return False, ("no stream of the profile breaks only this rule (one that breaks it is rejected for another "
                       "reason too)")
    c = cond.group()
    if c in NOT_ISOLATED:
        return True, f"{c} cannot be isolated: {NOT_ISOLATED[c]}"
    streams = isolated.get(c, [])
    mine = [s for s in streams if s in in_profile]
    if streams and not mine:
        return False, f"{c}'s isolated streams ({', '.join(streams)}) are outside the profile: an explicit-Gaussian one is needed"
    if mine:
        return False, f"{c}'s isolated streams of the profile ({', '.join(mine)}) break it at another bound: this mistake needs its own"
    return False, f"no isolated stream breaks {c} (its error streams of the profile, if any, are rejected for another reason too)"


def markdown(results: list[tuple[JsMutation, str, str]], seconds: float, differential: dict[str, str],
             differential_cases: int = 0) -> str:
    from lghcc.conformance.conditions import isolated_stream_list

    isolated: dict[str, list[str]] = {}
    for s in isolated_stream_list(STREAMS):
        isolated.setdefault(s.condition, []).append(s.id)
    in_profile = profile_streams()
    killed = sum(1 for _, s, _ in results if s == "killed")
    survived = [(m, *missing_stream(m, isolated, in_profile)) for m, s, _ in results if s == "survived"]
    equivalent = [x for x in survived if x[1]]
    lines = [BEGIN, "", "## Mutation testing of the JavaScript decoder", "",
             "Command: `python tools/js_mutation_test.py --report"
             + (f" --differential {differential_cases}" if differential else "") + "` (`make js-mutations`); "
             f"{len(results)} mutations of js/lghcc-decoder (tools/js_mutation_test.py: skipped checks of clause 8.2, "
             "bounds off by one, roundings, orders; those of wasm/decoder.ts rebuilt with the pinned AssemblyScript), "
             "each applied to a copy of the decoder whose conformance run (`node conformance.mjs`, the streams of the "
             f"explicit-Gaussian profile) must then fail; {seconds / 60:.1f} min on the shared 2-core machine.", "",
             f"**{killed} of {len(results)} killed**; {len(survived)} survived: {len(equivalent)} equivalent under the "
             f"rejection protocol (no stream can kill them), {len(survived) - len(equivalent)} that a stream the suite "
             "lacks would kill.", ""]
    for m, eq, why in sorted(survived, key=lambda x: not x[1]):
        caught = f" Differential fuzzer: {differential[m.id]}." if m.id in differential else ""
        lines.append(f"- `{m.id}` ({m.path}: {m.why}): {'equivalent: ' if eq else ''}{why}.{caught}")
    lines += ["", "| mutation | file | what | result |", "|---|---|---|---|"]
    for m, status, note in results:
        lines.append(f"| `{m.id}` | {m.path} | {m.why} | {status}: {note.replace('|', '/')[:120]} |")
    return "\n".join(lines + ["", END]) + "\n"


def write_report(section: str) -> None:
    text = REPORT.read_text()
    if BEGIN in text and END in text:
        text = text[:text.index(BEGIN)] + section + text[text.index(END) + len(END):].lstrip("\n")
    else:
        anchor = "<!-- conditions:end -->"
        at = text.index(anchor) + len(anchor) if anchor in text else len(text)
        text = text[:at].rstrip("\n") + "\n\n" + section + "\n" + text[at:].lstrip("\n")
    REPORT.write_text(text)


def differential_verdicts(survivors: list[JsMutation], cases: int) -> dict[str, str]:
    """differential_verdict of each survivor (none when ``cases`` is 0)."""
    if not cases or not survivors:
        return {}
    from lghcc.conformance.differential import seed_weights
    from lghcc.conformance.fuzz import Mutator, load_seeds

    seeds = load_seeds()
    mutator = Mutator(seeds)
    mutator.weights = seed_weights(seeds)
    out = {}
    for m in survivors:
        out[m.id] = differential_verdict(m, mutator, cases)
        print(f"differential {m.id}: {out[m.id]}", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("only", nargs="*", help="mutation ids or id prefixes (default: all)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds a conformance run may take (default 300)")
    ap.add_argument("--report", action="store_true", help="rewrite the section of tools/results/conformance.md")
    ap.add_argument("--differential", type=int, default=0, metavar="N",
                    help="also run N differential-fuzzer cases against each surviving mutation (does the fuzzer catch it?)")
    args = ap.parse_args(argv)
    if shutil.which("node") is None:
        print("js_mutation_test: node is not on the PATH", file=sys.stderr)
        return 2
    chosen = [m for m in MUTATIONS if not args.only or any(m.id == p or m.id.startswith(p) for p in args.only)]
    if not chosen:
        print(f"js_mutation_test: no mutation matches {args.only}", file=sys.stderr)
        return 2
    t0, results = time.perf_counter(), []
    for m in chosen:
        status, note = run_one(m, args.timeout)
        results.append((m, status, note))
        print(f"{status:8} {m.id}: {note}", flush=True)
    killed = sum(1 for _, s, _ in results if s == "killed")
    print(f"{killed}/{len(results)} killed")
    differential = differential_verdicts([m for m, s, _ in results if s == "survived"], args.differential)
    if args.report:
        write_report(markdown(results, time.perf_counter() - t0, differential, args.differential))
        print(f"wrote {REPORT.relative_to(ROOT)}")
    return 0 if killed == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
