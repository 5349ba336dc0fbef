#!/usr/bin/env python3
"""Long fuzz run of the reference decoder over mutated conformance streams and, with --scenes,
over freshly encoded random scenes (tools/fuzz_scenes.py) and their mutations.

Every case must end in lghcc.common.errors.LghccError or a valid decode, within --timeout
seconds, in a worker whose address space is limited to its parent's size plus --memory-mb
(an allocation beyond it raises MemoryError: a bug; the decoder's own bound, --max-memory,
is set to half of it, so a stream the memory plan admits never reaches the limit). Anything else
is a bug: another exception, a timeout, a worker that dies, a fresh scene stream that does not
decode to its own hash, an encoder exception. Failing inputs are saved to --failures with a
.txt beside each (outcome, mutation, traceback); reproduce one with
    lghcc-dec <file>.lghcc --print-hash

The mutation engine is lghcc.conformance.fuzz (also used by tests/test_fuzz.py).

    python tools/fuzz_decoder.py --minutes 3 --seed 1
    python tools/fuzz_decoder.py --cases 5000 --seed 7 --failures /tmp/lghcc-fuzz
    python tools/fuzz_decoder.py --cases 1000000 --scenes --seed 14 --out tools/results/fuzz.md
    make fuzz-long     # FUZZ_JOBS campaigns in parallel (--json each), then --merge into tools/results/fuzz.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning threads on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
import shlex  # noqa: E402
from collections import Counter  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lghcc.conformance.fuzz import Mutator, Summary, load_seeds, run_campaign  # noqa: E402


def summary_to_json(summary: Summary, command: str, started: str, seeds: int, timeout: float) -> dict:
    return {"command": command, "started": started, "seeds": seeds, "cases": summary.cases,
            "seconds": summary.seconds, "outcomes": dict(summary.outcomes), "slow": summary.slow,
            "slow_cpu_s": summary.slow_cpu_s, "slowest_cpu": list(summary.slowest_cpu), "timeout": timeout,
            "reasons": [[k, p, n] for (k, p), n in summary.reasons.items()], "slowest": list(summary.slowest),
            "peak_kib": summary.peak_kib, "growth_kib": summary.growth_kib, "largest": list(summary.largest),
            "failures": [[k, w, d] for k, w, d, _ in summary.failures]}


def merge_json(paths: list[str]) -> tuple[Summary, list[str], str, int]:
    """Summaries of campaigns run side by side, as one (their cases and outcomes add up; their time
    is the longest, since they ran at once)."""
    total = Summary()
    commands, started, seeds = [], "", 0
    total.timeout = 0.0
    for path in paths:
        d = json.loads(Path(path).read_text())
        total.timeout = max(total.timeout, d["timeout"])
        commands.append(d["command"])
        started = min(started, d["started"]) if started else d["started"]
        seeds = max(seeds, d["seeds"])
        total.cases += d["cases"]
        total.seconds = max(total.seconds, d["seconds"])
        total.outcomes.update(Counter(d["outcomes"]))
        total.reasons.update(Counter({(k, p): n for k, p, n in d["reasons"]}))
        if d["slowest"][0] > total.slowest[0]:
            total.slowest = tuple(d["slowest"])
        if d["slowest_cpu"][0] > total.slowest_cpu[0]:
            total.slowest_cpu = tuple(d["slowest_cpu"])
        total.slow += d["slow"]
        total.slow_cpu_s = d["slow_cpu_s"]
        total.peak_kib += d["peak_kib"]
        total.growth_kib += d["growth_kib"]
        if d["largest"][0] > total.largest[0]:
            total.largest = tuple(d["largest"])
        total.failures += [(k, w, det, b"") for k, w, det in d["failures"]]
    return total, commands, started, seeds


def commit() -> str:
    """The commit the run's code is at (with '+ changes' when the work tree differs from it)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" + uncommitted changes" if dirty else "")


def format_version() -> str:
    from lghcc.common.container import VERSION_MAJOR, VERSION_MINOR

    return f"{VERSION_MAJOR}.{VERSION_MINOR}"


def results_markdown(summary, command: str, started: str, seeds: int, args, jobs: int = 1) -> str:
    """tools/results/fuzz.md: the command, the figures, outcomes, reasons and memory."""
    bugs = {k: n for k, n in summary.outcomes.items() if k.startswith("BUG")}
    hangs = sum(n for k, n in bugs.items() if "timeout" in k)
    crashes = sum(bugs.values()) - hangs
    scene_cases = sum(n for k, n in summary.outcomes.items() if k.startswith("scene") or "round trip" in k
                      or k == "BUG: encoder")
    peaks = sorted(summary.peak_kib)
    peak = f"{peaks[-1] / 1024:.0f} MiB" if peaks else "not measured"
    growth = f"{max(summary.growth_kib) / 1024:.0f} MiB" if summary.growth_kib else "not measured"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "# Decoder fuzzing: long run",
        "",
        f"Started {started}, {summary.seconds / 3600:.2f} h ({jobs} campaign{'s' if jobs > 1 else ''} side by "
        f"side); machine: {os.cpu_count()} shared CPU cores, no GPU "
        f"(load average at the end {load:.1f}); the run was niced. Seed streams: {seeds} conformance streams "
        f"that decode, plus the fresh scene streams (the {args.pool} newest at a time).",
        "",
        f"Code: commit {commit()}; bitstream format version {format_version()} (the decoder's; the scene "
        "cases cover anchor and explicit-Gaussian scenes, neighbour prediction, step adjustment and tiles).",
        "",
        "Command" + ("s (run side by side, `make fuzz-long`; figures added up):" if jobs > 1 else ":"),
        "",
        *[f"    {c}" for c in command.split("\n")],
        "",
        "| cases | time | cases / s | structure-aware scene cases | crashes (tracebacks, worker deaths, MemoryError) "
        "| hangs (> {:g} s wall) | cases above {:g} s CPU | peak RSS of a case | largest growth in a case |".format(
            args.timeout, summary.slow_cpu_s),
        "|---|---|---|---|---|---|---|---|---|",
        f"| {summary.cases:,} | {summary.seconds:,.0f} s | {summary.cases / max(summary.seconds, 1e-9):,.1f} | "
        f"{scene_cases:,} | {crashes} | {hangs} | {summary.slow} | {peak} | {growth} |",
        "",
        "Outcomes:",
        "",
        "| outcome | cases |",
        "|---|---|",
    ]
    for k, n in sorted(summary.outcomes.items(), key=lambda kv: (not kv[0].startswith("BUG"), -kv[1])):
        lines.append(f"| {k} | {n:,} |")
    lines += ["", f"Errors by reason ({len(summary.reasons)} distinct class and message prefixes; the 25 most "
                  "frequent):", "", "| class | message prefix | cases |", "|---|---|---|"]
    for (kind, prefix), n in summary.reasons.most_common(25):
        lines.append(f"| {kind} | {prefix.replace('|', '/')} | {n:,} |")
    lines += ["", summary.memory_text() + ".", "",
              f"Slowest case: {summary.slowest[0]:.2f} s wall ({summary.slowest[1][:160]}); the most CPU: "
              f"{summary.slowest_cpu[0]:.2f} s ({summary.slowest_cpu[1][:160]}).", ""]
    if summary.failures:
        lines += ["Failures (first 20; inputs saved in the --failures folder):", ""]
        for kind, what, detail, _ in summary.failures[:20]:
            last = detail.strip().splitlines()[-1] if detail.strip() else ""
            lines.append(f"- {kind}: {what[:200]}: `{last[:200]}`")
        lines.append("")
    return "\n".join(lines)


def write_results(path: str, text: str) -> None:
    """Write the results file, keeping the differential fuzzer's section of it (tools/fuzz_differential.py)."""
    from fuzz_differential import keep_section

    p = Path(path)
    p.write_text(keep_section(p.read_text() if p.exists() else "", text))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    budget = ap.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=float, help="run for this many minutes (default 1)")
    budget.add_argument("--cases", type=int, help="run this many cases")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the mutations (default 0)")
    ap.add_argument("--timeout", type=float, default=5.0,
                    help="wall seconds allowed per case, then it is a hang (default 5; on a loaded shared machine a "
                         "niced run needs more: the long run uses 60 and reports cases above --slow-cpu)")
    ap.add_argument("--slow-cpu", type=float, default=5.0,
                    help="report cases that take more CPU seconds than this in the worker (default 5)")
    ap.add_argument("--memory-mb", type=int, default=2048,
                    help="address space a case may add to the worker, MiB (default 2048; 0: no limit)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads in the worker (default 1)")
    ap.add_argument("--streams", help="folder of conformance streams (default: the installed suite)")
    ap.add_argument("--scenes", action="store_true",
                    help="also generate and re-encode random scenes (tools/fuzz_scenes.py), one per "
                         "--mutations-per-scene cases, and mutate the fresh streams too")
    ap.add_argument("--mutations-per-scene", type=int, default=30, help="mutation cases per scene case (default 30)")
    ap.add_argument("--weigh-seeds", action="store_true",
                    help="draw seeds with probability inversely proportional to their decode time (long runs: "
                         "many more cases per hour; every seed is still mutated)")
    ap.add_argument("--pool", type=int, default=32, help="fresh scene streams kept as mutation seeds (default 32)")
    ap.add_argument("--failures", default="fuzz_failures", help="folder for failing inputs (default fuzz_failures)")
    ap.add_argument("--out", help="write the results as Markdown to this file (e.g. tools/results/fuzz.md)")
    ap.add_argument("--checkpoint-minutes", type=float, default=10.0,
                    help="with --out / --json: rewrite them every this many minutes while running (default 10); "
                         "SIGTERM or Ctrl-C stops the run and writes them for the cases done")
    ap.add_argument("--json", help="also write the summary as JSON (for --merge)")
    ap.add_argument("--merge", nargs="+", metavar="JSON",
                    help="no run: merge the --json summaries of campaigns run side by side into --out")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)
    if args.merge:
        summary, commands, started, seeds = merge_json(args.merge)
        args.timeout = summary.timeout  # the campaigns' own bound
        text = results_markdown(summary, "\n".join(commands), started, seeds, args, jobs=len(commands))
        if args.out:
            write_results(args.out, text)
            print(f"wrote {args.out}")
        else:
            print(text)
        return 1 if summary.bugs else 0

    command = "nice python tools/fuzz_decoder.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None
                                                                                        else sys.argv[1:]))
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    seeds = load_seeds(Path(args.streams) if args.streams else None)
    mutator = Mutator(seeds)
    if args.weigh_seeds:
        from lghcc.decoder.decode import decode_stream

        times = {}
        for sid, data in seeds.items():
            decode_stream(data)  # warm
            t0 = time.process_time()
            decode_stream(data)
            times[sid] = time.process_time() - t0
        mutator.weigh_by_time(times)
    scene_source = None
    if args.scenes:
        from fuzz_scenes import scene_case
        scene_source = scene_case
    seconds = None if args.cases else 60.0 * (args.minutes if args.minutes is not None else 1.0)
    last = [0.0, time.perf_counter()]

    def progress(s):
        now = time.perf_counter()
        if not args.quiet and now - last[0] > 30.0:
            last[0] = now
            print(f"{datetime.now().strftime('%H:%M:%S')} {s.cases} cases, {s.bugs} bugs, "
                  f"{s.cases / max(now - t_start, 1e-9):.1f} cases/s", file=sys.stderr, flush=True)
        if (args.out or args.json) and now - last[1] > 60.0 * args.checkpoint_minutes:
            last[1] = now
            s.seconds = now - t_start
            if args.out:
                write_results(args.out, results_markdown(s, command + "   (checkpoint: still running)", started,
                                                         len(seeds), args))
            if args.json:  # a partial summary that --merge can read if the run is cut short
                Path(args.json).write_text(json.dumps(summary_to_json(s, command + "   (checkpoint)", started,
                                                                      len(seeds), args.timeout)))

    print(f"seeds: {len(seeds)} conformance streams; seed {args.seed}; timeout {args.timeout:g} s; "
          f"memory limit +{args.memory_mb} MiB; torch threads {args.threads}; scenes {'on' if args.scenes else 'off'}",
          flush=True)
    import signal

    def stop(signum, frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGTERM, stop)
    t_start = time.perf_counter()
    summary = run_campaign(mutator, seed=args.seed, cases=args.cases, seconds=seconds, timeout=args.timeout,
                           memory_mb=args.memory_mb or None, threads=args.threads,
                           failures_dir=Path(args.failures), progress=progress, scene_source=scene_source,
                           mutations_per_scene=args.mutations_per_scene, pool_size=args.pool,
                           slow_cpu_s=args.slow_cpu)
    if summary.stopped:
        print(f"stopped after {summary.cases} cases (SIGTERM or Ctrl-C)")
        command += f"   (stopped after {summary.cases:,} cases)"
    print(summary.text())
    if args.json:
        Path(args.json).write_text(json.dumps(summary_to_json(summary, command, started, len(seeds), args.timeout)))
    if args.out:
        write_results(args.out, results_markdown(summary, command, started, len(seeds), args))
        print(f"wrote {args.out}")
    if summary.failures:
        print(f"failing inputs saved in {args.failures}/")
        for kind, what, detail, _ in summary.failures[:10]:
            print(f"  {kind}: {what}\n    {detail.strip().splitlines()[-1] if detail.strip() else ''}")
    return 1 if summary.bugs else 0


if __name__ == "__main__":
    sys.exit(main())
