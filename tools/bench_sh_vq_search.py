"""VQ of the SH rest through the settings search (estimate, no format change): the encoder's
search_settings (encoder/gaussians/gaussian_rd.py, target-PSNR mode, the preset's views) run once
with today's trials and once with every trial's SH rest coded as tools/bench_sh_vq.py's design br
(brd where the trial has the SH-degree choice): unweighted k-means palette of K entries per pruning
share, rate-chosen entries, the residual through today's path. Each landing is then measured as
bench_sh_vq measures a row (bits: the search's count plus palette and index bits; PSNR on the search
views and on bench_real's orbit).

    python tools/bench_sh_vq_search.py ../shared/data/playbot/playbot_lod4_8k.ply --preset medium --vq 256
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
import torch  # noqa: E402

import bench_sh_vq as bv  # noqa: E402
from lghcc.encoder.gaussians import gaussian_rd  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import SettingsSearch, Trial  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs  # noqa: E402


def vq_search_class(k: int):
    class Searched(bv.VQSearch):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            self.palettes = {}
            self.rate_rounds, self.candidates = 2, 16  # cheaper than bench_sh_vq's rows: every trial runs it

        def evaluate(self, cfg):
            design = "brd" if cfg.sh_degree_choice else "br"
            dec, bits, _ = self.trial(cfg, design, k, 0.0)
            mse = self._mse(dec, cfg.prune_share)
            t = Trial(cfg, mse, bits, 10 * math.log10(max(mse, 1e-12)) + self.lam * math.log2(max(bits, 1.0)))
            self.trials.append(t)
            return t
    return Searched


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene")
    p.add_argument("--preset", default="medium")
    p.add_argument("--vq", type=int, default=0, help="palette size K (0: today's trials)")
    p.add_argument("--orbit-up", default="-y")
    p.add_argument("--cache", type=Path, default=Path("/tmp/sh_vq_cache"))
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    scene = read_3dgs_ply(args.scene)
    cfg = load_config(args.preset, kind="gaussians")
    z = np.load(args.cache / f"{Path(args.scene).stem}_{args.preset}.npz")  # written by bench_sh_vq.py
    contrib, f = z["contrib"], z["f"]
    if args.vq:
        gaussian_rd.SettingsSearch = vq_search_class(args.vq)
    t0 = time.process_time()
    chosen, trials = gaussian_rd.search_settings(scene, contrib, cfg, sensitivity=f, log=print)
    gaussian_rd.SettingsSearch = SettingsSearch
    cpu = time.process_time() - t0
    s = bv.VQSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    s.palettes = {}
    s.rate_rounds, s.candidates = 2, 16
    from bench_real import orbit

    g = gaussians_from_scene(scene)
    o = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    o.cams = orbit(scene.means, 12, 320, args.orbit_up)
    with torch.no_grad():
        o.targets = [render_3dgs(g, c, background=(0, 0, 0), backend="torch").image for c in o.cams]
    design = None if not args.vq else ("brd" if chosen.sh_degree_choice else "br")
    dec, bits, extra = s.trial(chosen, design, args.vq, 0.0)
    ps = bv.psnr(s._mse(dec, chosen.prune_share))
    po = bv.psnr(o._mse(dec, chosen.prune_share))
    steps = {n: gaussian_rd._step(chosen, n) for n in gaussian_rd.GROUPS if n != "sh_band3"}
    print(f"RESULT {Path(args.scene).stem} {args.preset} vq={args.vq}: {bits / 8:,.0f} B (palette+index {extra / 8:,.0f}), "
          f"PSNR search {ps:.2f} / orbit {po:.2f} dB; {len(trials)} trials, search CPU {cpu:.0f} s; prune share "
          f"{chosen.prune_share:g}; steps {', '.join(f'{n} {v:.4g}' for n, v in steps.items())}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
