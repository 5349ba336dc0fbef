"""Plain 3DGS PLY -> anchor scene (Scaffold-GS), by fitting against renders of the source.

1. Views: ``views`` training and ``test_views`` held-out cameras on a sphere around the
   source (Fibonacci points, the held-out set on a shifted spiral so that no view is
   shared), looking at the centre of the robust bounding box of the Gaussians with
   opacity >= 0.05, at a distance where that box's sphere fills the field of view.
   The source is rendered into them with render/gaussians3dgs.py (SH colours for each
   view, black background).
2. Anchors: Gaussians with opacity >= ``min_opacity`` are voxelized on a grid through the
   world origin (a written checkpoint's voxel size can be inferred); those below are removed
   (a decision, counted in the statistics). The voxel size is given (``voxel_size``) or
   chosen from the data by this rule: **the size v at which about T voxels are occupied**
   (T = ``anchors``, default a quarter of the kept Gaussians), found by bisection on log v
   between lo = half the smallest distance between two distinct Gaussian means (every
   distinct mean then has a voxel of its own) and hi = 4 x the largest coordinate magnitude
   (every mean rounds to voxel 0). Both bounds come from the data, so a scene scaled by s gets
   the voxel scaled by s (a scene in millimetres or one whose spacing is 0.005 as well as one
   in metres), and no fixed ratio to the extent limits the search (a floater 10^6 voxels out
   does not). One anchor per occupied voxel, at the voxel's grid point, with K offset slots.
   **No Gaussian is dropped for lack of room**: each voxel first takes its K most important
   Gaussians (opacity x area); every other Gaussian takes a slot of the nearest voxel centre
   that still has one, occupied or empty (an empty one becomes a new anchor), the most
   important first where several want the last slots (``assign_to_voxels``). Its offset is
   then (mean - anchor) / voxel, more than half a voxel for these (donut: up to 2.2 voxels):
   offset scaling = voxel, so exp(offset scaling) x offset reproduces every mean exactly.
   Unused slots are masked dead (``offset_mask``). Base scaling = 1.25 x the largest scale of
   the anchor's Gaussians, so the covariance MLP's sigmoid can reach every one of them.
3. Initialization by distillation (no rendering): features and the three MLPs are fitted
   so that, for random view directions, each live offset reproduces its source Gaussian's
   opacity, scales, rotation and SH colour (Adam, ``distill_steps`` full-batch steps).
4. Render fitting (``RenderFit``): Adam on features, offsets, scalings and the MLP weights
   (anchor positions stay on the grid), loss (1 - l) L1 + l D-SSIM (l = 0.2, as 3DGS)
   between the anchor scene's render (render/neural_gaussians.py, differentiable) and the
   source render of a random training view, ``iterations`` steps. With a rate term
   (``rate_lambda`` > 0) it is LG-HCC's rate-distortion training, as lghcc-train
   --rate-lambda --prune naap runs it: after ``rate_from`` x ``iterations`` steps (the
   opacity each anchor showed in them ranks the anchors), NAAP prunes the anchors to
   ``prune_keep`` (pruned anchors merged into their nearest kept one; their Gaussians are
   removed by that decision and counted); from then on the scene renders with its
   attributes quantized at the encoder's steps (straight-through rounding) and the loss
   gains rate_lambda x the estimated bits per attribute value of the live attributes under
   the codec's hierarchy, per-channel prior (level 1) and GG-Conv twin (level 2)
   (encoder/anchors/rate_model.py), whose parameters are trained alongside. The twin is returned
   (``TranscodeResult.context_twin``) so that the encoder's GG-Conv fit can start from it.
   Progress (``progress``, app/progress.py): a bar per phase on a terminal, else a line with
   the time left at most every LGHCC_PROGRESS_INTERVAL seconds.

PSNR against the source renders on the held-out views is reported after 3 and after 4.
The source's SH degree is in the statistics (``sh_degree``): lghcc-enc writes it into the
stream (the ancillary source_info unit) and lghcc-dec --export writes the colours back at it.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

# ``python -m lghcc.encoder.anchors.transcode`` is an entry point: torch's OpenMP threads wait passively
# (set before torch is imported; as lghcc-enc and lghcc-train do; a user's own setting wins).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch import nn  # noqa: E402

from ...app.progress import progress_bar  # noqa: E402
from ...common.errors import InputError  # noqa: E402
from ...common.scene import AnchorScene  # noqa: E402
from ...render.camera import Camera  # noqa: E402
from ...render.gaussians3dgs import Gaussians3DGS, load_3dgs_ply, render_3dgs  # noqa: E402
from ...render.metrics import psnr, ssim_torch  # noqa: E402
from ...render.neural_gaussians import SceneTensors, TorchMLP, evaluate_anchors  # noqa: E402
from ...render.rasterizer import render_scene  # noqa: E402
from ...render.sh import sh_to_rgb  # noqa: E402
from ...render.views import fibonacci_sphere  # noqa: E402

if TYPE_CHECKING:
    from ..context.ggconv_train import ContextTwin


@dataclass
class TranscodeConfig:
    anchors: int | None = None  # target anchor count of the grid (default: kept Gaussians / 4)
    voxel_size: float | None = None  # overrides ``anchors``
    feature_dim: int = 32
    num_offsets: int = 10
    views: int = 32  # training views
    test_views: int = 6  # held-out views (PSNR report)
    resolution: int = 128  # square images
    fov_deg: float = 50.0
    min_opacity: float = 0.02  # source Gaussians below this are removed (counted), all others represented
    distill_steps: int = 400
    iterations: int = 200  # render-fitting steps
    lr_features: float = 0.0075
    lr_offsets: float = 0.002
    lr_scalings: float = 0.005
    lr_mlp: float = 0.004
    lambda_dssim: float = 0.2
    # Rate-distortion fitting (module doc, step 4): from iteration rate_from x iterations, the
    # anchors are pruned (prune) and, with rate_lambda > 0, the loss gains rate_lambda x the
    # estimated attribute bits per attribute value (lghcc-train --rate-lambda's term and scale)
    # with the attributes quantized at rate_steps (the encoder's feature, scaling and offset
    # steps: 0.02 is preset medium and lghcc-medium) under the hierarchy of coarse voxel scale
    # rate_voxel_scale and the GG-Conv twin of rate_k neighbours at rate_neighbour_level;
    # rate_voxel_scale None: a stream without the hierarchy (per-channel prior on every anchor).
    rate_lambda: float = 0.0
    rate_from: float = 0.25  # fraction of the fit iterations before pruning and the rate phase
    rate_steps: tuple = (0.02, 0.02, 0.02)
    rate_voxel_scale: int | None = 4
    rate_neighbour_level: int = 1
    rate_k: int = 8
    rate_lr: float = 0.002  # the rate model's own parameters
    prune: str | None = None  # none | naap | opacity; None: naap when rate_lambda > 0, else none
    prune_keep: float = 0.8  # fraction of the anchors kept
    naap_lambda: float = 0.5
    naap_gamma: float = 0.2
    seed: int = 0
    # progress of each phase (app/progress.py): a bar on a terminal, else a line with the time
    # left at most every LGHCC_PROGRESS_INTERVAL seconds
    progress: bool = False
    threads: int | None = None
    # where the fitting's rasterizer runs: cpu or cuda (gsplat; lghcc.render.rasterizer.select_device).
    # The held-out evaluation always renders on the CPU (evaluate_views), so reported PSNRs compare.
    device: str = "cpu"


def preset_transcode_config(preset: str, coding, **overrides) -> TranscodeConfig:
    """The transcoder's settings for lghcc-enc --mode anchors at ``preset`` (encoder/stream/config.py
    TRANSCODE_PRESETS; "lghcc-low" as "low"), with the rate model matching ``coding`` (the EncoderConfig the
    stream will be coded with): its feature, scaling and offset steps, and its hierarchy (coarse
    voxel scale, GG-Conv k and neighbour level) or none. ``overrides``: TranscodeConfig fields
    (None values ignored)."""
    from ..stream.config import TRANSCODE_PRESETS

    base = preset[len("lghcc-"):] if preset.startswith("lghcc-") else preset
    if base not in TRANSCODE_PRESETS:
        raise InputError(f"no transcoding settings for preset {preset!r} (known: {', '.join(TRANSCODE_PRESETS)})")
    level = coding.context_neighbour_level if coding.context_neighbour_level in (1, 2) else 1
    fields = {**TRANSCODE_PRESETS[base], "rate_steps": (coding.feature_step, coding.scaling_step, coding.offset_step),
              "rate_voxel_scale": coding.coarse_voxel_scale if coding.hierarchy else None,
              "rate_k": coding.context_k, "rate_neighbour_level": level}
    fields.update({k: v for k, v in overrides.items() if v is not None})
    if fields.get("prune") is None and fields["prune_keep"] >= 1:
        fields["prune"] = "none"
    return TranscodeConfig(**fields)


@dataclass
class TranscodeStats:
    """One transcode (module doc): what was done to the source, the fit's quality and timings."""
    gaussians: int  # of the source
    sh_degree: int  # of the source (lghcc-enc writes it into the stream's source_info unit)
    anchors: int  # of the transcoded scene
    voxel_size: float
    live_offsets: int
    anchors_before_pruning: int  # the voxels that received Gaussians (step 2)
    below_min_opacity: int  # source Gaussians removed (opacity < min_opacity)
    moved_gaussians: int  # Gaussians given a slot of a voxel other than their own
    new_anchors: int  # voxels without a Gaussian of their own that became anchors for them
    max_offset_voxels: float  # the largest offset, in voxels
    pruning: str | None  # the PruneReport of the fit's pruning (None: no pruning)
    pruned_gaussians: int  # Gaussians removed with their pruned anchors
    rate_lambda: float
    rate_bits_per_anchor: float | None  # estimated attribute bits per anchor at the end (None: no rate phase)
    views: int
    test_views: int
    resolution: int
    camera_distance: float
    psnr_init: float  # held-out PSNR against the source renders after distillation (NaN: no held-out views)
    psnr_final: float  # and after render fitting
    psnr_init_train: float  # the same on the first 4 training views
    psnr_final_train: float
    distill_loss: float | None  # the last distillation step's (None: no steps)
    fit_loss: list[float]  # every render-fitting step's
    time_render_source_s: float
    time_distill_s: float
    time_fit_s: float
    time_total_s: float

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class TranscodeResult:
    scene: AnchorScene
    stats: TranscodeStats
    # the GG-Conv twin trained in the rate phase, which the encoder's GG-Conv fit can start
    # from; None without a rate phase
    context_twin: ContextTwin | None = None


# --- views --------------------------------------------------------------------------------

def sphere_cameras(center: np.ndarray, radius: float, n: int, *, resolution: int = 128, fov_deg: float = 50.0,
                   offset: float = 0.5, prefix: str = "view") -> list[Camera]:
    """n cameras on a sphere around ``center`` looking at it; the sphere of ``radius``
    around the centre fills the field of view (distance radius / sin(fov / 2) x 1.05)."""
    dist = radius / math.sin(math.radians(fov_deg) / 2) * 1.05
    cams = []
    for j, d in enumerate(fibonacci_sphere(n, offset)):
        cams.append(Camera.look_at(center + dist * d, center, up=(0.0, 0.0, 1.0), width=resolution,
                                   height=resolution, fov_x_deg=fov_deg, near=dist * 1e-3, far=dist * 10,
                                   name=f"{prefix}_{j:03d}"))
    return cams


# --- anchors --------------------------------------------------------------------------------

def _occupied(points: np.ndarray, origin: np.ndarray, voxel: float) -> np.ndarray:
    return np.round((points - origin) / voxel).astype(np.int64)


def voxel_search_interval(points: np.ndarray) -> tuple[float, float]:
    """(lo, hi) of the voxel-size search (module doc, step 2), both from the data: at lo, half
    the smallest distance between two distinct points, every distinct point has a voxel of its
    own (a voxel's diagonal is lo sqrt(3) < that distance); at hi, four times the largest
    coordinate magnitude, every point rounds to voxel 0. Both scale with the scene, and no
    fixed ratio to the extent bounds the search (a floater far out does not)."""
    from scipy.spatial import cKDTree

    uniq = np.unique(points, axis=0)
    hi = 4.0 * float(np.abs(uniq).max())
    if uniq.shape[0] < 2:
        return (hi / 4 or 1.0), (hi or 1.0)
    d = cKDTree(uniq).query(uniq, k=2)[0][:, 1]
    return float(d.min()) / 2, max(hi, float(d.min()))


def voxel_size_for_count(points: np.ndarray, target: int) -> float:
    """Voxel size whose grid (through the world origin) has about ``target`` occupied voxels:
    bisection on log v within ``voxel_search_interval`` (module doc, step 2)."""
    origin = np.zeros(3)
    lo, hi = voxel_search_interval(points)
    if np.unique(_occupied(points, origin, lo), axis=0).shape[0] <= target:
        return lo  # every distinct point in a voxel of its own is still no more than the target
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        n = np.unique(_occupied(points, origin, mid), axis=0).shape[0]
        if n > target:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1.01:
            break
    return hi


def _cube_offsets(r: int) -> np.ndarray:
    """Integer vectors of [-r, r]^3, nearest to 0 first."""
    g = np.arange(-r, r + 1)
    d = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return d[np.argsort((d * d).sum(1), kind="stable")]


def _claim_slots(rows: np.ndarray, cid: np.ndarray, used: np.ndarray, importance: np.ndarray, k: int,
                 voxel_of: np.ndarray, slot_of: np.ndarray) -> None:
    """The points ``rows`` take free slots of their candidate voxels ``cid`` [m, c] (nearest
    first): each asks for its nearest voxel with a free slot, the most important first where
    more ask for a voxel than it has slots left; the others ask again. ``used`` (slots taken
    per voxel), ``voxel_of`` and ``slot_of`` are updated in place; a point whose candidates are
    all full keeps voxel -1 (it looks further)."""
    active = np.arange(rows.size)
    while active.size:
        free = used[cid[active]] < k  # [a, c]
        has = free.any(1)
        active, free = active[has], free[has]  # the others look further (next r)
        if not active.size:
            break
        want = cid[active, np.argmax(free, 1)]
        o = np.lexsort((-importance[rows[active]], want))  # per voxel, most important first
        want_s, act_s = want[o], active[o]
        rank = np.arange(want_s.size) - np.searchsorted(want_s, want_s, side="left")
        ok = rank < k - used[want_s]
        got = rows[act_s[ok]]
        voxel_of[got] = want_s[ok]
        slot_of[got] = used[want_s[ok]] + rank[ok]
        np.add.at(used, want_s[ok], 1)
        active = np.setdiff1d(active, act_s[ok], assume_unique=True)


def assign_to_voxels(points: np.ndarray, importance: np.ndarray, voxel: float, k: int,
                     max_radius: int = 1 << 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every point to a voxel slot (module doc, step 2). First each voxel takes its K most
    important points; every other point goes to the nearest voxel centre (occupied or empty)
    that still has a free slot, the most important first where more points ask for a voxel
    than it has slots left, the others trying their next nearest voxel. The search looks
    within r voxels of a point's own voxel for r = 1, 2, 4, ... until every point has a slot:
    no point is ever dropped for lack of room.

    Returns (coords [V, 3] of the voxels that received points, the voxel index [n] and the
    slot [n] of each point)."""
    n = points.shape[0]
    own = np.round(points / voxel).astype(np.int64)
    voxel_of = np.full(n, -1, np.int64)
    slot_of = np.full(n, -1, np.int64)
    table = np.zeros((0, 3), np.int64)  # every voxel looked at so far ...
    used = np.zeros(0, np.int64)  # ... and how many of its slots are taken
    todo = np.arange(n)
    r = 0
    while todo.size:
        if r > max_radius:
            raise InputError(f"transcode: {todo.size:,} Gaussians found no free voxel slot within {max_radius} "
                             "voxels")
        off = _cube_offsets(r)
        step = max(1, 4_000_000 // off.shape[0])  # bounded memory per pass
        for lo in range(0, todo.size, step):
            rows = todo[lo:lo + step]
            cand = own[rows][:, None, :] + off[None]  # [m, c, 3]
            old = table.shape[0]
            table, inv = np.unique(np.concatenate([table, cand.reshape(-1, 3)]), axis=0, return_inverse=True)
            inv = inv.reshape(-1)
            moved = inv[:old]  # old voxel index -> new one
            used_new = np.zeros(table.shape[0], np.int64)
            used_new[moved] = used
            used = used_new
            done = voxel_of >= 0
            voxel_of[done] = moved[voxel_of[done]]
            cid = inv[old:].reshape(cand.shape[:2])
            dist = ((points[rows][:, None, :] - cand * voxel) ** 2).sum(-1)
            cid = np.take_along_axis(cid, np.argsort(dist, axis=1, kind="stable"), 1)
            _claim_slots(rows, cid, used, importance, k, voxel_of, slot_of)
        todo = todo[voxel_of[todo] < 0]
        r = 1 if r == 0 else 2 * r
    keep = used > 0
    remap = np.cumsum(keep) - 1
    return table[keep], remap[voxel_of], slot_of


def anchorize(g: Gaussians3DGS, cfg: TranscodeConfig) -> dict:
    """Voxelize the source Gaussians and give each one an anchor's offset slot (module doc,
    step 2): below ``min_opacity`` removed (counted), every other one represented."""
    op = g.opacities.double().numpy()
    keep = np.nonzero(op >= cfg.min_opacity)[0]
    if keep.size == 0:
        raise InputError(f"{g.source}: no Gaussian has opacity >= {cfg.min_opacity}; nothing to transcode")
    pts = g.means.double().numpy()[keep]
    k = cfg.num_offsets
    if cfg.voxel_size is not None:
        if not (cfg.voxel_size > 0 and math.isfinite(cfg.voxel_size)):
            raise InputError(f"the voxel size must be a positive number, got {cfg.voxel_size}")
        voxel = float(cfg.voxel_size)
    else:
        target = cfg.anchors if cfg.anchors is not None else max(1, keep.size // 4)
        if target < 1:
            raise InputError(f"the anchor count must be positive, got {target}")
        voxel = voxel_size_for_count(pts, target)
    origin = np.zeros(3)  # the grid through the world origin: a written checkpoint's voxel size can be inferred
    sc = g.scales.double().numpy()[keep]
    importance = op[keep] * np.sort(sc, axis=1)[:, 1:].prod(1)  # opacity x area of the two largest axes
    coords, vi, slot = assign_to_voxels(pts, importance, voxel, k)
    slot_g = np.full((coords.shape[0], k), -1, np.int64)
    slot_g[vi, slot] = keep
    own = _occupied(pts, origin, voxel)
    moved = (coords[vi] != own).any(1)
    reach = np.abs(pts - coords[vi] * voxel).max(1) / voxel  # offset magnitude in voxels
    return {"coords": coords, "origin": origin.astype(np.float32), "voxel": voxel, "slot_gaussian": slot_g,
            "kept": int(keep.size), "moved": int(moved.sum()),
            "new_anchors": int(coords.shape[0] - np.unique(own, axis=0).shape[0]),
            "max_offset_voxels": float(reach.max()), "below_min_opacity": int(g.num_gaussians - keep.size)}


def _mlp(c_in: int, hidden: int, out: int, final: str, gen: torch.Generator) -> TorchMLP:
    l1, l2 = nn.Linear(c_in, hidden), nn.Linear(hidden, out)
    with torch.no_grad():  # PyTorch's default init, from our generator (reproducible)
        for lin in (l1, l2):
            bound = 1 / math.sqrt(lin.in_features)
            lin.weight.uniform_(-bound, bound, generator=gen)
            lin.bias.uniform_(-bound, bound, generator=gen)
    return TorchMLP([l1, l2], ["relu", final])


def initial_scene_tensors(g: Gaussians3DGS, a: dict, cfg: TranscodeConfig) -> SceneTensors:
    gen = torch.Generator().manual_seed(cfg.seed)
    n, k = a["slot_gaussian"].shape
    c = cfg.feature_dim
    slot = torch.as_tensor(a["slot_gaussian"])
    live = slot >= 0
    gi = slot.clamp_min(0)
    voxel = a["voxel"]
    pos32 = (torch.as_tensor(a["coords"], dtype=torch.float32) * np.float32(voxel)
             + torch.as_tensor(a["origin"], dtype=torch.float32))
    offsets = (g.means[gi].double() - pos32.double()[:, None, :]) / voxel
    offsets = torch.where(live[..., None], offsets, torch.zeros_like(offsets)).float()
    smax = torch.where(live, g.scales[gi].amax(-1), torch.zeros(n, k)).amax(1).clamp_min(voxel * 1e-4)
    scal = torch.cat([torch.full((n, 3), math.log(voxel)), torch.log(1.25 * smax)[:, None].repeat(1, 3)], 1)
    feats = 0.1 * torch.randn(n, c, generator=gen)
    mlps = {"opacity": _mlp(c + 4, c, k, "tanh", gen), "cov": _mlp(c + 4, c, 7 * k, "none", gen),
            "color": _mlp(c + 4, c, 3 * k, "sigmoid", gen)}
    p = lambda t: nn.Parameter(t.float().contiguous())  # noqa: E731
    return SceneTensors(pos32, p(feats), p(scal), p(offsets), mlps, live)


def distill(st: SceneTensors, g: Gaussians3DGS, a: dict, cfg: TranscodeConfig, cam_dist: float) -> list[float]:
    """Fit features and MLPs to the assigned source Gaussians' attributes (module doc, step 3)."""
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    slot = torch.as_tensor(a["slot_gaussian"])
    live = slot >= 0
    gi = slot.clamp_min(0)
    n, k = slot.shape
    t_op = g.opacities[gi].clamp(0, 0.999)
    base = torch.exp(st.scalings.detach()[:, 3:6])  # [n, 3]
    s_sorted = g.scales[gi]
    t_logsig = torch.log((s_sorted / base[:, None, :]).clamp(1e-6, 0.999))  # log sigmoid target
    t_quat = g.quats[gi]
    sh_t = g.sh[gi]  # [n, k, K, 3]
    means_t = g.means[gi]
    idx = torch.arange(n)
    params = [st.features] + [q for m in ("opacity", "cov", "color") for q in st.mlps[m].parameters()]
    opt = torch.optim.Adam(params, lr=0.01)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(cfg.distill_steps, 1), eta_min=1e-3)
    w = live.float()
    wsum = w.sum().clamp_min(1)
    losses = []
    bar = progress_bar(total=cfg.distill_steps, desc="transcode: distill", unit="step", disable=not cfg.progress,
                       leave=False)
    for _ in range(cfg.distill_steps):
        v = torch.randn(n, 3, generator=gen)
        v = v / torch.linalg.vector_norm(v, dim=1, keepdim=True)
        dist = torch.full((n, 1), cam_dist)
        op, cov, col = evaluate_anchors(st, idx, v, dist)
        l_op = ((op - t_op).abs() * w).sum() / wsum
        logsig = nn.functional.logsigmoid(cov[..., :3])
        l_sc = ((logsig - t_logsig).abs().mean(-1) * w).sum() / wsum
        q = nn.functional.normalize(cov[..., 3:7], dim=-1)
        l_rot = ((1 - (q * t_quat).sum(-1).abs()) * w).sum() / wsum
        cam = st.positions.detach()[:, None, :] - cam_dist * v[:, None, :]
        d = means_t - cam
        d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True).clamp_min(1e-12)
        t_col = sh_to_rgb(g.sh_degree, sh_t, d).clamp(0, 1)
        l_col = ((col - t_col).abs().mean(-1) * w).sum() / wsum
        loss = l_op + l_sc + l_rot + 2 * l_col
        _optimizer_step(opt, sched, loss, losses)
        bar.set_postfix(loss=f"{losses[-1]:.4f}", refresh=False)
        bar.update(1)
    bar.close()
    return losses


def _optimizer_step(opt, sched, loss: torch.Tensor, losses: list) -> None:
    """One Adam step with its schedule; the loss is logged."""
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    sched.step()
    losses.append(float(loss.detach()))


def _to_scene(st: SceneTensors, coords: np.ndarray, a: dict) -> AnchorScene:
    return AnchorScene(
        coords=coords.astype(np.int64), voxel_size=float(a["voxel"]), origin=a["origin"],
        features=st.features.detach().float().numpy().copy(), scalings=st.scalings.detach().float().numpy().copy(),
        offsets=st.offsets.detach().float().numpy().copy(),
        offset_mask=st.offset_mask.numpy().copy() if st.offset_mask is not None else None,
        mlps={r: st.mlps[r].to_render_mlp() for r in ("opacity", "cov", "color")}).validate()


@torch.no_grad()
def evaluate_views(scene, cams: list[Camera], targets: list[torch.Tensor]) -> float:
    """Mean PSNR of the anchor scene's renders against ``targets`` over ``cams``."""
    # the CPU reference renderer throughout the transcoder: results do not depend on the machine
    vals = [psnr(render_scene(scene, cam, backend="torch").image.clamp(0, 1).numpy(), t.numpy())
            for cam, t in zip(cams, targets)]
    return float(np.mean(vals))


class RenderFit:
    """Step 4 of the module doc: Adam on features, offsets, scalings and the MLPs against the
    source renders; at ``rate_iteration`` the anchors are pruned (``prune``) and, with
    ``rate_lambda`` > 0, the rate phase starts: the scene renders with its attributes quantized
    as the encoder will quantize them (straight-through rounding) and the loss gains
    rate_lambda x the estimated attribute bits per attribute value (encoder/anchors/rate_model.py, the
    model lghcc-train --rate-lambda trains with)."""

    def __init__(self, st: SceneTensors, a: dict, cfg: TranscodeConfig, backend: str):
        from ...render.rasterizer import rasterize_with

        self.st, self.cfg = st, cfg
        self.coords = a["coords"].copy()
        self.slot_gaussian = a["slot_gaussian"].copy()
        self.rasterize = rasterize_with(backend)
        self.gen = torch.Generator().manual_seed(cfg.seed + 2)
        n = st.num_anchors
        self.life_opacity = torch.zeros(n, dtype=torch.float64)  # what NAAP ranks anchors by, as lghcc-train
        self.life_views = torch.zeros(n, dtype=torch.float64)
        self.rate_model = self.rate_opt = None
        self.rate_bits = None  # the last estimate, bits per anchor
        self.prune_report, self.pruned_gaussians = None, 0
        groups = [{"params": [st.features], "lr": cfg.lr_features}, {"params": [st.offsets], "lr": cfg.lr_offsets},
                  {"params": [st.scalings], "lr": cfg.lr_scalings},
                  {"params": [q for r in ("opacity", "cov", "color") for q in st.mlps[r].parameters()],
                   "lr": cfg.lr_mlp}]
        self.opt = torch.optim.Adam(groups, eps=1e-15)
        self.sched = torch.optim.lr_scheduler.CosineAnnealingLR(self.opt, max(cfg.iterations, 1), eta_min=0.0)
        fs, ss, os_ = (float(x) for x in cfg.rate_steps)
        k = st.num_offsets
        self.steps = torch.tensor([fs] * st.features.shape[1] + [ss] * 6 + [os_] * (3 * k), dtype=torch.float64)

    # the attributes in the codec's channel layout: features, 6 scalings, offsets k-major
    def attribute_values(self) -> torch.Tensor:
        st = self.st
        return torch.cat([st.features, st.scalings, st.offsets.reshape(st.num_anchors, -1)], 1)

    def live_channels(self) -> torch.Tensor:
        st = self.st
        return torch.cat([torch.ones(st.num_anchors, st.features.shape[1] + 6, dtype=torch.bool),
                          st.offset_mask.repeat_interleave(3, dim=1)], 1)

    def scene_tensors(self) -> SceneTensors:
        """The scene as it renders: in the rate phase, with its attributes quantized."""
        st = self.st
        if self.rate_model is None:
            return st
        from .rate_model import quantize_ste

        c, n = st.features.shape[1], st.num_anchors
        f = quantize_ste(st.features, self.steps[:c])
        s = quantize_ste(st.scalings, self.steps[c:c + 6])
        o = quantize_ste(st.offsets.reshape(n, -1), self.steps[c + 6:]).reshape(st.offsets.shape)
        return SceneTensors(st.positions, f, s, o, dict(st.mlps), st.offset_mask)

    def step(self, cam: Camera, target: torch.Tensor, losses: list) -> None:
        from ...render.neural_gaussians import generate_neural_gaussians

        cfg = self.cfg
        ng = generate_neural_gaussians(self.scene_tensors(), cam)
        if ng.num_gaussians == 0:  # nothing in view: no parameter is reached; the schedule moves on
            self.sched.step()
            losses.append(float("nan"))
            return
        img = self.rasterize(ng.means, ng.quats, ng.scales, ng.opacities, ng.colors, cam).image
        l1 = (img - target).abs().mean()
        loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1 - ssim_torch(img, target))
        if self.rate_model is not None:
            n = self.st.num_anchors
            bits = self.rate_model(self.attribute_values(), generator=self.gen, live=self.live_channels())["total"]
            self.rate_bits = float(bits.detach()) / n
            loss = loss + cfg.rate_lambda * bits.float() / (n * self.rate_model.num_attrs)
        _optimizer_step(self.opt, self.sched, loss, losses)
        if self.rate_opt is not None:
            self.rate_opt.step()
            self.rate_opt.zero_grad(set_to_none=True)
        with torch.no_grad():  # as lghcc-train: opacity per anchor and view, over its K offsets
            self.life_opacity.index_add_(0, ng.anchor_index, ng.opacities.detach().double().clamp_min(0) / self.st.num_offsets)
            self.life_views[torch.unique(ng.anchor_index)] += 1

    def _swap(self, name: str, value: torch.Tensor, keep: torch.Tensor) -> None:
        """Replace parameter ``name`` of the scene by ``value`` (the kept anchors' rows); its Adam
        state carries over for the kept rows."""
        old = getattr(self.st, name)
        new = nn.Parameter(value.float().contiguous())
        for g in self.opt.param_groups:
            g["params"] = [new if p is old else p for p in g["params"]]
        state = self.opt.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                state[key] = state[key][keep].contiguous()
            self.opt.state[new] = state
        setattr(self.st, name, new)

    @torch.no_grad()
    def prune(self) -> None:
        """NAAP (or opacity pruning) of the anchors by the opacity they showed in the views so far,
        as lghcc-train --prune does once its anchors are grown; NAAP merges the offsets and
        scalings of every pruned anchor into its nearest kept one (eq. 11; a dead offset slot of
        a pruned anchor leaves the kept one's slot as it is). The Gaussians of pruned anchors
        are removed: a rate-distortion decision, counted in the statistics."""
        from .naap import NaapConfig, naap_plan, opacity_plan

        cfg, st = self.cfg, self.st
        acc = (self.life_opacity / self.life_views.clamp_min(1)).numpy()
        if cfg.prune == "naap":
            plan = naap_plan(self.coords, acc, NaapConfig(keep_ratio=cfg.prune_keep, lam=cfg.naap_lambda,
                                                          gamma=cfg.naap_gamma))
        else:
            plan = opacity_plan(acc, keep_ratio=cfg.prune_keep)
        keep_np = plan.keep
        keep = torch.from_numpy(keep_np)
        mask = st.offset_mask.numpy()
        offsets = st.offsets.detach().numpy().copy()
        if plan.targets is not None and plan.targets.size:
            gone = np.nonzero(~keep_np)[0]
            into = np.nonzero(keep_np)[0][plan.targets]
            offsets[gone] = np.where(mask[gone][..., None], offsets[gone], offsets[into])
        offsets = plan.merge(offsets, cfg.naap_gamma)
        scalings = plan.merge(st.scalings.detach().numpy(), cfg.naap_gamma)
        self.pruned_gaussians += int(mask[~keep_np].sum())
        self._swap("features", st.features.detach()[keep], keep)
        self._swap("scalings", torch.from_numpy(scalings), keep)
        self._swap("offsets", torch.from_numpy(offsets), keep)
        st.positions = st.positions[keep]
        st.offset_mask = st.offset_mask[keep]
        self.coords = self.coords[keep_np]
        self.slot_gaussian = self.slot_gaussian[keep_np]
        self.life_opacity, self.life_views = self.life_opacity[keep], self.life_views[keep]
        self.prune_report = str(plan.report())

    def start_rate_phase(self) -> None:
        """The rate model of the (final) anchor set, with the GG-Conv twin of the size the encoder
        will fit for this many level-2 anchors, as lghcc-train builds it."""
        from ...common.geometry import normative_order
        from ...common.hierarchy import build_hierarchy
        from ..stream.config import EncoderConfig, context_model_size
        from ..context.ggconv_train import GGConvTrainConfig
        from .rate_model import AnchorRateModel

        cfg = self.cfg
        twin = None
        if cfg.rate_voxel_scale is not None:
            n2 = build_hierarchy(self.coords[normative_order(self.coords)], cfg.rate_voxel_scale).num_level2
            ch, feat_hidden, head_hidden = context_model_size(EncoderConfig(), n2)[:3]
            twin = GGConvTrainConfig(k=cfg.rate_k, neighbour_level=cfg.rate_neighbour_level, ctx_channels=ch,
                                     feat_hidden=feat_hidden, head_hidden=head_hidden, seed=cfg.seed)
        self.rate_model = AnchorRateModel(self.coords, self.steps.numpy(), self.st.features.shape[1],
                                          cfg.rate_voxel_scale, self.attribute_values().detach().numpy(), twin)
        self.rate_opt = torch.optim.Adam(self.rate_model.parameters(), lr=cfg.rate_lr)

    @torch.no_grad()
    def rate_estimate(self) -> float | None:
        """Estimated attribute bits per anchor of the rounded attributes (no noise); None before
        the rate phase."""
        if self.rate_model is None:
            return None
        bits = self.rate_model(self.attribute_values(), noise=False, live=self.live_channels())["total"]
        return float(bits) / self.st.num_anchors


def check_transcode_config(cfg: TranscodeConfig) -> None:
    """InputError for counts, sizes and fit settings the transcoder cannot work with."""
    if cfg.num_offsets < 1 or cfg.feature_dim < 1 or cfg.views < 1 or cfg.resolution < 8:
        raise InputError("transcode: need at least 1 offset, 1 feature, 1 view and 8x8 pixels")
    if cfg.iterations < 0 or cfg.distill_steps < 0 or cfg.test_views < 0:
        raise InputError("transcode: iteration, step and view counts cannot be negative")
    check_rate_config(cfg)


def check_rate_config(cfg: TranscodeConfig) -> None:
    """InputError for rate-distortion settings (module doc, step 4) out of their range."""
    if not (cfg.rate_lambda >= 0 and math.isfinite(cfg.rate_lambda)):
        raise InputError(f"transcode: the rate lambda must be a non-negative number, got {cfg.rate_lambda}")
    if cfg.prune not in (None, "none", "naap", "opacity"):
        raise InputError(f"transcode: prune must be none, naap or opacity, got {cfg.prune!r}")
    if not 0 < cfg.prune_keep <= 1:
        raise InputError(f"transcode: prune-keep must be in (0, 1], got {cfg.prune_keep}")
    if not 0 <= cfg.rate_from < 1:
        raise InputError(f"transcode: rate-from is a fraction of the fit iterations in [0, 1), got {cfg.rate_from}")
    steps = list(cfg.rate_steps)
    if len(steps) != 3 or not all(isinstance(x, (int, float)) and x > 0 and math.isfinite(x) for x in steps):
        raise InputError(f"transcode: rate steps are 3 positive numbers (feature, scaling, offset), got {steps}")
    if (cfg.rate_voxel_scale is not None and cfg.rate_voxel_scale < 2) or cfg.rate_neighbour_level not in (1, 2) \
            or cfg.rate_k < 1:
        raise InputError("transcode: rate voxel scale must be >= 2, the neighbour level 1 or 2 and k >= 1")


@dataclass
class TranscodeViews:
    """The training and held-out cameras and the source rendered into them."""
    train: list[Camera]
    test: list[Camera]
    camera_distance: float
    train_targets: list[torch.Tensor]
    test_targets: list[torch.Tensor]


def render_source_views(g: Gaussians3DGS, cfg: TranscodeConfig, backend: str) -> TranscodeViews:
    """Step 1 of the module doc: the cameras, and the source rendered into them."""
    center, radius = g.bounds()
    train = sphere_cameras(center, radius, cfg.views, resolution=cfg.resolution, fov_deg=cfg.fov_deg, prefix="train")
    test = sphere_cameras(center, radius, cfg.test_views, resolution=cfg.resolution, fov_deg=cfg.fov_deg,
                          offset=0.25, prefix="test") if cfg.test_views else []
    cam_dist = float(np.linalg.norm(train[0].center - center))
    with torch.no_grad():
        bar = progress_bar(train + test, desc="transcode: render source", unit="view", disable=not cfg.progress,
                           leave=False)
        targets = [render_3dgs(g, cam, backend=backend).image.clamp(0, 1) for cam in bar]
    return TranscodeViews(train, test, cam_dist, targets[:len(train)], targets[len(train):])


def held_out_psnr(scene, views: TranscodeViews) -> tuple[float, float]:
    """(PSNR on the held-out views (NaN: none), on the first 4 training views)."""
    held_out = evaluate_views(scene, views.test, views.test_targets) if views.test else float("nan")
    return held_out, evaluate_views(scene, views.train[:4], views.train_targets[:4])


def fit_to_source_renders(fit: RenderFit, views: TranscodeViews, cfg: TranscodeConfig, say) -> list[float]:
    """Step 4 of the module doc: ``iterations`` steps on random training views; at the first
    iteration of the rate phase the anchors are pruned and the rate term switched on ->
    the loss of every step."""
    rate_it = int(round(cfg.rate_from * cfg.iterations))  # the first iteration of the rate phase
    rng = np.random.default_rng(cfg.seed)
    losses: list[float] = []
    bar = progress_bar(total=cfg.iterations, desc="transcode: fit", unit="it", disable=not cfg.progress, leave=False)
    for it in range(cfg.iterations):
        if it == rate_it:
            if cfg.prune != "none":
                fit.prune()
                say(f"transcode: pruned after {it} iterations: {fit.prune_report}, {fit.pruned_gaussians:,} "
                    "Gaussians removed with their anchors")
            if cfg.rate_lambda > 0:
                fit.start_rate_phase()
        j = int(rng.integers(len(views.train)))
        fit.step(views.train[j], views.train_targets[j], losses)
        info = {"loss": f"{losses[-1]:.4f}"}
        if fit.rate_bits is not None:
            info["bits/anchor"] = f"{fit.rate_bits:.0f}"
        bar.set_postfix(info, refresh=False)
        bar.update(1)
    bar.close()
    return losses


def _say_anchorized(say, g: Gaussians3DGS, a: dict, cfg: TranscodeConfig) -> None:
    say(f"transcode: {g.num_gaussians:,} Gaussians (SH degree {g.sh_degree}) -> {len(a['coords']):,} anchors, "
        f"voxel {a['voxel']:.4g}, K={cfg.num_offsets}: every Gaussian with opacity >= {cfg.min_opacity} has a slot "
        f"({a['moved']:,} in a voxel next to their own, {a['new_anchors']:,} anchors created for them, offsets up to "
        f"{a['max_offset_voxels']:.2f} voxels); {a['below_min_opacity']:,} below that opacity removed")


def transcode_3dgs(source: str | Gaussians3DGS, cfg: TranscodeConfig | None = None, log=None) -> TranscodeResult:
    """A plain 3DGS scene (a PLY path or loaded Gaussians) -> an AnchorScene (module doc)."""
    from ...render.rasterizer import select_device

    cfg = cfg or TranscodeConfig()
    say = log or (lambda *a: None)
    check_transcode_config(cfg)
    if cfg.prune is None:
        cfg = dataclasses.replace(cfg, prune="naap" if cfg.rate_lambda > 0 else "none")
    backend = select_device(cfg.device)  # 'no CUDA device: ...' before any work
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    t0 = time.perf_counter()
    g = load_3dgs_ply(source) if not isinstance(source, Gaussians3DGS) else source
    views = render_source_views(g, cfg, backend)
    t_render = time.perf_counter() - t0
    a = anchorize(g, cfg)
    _say_anchorized(say, g, a, cfg)
    st = initial_scene_tensors(g, a, cfg)
    t1 = time.perf_counter()
    distill_losses = distill(st, g, a, cfg, views.camera_distance)
    t_distill = time.perf_counter() - t1
    psnr_init, psnr_init_train = held_out_psnr(st, views)
    say(f"transcode: after distillation ({cfg.distill_steps} steps, {t_distill:.1f} s): held-out PSNR {psnr_init:.2f} dB")
    t2 = time.perf_counter()
    fit = RenderFit(st, a, cfg, backend)
    losses = fit_to_source_renders(fit, views, cfg, say)
    t_fit = time.perf_counter() - t2
    scene = _to_scene(st, fit.coords, a)
    psnr_final, psnr_final_train = held_out_psnr(scene, views)
    rate = fit.rate_estimate()
    say(f"transcode: after render fitting ({cfg.iterations} iterations, {t_fit:.1f} s): "
        f"held-out PSNR {psnr_final:.2f} dB" + ("" if rate is None else f", ~{rate:.0f} attribute bits per anchor"))
    stats = TranscodeStats(
        gaussians=g.num_gaussians, sh_degree=g.sh_degree, anchors=scene.num_anchors, voxel_size=scene.voxel_size,
        live_offsets=int(scene.offset_mask.sum()), anchors_before_pruning=len(a["coords"]),
        below_min_opacity=a["below_min_opacity"], moved_gaussians=a["moved"], new_anchors=a["new_anchors"],
        max_offset_voxels=a["max_offset_voxels"], pruning=fit.prune_report, pruned_gaussians=fit.pruned_gaussians,
        rate_lambda=cfg.rate_lambda, rate_bits_per_anchor=rate, views=len(views.train), test_views=len(views.test),
        resolution=cfg.resolution, camera_distance=views.camera_distance, psnr_init=psnr_init, psnr_final=psnr_final,
        psnr_init_train=psnr_init_train, psnr_final_train=psnr_final_train,
        distill_loss=distill_losses[-1] if distill_losses else None, fit_loss=losses, time_render_source_s=t_render,
        time_distill_s=t_distill, time_fit_s=t_fit, time_total_s=time.perf_counter() - t0)
    twin = fit.rate_model.context_twin() if fit.rate_model is not None else None
    return TranscodeResult(scene, stats, twin)


_CLI_FIELDS = {"anchors": int, "voxel_size": float, "feature_dim": int, "num_offsets": int, "views": int,
               "test_views": int, "resolution": int, "distill_steps": int, "iterations": int, "rate_lambda": float,
               "rate_from": float, "prune_keep": float, "seed": int, "threads": int}


def _arguments():
    import argparse

    d = TranscodeConfig()
    p = argparse.ArgumentParser(prog="python -m lghcc.encoder.anchors.transcode", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help="plain 3DGS PLY (INRIA layout)")
    p.add_argument("-o", "--output", help="Scaffold-GS model folder to write (with context_twin.pt after a rate "
                                          "phase, which lghcc-enc's GG-Conv fit starts from)")
    p.add_argument("--json", help="write the statistics as JSON")
    for name, typ in _CLI_FIELDS.items():
        default = getattr(d, name)
        p.add_argument("--" + name.replace("_", "-"), type=typ, default=default, help=f"default {default}")
    p.add_argument("--prune", choices=("none", "naap", "opacity"),
                   help="anchor pruning before the rate phase (default: naap with --rate-lambda > 0, else none)")
    p.add_argument("--rate-step", type=float, default=d.rate_steps[0],
                   help=f"the encoder's feature, scaling and offset step (default {d.rate_steps[0]}: preset medium)")
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m lghcc.encoder.anchors.transcode SCENE.ply -o MODEL_DIR``: transcode and write the
    Scaffold-GS layout (and the statistics as JSON)."""
    import json
    import sys

    from ...common.errors import LghccError
    from ...formats.scaffold_io import locate_ply, write_scaffold
    from ..context.ggconv_train import TWIN_FILE

    args = _arguments().parse_args(argv)
    cfg = TranscodeConfig(**{k: getattr(args, k) for k in _CLI_FIELDS}, prune=args.prune,
                          rate_steps=(args.rate_step,) * 3, progress=True)
    try:
        res = transcode_3dgs(args.input, cfg, log=lambda *a: print(*a, flush=True))
        if args.output:
            write_scaffold(res.scene, args.output)
            if res.context_twin is not None:
                res.context_twin.save(locate_ply(args.output).parent / TWIN_FILE)
    except LghccError as e:
        print(f"transcode: error: {e}", file=sys.stderr)
        return 1
    st = {k: v for k, v in res.stats.to_json().items() if k != "fit_loss"}
    print(json.dumps(st, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({**st, "config": {k: getattr(cfg, k) for k in vars(cfg)}, "fit_loss": res.stats.fit_loss},
                      f, indent=1)
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
