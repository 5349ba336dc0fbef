"""Research (issue 53, scale.md "Round 4"). Run the settings search alone on a scene with its contributions and sensitivities
(cached in SCENE.PRESET.prep.pkl beside it); --out: every trial's error, bits, share and CPU s as JSON."""
import os, sys, time, pickle, json, argparse
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import numpy as np
from lghcc.formats.ply3dgs import read_3dgs_ply
from lghcc.encoder.stream.config import load_config
from lghcc.encoder.gaussians import gaussian_fit as gf, gaussian_rd as rd
from lghcc.encoder.gaussians.gaussian_views import scene_views

ap = argparse.ArgumentParser()
ap.add_argument("ply"); ap.add_argument("--preset", default="medium"); ap.add_argument("--out")
ap.add_argument("--prof"); ap.add_argument("--max-trials", type=int, default=0)
ap.add_argument("--no-floor", action="store_true", help="the pruning-floor rule off (every share of the ladder)")
a = ap.parse_args()
if a.no_floor and hasattr(rd, "PRUNING_FLOOR_EXPONENT"):
    rd.PRUNING_FLOOR_EXPONENT = 0.0
scene = read_3dgs_ply(a.ply)
cfg = load_config(a.preset, kind="gaussians")
views = scene_views(scene, cfg.views)
pk = f"{a.ply}.{a.preset}.prep.pkl"
if not os.path.exists(pk):
    g = gf.gaussians_from_scene(scene)
    cc = views.contribution_cameras(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px)
    contrib = gf.pruning_key(gf.measure_contributions(g, cc, False, gf.pruning_regions(views)), views)
    sv = gf.sensitivity_views(cfg, scene.num_gaussians)
    sc = views.cameras(scene, sv, cfg.fit_resolution, cfg.resolve_px)
    sens = gf.measure_sensitivities(scene, sc, cfg, gf.PrepareStats(gaussians_in=scene.num_gaussians), False)
    pickle.dump((contrib, sens), open(pk, "wb"))
contrib, sens = pickle.load(open(pk, "rb"))
times = []
orig = rd.SettingsSearch.evaluate
def timed(self, c):
    t = time.perf_counter(); tp = time.process_time()
    r = orig(self, c)
    times.append((time.perf_counter() - t, time.process_time() - tp))
    if a.max_trials and len(times) >= a.max_trials:
        raise SystemExit
    return r
rd.SettingsSearch.evaluate = timed
stats = gf.PrepareStats(gaussians_in=scene.num_gaussians)
prof = None
if a.prof:
    import cProfile; prof = cProfile.Profile(); prof.enable()
t0, c0 = time.perf_counter(), time.process_time()
trials_out = []
orig_ss = rd.search_settings
def ss(*args, **kw):
    cfg2, trials = orig_ss(*args, **kw)
    trials_out.extend(trials); return cfg2, trials
rd.search_settings = ss
ladder_at = []
orig_fb = rd.fewest_bits_at_target
def fb(s_, best, groups, target_mse):
    ladder_at.append(len(s_.trials)); ladder_at.append(target_mse)
    return orig_fb(s_, best, groups, target_mse)
rd.fewest_bits_at_target = fb
try:
    chosen, sample = gf.search_for_settings(scene, contrib, sens, cfg, views, stats, print)
except SystemExit:
    chosen = None
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
if prof:
    prof.disable(); prof.dump_stats(a.prof)
print(f"search: {len(times)} trials, {wall:.1f} s wall, {cpu:.1f} s CPU(process), {1000*cpu/scene.num_gaussians:.3f} ms CPU/Gaussian")
rec = {"n": scene.num_gaussians, "wall": wall, "cpu": cpu, "times": times, "ladder_start": ladder_at,
       "trials": [(t.mse, t.bits) for t in trials_out],
       "shares": [(t.cfg.prune_share, t.cfg.sh_dc_step, t.cfg.opacity_step) for t in trials_out],
       "target_mse": None if not cfg.target_psnr else 10 ** (-cfg.target_psnr / 10),
       "chosen": None if chosen is None else {k: (list(v) if isinstance(v, tuple) else v) for k, v in chosen.__dict__.items() if isinstance(v, (int, float, tuple, str, bool, type(None)))}}
if a.out: json.dump(rec, open(a.out, "w"), indent=1)
