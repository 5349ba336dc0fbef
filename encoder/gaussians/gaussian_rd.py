"""Rate-distortion choice of an explicit-Gaussian scene's coding settings (informative).

The settings (pruning share, position grid step, the quantization step of each attribute
group, the SH degree) trade bits for fidelity differently on every scene: a blurry scene
hides coarse colours, a scene of thin flat Gaussians needs fine rotations. The encoder
measures instead of guessing. It minimizes

    J = 10 log10(D) + lambda * log2(R)

over the settings, with D the mean squared error of renders of the quantized scene against
renders of the source (the ``search_view_plan`` fit cameras: more and larger on a small scene) and
R the bits the stream spends (geometry coded for real; attributes as ideal code lengths under
the per-channel prior, which the coder reaches within 0.01%, or under neighbour prediction where
that is smaller; the values chosen by rate-distortion optimized quantization, encoder/gaussians/rdoq.py,
when the sensitivities are given, as the coder will choose them). So ``lambda`` is in dB per
doubling of the stream: the search stops where twice the bytes would buy less than lambda dB
of PSNR. Measured in relative rate, the same lambda lands at a like point of every scene's
rate-distortion curve, whatever its Gaussian count and SH degree.
The search: one probe per attribute group measures what doubling its step costs in D and
saves in R; a high-rate model gives every group's step for lambda; every share of a ladder of
pruning shares (with no target) and a check of each step a factor sqrt(2) either way follow.

A fixed lambda lands at a like slope of every scene's curve, not at a like quality: on a small
scene whose curve is shallow (playbot, 8k Gaussians: ~8 dB per doubling) lambda 10 went down to
28 dB. So the presets give a quality instead (``target_psnr``, dB on the search views): lambda is
the one the model says reaches it, and after the search, every pruning share of the ladder is
moved onto the target by one common factor on every step (``common_factor_move``: a secant in
log steps with the measured exponent of error ~ f^k, against real renders); the fewest bits
measured that reach it are kept.
"""

from __future__ import annotations

import dataclasses
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from ...common import attributes as attr
from ...common.attributes import STEP_ADJUST_FACTORS, GaussianLayout, implied_w
from ...common.entropy.symbol_coder import best_level, code_lengths_bits
from ...common.geometry import encode_geometry, normative_order
from ...common.neighbour_prediction import neighbour_graph
from ...common.scene import GaussianScene
from ..stream.config import GaussianEncoderConfig
from .gaussian_grid import choose_grid, coded_values, snap_to_grid
from .gaussian_views import ORBIT, SceneViews
from .merging import pruned_scene
from . import sh_transform as sht
from ..stream.neighbour_coding import NeighbourCoding, usable as neighbour_usable
from .rdoq import (adjust_on_graph, channel_groups, channel_steps, degrees_on_graph, group_slopes, orientation_columns,
                   rd_quantize, sh_degree_subset, sh_degrees_wanted, without_dropped_bands)
from ...render.gaussians3dgs import Gaussians3DGS, gaussians_from_scene
from ...render.rasterizer import rasterize
from ...render.view_threads import map_views

# Pruning shares tried: of the total on an orbit, the most any one view may lose from inside and
# from a capture's cameras (gaussian_fit.py pruning_key). A Gaussian's largest share of one view is
# several times its share of all views together (the donut's sum of them is about 3), so the ladder
# goes to 25.6%: up to 6.4% of any view the search stopped at its top on the donut at low and high.
# On the orbit the search chose no share above 6.4% on the donut and playbot lod4 at any preset
# (tools/results/views.md (c)): there the two new shares cost trials and bought nothing measured
PRUNE_LADDER = (0.0, 0.0005, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032, 0.064, 0.128, 0.256)
STEP_FIELDS = ("position_step", "sh_dc_step", "opacity_step", "scale_step", "rotation_step")


@dataclass
class Trial:
    cfg: GaussianEncoderConfig
    mse: float
    bits: float
    cost: float


def search_view_plan(cfg: GaussianEncoderConfig, num_gaussians: int) -> tuple[int, int]:
    """(views, resolution) of the search on a scene of ``num_gaussians`` (config.py,
    search_reference_gaussians): s = reference / N times the pixels of ``search_views`` x
    ``search_resolution``^2, 1 <= s <= search_max_scale; sqrt(s) (at most 2) times the views, the
    rest as resolution. On donut (46k Gaussians, high) 16 views at 256 px instead of 8 at 128 gave
    0.48 x SPZ's bytes at equal PSNR on the orbit instead of 0.53, for 1.5 x the encode time; with
    the plan, four real scenes need 1.7-5.7% fewer bytes at equal orbit PSNR (tools/results/rdoq.md)."""
    if cfg.search_reference_gaussians <= 0 or num_gaussians <= 0:
        return cfg.search_views, cfg.search_resolution
    s = min(max(cfg.search_reference_gaussians / num_gaussians, 1.0), cfg.search_max_scale)
    views = math.floor(cfg.search_views * min(math.sqrt(s), 2.0) + 0.5)
    return views, math.floor(cfg.search_resolution * math.sqrt(s * cfg.search_views / views) + 0.5)


class SceneRenders:
    """A scene's search views (``views``, gaussian_views.py) and its renders on black in them, made
    once per view plan (views, resolution, resolve_px) and shared by whoever measures against them: on
    a sampled search the ratio and the search's offsets measure against the source's (the pair
    rendered them twice); the whole-scene check, or the trim without a sample, against the fitted
    scene's; the landing against the source's, in the landing's views (gaussian_fit.py)."""

    def __init__(self, scene: GaussianScene, views: SceneViews = ORBIT):
        self.scene, self.views = scene, views
        self._cams: dict[tuple, list] = {}
        self._images: dict[tuple, list[torch.Tensor]] = {}

    def cams(self, plan: tuple[int, int, float]) -> list:
        if plan not in self._cams:
            self._cams[plan] = self.views.cameras(self.scene, *plan)
        return self._cams[plan]

    def images(self, plan: tuple[int, int, float]) -> list[torch.Tensor]:
        if plan not in self._images:
            self._images[plan] = whole_scene_renders(self.scene, self.cams(plan))
        return self._images[plan]


@dataclass
class Backdrop:
    """A search on a sample (encoder/gaussians/search_sample.py): the whole scene and which of its Gaussians
    the sample is. The search's views are the whole scene's, and every error is the sample's in
    the whole scene, the other Gaussians held at their values (``ViewLayers``): cells cut closed
    surfaces open, and the sample alone would show what the whole scene hides (and hide nothing it
    shows). ``renders``: the whole scene's (made here when not given)."""
    whole: GaussianScene
    members: np.ndarray  # bool [N]
    renders: SceneRenders | None = None

    def __post_init__(self):
        if self.renders is None:
            self.renders = SceneRenders(self.whole)

    @property
    def held(self) -> GaussianScene:
        """The Gaussians of the whole scene that are not in the sample."""
        return self.whole.subset(~self.members)


def with_held(part: GaussianScene, backdrop: Backdrop) -> GaussianScene:
    """The whole scene with ``part`` (a trial's sample) in the place of the sample."""
    held = backdrop.held
    return GaussianScene(*(np.concatenate([getattr(part, f), getattr(held, f)])
                           for f in ("means", "sh", "opacity", "log_scales", "rotations")))


def whole_scene_renders(scene: GaussianScene, cams: list) -> list[torch.Tensor]:
    """The images of ``scene`` in ``cams`` on black."""
    g = gaussians_from_scene(scene)
    with torch.no_grad():
        return list(map_views(lambda cam: render_on_black(g, cam).image, cams))


def whole_scene_error(backdrop: Backdrop, part: GaussianScene, cams: list,
                      targets: list[torch.Tensor] | None = None) -> float:
    """The squared error, mean over ``cams``, of the whole scene with ``part`` in the place of the
    sample against the whole scene (``targets``: its renders, made here when not given)."""
    targets = whole_scene_renders(backdrop.whole, cams) if targets is None else targets
    trial = whole_scene_renders(with_held(part, backdrop), cams)
    return float(np.mean([((a - b) ** 2).double().mean().item() for a, b in zip(trial, targets)]))


def plainly_rounded(scene: GaussianScene, contrib: np.ndarray, cfg: GaussianEncoderConfig) -> GaussianScene:
    """``scene`` on its grid at ``cfg``'s position step, every value rounded at ``cfg``'s steps (no
    pruning, no RDOQ or step adjustment, no bits counted): a trial's distortion at a fraction of
    its cost, for comparing two scenes."""
    voxel, origin = choose_grid(scene, GaussianEncoderConfig(position_step=cfg.position_step), contrib)
    grid, _ = snap_to_grid(scene, voxel, origin, contrib)
    layout = GaussianLayout(scene.sh_degree)
    steps = channel_steps(cfg, scene.sh_degree)
    return GaussianScene(grid.means, *layout.split((np.rint(coded_values(scene).astype(np.float64) / steps) * steps)
                                                   .astype(np.float32)))


@dataclass
class ViewLayers:
    """One view of a sample in its whole scene, made once: the held Gaussians split at the sample's
    depth into a front layer (its transmittance TF) and a back layer (its colour B on black). Held
    front, sample, held back composite to CF + TF (S + (1 - A) B) (S: the sample's colour on black,
    A: its alpha), so a trial's error in the whole scene is TF ((S - S0) + (A0 - A) B), from a
    render of the sample alone: a trial costs what the sample alone costs, whatever the scene
    holds. Exact where each held Gaussian lies wholly in front of or behind the sample in the view;
    a held Gaussian goes by the sample's depth at its centre pixel (in front where the sample is
    not). On real scenes they miss a part of the error where sample and held Gaussians interleave
    in depth (cut cells): the search adds what they missed on the first trial of each pruning
    share (``SettingsSearch._mse``); the whole-to-sample ratio is measured on whole-scene renders
    (``sample_distortion_ratio``)."""
    sample0: torch.Tensor  # [H, W, 3] the source sample's colour on black
    alpha0: torch.Tensor  # [H, W] its alpha
    front_t: torch.Tensor  # [H, W, 1] TF
    back: torch.Tensor  # [H, W, 3] B

    def error(self, trial) -> torch.Tensor:
        """[H, W, 3]: the whole scene's picture with the trial's sample (a RenderResult of the sample
        alone on black) minus the source's."""
        return self.front_t * ((trial.image - self.sample0) + (self.alpha0 - trial.alpha)[..., None] * self.back)


# Sample alpha below which a pixel has no sample depth (``view_layers``).
LAYER_ALPHA_MIN = 1e-3


def render_on_black(g: Gaussians3DGS, cam, depth: bool = False):
    """The RenderResult of ``g`` in view ``cam`` on black (the search's renders)."""
    return rasterize(g.means, g.quats, g.scales, g.opacities, g.colors(cam.center), cam, background=torch.zeros(3),
                     render_depth=depth)


def _subset(g: Gaussians3DGS, rows: torch.Tensor) -> Gaussians3DGS:
    return dataclasses.replace(g, means=g.means[rows], quats=g.quats[rows], scales=g.scales[rows],
                               opacities=g.opacities[rows], sh=g.sh[rows])


def front_of_sample(sample_depth: np.ndarray, held: Gaussians3DGS, cam) -> np.ndarray:
    """bool [M]: the held Gaussians in front of the sample in view ``cam``: nearer than the sample's
    depth (``sample_depth`` [H, W], inf where the sample is not) at their centre pixel; a centre off
    the image counts as in front."""
    uv, z = cam.project(held.means.double().numpy())
    with np.errstate(invalid="ignore"):
        px = np.floor(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)).astype(np.int64)
    on = (z > cam.near) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    d = np.full(z.shape, np.inf)
    d[on] = sample_depth[px[on, 1], px[on, 0]]
    return ~(z >= d)


def view_layers(sample: Gaussians3DGS, held: Gaussians3DGS, rows: torch.Tensor, cam) -> ViewLayers:
    """The ``ViewLayers`` of view ``cam``: the source sample and the held Gaussians ``rows`` (those in
    its footprint, ``held_in_footprint``; the others change no error)."""
    r0 = render_on_black(sample, cam, depth=True)
    a0 = r0.alpha.double()
    depth = torch.where(a0 > LAYER_ALPHA_MIN, r0.depth.double() / a0.clamp_min(1e-30), torch.tensor(math.inf))
    h = _subset(held, rows)
    front = torch.from_numpy(front_of_sample(depth.numpy(), h, cam))
    f, b = (render_on_black(_subset(h, m), cam) for m in (front, ~front))
    return ViewLayers(r0.image, r0.alpha, (1 - f.alpha)[..., None], b.image)


# Tiles (px a side) of the footprint test of the held Gaussians (``held_in_footprint``), and the
# margin (tiles) a trial's Gaussians may grow into: quantized scales and snapped positions move them.
FOOTPRINT_TILE = 16
FOOTPRINT_MARGIN = 1


def _tile_boxes(g: Gaussians3DGS, cam) -> np.ndarray:
    """int64 [M, 4]: each Gaussian's tiles (x0, y0, x1, y1, inclusive) within 3 sigma of its
    largest scale (an upper bound of what the rasterizer draws), clipped to the image; x1 < x0
    for one behind the camera or off the image."""
    uv, z = cam.project(g.means.double().numpy())
    radius = 3 * g.scales.double().numpy().max(axis=1) * max(cam.fx, cam.fy) / np.maximum(z, cam.near) + 1
    nx, ny = -(-cam.width // FOOTPRINT_TILE), -(-cam.height // FOOTPRINT_TILE)
    with np.errstate(invalid="ignore"):
        lo = np.floor((uv - radius[:, None]) / FOOTPRINT_TILE)
        hi = np.floor((uv + radius[:, None]) / FOOTPRINT_TILE)
    box = np.stack([np.clip(lo[:, 0], 0, nx), np.clip(lo[:, 1], 0, ny),
                    np.clip(hi[:, 0], -1, nx - 1), np.clip(hi[:, 1], -1, ny - 1)], axis=1)
    box = np.nan_to_num(box, nan=-1).astype(np.int64)
    box[~(z > cam.near), 2] = -1
    return box


def held_in_footprint(sample: Gaussians3DGS, held: Gaussians3DGS, cam) -> torch.Tensor:
    """The held Gaussians that reach the tiles of view ``cam`` the sample's Gaussians reach (grown by
    FOOTPRINT_MARGIN): elsewhere a trial renders the source's pixels whatever it holds, so the
    others change no error and are left out of the layers (``view_layers``)."""
    nx, ny = -(-cam.width // FOOTPRINT_TILE), -(-cam.height // FOOTPRINT_TILE)
    s = _tile_boxes(sample, cam)
    s = s[(s[:, 2] >= s[:, 0]) & (s[:, 3] >= s[:, 1])]
    m = FOOTPRINT_MARGIN
    x0, y0 = np.maximum(s[:, 0] - m, 0), np.maximum(s[:, 1] - m, 0)
    x1, y1 = np.minimum(s[:, 2] + m, nx - 1) + 1, np.minimum(s[:, 3] + m, ny - 1) + 1
    mask = np.zeros((ny + 1, nx + 1), np.int64)  # difference array of the sample's tiles
    for y, x, v in ((y0, x0, 1), (y0, x1, -1), (y1, x0, -1), (y1, x1, 1)):
        np.add.at(mask, (y, x), v)
    covered = (mask.cumsum(0).cumsum(1)[:ny, :nx] > 0).astype(np.int64)
    area = np.zeros((ny + 1, nx + 1), np.int64)  # summed-area table of the covered tiles
    area[1:, 1:] = covered.cumsum(0).cumsum(1)
    b = _tile_boxes(held, cam)
    ok = (b[:, 2] >= b[:, 0]) & (b[:, 3] >= b[:, 1])
    b = np.where(ok[:, None], b, 0)
    hits = area[b[:, 3] + 1, b[:, 2] + 1] - area[b[:, 1], b[:, 2] + 1] - area[b[:, 3] + 1, b[:, 0]] + area[b[:, 1], b[:, 0]]
    return torch.from_numpy(np.flatnonzero(ok & (hits > 0)))


# The (pruning share, position step) pairs whose grid, values and neighbour graph a search keeps: each
# holds a copy of the kept Gaussians' values (float64 [N, M]), the scene on its grid and its graph, 620 B
# per Gaussian at SH degree 3 (measured at 100k); a search makes one for most of its trials (the pruning
# ladder's moves onto the target scale the position step with the others: 38 pairs in 59 trials on a test
# scene); keeping them all would be the largest part of the preparation's peak (tools/results/scale.md, "SH 3
# memory"). Two are kept: the trials of one pair follow one another (the probes of the attribute steps, a
# share's first trial and its move), so with two none is made twice on that scene, and one made again
# would be the same.
GRID_CACHE_KEYS = 2


def _cached(cache: dict, key, make):
    """``cache[key]``, made by ``make()`` where missing; the GRID_CACHE_KEYS most recently used kept."""
    if key in cache:
        cache[key] = cache.pop(key)  # the most recent last
    else:
        cache[key] = make()
        while len(cache) > GRID_CACHE_KEYS:
            del cache[next(iter(cache))]
    return cache[key]


class SettingsSearch:
    """Evaluates settings on one scene (the sample of a ``backdrop``, with one); caches what
    depends only on pruning and the grid (GRID_CACHE_KEYS)."""

    def __init__(self, scene: GaussianScene, contrib: np.ndarray, cfg: GaussianEncoderConfig, lam: float,
                 views: int, resolution: int, sensitivity: np.ndarray | None = None,
                 backdrop: Backdrop | None = None, renders: SceneRenders | None = None,
                 view_share: np.ndarray | None = None):
        """``renders``: ``scene``'s, where another measurement shares them (without a ``backdrop``;
        with one, its own). ``view_share``: each Gaussian's largest share of one view, which the
        pruning goes by where given (merging.py ``pruned_scene``)."""
        self.scene, self.contrib, self.lam, self.sensitivity = scene, contrib, lam, sensitivity
        self.view_share = view_share
        self.whole = backdrop.renders if backdrop is not None else renders or SceneRenders(scene)
        self.plan = (views, resolution, cfg.resolve_px)
        self.cams = self.whole.cams(self.plan)
        g = gaussians_from_scene(scene)
        self.backdrop = backdrop
        self.offsets: dict[float, float] = {}  # pruning share -> exact minus layered error (``_mse``)
        with torch.no_grad():
            if backdrop is None:
                self.targets = self.whole.images(self.plan)
                self.layers = None
            else:
                held = gaussians_from_scene(backdrop.held)
                self.layers = list(map_views(lambda cam: view_layers(g, held, held_in_footprint(g, held, cam), cam),
                                             self.cams))
        self.values = coded_values(scene).astype(np.float64)  # at the scene's SH degree
        self.cfg = cfg
        self._grids: dict = {}
        self._graphs: dict = {}
        self.trials: list[Trial] = []

    def _graph(self, key, grid: GaussianScene):
        """The normative order of the grid's points and their neighbour graph (cached per grid)."""
        def make():
            order = normative_order(grid.coords)
            graph = neighbour_graph(grid.coords[order], self.cfg.prediction_lods, self.cfg.prediction_neighbours) \
                if self.cfg.neighbour_prediction and neighbour_usable(grid.coords) else None
            return order, graph
        return _cached(self._graphs, key, make)

    def _attribute_bits(self, key, grid: GaussianScene, q: np.ndarray, prior_bits: float,
                        adjust: np.ndarray | None = None, degrees: np.ndarray | None = None,
                        layout: GaussianLayout | None = None) -> float:
        """The attribute bits the encoder will spend: the per-channel prior's, or neighbour
        prediction's where it is smaller (encoder/stream/neighbour_coding.py; cross-channel prediction,
        which both can add, is left out of the estimate). With step adjustment (``adjust``, rows
        in the scene's order) or SH degrees (``degrees``, with the ``layout``), neighbour
        prediction's."""
        order, graph = self._graph(key, grid)
        if graph is None:
            return prior_bits
        qo = q[order]
        nc = NeighbourCoding(qo, grid.coords[order], self.cfg.prediction_lods, self.cfg.prediction_neighbours,
                             self.cfg.prediction_buckets, False, layout, graph=graph,
                             adjust=None if adjust is None else adjust[order],
                             degrees=None if degrees is None else degrees[order])
        needed = adjust is not None or degrees is not None
        return nc.ideal_stream_bits() if needed else min(prior_bits, nc.ideal_stream_bits())

    def _values_bits(self, key, grid: GaussianScene, q: np.ndarray, adjust: np.ndarray | None,
                     degrees: np.ndarray | None, layout: GaussianLayout) -> float:
        """The attribute bits of the values ``q`` (``_attribute_bits``, against the per-channel prior's)."""
        prior_bits = 0.0
        # with step adjustment or SH degrees (both only with a neighbour graph) the estimate is neighbour
        # prediction's alone: the prior's bits, 56 channels' code lengths at SH 3, are not counted
        for c in range(q.shape[1] if adjust is None and degrees is None else 0):
            r = q[:, c] - int(np.median(q[:, c]))
            prior_bits += float(code_lengths_bits(r, np.full(r.shape, best_level(r), np.int64)).sum())
        return self._attribute_bits(key, grid, q, prior_bits, adjust, degrees, layout)

    def _grid(self, share: float, position_step: float):
        """(which Gaussians are kept, the kept on their grid, the geometry's bits, their values) of a
        pruning share and position step (cached: GRID_CACHE_KEYS of them)."""
        return _cached(self._grids, (share, position_step), lambda: self._make_grid(share, position_step))

    def _make_grid(self, share: float, position_step: float):
        if share == 0 and self.scene.coords is not None:
            # a scene already on its grid (fitted there) keeps it, whatever position_step says
            keep = np.ones(self.scene.num_gaussians, dtype=bool)
            bits = 8.0 * len(encode_geometry(np.unique(self.scene.coords, axis=0)))
            return keep, self.scene, bits, self.values
        keep, kept, weights = pruned_scene(self.scene, self.contrib, share, self.cfg.prune_mode, self.view_share)
        cfg = GaussianEncoderConfig(position_step=position_step)
        voxel, origin = choose_grid(kept, cfg, weights)
        grid, _ = snap_to_grid(kept, voxel, origin, weights)
        # merged Gaussians carry their groups' values (drop: the scene's, as coded_values of the subset)
        values = self.values[keep] if keep.all() or self.cfg.prune_mode == "drop" else \
            coded_values(kept).astype(np.float64)
        return keep, grid, 8.0 * len(encode_geometry(np.unique(grid.coords, axis=0))), values

    def _sensitivity_of(self, keep: np.ndarray, layout: GaussianLayout, steps: np.ndarray) -> np.ndarray:
        """The sensitivities of the kept Gaussians' coded channels; with the SH transform (format 1.6) the
        SH rest's are the coefficients' (encoder/gaussians/sh_transform.py), ``steps`` the channels' in values."""
        f = sh_degree_subset(self.sensitivity[keep], layout.sh_degree)
        if layout.sh_transform is None:
            return f
        rest = sht.sh_rest_columns(layout.sh_channels)
        g = np.array(f, dtype=np.float64)
        g[:, rest] = sht.coefficient_sensitivity(g[:, rest], steps[rest], layout.sh_transform)
        return g

    def _adjust(self, key, grid: GaussianScene, f: np.ndarray | None, x: np.ndarray, layout: GaussianLayout,
                cfg: GaussianEncoderConfig) -> np.ndarray | None:
        """Each kept Gaussian's step-adjustment index (scene order), or None without the tool (``f``: the
        kept Gaussians' sensitivities, ``_sensitivity_of``)."""
        order, graph = self._graph(key, grid)
        if not step_adjust_wanted(cfg, self.sensitivity) or graph is None:
            return None
        return adjust_on_graph(x, f, layout.sh_degree, grid.coords, order, graph, cfg, layout.sh_transform is not None)

    def _rd_quantized(self, key, grid: GaussianScene, f: np.ndarray, x: np.ndarray, layout: GaussianLayout,
                      cfg: GaussianEncoderConfig, adjust: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The values RDOQ chooses for the kept Gaussians (scene order, each row's own steps), the
        bands above each one's SH degree set to 0, and the degrees (None without the tool), as
        the coding will choose them (encoder/gaussians/rdoq.py; ``f`` as ``_adjust``'s)."""
        order, graph = self._graph(key, grid)
        degree = layout.sh_degree
        mu = group_slopes(f, channel_groups(degree, layout.sh_transform is not None), cfg.rd_quantization)
        # the way RDOQ writes each Gaussian (encoder/gaussians/rdoq.py) is chosen afresh in every trial, as
        # the coding chooses it: kept from the first trial, later trials measured 0.10-0.37 dB worse than
        # the coding codes them (tools/results/search_ways.md); choosing them costs a trial about 3% more
        q = np.empty(x.shape, dtype=np.int64)
        q[order] = rd_quantize(x[order], f[order], mu, grid.coords[order], graph, cfg.prediction_buckets,
                               orientation_columns(layout), None, None if adjust is None else adjust[order],
                               cfg.rotation_length)
        degrees = None
        if sh_degrees_wanted(cfg, self.sensitivity, degree) and graph is not None:
            degrees = degrees_on_graph(x, q, f, layout, grid.coords, order, graph, cfg, adjust)
        return (q, None) if degrees is None else (without_dropped_bands(q, degrees, layout), degrees)

    def _mse(self, dec: GaussianScene, share: float = 0.0) -> float:
        """The squared error of renders of ``dec`` against the source's, mean over the views. With a
        ``Backdrop``, the error of the whole scene's pictures: for the first trial of each pruning
        ``share`` the whole scene rendered (``whole_scene_error``), for every later one the layers'
        error (``ViewLayers``) plus what they missed on that first trial. The layers miss a part of
        what the grid's snap costs (sample and held Gaussians interleave in depth where cells are
        cut, and a move there changes which hides which), and little else: on the donut (20k
        sample) they measured 61-66% of the error at the preset's steps, 64% of what doubling the
        position step added, but 80-98% of what coarser or finer attribute steps added and 99% of what
        pruning 3.2% added; the exact minus layered error stayed at 1.65-1.68e-6 with and without
        pruning. So the offset is added, not a factor (one factor of the first trial put later
        trials off by -4 to +49%; the offset -6 to +4% where the attribute steps move, but -16 to
        -24% where the position step does; tools/results/search_sampling.md, section (f)), once per
        share: at most one whole-scene render per view per share of the pruning ladder, whatever
        the number of trials."""
        g = gaussians_from_scene(dec)
        with torch.no_grad():
            if self.layers is None:
                return float(np.mean(list(map_views(
                    lambda k: ((render_on_black(g, self.cams[k]).image - self.targets[k]) ** 2).double().mean().item(),
                    range(len(self.cams))))))
            layered = float(np.mean(list(map_views(
                lambda k: (self.layers[k].error(render_on_black(g, self.cams[k])) ** 2).double().mean().item(),
                range(len(self.cams))))))
        if share not in self.offsets:
            self.offsets[share] = whole_scene_error(self.backdrop, dec, self.cams, self.whole.images(self.plan)) - layered
        return max(layered + self.offsets[share], 0.0)

    def rounding_distortion(self, cfg: GaussianEncoderConfig) -> float:
        """The squared error of the scene rounded plainly at ``cfg``'s steps (``plainly_rounded``)."""
        return self._mse(plainly_rounded(self.scene, self.contrib, cfg))

    def evaluate(self, cfg: GaussianEncoderConfig) -> Trial:
        key = (cfg.prune_share, cfg.position_step)
        keep, grid, geometry_bits, values = self._grid(*key)
        degree = self.scene.sh_degree if cfg.sh_degree is None else min(cfg.sh_degree, self.scene.sh_degree)
        steps = channel_steps(cfg, degree)
        x = sh_degree_subset(values, degree) / steps
        layout = _with_sh_transform(GaussianLayout(degree), x, cfg)  # x's SH rest then the coefficients
        # the sensitivities in the trial's coded channels, made once for the step adjustment and RDOQ (both
        # need RDOQ on)
        rdoq_on = self.sensitivity is not None and cfg.rd_quantization > 0
        f = self._sensitivity_of(keep, layout, steps) if rdoq_on else None
        adjust = self._adjust(key, grid, f, x, layout, cfg)
        factor = 1.0 if adjust is None else STEP_ADJUST_FACTORS[adjust].astype(np.float64)[:, None]
        q, degrees = np.rint(x / factor).astype(np.int64), None
        if cfg.rotation_length:  # unit lengths (index 0) where RDOQ does not choose them
            q[:, layout.rotation_start] = 0
        if rdoq_on:
            q, degrees = self._rd_quantized(key, grid, f, x, layout, cfg, adjust)
        values = _decoded_values(q, steps, factor, layout)
        if cfg.rotation_length:
            w = layout.rotation_start
            values[:, w] = implied_w(q[:, w], values[:, w + 1:w + 4])
        dec = GaussianScene(grid.means, *layout.split(values))
        # the bits (numpy, one core) counted in a thread beside the renders of the error
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="lghcc-bits") as pool:
            counted = pool.submit(self._values_bits, key, grid, q, adjust, degrees, layout)
            mse = self._mse(dec, cfg.prune_share)
            bits = geometry_bits + counted.result() + _transform_bits(layout)
        cost = 10 * math.log10(max(mse, 1e-12)) + self.lam * math.log2(max(bits, 1.0))
        trial = Trial(cfg, mse, bits, cost)
        self.trials.append(trial)
        return trial


def _with_sh_transform(layout: GaussianLayout, x: np.ndarray, cfg: GaussianEncoderConfig) -> GaussianLayout:
    """With ``cfg.sh_transform`` where it pays (format 1.6; as encoder/gaussians/gaussians.py sh_transformed):
    the layout carrying the scene's transform, and ``x``'s SH rest (in band steps) turned, in place, into its
    coefficients; ``layout`` otherwise."""
    rest = sht.sh_rest_columns(layout.sh_channels)
    transform = sht.chosen_transform(x[:, rest], cfg.sh_transform, layout.sh_degree)
    if transform is None:
        return layout
    x[:, rest] = sht.forward(x[:, rest], transform)
    return dataclasses.replace(layout, sh_transform=transform)


def _decoded_values(q: np.ndarray, steps: np.ndarray, factor, layout: GaussianLayout) -> np.ndarray:
    """float32: the values a trial's ``q`` decodes to (``factor`` the rows' step-adjustment factors), the SH rest
    by the inverse transform (clause 11.11) in units of its band steps / 2^GUARD_BITS."""
    if layout.sh_transform is None:
        return (q * steps * factor).astype(np.float32)
    fine = steps.copy()
    fine[sht.sh_rest_columns(layout.sh_channels)] /= sht.guard_factor()
    return (attr.inverse_sh_transform(q, layout, "trial") * fine * factor).astype(np.float32)


def _transform_bits(layout: GaussianLayout) -> float:
    """The bits of a trial's sh_transform unit (0 without one)."""
    t = layout.sh_transform
    return 0.0 if t is None else 8.0 * len(t.to_unit(layout.sh_degree).to_bytes())


def step_adjust_wanted(cfg: GaussianEncoderConfig, sensitivity: np.ndarray | None) -> bool:
    """Step adjustment needs the sensitivities and RDOQ (and, checked by the callers, neighbour
    prediction)."""
    return cfg.step_adjust_max > 0 and sensitivity is not None and cfg.rd_quantization > 0


def scene_step_adjust(scene: GaussianScene, sensitivity: np.ndarray | None,
                      cfg: GaussianEncoderConfig) -> np.ndarray | None:
    """The step-adjustment indices of a scene on its grid at cfg's steps (scene order), as the
    coding will choose them; None where the tool is off or the scene does not admit neighbour
    prediction."""
    if not step_adjust_wanted(cfg, sensitivity) or not cfg.neighbour_prediction or not neighbour_usable(scene.coords):
        return None
    degree = scene.sh_degree
    order = normative_order(scene.coords)
    graph = neighbour_graph(scene.coords[order], cfg.prediction_lods, cfg.prediction_neighbours)
    x = coded_values(scene).astype(np.float64) / channel_steps(cfg, degree)
    return adjust_on_graph(x, sh_degree_subset(sensitivity, degree), degree, scene.coords, order, graph, cfg)


GROUPS = ("position", "sh_dc", "sh_band1", "sh_band2", "sh_band3", "opacity", "scale", "rotation")


def _step(cfg: GaussianEncoderConfig, group: str) -> float:
    if group.startswith("sh_band"):
        return float(cfg.sh_band_steps[int(group[-1]) - 1])
    return float(getattr(cfg, "position_step" if group == "position" else f"{group}_step"))


def _with_step(cfg: GaussianEncoderConfig, group: str, step: float) -> GaussianEncoderConfig:
    if group.startswith("sh_band"):
        bands = list(cfg.sh_band_steps)
        bands[int(group[-1]) - 1] = float(step)
        return dataclasses.replace(cfg, sh_band_steps=tuple(bands))
    return dataclasses.replace(cfg, **{"position_step" if group == "position" else f"{group}_step": float(step)})


def _model(base: Trial, probes: dict[str, tuple[Trial, float]]):
    """The high-rate model's terms from the probes: per group the distortion per step^2 (a), the
    bits saved per doubling (slope) and the probed base step; the distortion the steps leave."""
    a, slope, s0 = {}, {}, {}
    for grp, (t, step) in probes.items():
        a[grp] = max(t.mse - base.mse, 1e-18) / (3 * step * step)
        slope[grp] = max(base.bits - t.bits, 0.0)
        s0[grp] = step
    resid = max(base.mse - sum(a[g] * s0[g] ** 2 for g in a), 0.05 * base.mse)
    return a, slope, s0, resid


def predicted_mse(base: Trial, probes: dict[str, tuple[Trial, float]], steps: dict[str, float]) -> float:
    a, _, _, resid = _model(base, probes)
    return resid + sum(a[g] * steps[g] ** 2 for g in a)


def lambda_for_target(base: Trial, probes: dict[str, tuple[Trial, float]], target_mse: float,
                      lo: float = 0.05, hi: float = 64.0) -> float:
    """The lambda whose model steps (``optimal_steps``) are predicted to render at target_mse:
    bisection in log lambda (the predicted distortion grows with lambda)."""
    for _ in range(30):
        mid = math.sqrt(lo * hi)
        if predicted_mse(base, probes, optimal_steps(base, probes, mid)) > target_mse:
            hi = mid
        else:
            lo = mid
    return math.sqrt(lo * hi)


def optimal_steps(base: Trial, probes: dict[str, tuple[Trial, float]], lam: float,
                  bounds: tuple[float, float] = (1 / 8, 8)) -> dict[str, float]:
    """Steps minimizing J under the high-rate model: doubling group c's step adds a_c * 3
    step^2 to D (uniform rounding noise) and saves slope_c bits (measured), so the optimum has
    a_c step_c^2 = lambda slope_c D ln10 / (10 R ln2 ln4); solved by fixed-point iteration on
    D and R. ``probes``: group -> (trial with that group's step doubled, the base step)."""
    a, slope, s0, resid = _model(base, probes)
    steps = dict(s0)
    for _ in range(50):
        d = resid + sum(a[g] * steps[g] ** 2 for g in a)
        r = max(base.bits - sum(slope[g] * math.log2(steps[g] / s0[g]) for g in a), 0.05 * base.bits)
        for g in a:
            if slope[g] <= 0:
                steps[g] = s0[g] * bounds[1]  # bits do not depend on it: as coarse as allowed
                continue
            want = math.sqrt(lam * slope[g] * d * math.log(10) / (10 * r * math.log(2) * math.log(4) * a[g]))
            steps[g] = min(max(want, s0[g] * bounds[0]), s0[g] * bounds[1])
    return steps


def probe_groups(s: SettingsSearch, cfg: GaussianEncoderConfig, groups: list[str], target_mse: float | None,
                 say) -> tuple[Trial, dict[str, tuple[Trial, float]]]:
    """The trial of ``cfg`` and one probe per group with its step doubled -> (base, {group:
    (probe, step)}). With a target, the lambda the model gives for it, and the trials so far
    costed at it."""
    base = s.evaluate(cfg)
    probes = {g: (s.evaluate(_with_step(cfg, g, 2 * _step(cfg, g))), _step(cfg, g)) for g in groups}
    if target_mse is not None:
        s.lam = lambda_for_target(base, probes, target_mse)
        for t in s.trials:  # the trials so far, costed at the lambda now known
            t.cost = 10 * math.log10(max(t.mse, 1e-12)) + s.lam * math.log2(max(t.bits, 1.0))
        say(f"settings: lambda {s.lam:.3g} dB per doubling for {cfg.target_psnr:g} dB (model)")
    return base, probes


def model_step_trial(s: SettingsSearch, cfg: GaussianEncoderConfig, base: Trial,
                     probes: dict[str, tuple[Trial, float]]) -> Trial:
    """The best of the probes and the model's steps for lambda. The model holds at high rate;
    where its answer measures worse, it moves halfway back (in log steps), at most 4 times."""
    steps = optimal_steps(base, probes, s.lam)
    best = min([base] + [p for p, _ in probes.values()], key=lambda t: t.cost)
    for _ in range(4):
        cur = cfg
        for g, st in steps.items():
            cur = _with_step(cur, g, st)
        t = s.evaluate(cur)
        if t.cost < best.cost:
            return t
        steps = {g: math.sqrt(st * _step(cfg, g)) for g, st in steps.items()}
    return best


def walk_pruning_ladder(s: SettingsSearch, best: Trial) -> Trial:
    """Every pruning share of PRUNE_LADDER measured at the best steps so far; the one of least J.
    J is not convex in the share (on a trained lego at SH degree 3 the first step up measured
    worse, while 0.4% of the contribution removed 22% of the Gaussians for nothing visible), so
    a walk that stops at the first rise misses it."""
    for share in PRUNE_LADDER:
        if share != best.cfg.prune_share:
            t = s.evaluate(dataclasses.replace(best.cfg, prune_share=share))
            if t.cost < best.cost:
                best = t
    return best


def check_steps_either_way(s: SettingsSearch, best: Trial, groups: list[str]) -> Trial:
    """Each group's step a factor sqrt(2) up and down against real renders."""
    for g in groups:
        for f in (2 ** 0.5, 2 ** -0.5):
            t = s.evaluate(_with_step(best.cfg, g, _step(best.cfg, g) * f))
            if t.cost < best.cost:
                best = t
                break
    return best


def fewest_bits_at_target(s: SettingsSearch, best: Trial, groups: list[str], target_mse: float) -> Trial:
    """Every pruning share of the ladder moved onto the target (``onto_target``); then, of every
    setting measured on the way, the fewest bits that reach the target. Pruning and coarser steps
    trade against each other differently on every scene: on a trained lego (SH degree 3) the share
    that J preferred at the model's steps left no setting at the target but the preset's own
    (104,929 bytes from lghcc-enc --preset low), while 1.6% pruned with the steps moved onto the
    target gives 75,020 bytes (the scene and how to make it: tools/results/real_scenes.md, section
    lego-trained). Every share is moved: ranking the shares by the high-rate model's bits at the
    target and moving only the best 3 cost the donut's medium 27% more bytes (223,707 against
    175,730 at 1.6% pruned), its start being 5 dB below the target, where the model predicts none
    of them to get there.
    Each share starts from the steps where the share before it met the target, with the exponent
    of error ~ f^k measured there (the shares differ by a little pruning, so one move mostly lands
    in the band), else from the steps the search chose (starting from the finest steps a share had
    tried, the logo's medium once ended 8.8 dB above its target)."""
    start_cfg, exponent = best.cfg, TARGET_FIRST_EXPONENT
    for share in PRUNE_LADDER:
        cfg = dataclasses.replace(start_cfg, prune_share=share)
        start = best if cfg == best.cfg else s.evaluate(cfg)
        tried = onto_target_trials(s, start, groups, target_mse, SHARE_MOVES, exponent)
        if at_pruning_floor(tried, target_mse):
            break
        landed = fewest_bits_meeting(list(tried.values()), target_mse)
        start_cfg = landed.cfg if landed.mse <= target_mse else best.cfg
        exponent = bracket_exponent({f: t.mse for f, t in tried.items()}, target_mse) or exponent
    return fewest_bits_meeting(s.trials, target_mse)


# A pruning share none of whose trials meets the target, and whose two finest measured error ~ f^k with k
# below this (finer steps bought almost nothing: a quarter of the step 0.6 dB at k = 0.1), is at the floor
# its pruning leaves: the shares after it prune more (the pruned Gaussians of a share are among those of
# every larger one), their floors are higher, and their moves only make the steps finer for nothing
# (the 20k SH-3 scene at medium: 42.1 -> 42.6 -> 42.7 -> 42.7 dB for 264 -> 788 kB at share 0.032). At
# medium on playbot lod4 and lod3, the donut and SH-3 scenes of 20k and 100k: 8-20 fewer of 48-62 trials,
# the same settings (tools/results/scale.md, "Round 4").
PRUNING_FLOOR_EXPONENT = 0.5


def at_pruning_floor(tried: dict[float, Trial], target_mse: float) -> bool:
    """Whether a share's trials (common factor -> Trial) miss the target at the floor its pruning leaves
    (PRUNING_FLOOR_EXPONENT): the pruning ladder stops there."""
    if len(tried) < 2 or any(t.mse <= target_mse for t in tried.values()):
        return False
    (f1, t1), (f2, t2) = sorted(tried.items())[:2]
    return _measured_exponent(f1, t1.mse, f2, t2.mse) < PRUNING_FLOOR_EXPONENT


def fewest_bits_meeting(trials: list[Trial], target_mse: float) -> Trial:
    """Of the ``trials`` that meet the target, the one of fewest bits; the one of least error where
    none does."""
    meeting = [t for t in trials if t.mse <= target_mse]
    return min(meeting, key=lambda t: t.bits) if meeting else min(trials, key=lambda t: t.mse)


def search_settings(scene: GaussianScene, contrib: np.ndarray, cfg: GaussianEncoderConfig, *,
                    sensitivity: np.ndarray | None = None, log=None, backdrop: Backdrop | None = None,
                    views: SceneViews = ORBIT,
                    view_share: np.ndarray | None = None) -> tuple[GaussianEncoderConfig, list[Trial]]:
    """Choose the settings for ``cfg.rd_lambda`` (module doc): one probe per group measures how
    much doubling its step costs in D and saves in R, the high-rate model gives the steps, every
    share of the pruning ladder is measured, and each group's step is then checked a
    factor sqrt(2) up and down against real renders. ``backdrop``: ``scene`` is a sample of it (its
    renders hold the views); ``views``: where to look from otherwise; ``view_share``: the pruning's
    (``SettingsSearch``). -> (settings, every trial)."""
    say = log or (lambda *a: None)
    t0 = time.perf_counter()
    s = SettingsSearch(scene, contrib, cfg, cfg.rd_lambda, cfg.search_views, cfg.search_resolution, sensitivity,
                       backdrop, SceneRenders(scene, views) if backdrop is None else None, view_share)
    n = scene.num_gaussians
    groups = [g for g in GROUPS if not g.startswith("sh_band") or int(g[-1]) <= scene.sh_degree]
    target_mse = 10 ** (-cfg.target_psnr / 10) if cfg.target_psnr > 0 else None
    if target_mse is not None:
        # the model explains distortion by the steps only: probed without pruning, what the steps
        # leave is small and the lambda it gives for the target means something (the pruning
        # ladder comes after, at that lambda)
        cfg = dataclasses.replace(cfg, prune_share=0.0)
    base, probes = probe_groups(s, cfg, groups, target_mse, say)
    best = model_step_trial(s, cfg, base, probes)
    say(f"settings: model step {len(s.trials)} trials, {time.perf_counter() - t0:.0f} s: "
        f"{-10 * math.log10(max(best.mse, 1e-12)):.2f} dB at {best.bits / n:.1f} bits/Gaussian")
    if target_mse is None:
        best = walk_pruning_ladder(s, best)
    best = check_steps_either_way(s, best, groups)
    if target_mse is not None:
        # every share is measured at the target here: the walk at the model's lambda (8 trials)
        # would only choose the share where the steps are checked either way
        best = fewest_bits_at_target(s, best, groups, target_mse)
    say(f"settings: {len(s.trials)} trials, {time.perf_counter() - t0:.0f} s: "
        f"{-10 * math.log10(max(best.mse, 1e-12)):.2f} dB at {best.bits / n:.1f} bits/Gaussian, "
        f"pruning {100 * best.cfg.prune_share:g}% of the contribution")
    return best.cfg, s.trials


def trim_to_target(scene: GaussianScene, weights: np.ndarray, cfg: GaussianEncoderConfig, *,
                   sensitivity: np.ndarray | None = None, log=None,
                   renders: SceneRenders | None = None) -> tuple[GaussianEncoderConfig, Trial, Trial]:
    """After the fit, which tuned the values to render closer to the source than the search
    measured (about 1 dB), the attribute steps move onto ``cfg.target_psnr`` again (``onto_target``
    on the fitted scene, its grid kept): the fit's gain becomes fewer bytes at the quality asked
    for (``renders``: ``scene``'s). After a search on a sample the whole-scene check does this
    instead (``meet_on_whole_scene``). -> (settings, the trial before, the trial chosen)."""
    as_fitted = dataclasses.replace(cfg, prune_share=0.0)  # the scene is already pruned
    s = SettingsSearch(scene, weights, as_fitted, 0.0, cfg.search_views, cfg.search_resolution, sensitivity,
                       renders=renders)
    groups = _attribute_groups(scene)
    before = s.evaluate(as_fitted)
    best = onto_target(s, before, groups, 10 ** (-cfg.target_psnr / 10), moves=4)
    if log:
        log(f"settings after the fit: {-10 * math.log10(max(before.mse, 1e-12)):.2f} dB at "
            f"{before.bits / 8:,.0f} B -> {-10 * math.log10(max(best.mse, 1e-12)):.2f} dB at {best.bits / 8:,.0f} B "
            f"(estimated)")
    chosen = dataclasses.replace(best.cfg, prune_share=cfg.prune_share) if best is not before else cfg
    return chosen, before, best


def _scaled(cfg: GaussianEncoderConfig, groups: list[str], f: float) -> GaussianEncoderConfig:
    for g in groups:
        cfg = _with_step(cfg, g, _step(cfg, g) * f)
    return cfg


def onto_target_trials(s: SettingsSearch, best: Trial, groups: list[str], target_mse: float, moves: int,
                       first_exponent: float | None = None) -> dict[float, Trial]:
    """``best`` and the trials of every step times one common factor f that move it onto
    ``target_mse`` (``common_factor_trials``), factor -> Trial."""
    return common_factor_trials(lambda f: best if f == 1.0 else s.evaluate(_scaled(best.cfg, groups, f)),
                                target_mse, moves, first_exponent)


def onto_target(s: SettingsSearch, best: Trial, groups: list[str], target_mse: float, moves: int = 4) -> Trial:
    """Every step times one common factor f so that the renders meet ``target_mse`` within
    TARGET_TOLERANCE (``common_factor_move``, at most ``moves`` trials after ``best``). Returns the
    trial of fewest bits that meets the target, or the one of least error when none does. It once
    doubled or halved f until the target was crossed, then bisected to within a factor 1.1: 4-5
    trials a share, landing up to 0.8 dB above the target (f 1.1 is 0.8 dB at k = 2)."""
    return fewest_bits_meeting(list(onto_target_trials(s, best, groups, target_mse, moves).values()), target_mse)


# The common-factor moves onto a quality target, in the search (each pruning share), the trim after
# the fit (without a sample) and the whole-scene check (after a search on a sample). The check's
# trials render and code the whole prepared scene (12-23 s each on the logo, 307k, at load 3-5; 30 s
# at 1M): at most 1 + 5 in all.
WHOLE_SCENE_MOVES = 5
# How far below the target (dB) the whole-scene check accepts its trial: the trials' own noise (at
# 1M: 44.88 dB at x1, 44.64 at the finer x0.972; the check chased 0.12 dB with 5 more trials, 150 s).
# The check's band is then 0.1 below to 0.15 above the target.
WHOLE_SCENE_MISS = 0.1
# The exponent k (error ~ f^k) the whole-scene check's first move assumes: measured on whole prepared
# scenes 2.7 on the logo (x1 48.76 dB, x1.52 43.85), 2.87 and 2.73 at 1M (x1 43.77, x0.865 45.58; x1 42.40,
# x0.739 45.98), 3.0 at 300k (x1 45.44, x1.11 44.10) and 2.4 on the donut (20k sample: x1 44.77, x0.794
# 47.16). With the search's k = 2 the second 1M check's first move overshot by 0.9 dB and took a third
# trial (tools/results/scale.md); on a power law with 0.1-0.2 dB noise and k 2.4-3.0 this prior takes
# 3.1-3.3 trials on average against 3.5-3.7 (a simulation of ``common_factor_trials``, same file).
WHOLE_SCENE_FIRST_EXPONENT = 2.7
# The moves of each pruning share in the search: the share before it hands over its steps and the
# exponent it measured, so one move mostly lands in the band.
SHARE_MOVES = 3
# How far above the target (dB) the renders may be before a move makes the steps coarser (a miss
# below the target is always moved); moves aim at the middle of this band.
TARGET_TOLERANCE = 0.25
# The exponent k of error ~ f^k (f: the common factor on the attribute steps) a first move
# assumes; later moves measure it on their own trials. Measured: the logo (307k, medium) 2.5
# to 4.5 coarser (48.76 dB at x1, 45.78 at x1.31, 44.61 at x1.39, 37.60 at x2.31: k = 1, the full
# target / error, overshot by 7.4 dB), the donut (20k sample, 4 views of 64 px) 3.0 finer, playbot
# lod4 (3k sample, the same views) 2.1 finer (tools/results/search_sampling.md (h)).
TARGET_FIRST_EXPONENT = 2.0
# The most one move changes the steps by, and the range of the exponents it measures.
TARGET_MAX_MOVE = 4.0
TARGET_EXPONENTS = (0.25, 4.0)
# Where in a bracket (log f) a move may land at the least and the most: the secant, kept off its
# ends, shrinks the bracket by a quarter at least (the logo's error is not a smooth power of f).
TARGET_BRACKET = (0.25, 0.75)


def _measured_exponent(f1: float, e1: float, f2: float, e2: float) -> float:
    """k of e ~ f^k through two trials (factor, error), within TARGET_EXPONENTS."""
    lo, hi = TARGET_EXPONENTS
    k = math.log(max(e2, 1e-30) / max(e1, 1e-30)) / math.log(f2 / f1)
    return min(max(k, lo), hi)


def bracket_exponent(measured: dict[float, float], target_mse: float) -> float | None:
    """k of error ~ f^k through the two trials that bracket the target most closely (factor ->
    error; None without a bracket): the secant of a move inside the bracket, and what the next
    move onto a like target may assume first."""
    meet = [f for f, e in measured.items() if e <= target_mse]
    fail = [f for f, e in measured.items() if e > target_mse]
    if not meet or not fail:
        return None
    a, b = max(meet), min(fail)
    return _measured_exponent(a, measured[a], b, measured[b])


def common_factor_move(measured: dict[float, float], target_mse: float,
                       first_exponent: float | None = None) -> float | None:
    """The common factor (on the first trial's attribute steps) of the next trial onto the target,
    from the trials so far (factor -> error); None when the largest factor that meets the target
    is within TARGET_TOLERANCE of it, or when the trials bracket the target within 1% in factor.
    The error taken as c f^k: k through the two trials that bracket the target, else through the
    two nearest it on its one side (all too good, or all missing) where the error grows with f,
    else ``first_exponent`` (TARGET_FIRST_EXPONENT by default); the move aims at the middle of the
    band, stays inside a bracket (TARGET_BRACKET) and within a factor TARGET_MAX_MOVE of the trial
    it starts from.
    Why one bracketed move and not a second one finer by the full target / error after a miss: on
    the logo that stopped 1.7 dB above the target, +4.8% bytes (tools/results/search_sampling.md
    (f), (h))."""
    meet = sorted(f for f, e in measured.items() if e <= target_mse)
    fail = sorted(f for f, e in measured.items() if e > target_mse)
    if meet and measured[meet[-1]] * 10 ** (TARGET_TOLERANCE / 10) >= target_mse:
        return None
    aim = target_mse * 10 ** (-TARGET_TOLERANCE / 20)
    if meet and fail:
        a, b = meet[-1], fail[0]
        if b <= a * 1.01:
            return None
        f = a * (aim / max(measured[a], 1e-30)) ** (1 / bracket_exponent(measured, target_mse))
        lo, hi = TARGET_BRACKET
        return min(max(f, a * (b / a) ** lo), a * (b / a) ** hi)
    near = meet[::-1] if meet else fail  # the nearest the target first
    a = near[0]
    k = first_exponent or TARGET_FIRST_EXPONENT
    if len(near) > 1 and (measured[near[1]] - measured[a]) * (near[1] - a) > 0:
        # two trials on one side; where the error fell as the steps grew, that was the trials'
        # noise, not the slope (at 1M: steps x0.972 measured 0.24 dB worse than x1), so the prior
        k = _measured_exponent(a, measured[a], near[1], measured[near[1]])
    return min(max(a * (aim / max(measured[a], 1e-30)) ** (1 / k), a / TARGET_MAX_MOVE), a * TARGET_MAX_MOVE)


def common_factor_trials(measure, target_mse: float, moves: int = WHOLE_SCENE_MOVES,
                         first_exponent: float | None = None) -> dict[float, Trial]:
    """Trials onto the target, factor -> Trial (``measure(f)``: the trial with every attribute
    step times f): f = 1, then at most ``moves`` more from ``common_factor_move``."""
    trials = {1.0: measure(1.0)}
    for _ in range(moves):
        f = common_factor_move({f: t.mse for f, t in trials.items()}, target_mse, first_exponent)
        if f is None or f in trials:
            break
        trials[f] = measure(f)
    return trials


def _attribute_groups(scene: GaussianScene) -> list[str]:
    return [g for g in GROUPS if g != "position" and (not g.startswith("sh_band") or int(g[-1]) <= scene.sh_degree)]


def sample_distortion_ratio(scene: GaussianScene, contrib: np.ndarray, cfg: GaussianEncoderConfig,
                            sample: np.ndarray, renders: SceneRenders | None = None) -> float:
    """The whole scene's squared error over the sample's (``sample``, encoder/gaussians/search_sample.py) at
    ``cfg``'s steps, plainly rounded without pruning (``plainly_rounded``: a whole-scene trial would
    code the whole scene), on the search views; the sample's error is that of the whole scene
    rendered with only the sample rounded: it covers fewer pixels of the views than the whole, so
    the same steps measure less error on it (``renders``: the scene's, shared with the search's offsets). The search asks the sample for the target's error
    divided by this ratio. Measured on the layers instead, plain rounding's error came out 39% low
    on the donut (20k sample), the ratio 3.80 instead of 2.33 (an RDOQ trial at the same steps on
    whole renders: 2.31), and the search aimed 1-2 dB above the target (search_sampling.md (e), (f))."""
    whole = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, renders=renders)
    part = plainly_rounded(scene.subset(sample), contrib[sample], cfg)
    return max(whole.rounding_distortion(cfg), 1e-12) / max(whole._mse(with_held(part, Backdrop(scene, sample))), 1e-12)


def on_sample(cfg: GaussianEncoderConfig, ratio: float) -> GaussianEncoderConfig:
    """``cfg`` with its target moved to the sample's error (the whole scene's over ``ratio``)."""
    if not cfg.target_psnr > 0:
        return cfg
    return dataclasses.replace(cfg, target_psnr=cfg.target_psnr + 10 * math.log10(max(ratio, 1e-12)))


def meet_on_whole_scene(scene: GaussianScene, weights: np.ndarray, cfg: GaussianEncoderConfig, *,
                        sensitivity: np.ndarray | None = None, log=None, renders: SceneRenders | None = None,
                        where: str = "on the whole scene") -> tuple[GaussianEncoderConfig, list[Trial]]:
    """The check of settings chosen on a sample against ``cfg.target_psnr`` on the whole (fitted,
    pruned) scene, less WHOLE_SCENE_MISS: one trial; while the fewest bits that meet it are off it
    by more than TARGET_TOLERANCE (or none meets it), every attribute step times one common factor
    (``common_factor_move``, first with k = WHOLE_SCENE_FIRST_EXPONENT, at most WHOLE_SCENE_MOVES
    trials more: at most 6 whole-scene trials). Of
    the trials that meet the target, the fewest bits; the least error where none does (``renders``:
    the scene's; ``where`` names them in the log). It starts from the search's settings: a trim on the sample before it moved the same
    common factor against the ratio measured before the fit, which the fit moves (at 1M its settings
    measured 1.2 dB short here), for two whole renders per view and 5 trials of the sample
    (tools/results/scale.md). -> (settings, trials)."""
    as_fitted = dataclasses.replace(cfg, prune_share=0.0)  # the scene is already pruned
    s = SettingsSearch(scene, weights, as_fitted, 0.0, cfg.search_views, cfg.search_resolution, sensitivity,
                       renders=renders)
    target_mse = 10 ** (-(cfg.target_psnr - WHOLE_SCENE_MISS) / 10)
    groups = _attribute_groups(scene)
    tried = common_factor_trials(lambda f: s.evaluate(_scaled(as_fitted, groups, f)), target_mse,
                                 first_exponent=WHOLE_SCENE_FIRST_EXPONENT)
    before, best = tried[1.0], fewest_bits_meeting(s.trials, target_mse)
    if log:
        log(f"settings {where}: {-10 * math.log10(max(before.mse, 1e-12)):.2f} dB at "
            f"{before.bits / 8:,.0f} B" + ("" if best is before else
                                          f" -> {-10 * math.log10(max(best.mse, 1e-12)):.2f} dB at "
                                          f"{best.bits / 8:,.0f} B") + f" (estimated, {len(s.trials)} trials: " +
            ", ".join(f"steps x{f:.3g} {-10 * math.log10(max(t.mse, 1e-12)):.2f} dB" for f, t in tried.items()) + ")")
    chosen = dataclasses.replace(best.cfg, prune_share=cfg.prune_share) if best is not before else cfg
    return chosen, s.trials
