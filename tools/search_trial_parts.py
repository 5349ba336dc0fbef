"""Research (issue 53, scale.md "Round 4"): the CPU seconds of each part of a search trial at the preset's
steps times 1.1, 1.2, ... (the bits counted inline in the main thread), on SCENE with search_trials.py's cache.
Usage: search_trial_parts.py SCENE.ply TRIALS [PRESET]."""
import os, sys, time, pickle, dataclasses, collections
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import numpy as np
from lghcc.formats.ply3dgs import read_3dgs_ply
from lghcc.encoder.stream.config import load_config
from lghcc.encoder.gaussians import gaussian_rd as rd
from lghcc.encoder.gaussians.gaussian_views import scene_views
ply, reps = sys.argv[1], int(sys.argv[2])
preset = sys.argv[3] if len(sys.argv) > 3 else "medium"
scene = read_3dgs_ply(ply)
cfg = load_config(preset, kind="gaussians")
views = scene_views(scene, cfg.views)
contrib, sens = pickle.load(open(f"{ply}.{preset}.prep.pkl", "rb"))
count, res = rd.search_view_plan(cfg, scene.num_gaussians)
cfg = dataclasses.replace(cfg, search_views=count, search_resolution=res, search_reference_gaussians=0, prune_share=0.0)
s = rd.SettingsSearch(scene, contrib.total, cfg, 8.0, count, res, sens, None, rd.SceneRenders(scene, views), contrib.view_share)
acc = collections.defaultdict(float)
def wrap(obj, name, label):
    f = getattr(obj, name)
    def w(*a, **k):
        c = time.process_time(); t = time.perf_counter()
        try: return f(*a, **k)
        finally:
            acc[label] += time.process_time() - c; acc[label + " wall"] += time.perf_counter() - t
    setattr(obj, name, w)
for n in ("adjust_on_graph", "rd_quantize", "_with_sh_transform", "_decoded_values", "degrees_on_graph"):
    wrap(rd, n, n)
for n in ("_values_bits", "_mse", "_sensitivity_of", "_grid"):
    wrap(rd.SettingsSearch, n, n)
class Inline:
    def __init__(self, *a, **k): pass
    def __enter__(self): return self
    def __exit__(self, *e): return False
    def submit(self, fn, *args):
        v = fn(*args)
        return type("R", (), {"result": lambda self: v})()
rd.ThreadPoolExecutor = Inline
s.evaluate(cfg); acc.clear()
c0, t0 = time.process_time(), time.perf_counter()
out = []
for k in range(reps):
    t = s.evaluate(rd._scaled(cfg, rd._attribute_groups(scene), 1.0 + 0.1 * (k + 1)))
    out.append((t.mse, t.bits))
tot = time.process_time() - c0
print(f"{scene.num_gaussians} Gaussians, {count} views of {res} px: {reps} trials {tot:.1f} CPU s, {time.perf_counter()-t0:.1f} wall; per trial:")
for k in sorted(acc, key=lambda k: -acc[k]):
    if not k.endswith("wall"): print(f"  {k:20s} {acc[k]/reps:6.2f} CPU s  {acc[k+' wall']/reps:6.2f} wall")
print("  total/trial", f"{tot/reps:.2f}")
print(out)
