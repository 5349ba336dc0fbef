"""lghcc-batch: scenes x presets (x rate lambdas) -> encode, decode, evaluate; on Ray or here."""

from __future__ import annotations

import os

# torch in this process (--local) and in Ray's workers (set through runtime_env, batch/runner.py):
# passive OpenMP waiting, so that threads do not spin against other work (see decoder/cli.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import sys  # noqa: E402

from ..common.errors import LghccError  # noqa: E402

DESCRIPTION = """\
Run a sweep: every scene of a sweep file coded with every preset (and, for scenes trained
from images, every rate lambda): encode, decode (hash checked), and evaluate the decoded
scene against the source rendered from fixed orbit cameras (PSNR, SSIM), with the bytes of
each part and the times. Writes one JSON per cell and the stream, then results.md (one
table), results.json and an RD plot per scene (rd_<scene>.png; needs matplotlib).

Where it runs: on a local Ray instance by default (ray.init(); `pip install 'lghcc[batch]'`),
on a running Ray cluster with --address HOST:PORT, or in this process with --local (no Ray).

Resumable: a cell already finished with the same settings is not run again; a failed one is
retried. A failed cell does not stop the others; the exit status is then 2. A sweep file
with an unknown key or a missing scene, or a cluster that cannot be reached, is reported
before any work starts (exit status 1).

sweep file (paths relative to it; see batch/sweep.py for every key):
  scenes:
    - {name: donut, path: ../shared/data/donut/donut.ply}
    - {name: demo, procedural: 2000}
    - {name: lego, train: ../shared/data/lego/lego_100, train_options: {iterations: 2000}}
  presets: [low, medium, high]
  lambdas: [0, 0.004]
  evaluation: {views: 8, size: 256x256}

examples:
  lghcc-batch sweep.yaml                        local Ray, every core
  lghcc-batch sweep.yaml --local                no Ray: one cell after another in this process
  lghcc-batch sweep.yaml --address 10.0.0.5:6379   a cluster (ray start --head on 10.0.0.5)
"""


def setup_args() -> argparse.ArgumentParser:
    from ..app.cliargs import add_version_option

    p = argparse.ArgumentParser(prog="lghcc-batch", description=DESCRIPTION,
                                epilog="exit status:\n  0    every cell finished\n  1    error before any work "
                                       "(sweep file, cluster)\n  2    bad command line, or some cells failed (see "
                                       "results.md)\n  130  interrupted (Ctrl-C); finished cells are kept, a rerun "
                                       "resumes\n",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    p.add_argument("sweep", help="the sweep file (YAML)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="results folder (default: the sweep's `output`, else <sweep>_results beside it)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--local", action="store_true", help="run in this process, one cell after another (no Ray)")
    where.add_argument("--address", metavar="HOST:PORT",
                       help="join a running Ray cluster (its head's address; ray://HOST:PORT for Ray Client; auto)")
    p.add_argument("--num-cpus", type=int, help="CPUs of the local Ray instance (default: all)")
    p.add_argument("--cpus-per-cell", type=int, default=1,
                   help="CPUs (torch threads) per task (default 1: one cell per core)")
    p.add_argument("--connect-timeout", type=float, default=15.0, metavar="S",
                   help="seconds to wait for the cluster's address to answer (default 15)")
    p.add_argument("-y", "--overwrite", action="store_true",
                   help="run every cell again, replacing its files (default: a cell already finished with the same "
                        "settings is kept: the results folder is resumed, never partly overwritten)")
    p.add_argument("--dry-run", action="store_true", help="check the sweep file and list the cells; run nothing")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv: list[str] | None = None) -> int:
    from ..app.cliargs import run_cli

    return run_cli("lghcc-batch", _main, argv, "finished cells are kept; rerun to resume")


def _main(argv: list[str] | None) -> int:
    args = setup_args().parse_args(argv)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    try:
        from .report import write_report
        from .runner import Store, run_sweep
        from .sweep import load_sweep

        if args.cpus_per_cell < 1:
            raise LghccError(f"--cpus-per-cell must be at least 1, got {args.cpus_per_cell}")
        if args.num_cpus is not None and (args.num_cpus < 1 or args.local or args.address):
            raise LghccError("--num-cpus is a positive count for the local Ray instance (not with --local or "
                             "--address)")
        sweep = load_sweep(args.sweep, args.output)
        if args.dry_run:
            store = Store(sweep.output)
            for c in sweep.cells():
                say(f"{c.id}: {'done' if store.done(sweep, c) else 'to run'}")
            return 0
        records = run_sweep(sweep, local=args.local, address=args.address, num_cpus=args.num_cpus,
                            cpus_per_cell=args.cpus_per_cell, connect_timeout_s=args.connect_timeout, say=say,
                            redo=args.overwrite)
        md = write_report(sweep, records, argv)
    except LghccError as e:
        print(f"lghcc-batch: error: {e}", file=sys.stderr)
        return 1
    failed = [r for r in records if r["status"] != "ok"]
    say(f"wrote {md}" + (f" and {sweep.output / 'results.json'}" if md else ""))
    if failed:
        print(f"lghcc-batch: {len(failed)} of {len(records)} cells failed: "
              + ", ".join(r["cell"] for r in failed) + f" (errors in {md})", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
