#!/usr/bin/env python3
"""lghcc-enc with its resident memory traced per stage: where the encoder's peak is (issue 53).

Runs `lghcc-enc` (lghcc.encoder.cli.main) in this process with its arguments, samples the process's
RSS every 10 ms in a thread, and marks the entry and exit of the preparation's and the coding's
stages (contributions, sensitivities, the settings search's probes, model step, checks and pruning
ladder, the fit, the landing, RDOQ, the neighbour coding, the tiles). After the encode it prints one
line per mark: seconds since the start, the RSS then, the peak since the mark before, and the stage
(">" entering, "<" leaving with its seconds), then the overall peak. Tiles coded in worker processes
(--jobs) are not in this process's RSS: the whole-scene stages before them are what peak.

    python tools/trace_encoder_memory.py SCENE.ply -o OUT.lghcc -y --preset medium --jobs 2 --no-verify > trace.txt

Results: tools/results/scale.md, section "SH 3 memory (issue 53)", round 3. Exit status: lghcc-enc's.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads on a shared machine

import functools  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

# (module, functions) whose entry and exit are marked
STAGES = [
    ("lghcc.encoder.gaussians.gaussian_fit", ["measure_contributions", "measure_sensitivities", "search_for_settings",
                                              "_search_sample", "pruned_on_grid", "fit_to_renders", "land_on_target",
                                              "whole_scene_check", "trim_steps", "check_on_held_back_views"]),
    ("lghcc.encoder.gaussians.gaussian_rd", ["sample_distortion_ratio", "search_settings", "probe_groups",
                                             "model_step_trial", "check_steps_either_way", "fewest_bits_at_target",
                                             "meet_on_whole_scene"]),
    ("lghcc.encoder.gaussians.gaussians", ["without_invisible", "on_own_voxels", "gaussian_attribute_input",
                                           "rd_quantized_input", "assemble_gaussian_stream", "code_attributes"]),
    ("lghcc.encoder.gaussians.rdoq", ["rd_quantize", "adjust_on_graph"]),
    ("lghcc.encoder.stream.encode", ["code_neighbours_or_prior", "stream_tiles", "write_stream"]),
    ("lghcc.encoder.stream.tile_workers", ["code_tiles"]),
]
SAMPLE_S = 0.01


def rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class Trace:
    """RSS samples and stage marks (time, RSS, name)."""

    def __init__(self):
        self.samples: list[tuple[float, int]] = []
        self.marks: list[tuple[float, int, str]] = []
        self.depth = 0
        self.stop = False

    def sample(self) -> None:
        while not self.stop:
            self.samples.append((time.perf_counter(), rss()))
            time.sleep(SAMPLE_S)

    def wrap(self, module: str, name: str) -> None:
        """Mark ``module.name``'s entry and exit, where it is defined and where it was imported by name."""
        m = importlib.import_module(module)
        f = getattr(m, name)

        @functools.wraps(f)
        def marked(*a, **k):
            indent = "  " * self.depth
            self.marks.append((time.perf_counter(), rss(), f"{indent}> {name}"))
            self.depth += 1
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self.depth -= 1
                self.marks.append((time.perf_counter(), rss(), f"{indent}< {name} {time.perf_counter() - t:.2f}s"))
        for other in [m] + [x for x in list(sys.modules.values()) if getattr(x, "__name__", "").startswith("lghcc")]:
            if getattr(other, name, None) is f:
                setattr(other, name, marked)

    def report(self, t0: float) -> None:
        points = sorted([(t, r, None) for t, r in self.samples] + [(t, r, n) for t, r, n in self.marks])
        peak = 0
        for t, r, name in points:
            peak = max(peak, r)
            if name is not None:
                print(f"{t - t0:8.2f}s rss {r / 2 ** 20:7.0f} MiB  peak since the last mark {peak / 2 ** 20:7.0f}  "
                      f"{name}")
                peak = r
        print(f"overall peak {max(r for _, r in self.samples) / 2 ** 20:,.0f} MiB")


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    from lghcc.encoder import cli

    trace = Trace()
    for module, names in STAGES:
        for name in names:
            trace.wrap(module, name)
    t0 = time.perf_counter()
    sampler = threading.Thread(target=trace.sample, daemon=True)
    sampler.start()
    try:
        return cli.main(argv)
    finally:
        trace.stop = True
        sampler.join()
        trace.report(t0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
