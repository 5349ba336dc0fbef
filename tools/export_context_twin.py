"""Write the GG-Conv context twin of an lghcc-train --rate-lambda run beside its newest scene.

lghcc-train saves the twin (context_twin.pt) with every checkpoint folder of the rate phase;
runs trained before it did keep it only in their train_state.pth. This reads that state with
the trainer's own code and writes the twin where lghcc-enc looks for it:

    python tools/export_context_twin.py runs/lego_rd [runs/other ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="lghcc-train output folders")
    args = ap.parse_args(argv)

    import torch

    from lghcc.common.errors import LghccError
    from lghcc.formats.scaffold_io import locate_ply
    from lghcc.encoder.training.checkpoints import read_train_state
    from lghcc.encoder.training.config import TrainConfig
    from lghcc.encoder.training.loop import Trainer
    from lghcc.render.datasets import load_dataset
    from lghcc.encoder.context.ggconv_train import TWIN_FILE

    torch.set_num_threads(1)
    status = 0
    for run in map(Path, args.runs):
        try:
            state = read_train_state(run)
            cfg = TrainConfig(**state["config"])
            tr = Trainer(cfg, load_dataset(cfg.data, cfg.background, cfg.downscale, cfg.images), run)
            tr.load_state_dict(state)
            folder = locate_ply(run).parent
        except (OSError, KeyError, LghccError) as e:
            print(f"{run}: cannot read the run ({e})", file=sys.stderr)
            status = 1
            continue
        twin = None if tr.rate_model is None else tr.rate_model.context_twin()
        if twin is None:
            print(f"{run}: no rate phase (lghcc-train --rate-lambda), so no twin", file=sys.stderr)
            status = 1
            continue
        if folder.name != f"iteration_{tr.iteration}":
            print(f"{run}: the newest scene ({folder.name}) is not the training state's iteration {tr.iteration}",
                  file=sys.stderr)
            status = 1
            continue
        twin.save(folder / TWIN_FILE)
        print(f"{run}: wrote {folder / TWIN_FILE} (k={twin.k}, neighbour level {twin.neighbour_level}, "
              f"sizes {twin.sizes}, step {twin.step:g})")
    return status


if __name__ == "__main__":
    sys.exit(main())
