#!/usr/bin/env python3
"""Long fuzz run of the reference decoder over mutated conformance streams.

Every case must end in lghcc.common.errors.LghccError or a valid decode, within --timeout
seconds, in a worker whose address space is limited to its parent's size plus --memory-mb
(an allocation beyond it raises MemoryError: a bug). Anything else is a bug: another
exception, a timeout, a worker that dies. Failing inputs are saved to --failures with a
.txt beside each (outcome, mutation, traceback); reproduce one with
    lghcc-dec <file>.lghcc --print-hash

The mutation engine is lghcc.conformance.fuzz (also used by tests/test_fuzz.py).

    python tools/fuzz_decoder.py --minutes 3 --seed 1
    python tools/fuzz_decoder.py --cases 5000 --seed 7 --failures /tmp/lghcc-fuzz
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lghcc.conformance.fuzz import Mutator, load_seeds, run_campaign


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    budget = ap.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=float, help="run for this many minutes (default 1)")
    budget.add_argument("--cases", type=int, help="run this many cases")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the mutations (default 0)")
    ap.add_argument("--timeout", type=float, default=5.0, help="seconds allowed per case (default 5)")
    ap.add_argument("--memory-mb", type=int, default=2048,
                    help="address space a case may add to the worker, MiB (default 2048; 0: no limit)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads in the worker (default 1)")
    ap.add_argument("--streams", help="folder of conformance streams (default: the installed suite)")
    ap.add_argument("--failures", default="fuzz_failures", help="folder for failing inputs (default fuzz_failures)")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)

    seeds = load_seeds(Path(args.streams) if args.streams else None)
    mutator = Mutator(seeds)
    seconds = None if args.cases else 60.0 * (args.minutes if args.minutes is not None else 1.0)
    last = [0.0]

    def progress(s):
        now = time.perf_counter()
        if not args.quiet and now - last[0] > 2.0:
            last[0] = now
            print(f"\r{s.cases} cases, {s.bugs} bugs", end="", file=sys.stderr, flush=True)

    print(f"seeds: {len(seeds)} conformance streams; seed {args.seed}; timeout {args.timeout:g} s; "
          f"memory limit +{args.memory_mb} MiB; torch threads {args.threads}")
    summary = run_campaign(mutator, seed=args.seed, cases=args.cases, seconds=seconds, timeout=args.timeout,
                           memory_mb=args.memory_mb or None, threads=args.threads,
                           failures_dir=Path(args.failures), progress=progress)
    if not args.quiet:
        print(file=sys.stderr)
    print(summary.text())
    if summary.failures:
        print(f"failing inputs saved in {args.failures}/")
        for kind, what, detail, _ in summary.failures[:10]:
            print(f"  {kind}: {what}\n    {detail.strip().splitlines()[-1] if detail.strip() else ''}")
    return 1 if summary.bugs else 0


if __name__ == "__main__":
    sys.exit(main())
