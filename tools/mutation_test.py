#!/usr/bin/env python3
"""Mutation testing of the reference decoder against the conformance suite (issue 14).

For each mutation of lghcc.conformance.mutations (one careless implementer's mistake in one
normative operation), a forked process patches the decoder, then decodes the conformance streams
with the in-process runner (the smallest first) until one fails: the mutation is *killed* by that
stream (its hash changed, a stream that must be rejected decoded or was rejected for another
reason, the decoder crashed), or *survives* the whole suite. A mutation that runs past --timeout
is killed as a hang. A mutation whose edit no longer matches the code is *stale*.

    python tools/mutation_test.py                       # all, summary per module
    python tools/mutation_test.py ggconv knn            # only these groups (or mutation ids / id prefixes)
    python tools/mutation_test.py --report              # also rewrite the section of tools/results/conformance.md
    make mutations                                      # the same as --report
    python tools/mutation_test.py --conditions          # per condition of spec clause 8.2 (issue 35): is the
                                                        # mutation that removes its check killed by its own
                                                        # isolated stream through acceptance?
    python tools/mutation_test.py --conditions E17 E42  # only these conditions
    python tools/mutation_test.py --conditions --report # also rewrite that section of the report

Exit status: 0 when every mutation is killed, 1 when one survives or is stale, 2 usage error.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import multiprocessing as mp  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "tools" / "results" / "conformance.md"
BEGIN, END = "<!-- mutations:begin -->", "<!-- mutations:end -->"
COND_BEGIN, COND_END = "<!-- conditions:begin -->", "<!-- conditions:end -->"
ACCEPTED = "decoded a stream that must be rejected"  # the runner's note when a decoder accepts an error stream


def _child(conn, mutation_id: str, case_ids: list[str], streams: str | None = None) -> None:
    """In the forked process: patch, run the cases in order, report the first failure."""
    try:
        import torch

        torch.set_num_threads(1)
        from lghcc.conformance import mutations, runner

        m = next(x for x in mutations.MUTATIONS if x.id == mutation_id)
        try:
            mutations.apply(m)
        except mutations.StaleMutation as e:
            conn.send(("stale", "", str(e)))
            return
        cases = {c.id: c for c in runner.load_cases(Path(streams) if streams else runner.STREAMS_DIR)}
        for cid in case_ids:
            o = runner.run_case(cases[cid])
            if not o.passed:
                conn.send(("killed", cid, o.note[:200]))
                return
        conn.send(("survived", "", ""))
    except Exception:  # noqa: BLE001 - the harness itself failed: reported as such
        conn.send(("harness error", "", traceback.format_exc()[-300:]))


def run_one(mutation_id: str, case_ids: list[str], timeout: float,
            streams: str | None = None) -> tuple[str, str, str, float]:
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(child, mutation_id, case_ids, streams), daemon=True)
    t0 = time.perf_counter()
    p.start()
    child.close()
    if parent.poll(timeout):
        try:
            status, killer, note = parent.recv()
        except EOFError:
            status, killer, note = "killed", "(decoder process died)", f"exit code {p.exitcode}"
    else:
        status, killer, note = "killed", "(hang)", f"no result within {timeout:g} s"
    if p.is_alive():
        p.kill()
    p.join()
    if status == "harness error" and p.exitcode not in (0, None):
        status, killer, note = "killed", "(decoder process died)", f"exit code {p.exitcode}"
    return status, killer, note, time.perf_counter() - t0


def select(mutations, patterns: list[str]):
    if not patterns:
        return list(mutations)
    out = [m for m in mutations if any(m.group == p or m.id == p or m.id.startswith(p + ".") or
                                       (p.endswith("*") and m.id.startswith(p[:-1])) for p in patterns)]
    if not out:
        raise SystemExit(f"mutation_test: error: no mutation matches {patterns}")
    return out


def markdown(results, total_s: float, n_cases: int) -> str:
    by_group: dict[str, Counter] = defaultdict(Counter)
    for m, (status, *_rest) in results:
        by_group[m.group][status] += 1
    lines = [BEGIN, "", "## Mutation testing (decision coverage)", "",
             "Command: `python tools/mutation_test.py --report` (`make mutations`); "
             f"{len(results)} mutations of conformance/mutations.py against the {n_cases} streams of the "
             f"suite, {total_s / 60:.1f} min on the shared 2-core machine. Each mutation is one mistake a careless "
             "implementer of spec/ could make in one normative operation, applied to the reference decoder; it is "
             "killed when some stream then fails (hash, rejection class or reason, crash, hang).", "",
             "| module | killed | total | survived | stale |", "|---|---|---|---|---|"]
    for group in sorted(by_group):
        c = by_group[group]
        total = sum(c.values())
        lines.append(f"| {group} | {c['killed']} | {total} | {c['survived']} | {c['stale'] + c['harness error']} |")
    c = Counter(status for _, (status, *_r) in results)
    lines.append(f"| **all** | **{c['killed']}** | **{len(results)}** | **{c['survived']}** | "
                 f"**{c['stale'] + c['harness error']}** |")
    lines += ["", "Per mutation (the first stream that fails, smallest first):", "",
              "| mutation | what a wrong decoder does | outcome | killed by |", "|---|---|---|---|"]
    for m, (status, killer, note, _s) in results:
        lines.append(f"| `{m.id}` | {m.description.replace('|', '/')} | {status} | {killer or note[:80]} |")
    lines += ["", END]
    return "\n".join(lines)


def condition_rows(chosen: list[str], timeout: float) -> list[tuple[str, str, str, str, str]]:
    """Per isolated stream of each condition of clause 8.2 (one row per bound): (condition, mutation,
    isolated stream, killed by acceptance 'yes'/'no'/'-', what the mutant did). The mutant runs only its
    own stream (conformance/conditions.py)."""
    from lghcc.conformance import conditions

    streams = conditions.isolated_stream_list()
    rows = []
    for cond in chosen:
        mine = [s for s in streams if s.condition == cond]
        if not mine:
            rows.append((cond, conditions.CHECK_REMOVALS.get(cond, ""), "none", "-",
                         conditions.NOT_ISOLATED.get(cond, "no isolated stream")))
        for s in mine:
            status, killer, note, _ = run_one(s.check_removal, [s.id], timeout)
            accepted = status == "killed" and killer == s.id and note.startswith(ACCEPTED)
            shown = f"{s.id} ({s.bound})" if s.bound else s.id
            rows.append((cond, s.check_removal, shown, "yes" if accepted else "no",
                         note if status == "killed" else f"{status}: the mutant passes its stream"))
            print(f"{cond:4s} {s.check_removal:36s} {s.id:44s} {'yes' if accepted else 'NO'}  {note[:70]}",
                  flush=True)
    return rows


def conditions_markdown(rows, total_s: float) -> str:
    n = sum(r[3] == "yes" for r in rows)
    isolated = sum(r[2] != "none" for r in rows)
    conds_without = sum(r[2] == "none" for r in rows)
    lines = [COND_BEGIN, "", "## Clause 8.2 conditions: isolated streams and their check-removal mutants", "",
             "Command: `python tools/mutation_test.py --conditions --report`; "
             f"{total_s / 60:.1f} min on the shared 2-core machine. For each rejection condition of spec clause "
             "8.2, the mutation that removes its check (conformance/conditions.py `CHECK_REMOVALS`) runs against "
             "each isolated error stream of the condition only (test.yaml `condition`; one row per bound or field: "
             "`bound`, with the narrower mutation a stream names in `check_removal`): it is *killed by acceptance* "
             "when it decodes that stream without an error (the runner: \"decoded a stream that must be "
             "rejected\"); a rejection for another reason does not count. A condition without an isolated "
             "stream says why (`NOT_ISOLATED`; spec clause 8.2).", "",
             f"{n} of {isolated} isolated streams kill their mutant by acceptance; {conds_without} of "
             f"{len({r[0] for r in rows})} conditions cannot be isolated.", "",
             "| condition | mutation | isolated stream | killed by acceptance | note |", "|---|---|---|---|---|"]
    for cond, mutation, stream, yes, note in rows:
        lines.append(f"| {cond} | `{mutation or '-'}` | {stream} | {yes} | {note[:160].replace('|', '/')} |")
    lines += ["", COND_END]
    return "\n".join(lines)


def write_report(text: str, begin: str = BEGIN, end: str = END) -> None:
    old = REPORT.read_text()
    if begin in old and end in old:
        new = old[:old.index(begin)] + text + old[old.index(end) + len(end):]
    else:
        new = old.rstrip("\n") + "\n\n" + text + "\n"
    REPORT.write_text(new)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("select", nargs="*", help="groups, mutation ids, id prefixes or 'prefix*' (default: all)")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per mutation before it counts as a hang")
    ap.add_argument("--report", action="store_true", help=f"rewrite the mutation section of {REPORT.relative_to(ROOT)}")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--conditions", action="store_true",
                    help="per condition of spec clause 8.2 (the selection: condition names, default all): is the "
                         "mutation removing its check killed by its isolated stream through acceptance?")
    args = ap.parse_args(argv)
    from lghcc.conformance import mutations, runner

    if args.conditions:
        return main_conditions(args)

    chosen = select(mutations.MUTATIONS, args.select)
    if args.list:
        for m in chosen:
            print(f"{m.id:45s} {m.target}: {m.description}")
        return 0
    # warm the imports only: nothing is decoded in this process, so no cache holds an unmutated model
    import lghcc.common.context.ggconv  # noqa: F401
    import lghcc.common.context.parent_mlp  # noqa: F401
    import lghcc.decoder.decode  # noqa: F401
    import torch  # noqa: F401

    cases = runner.load_cases()
    case_ids = [c.id for c in sorted(cases, key=lambda c: c.stream.stat().st_size)]
    t0 = time.perf_counter()
    base = run_one_baseline(case_ids, args.timeout)
    if base:
        print(f"mutation_test: error: the unmutated decoder fails the suite: {base}", file=sys.stderr)
        return 2
    results = []
    for i, m in enumerate(chosen):
        res = run_one(m.id, case_ids, args.timeout)
        results.append((m, res))
        status, killer, note, secs = res
        print(f"[{i + 1}/{len(chosen)}] {m.id:42s} {status:9s} {killer or note[:100]} ({secs:.1f} s)", flush=True)
    total = time.perf_counter() - t0
    c = Counter(r[0] for _, r in results)
    by_group: dict[str, Counter] = defaultdict(Counter)
    for m, r in results:
        by_group[m.group][r[0]] += 1
    print(f"\n{c['killed']} of {len(results)} killed, {c['survived']} survived, {c['stale']} stale "
          f"in {total / 60:.1f} min")
    for g in sorted(by_group):
        print(f"  {g:14s} {by_group[g]['killed']}/{sum(by_group[g].values())}")
    survivors = [m.id for m, r in results if r[0] != "killed"]
    if survivors:
        print("not killed: " + ", ".join(survivors))
    if args.report:
        if args.select:
            print("mutation_test: --report needs the whole list (no selection); not written", file=sys.stderr)
        else:
            write_report(markdown(results, total, len(cases)))
            print(f"wrote the mutation section of {REPORT.relative_to(ROOT)}")
    return 0 if not survivors else 1


def main_conditions(args) -> int:
    """--conditions: exit status 0 when every isolated stream kills its mutant by acceptance."""
    from lghcc.conformance import conditions

    chosen = args.select or conditions.CONDITIONS
    unknown = sorted(set(chosen) - set(conditions.CONDITIONS))
    if unknown:
        raise SystemExit(f"mutation_test: error: no condition {', '.join(unknown)} in spec clause 8.2")
    t0 = time.perf_counter()
    rows = condition_rows(list(chosen), args.timeout)
    failed = [r[0] for r in rows if r[3] == "no"]
    print(f"\n{sum(r[3] == 'yes' for r in rows)} of {sum(r[2] != 'none' for r in rows)} isolated streams kill "
          f"their mutant by acceptance" + (f"; not: {', '.join(failed)}" if failed else ""))
    if args.report:
        if args.select:
            print("mutation_test: --report needs every condition (no selection); not written", file=sys.stderr)
        else:
            write_report(conditions_markdown(rows, time.perf_counter() - t0), COND_BEGIN, COND_END)
            print(f"wrote the conditions section of {REPORT.relative_to(ROOT)}")
    return 1 if failed else 0


def run_one_baseline(case_ids: list[str], timeout: float) -> str:
    """'' when the unmutated decoder passes every stream (a mutation is judged against that)."""
    from lghcc.conformance import mutations

    probe = mutations.Mutation("baseline", "baseline", "lghcc.common.entropy.range_coder:check_frequencies",
                               "no change", ((("def check_frequencies", "def check_frequencies"),)))
    mutations.MUTATIONS.append(probe)
    try:
        status, killer, note, _ = run_one("baseline", case_ids, timeout)
    finally:
        mutations.MUTATIONS.remove(probe)
    return "" if status == "survived" else f"{killer}: {note}"


if __name__ == "__main__":
    sys.exit(main())
