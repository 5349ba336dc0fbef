#!/usr/bin/env python3
"""Differential fuzzing of the two decoders (issue 56, item 3): the same streams to the reference
decoder and the JavaScript decoder (js/lghcc-decoder, in one Node process:
tools/js_decode_server.mjs); the same hash, or a rejection by both, is required (the rules are in
lghcc/conformance/differential.py). Streams: mutations of the conformance streams that decode
(conformance/fuzz.py's Mutator: bytes, units, syntax elements) and, with --scenes, fresh encoder
streams of random scenes (tools/fuzz_scenes.py: explicit-Gaussian scenes with every tool of the
profile, four in five; anchor scenes, which the JavaScript decoder must refuse as unsupported,
one in five) with their box decodes, then mutations of them.

Two rejections for different conditions agree when the stream is shown to break both, either way:
the JavaScript decoder without its checks of its condition (conformance/js_checks.py: copies of its
sources, kept loaded in a second Node server) names the reference's, or the reference without its
checks names the JavaScript decoder's (lghcc/conformance/differential.py states the rule).

A disagreement saves the stream and both verdicts to --failures (diff_<sha>.lghcc and .txt);
reproduce with `lghcc-dec F --print-hash` and `node js/lghcc-decoder/cli.mjs F`.

    python tools/fuzz_differential.py --cases 2000 --scenes --seed 1
    python tools/fuzz_differential.py --minutes 60 --scenes --json fuzz_logs/diff_1.json
    python tools/fuzz_differential.py --minutes 60 --scenes --jobs 2 --json fuzz_logs/diff.json   # one per core
    python tools/fuzz_differential.py --merge fuzz_logs/diff_*.json --out tools/results/fuzz.md
    make fuzz-diff      # FUZZ_DIFF_JOBS campaigns side by side, merged into tools/results/fuzz.md

--out rewrites only the differential section of the file (between its markers). Exit status: 0
no disagreement, 1 a disagreement or a bug, 2 usage error.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning threads on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
import random  # noqa: E402
import shlex  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lghcc.conformance.differential import (MAX_CONFIRM_CHAIN, DiffSummary, run_differential,  # noqa: E402
                                            seed_weights)
from lghcc.conformance.fuzz import Mutator, load_seeds  # noqa: E402

BEGIN, END = "<!-- differential:begin -->", "<!-- differential:end -->"
TARGET_CASES = 1_000_000  # issue 56, item 4
GAUSSIAN_SHARE = 0.8  # of the fresh scenes: explicit-Gaussian (the JavaScript decoder's profile)


def differential_scene_case(rng: random.Random, max_points: int = 3000):
    """A fresh scene stream: explicit Gaussians (GAUSSIAN_SHARE of them) or an anchor scene, of at
    most ``max_points`` Gaussians or anchors."""
    from fuzz_scenes import anchor_scene_case, gaussian_scene_case

    if rng.random() < GAUSSIAN_SHARE:
        return gaussian_scene_case(rng, max_points)
    return anchor_scene_case(rng, max_points)


def code_version() -> str:
    """The commit and the bitstream format version the campaign runs (taken at its start)."""
    from fuzz_decoder import commit, format_version

    return f"commit {commit()}; bitstream format version {format_version()}"


def summary_to_json(s: DiffSummary, command: str, started: str, seeds: int, code: str) -> dict:
    return {"command": command, "started": started, "seeds": seeds, "code": code, "cases": s.cases,
            "seconds": s.seconds,
            "scene_cases": s.scene_cases, "duplicates": s.duplicates, "outcomes": dict(s.outcomes),
            "class_pairs": [[a, b, n] for (a, b), n in s.class_pairs.items()], "disagreements": s.disagreements,
            "condition_pairs": [[a, b, n] for (a, b), n in s.condition_pairs.items()], "confirmed": s.confirmed,
            "not_compared": s.not_compared, "classes_differ": s.classes_differ}


def merge_json(paths: list[str]) -> tuple[DiffSummary, list[str], str, int, list[str]]:
    """Campaigns run side by side as one: their cases add up, their time is the longest."""
    total, commands, started, seeds, codes = DiffSummary(), [], "", 0, []
    for path in paths:
        d = json.loads(Path(path).read_text())
        commands.append(d["command"])
        if d["code"] not in codes:
            codes.append(d["code"])
        started = min(started, d["started"]) if started else d["started"]
        seeds = max(seeds, d["seeds"])
        total.cases += d["cases"]
        total.scene_cases += d["scene_cases"]
        total.duplicates += d.get("duplicates", 0)
        total.seconds = max(total.seconds, d["seconds"])
        total.outcomes.update(Counter(d["outcomes"]))
        total.class_pairs.update(Counter({(a, b): n for a, b, n in d["class_pairs"]}))
        total.condition_pairs.update(Counter({(a, b): n for a, b, n in d.get("condition_pairs", [])}))
        total.confirmed += [tuple(x) for x in d.get("confirmed", [])]
        total.disagreements += [tuple(x) for x in d["disagreements"]]
        total.not_compared += [tuple(x) for x in d.get("not_compared", [])]
        total.classes_differ += [tuple(x) for x in d.get("classes_differ", [])]
    return total, commands, started, seeds, codes


def results_markdown(s: DiffSummary, commands: list[str], started: str, seeds: int, codes: list[str]) -> str:
    """The differential section of tools/results/fuzz.md, markers included."""
    partial = s.cases < TARGET_CASES
    lines = [BEGIN, "", "## Differential fuzzing: the reference decoder against the JavaScript decoder", "",
             f"Started {started}; {s.seconds / 3600:.2f} h ("
             f"{f'{len(commands)} campaigns side by side' if len(commands) > 1 else 'one campaign'}, "
             f"`tools/fuzz_differential.py`, `make fuzz-diff`); machine: {os.cpu_count()} shared CPU "
             f"cores, no GPU. Code: {' and '.join(codes)}. Seeds: {seeds} "
             "conformance streams that decode (those of the JavaScript decoder's profile drawn ten times as often as "
             "the others), plus the fresh scene streams (the 32 newest at a time; four in five explicit-Gaussian, with "
             "every tool of the profile).", ""]
    if partial:
        lines += [f"**A partial run: {s.cases:,} cases of the {TARGET_CASES:,} issue 56 item 4 asks for** (the "
                  "session's time); `make fuzz-diff` runs the whole campaign.", ""]
    lines += ["Commands:", "", *[f"    {c}" for c in commands], "",
              "| cases | fresh scene streams | duplicate mutations (skipped) | cases / s | disagreements and bugs |",
              "|---|---|---|---|---|",
              f"| {s.cases:,} | {s.scene_cases:,} | {s.duplicates:,} | {s.cases / max(s.seconds, 1e-9):.1f} | {s.bugs} |",
              "",
              "| outcome | cases |", "|---|---|"]
    for k, n in sorted(s.outcomes.items(), key=lambda kv: (not kv[0].startswith(("DISAGREE", "BUG")), -kv[1])):
        lines.append(f"| {k} | {n:,} |")
    lines += ["", "Conditions of clause 8.2 of the cases both decoders rejected (reference, JavaScript; '-': the "
              "error names none, the JavaScript decoder's UnsupportedStreamError for a stream outside its profile). "
              "Equal conditions agree. Different ones (clause 8.2 does not order the checks: a decoder may report any "
              "condition a stream breaks) agree only when the stream is shown to break both, one way or the other: "
              "the JavaScript decoder without its checks of its own condition (a copy of its sources with each throw "
              "that names it removed; then of each condition it names next, at most "
              f"{MAX_CONFIRM_CHAIN}) rejects it for the reference's condition; or the reference decoder without its "
              "checks of its condition (conformance/conditions.py's removals, likewise chained) rejects it for the "
              "JavaScript decoder's; or the elements that condition is about, read alone, break it (a "
              "decoded_scene_hash unit; an attribute unit header's attribute_level and context_model_id for E45, E46, "
              "E62; E61 as the case of E14 it is). Otherwise the case is a disagreement.", "",
              "| reference | JavaScript | cases |", "|---|---|---|"]
    for (a, b), n in sorted(s.condition_pairs.items(), key=lambda kv: (kv[0][0] == kv[0][1], -kv[1])):
        lines.append(f"| {a} | {b} | {n:,} |")
    if s.confirmed:
        lines += ["", "Different conditions confirmed (the first 20; the chain of conditions the reference named "
                  "with the checks removed):", ""]
        lines += [f"- {what[:120]}: {chain}" for what, chain in s.confirmed[:20]]
    lines += ["", "Error classes of the same cases:", "", "| reference | JavaScript | cases |", "|---|---|---|"]
    for (a, b), n in s.class_pairs.most_common():
        lines.append(f"| {a} | {b} | {n:,} |")
    if s.classes_differ:
        lines += ["", "Both rejected with different classes, the JavaScript decoder's UnsupportedStreamError aside (the first 20):",
                  ""]
        lines += [f"- {what[:160]}; reference: {ref[:160]}; JavaScript: {js[:160]}" for _, what, ref, js in s.classes_differ[:20]]
    if s.not_compared:
        lines += ["", "Cases not compared (a resource bound of one decoder; the first 20):", ""]
        lines += [f"- {what[:160]}; reference: {ref[:160]}; JavaScript: {js[:160]}" for _, what, ref, js in s.not_compared[:20]]
    if s.disagreements:
        lines += ["", "Disagreements (first 20; the streams in the --failures folder):", ""]
        lines += [f"- {label}: {what[:160]}; reference: {ref[:160]}; JavaScript: {js[:160]}"
                  for label, what, ref, js in s.disagreements[:20]]
    return "\n".join(lines + ["", END]) + "\n"


def write_section(path: Path, section: str) -> None:
    """Replace the differential section of ``path`` (or append it)."""
    text = path.read_text() if path.exists() else ""
    if BEGIN in text and END in text:
        text = text[:text.index(BEGIN)] + section + text[text.index(END) + len(END):].lstrip("\n")
    else:
        text = text.rstrip("\n") + "\n\n" + section
    path.write_text(text)


def keep_section(old_text: str, new_text: str) -> str:
    """``new_text`` with the differential section of ``old_text`` appended (tools/fuzz_decoder.py
    rewrites tools/results/fuzz.md whole)."""
    if BEGIN not in old_text or END not in old_text or BEGIN in new_text:
        return new_text
    return new_text.rstrip("\n") + "\n\n" + old_text[old_text.index(BEGIN):old_text.index(END) + len(END)] + "\n"


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    budget = ap.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=float, help="run for this many minutes (default 1)")
    budget.add_argument("--cases", type=int, help="run this many cases")
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds a decoder may take on a case (default 30)")
    ap.add_argument("--memory-mb", type=int, default=2048,
                    help="address space a case may add to the reference's worker, MiB; both decoders' own bound "
                         "is half of it (default 2048)")
    ap.add_argument("--scenes", action="store_true", help="also fresh encoder streams of random scenes")
    ap.add_argument("--mutations-per-scene", type=int, default=400,
                    help="mutation cases per fresh scene (default 400: a fresh scene costs its encoding, its box decodes and "
                         "the trace of its syntax elements, 1 to 3 s on a shared core, as much as 50 to 100 mutation cases)")
    ap.add_argument("--scene-max-points", type=int, default=1000,
                    help="Gaussians (anchors) of a fresh scene at most (default 1000; the scene generator's own bound is "
                         "3000: a scene of 3000 takes 10 to 20 s of CPU to encode, the time of hundreds of cases, and its "
                         "mutations are drawn seldom, --cost-cap-ms)")
    ap.add_argument("--decoder-dir", help="the JavaScript decoder's folder (default js/lghcc-decoder)")
    ap.add_argument("--failures", default="fuzz_failures_diff", help="folder for disagreeing streams")
    ap.add_argument("--json", help="write the summary as JSON (for --merge); rewritten every --checkpoint-minutes")
    ap.add_argument("--checkpoint-minutes", type=float, default=5.0)
    ap.add_argument("--out", help="rewrite the differential section of this file (tools/results/fuzz.md)")
    ap.add_argument("--merge", nargs="+", metavar="JSON", help="no run: merge the --json summaries into --out")
    ap.add_argument("--cost-cap-ms", type=float, default=50.0,
                    help="a seed whose reference decode takes longer (CPU ms) is drawn less often: half as often for "
                         "each doubling beyond it, so that a long run spends its time on many cases rather than on the "
                         "slowest seeds (default 50; 0: every seed of the profile alike)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="campaigns side by side, one per core, each with its own reference worker and Node server "
                         "(seeds SEED, SEED + 7919, ...; --cases split among them; --json merged every checkpoint; "
                         "--failures gets a folder per job); default 1")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    return args


JOB_SEED_STEP = 7919  # job j of --jobs runs --seed SEED + j * JOB_SEED_STEP


def job_argv(args, j: int) -> list[str]:
    """The command line of job ``j`` (0-based) of ``--jobs``: its share of the budget, its seed, its
    own JSON summary and failures folder."""
    out = [sys.executable, str(Path(__file__).resolve())]
    if args.cases is not None:
        out += ["--cases", str(args.cases // args.jobs + (j < args.cases % args.jobs))]
    else:
        out += ["--minutes", str(args.minutes if args.minutes is not None else 1.0)]
    out += ["--seed", str(args.seed + j * JOB_SEED_STEP), "--timeout", str(args.timeout), "--memory-mb",
            str(args.memory_mb), "--mutations-per-scene", str(args.mutations_per_scene), "--failures",
            str(Path(args.failures) / f"job{j + 1}"), "--json", job_json(args, j), "--checkpoint-minutes",
            str(args.checkpoint_minutes), "--cost-cap-ms", str(args.cost_cap_ms), "--scene-max-points",
            str(args.scene_max_points)]
    out += ["--scenes"] * args.scenes + ["--quiet"] * args.quiet
    return out + (["--decoder-dir", args.decoder_dir] if args.decoder_dir else [])


def job_json(args, j: int) -> str:
    return f"{args.json}.job{j + 1}" if args.json else str(Path(args.failures) / f"job{j + 1}.json")


def run_jobs(args) -> int:
    """--jobs campaigns as child processes; their JSON summaries merged into --json at each
    checkpoint and at the end, and into --out. SIGTERM / Ctrl-C stops them all (each reports the
    cases it did)."""
    import subprocess

    Path(args.failures).mkdir(parents=True, exist_ok=True)
    children = [subprocess.Popen(job_argv(args, j)) for j in range(args.jobs)]
    paths = [job_json(args, j) for j in range(args.jobs)]

    def stop(signum, frame):
        for c in children:
            if c.poll() is None:
                c.send_signal(signal.SIGTERM)
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    while any(c.poll() is None for c in children):
        time.sleep(min(60.0 * args.checkpoint_minutes, 10.0))
        if args.json:
            merge_into(args, paths)
    summary = merge_into(args, paths) or merge_into(args, paths)
    if summary is None:
        print("no job wrote its summary", file=sys.stderr)
        return 1
    print(summary.text())
    return 1 if summary.bugs or any(c.returncode not in (0, 1) for c in children) else 0


def merge_into(args, paths: list[str]):
    """The jobs' summaries written so far, merged into --json (as JSON) and --out; None when none is."""
    done = [p for p in paths if Path(p).exists()]
    try:
        summary, commands, started, seeds, codes = merge_json(done)
    except ValueError:  # a job is rewriting its summary just now: the next checkpoint merges it
        return None
    if not done:
        return None
    if args.json:
        merged = summary_to_json(summary, " && ".join(commands), started, seeds, " and ".join(codes))
        merged["commands"] = commands
        Path(args.json).write_text(json.dumps(merged))
    if args.out:
        write_section(Path(args.out), results_markdown(summary, commands, started, seeds, codes))
    return summary


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.jobs > 1 and not args.merge:
        return run_jobs(args)
    if args.merge:
        summary, commands, started, seeds, codes = merge_json(args.merge)
        text = results_markdown(summary, commands, started, seeds, codes)
        write_section(Path(args.out), text) if args.out else print(text)
        return 1 if summary.bugs else 0
    command = "nice python tools/fuzz_differential.py " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    code = code_version()
    seeds = load_seeds()
    mutator = Mutator(seeds)
    mutator.weights = seed_weights(seeds)
    last = [time.perf_counter()] * 2

    def progress(s: DiffSummary) -> None:
        now = time.perf_counter()
        if not args.quiet and now - last[0] > 30.0:
            last[0] = now
            print(f"{datetime.now().strftime('%H:%M:%S')} {s.cases} cases, {s.bugs} disagreements, "
                  f"{s.cases / max(s.seconds, 1e-9):.1f} cases/s", file=sys.stderr, flush=True)
        if args.json and now - last[1] > 60.0 * args.checkpoint_minutes:
            last[1] = now
            Path(args.json).write_text(json.dumps(summary_to_json(s, command + "   (checkpoint)", started,
                                                                  len(seeds), code)))

    def stop(signum, frame):  # SIGTERM: stop the campaign and report the cases done
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, stop)
    summary = run_differential(
        mutator, seed=args.seed, cases=args.cases,
        seconds=None if args.cases else 60.0 * (args.minutes if args.minutes is not None else 1.0),
        timeout=args.timeout, memory_mb=args.memory_mb, failures_dir=Path(args.failures), progress=progress,
        decoder_dir=Path(args.decoder_dir) if args.decoder_dir else None,
        scene_source=(lambda rng: differential_scene_case(rng, args.scene_max_points)) if args.scenes else None,
        mutations_per_scene=args.mutations_per_scene,
        cost_cap=args.cost_cap_ms / 1000.0)
    if summary.stopped:
        command += f"   (stopped after {summary.cases:,} cases)"
    print(summary.text())
    if args.json:
        Path(args.json).write_text(json.dumps(summary_to_json(summary, command, started, len(seeds), code)))
    if args.out:
        write_section(Path(args.out), results_markdown(summary, [command], started, len(seeds), [code]))
    for label, what, ref, js in summary.disagreements[:10]:
        print(f"  {label}: {what[:150]}\n    reference: {ref[:200]}\n    JavaScript: {js[:200]}")
    return 1 if summary.bugs else 0


if __name__ == "__main__":
    sys.exit(main())
