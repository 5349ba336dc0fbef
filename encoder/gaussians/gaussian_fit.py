"""Rate-aware preparation of an explicit-Gaussian scene before coding (informative).

Against renders of the source scene from ``fit_views`` cameras on a sphere around it (plus
any cameras the caller gives, e.g. the scene's own training views):

1. each Gaussian's contribution to those pictures (render/importance.py), and the pictures'
   sensitivity to each of its values for rate-distortion optimized quantization
   (encoder/gaussians/rdoq.py; used by the search, the trim and the coding);
2. pruning: the least contributing Gaussians whose contributions add up to at most
   ``prune_share`` of the total are dropped (a rate-distortion decision: each costs the same
   bits, and these change the pictures least);
3. the position grid (encoder/gaussians/gaussians.py: ``choose_grid`` weighted by contribution) and the
   snap to it; the positions stay there;
4. fitting: ``fit_iterations`` Adam steps on the kept Gaussians' SH, opacity, scales and
   rotations with their quantization simulated (straight-through rounding to the preset's
   steps), minimizing the squared error against the source renders plus ``fit_rate_lambda``
   times the estimated bits of the coded values (the per-channel prior's discretized Gaussian
   with the frozen tables' scales, spec clause 10), so the values move where the decoded
   scene renders closest to the source at the rate the stream will pay. The pruned
   Gaussians' share of the pictures is taken over by their neighbours;
5. with a quality asked for (``target_psnr``), the attribute steps move onto it again
   (encoder/gaussians/gaussian_rd.py ``trim_to_target``): what the fit gained becomes fewer bytes;
   after a search on a sample, the whole-scene check does this on the whole prepared scene
   (``meet_on_whole_scene``).

The result is a GaussianScene on its grid that encode_gaussian_scene codes exactly as the
fit simulated it.

Views that resolve the Gaussians: the orbit views see the whole scene at ``fit_resolution``
(``search_resolution`` for the search) pixels. On a scene of many small Gaussians (the 307k
PlayCanvas logo: its typical Gaussian spans 0.05 px at 128 px) such views are blind to what
the Gaussians hold, because 3DGS rendering dilates each one to at least 0.3 px^2 and the dilated
blobs hide one another: with 56% of the logo's Gaussians pruned, 128 px renders stay at 62 dB
PSNR against the source, 320 px renders drop to 28 dB. So where the typical Gaussian (median of exp(mean log scale)) spans
fewer than ``resolve_px`` pixels in the orbit views, they are magnified by
m = resolve_px / size (at most 8): the contributions come from whole orbit views at m times the
resolution, and the fit and the search render as many crops besides the orbit views (field of
view m times narrower, aimed at Gaussians drawn at random, same pixel count). The default 0.1 px
leaves every scene whose orbit views already resolve it as it was (donut 0.21 px, playbot 0.12 to
0.21 px at 128 px; there the 128 px views stay within 0.7 to 3.7 dB of 320 px ones under pruning);
on the logo, 128 px crops at m = 2.09 follow 320 px renders (31.3 against 28.4 dB, 27.8 against
25.9, 23.7 against 23.0). Measured in tools/results/resolve.md.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from ...app.progress import progress_bar

from ...common.attributes import STEP_ADJUST_FACTORS
from ...common.scene import GaussianScene
from ..stream.config import GaussianEncoderConfig
from . import sh_transform as sht
from .gaussian_grid import OPACITY_LOGIT_LIMIT, canonical_rotations, choose_grid, snap_to_grid
from .gaussian_views import CHECK_VIEWS, LANDING_VIEWS, SceneViews, scene_views
from .merging import pruned_scene
from ..stream.stats import PrepareStats
from ...render.camera import Camera
from ...render.gaussians3dgs import Gaussians3DGS, gaussians_from_scene, render_3dgs
from ...render.importance import Contributions, view_contributions
from ...render.rasterizer import rasterize
from ...render.sh import sh_to_rgb
from ...render.view_threads import map_views

if TYPE_CHECKING:
    from .gaussian_rd import SceneRenders


@dataclass
class PreparedGaussians:
    scene: GaussianScene  # on its grid, pruned and fitted
    weights: np.ndarray  # contribution of each kept Gaussian (its share of the pictures)
    sensitivity: np.ndarray | None  # the pictures' sensitivity to each kept Gaussian's values (encoder/gaussians/rdoq.py)
    cfg: GaussianEncoderConfig  # the settings to code it with (chosen by the search when it ran)
    stats: PrepareStats
    views: SceneViews  # where it was measured from


def _ste(x: torch.Tensor, step) -> torch.Tensor:
    """Rounding to multiples of ``step`` with the identity's gradient (quantization as coded)."""
    return x + (torch.round(x / step) * step - x).detach()


_SQRT_HALF = 1.0 / math.sqrt(2.0)


def _bits(x_steps: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Ideal bits of values x (in steps) under a discretized Gaussian (mean mu, scale sigma) with
    probabilities floored at 2^-24, as the frozen tables code them (estimate_bits_float)."""
    a = (x_steps - mu).abs()
    p = 0.5 * (torch.erf((0.5 - a) / sigma * _SQRT_HALF) - torch.erf((-0.5 - a) / sigma * _SQRT_HALF))
    return -torch.log2(p.clamp_min(2.0 ** -24)).sum()


def _rest_band_steps(num_coefficients: int, cfg: GaussianEncoderConfig) -> np.ndarray:
    """float64 [num_coefficients - 1]: the step of each SH-rest coefficient, its band's (band b holds
    coefficients b^2 .. (b + 1)^2 - 1)."""
    band = np.floor(np.sqrt(np.arange(1, num_coefficients))).astype(int)
    return np.asarray(cfg.sh_band_steps, np.float64)[band - 1]


class _Fit:
    """The fitted parameters and their quantized values as the encoder will code them."""

    def __init__(self, scene: GaussianScene, cfg: GaussianEncoderConfig, step_adjust: np.ndarray | None = None,
                 sh_basis: np.ndarray | None = None):
        t = lambda a: torch.tensor(np.asarray(a, np.float64), dtype=torch.float32)  # noqa: E731
        self.cfg = cfg
        # each Gaussian's factor on its steps (step adjustment, clause 11.8; 1 without it)
        self.factor = torch.ones(scene.num_gaussians, 1) if step_adjust is None else \
            torch.from_numpy(STEP_ADJUST_FACTORS[step_adjust].astype(np.float32))[:, None]
        self.means = t(scene.means)
        self.degree = scene.sh_degree
        self.sh_dc = t(scene.sh[:, :1]).requires_grad_(True)
        self.sh_rest = t(scene.sh[:, 1:]).requires_grad_(True)
        self.opacity = t(np.clip(scene.opacity, -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT)).requires_grad_(True)
        self.log_scales = t(scene.log_scales).requires_grad_(True)
        self.rotations = t(canonical_rotations(scene.rotations)).requires_grad_(True)
        self.rest_steps = torch.tensor(_rest_band_steps(scene.sh.shape[1], cfg), dtype=torch.float32)[None, :, None]
        # With the SH transform (format 1.6) the coded SH rest is the coefficients t of u = B t (u the values in
        # band steps): the fit rounds and prices t, as the stream will (sh_transform_basis)
        self.basis = None if sh_basis is None else (torch.from_numpy(sh_basis.astype(np.float32)),
                                                    torch.from_numpy(np.linalg.inv(sh_basis).astype(np.float32)))
        self.rate_model = None

    def params(self) -> list[torch.Tensor]:
        return [self.sh_dc, self.sh_rest, self.opacity, self.log_scales, self.rotations]

    def quantized(self):
        """(SH, opacity, log scales, rotations) rounded to their steps, with straight-through gradients."""
        c, k = self.cfg, self.factor
        rot = self.rotations / self.rotations.norm(dim=1, keepdim=True).clamp_min(1e-12)
        sh = torch.cat([_ste(self.sh_dc, c.sh_dc_step * k[:, :, None]), self._quantized_rest()], 1)
        op = _ste(self.opacity.clamp(-OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT), c.opacity_step * k[:, 0])
        return sh, op, _ste(self.log_scales, c.scale_step * k), _ste(rot, c.rotation_step * k)

    def _quantized_rest(self) -> torch.Tensor:
        """The SH rest rounded as coded: values to their band steps, or, with the transform, the
        coefficients to one step each (the decoder's 2^-GUARD_BITS value grid is not simulated:
        1/256 of a rounding's error)."""
        step = self.rest_steps * self.factor[:, :, None]
        if self.basis is None:
            return _ste(self.sh_rest, step)
        b, b_inv = self.basis
        n = self.sh_rest.shape[0]
        t = _ste((self.sh_rest / step).reshape(n, -1) @ b_inv.T, 1.0)
        return (t @ b.T).reshape(self.sh_rest.shape) * step

    def values_in_steps(self, sh, op, ls, rot) -> list[torch.Tensor]:
        """The coded integers (before rounding: the straight-through values), channel by channel."""
        c, k = self.cfg, self.factor
        n = sh.shape[0]
        rest = (sh[:, 1:] / (self.rest_steps * k[:, :, None])).reshape(n, -1)
        if self.basis is not None:
            rest = rest @ self.basis[1].T
        return [(sh[:, :1] / (c.sh_dc_step * k[:, :, None])).reshape(n, -1), rest,
                (op / (c.opacity_step * k[:, 0]))[:, None], ls / (c.scale_step * k), rot / (c.rotation_step * k)]

    def init_rate_model(self) -> None:
        """Per channel: the median and the RMS deviation (in steps) of the quantized start values,
        the per-channel prior the stream will use (held fixed during the fit)."""
        with torch.no_grad():
            v = torch.cat(self.values_in_steps(*self.quantized()), 1).double()
            mu = v.median(dim=0).values
            sigma = ((v - mu) ** 2).mean(0).sqrt().clamp(0.11, 512.0)
        self.rate_model = (mu.float(), sigma.float())

    def rate_bits(self) -> torch.Tensor:
        """Estimated bits of the quantized values under the per-channel prior (straight-through)."""
        mu, sigma = self.rate_model
        return _bits(torch.cat(self.values_in_steps(*self.quantized()), 1), mu, sigma)

    def render(self, cam: Camera, sh, op, ls, rot) -> torch.Tensor:
        d = self.means - torch.as_tensor(cam.center, dtype=torch.float32)
        d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-12)
        colors = sh_to_rgb(self.degree, sh, d)
        return rasterize(self.means, rot, torch.exp(ls), torch.sigmoid(op), colors, cam,
                         background=torch.zeros(3)).image

    def scene(self, grid: GaussianScene) -> GaussianScene:
        f = lambda x: x.detach().numpy().astype(np.float32)  # noqa: E731
        rot = self.rotations / self.rotations.norm(dim=1, keepdim=True).clamp_min(1e-12)
        sh = torch.cat([self.sh_dc, self.sh_rest], 1)
        return GaussianScene.on_grid(grid.coords, grid.voxel_size, grid.origin, f(sh), f(self.opacity),
                                     f(self.log_scales), f(rot))


def _lrs(cfg: GaussianEncoderConfig) -> list[float]:
    """Adam learning rates of (SH DC, higher SH bands, opacity, log scales, rotations), about a tenth
    of 3DGS training's (the values start near a solution); the higher bands 20x slower, as in 3DGS."""
    s = cfg.fit_lr_scale
    return [1e-3 * s, 5e-5 * s, 5e-3 * s, 1e-3 * s, 5e-4 * s]


def measure_contributions(g: Gaussians3DGS, cams: list[Camera], progress: bool, regions: int = 1) -> Contributions:
    """Each Gaussian's contribution to the pictures of ``cams``, in all and to the view (the region
    of a regions x regions grid of a view) it matters most to (render/importance.py)."""
    bar = progress_bar(total=len(cams), desc="contributions", unit="view", disable=not progress, leave=False)
    contrib = view_contributions(g.means, g.quats, g.scales, g.opacities, cams, on_view=bar.update, regions=regions)
    bar.close()
    return contrib


def pruning_key(contrib: Contributions, views: SceneViews) -> Contributions:
    """``contrib`` with the view shares the pruning goes by (no view loses more than the pruning
    share of what it shows) where the views see different parts of the scene (inside, both, the
    capture's cameras), without them on an orbit, where every view sees the whole object and the
    share of the total is the pruning's key: there the search's error is the mean
    over views alike, and by the views' shares the donut at low needed 0.49 of SPZ's bytes at equal
    PSNR where by the total it needed 0.33 (the search chose the ladder's top, and more kept)."""
    return contrib if views.kind != "orbit" else dataclasses.replace(contrib, view_share=None)


# The view shares are taken per region of a PRUNING_REGIONS x PRUNING_REGIONS grid of each view (a
# region's share bounds the view's, render/importance.py): a detail that fills a corner of one view
# is not pruned because the rest of that view is busy.
PRUNING_REGIONS = 4


def pruning_regions(views: SceneViews) -> int:
    """The regions per side of a view that ``pruning_key``'s view shares are taken over (1 on an
    orbit, which prunes by the total)."""
    return 1 if views.kind == "orbit" else PRUNING_REGIONS


def measure_sensitivities(scene: GaussianScene, cams: list[Camera], cfg: GaussianEncoderConfig, stats: PrepareStats,
                          progress: bool) -> np.ndarray | None:
    """The pictures' sensitivity to each value (encoder/gaussians/rdoq.py) on the fit views, for
    rate-distortion optimized quantization (None when ``cfg.rd_quantization`` is 0)."""
    if not cfg.rd_quantization > 0:
        return None
    from .rdoq import SENSITIVITY_PROBES, sensitivities

    t0 = time.perf_counter()
    bar = progress_bar(total=len(cams), desc="sensitivities", unit="view", disable=not progress, leave=False)
    f = sensitivities(scene, cams, probes=SENSITIVITY_PROBES, on_view=bar.update)
    bar.close()
    stats.time_sensitivities_s = time.perf_counter() - t0
    return f


@dataclass
class SearchSample:
    """The part of a large scene the settings search measured (encoder/gaussians/search_sample.py)."""
    members: np.ndarray  # bool [N]: the sampled Gaussians of the scene as it came in
    ratio: float  # the whole scene's squared error over the sample's at the same settings
    renders: SceneRenders  # the scene's search renders as it came in: the ratio's, reused by the search


def _search_sample(scene: GaussianScene, contrib: np.ndarray, cfg: GaussianEncoderConfig, views: SceneViews,
                   say) -> SearchSample | None:
    """The sample the search measures on a scene above ``search_sample_gaussians`` (None below),
    with the ratio of the whole scene's error to the sample's when a target is asked for."""
    from .gaussian_rd import SceneRenders, sample_distortion_ratio
    from .search_sample import search_sample

    members = search_sample(scene.means, cfg.search_sample_gaussians)
    if members is None:
        return None
    renders = SceneRenders(scene, views)
    ratio = sample_distortion_ratio(scene, contrib, cfg, members, renders) if cfg.target_psnr > 0 else 1.0
    say(f"settings: searched on a sample of {int(members.sum()):,} of {scene.num_gaussians:,} Gaussians (whole "
        f"scene's error {ratio:.3g} x the sample's)")
    return SearchSample(members, ratio, renders)


def search_for_settings(scene: GaussianScene, contrib: Contributions, sensitivity: np.ndarray | None,
                        cfg: GaussianEncoderConfig, views: SceneViews, stats: PrepareStats,
                        say) -> tuple[GaussianEncoderConfig, SearchSample | None]:
    """The settings for the quality or lambda asked for (encoder/gaussians/gaussian_rd.py) from
    ``views``, measured on a sample of a scene above ``search_sample_gaussians`` (with the sample);
    the preset's when neither is asked for."""
    if not (cfg.rd_lambda > 0 or cfg.target_psnr > 0):
        return cfg, None
    from .gaussian_rd import Backdrop, on_sample, search_settings, search_view_plan

    count, resolution = search_view_plan(cfg, scene.num_gaussians)
    say(f"settings: searched on {count} views of {resolution} px")
    # the plan, applied once: trim_to_target after the fit reads these views from the settings
    cfg = dataclasses.replace(cfg, search_views=count, search_resolution=resolution, search_reference_gaussians=0)
    t0 = time.perf_counter()
    sample = _search_sample(scene, contrib.total, cfg, views, say)
    if sample is None:
        cfg, trials = search_settings(scene, contrib.total, cfg, sensitivity=sensitivity, log=say, views=views,
                                      view_share=contrib.view_share)  # None: by the total (pruning_key)
    else:
        m = sample.members
        chosen, trials = search_settings(scene.subset(m), contrib.total[m], on_sample(cfg, sample.ratio),
                                         sensitivity=None if sensitivity is None else sensitivity[m], log=say,
                                         backdrop=Backdrop(scene, m, sample.renders),
                                         view_share=None if contrib.view_share is None else contrib.view_share[m])
        cfg = dataclasses.replace(chosen, target_psnr=cfg.target_psnr)
        stats.search_sample_gaussians, stats.search_sample_ratio = int(m.sum()), sample.ratio
    stats.time_search_s, stats.search_trials = time.perf_counter() - t0, len(trials)
    return cfg, sample


def pruned_on_grid(scene: GaussianScene, contrib: Contributions, cfg: GaussianEncoderConfig, stats: PrepareStats,
                   num_views: int, say) -> tuple[GaussianScene, np.ndarray, np.ndarray]:
    """Pruning by contribution (``pruning_key``: by the views' shares, no view losing more than
    ``prune_share`` of what any region of it shows, or by the total; the pruned dropped or merged, ``prune_mode``),
    then the grid weighted by contribution -> (the kept Gaussians on their grid, their contributions,
    which Gaussians were kept)."""
    keep, kept, weights = pruned_scene(scene, contrib.total, cfg.prune_share, cfg.prune_mode, contrib.view_share)
    stats.gaussians_pruned = int((~keep).sum())
    of = "the contribution" if contrib.view_share is None else "any region of a view's contribution"
    say(f"contributions from {num_views} views in {stats.time_contributions_s:.1f} s; pruned "
        f"{stats.gaussians_pruned:,} of {scene.num_gaussians:,} Gaussians ({100 * cfg.prune_share:g}% of {of} at "
        f"most, {cfg.prune_mode})")
    voxel, origin = choose_grid(kept, cfg, weights)
    grid, moved = snap_to_grid(kept, voxel, origin, weights)
    stats.voxel_size, stats.gaussians_moved_off_shared_voxels = voxel, moved
    return grid, weights, keep


@dataclass
class _Optimizer:
    """Adam on the fitted parameters with a cosine schedule, and the decoupled rate term."""
    opt: torch.optim.Adam
    sched: torch.optim.lr_scheduler.CosineAnnealingLR
    rate_lambda: float  # fit_rate_lambda: in steps^2 per bit
    step_sq: list[torch.Tensor]  # the square of each parameter's quantization step

    @classmethod
    def of(cls, fit: _Fit, cfg: GaussianEncoderConfig) -> _Optimizer:
        groups = [{"params": [p], "lr": lr} for p, lr in zip(fit.params(), _lrs(cfg))]
        opt = torch.optim.Adam(groups, eps=1e-15)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.fit_iterations, eta_min=0.0)
        step_sq = [torch.tensor(cfg.sh_dc_step ** 2), fit.rest_steps ** 2, torch.tensor(cfg.opacity_step ** 2),
                   torch.tensor(cfg.scale_step ** 2), torch.tensor(cfg.rotation_step ** 2)]
        return cls(opt, sched, cfg.fit_rate_lambda, step_sq)

    def step(self, fit: _Fit, cam: Camera, target: torch.Tensor) -> float:
        """One step on one view -> its squared error. The rate term is applied decoupled from
        Adam (as AdamW decouples weight decay): Adam normalizes each parameter's gradient, so a
        rate gradient added to the loss would move every parameter the picture does not depend
        on at the full learning rate, whatever lambda is. Each step instead moves the values
        down the gradient of the estimated bits by lr x fit_rate_lambda x (step^2 of the value)
        per bit, i.e. lambda in steps^2 per bit."""
        img = fit.render(cam, *fit.quantized())
        mse = ((img - target) ** 2).mean()
        self.opt.zero_grad(set_to_none=True)
        mse.backward()
        self.opt.step()
        if self.rate_lambda > 0:
            grads = torch.autograd.grad(fit.rate_bits(), fit.params())
            with torch.no_grad():
                for p, g, group, sq in zip(fit.params(), grads, self.opt.param_groups, self.step_sq):
                    p -= group["lr"] * self.rate_lambda * sq * g
        self.sched.step()
        return float(mse.detach())


def source_renders(g: Gaussians3DGS, cams: list[Camera], drawn: list[int]) -> dict[int, torch.Tensor]:
    """The source's render on black of each view the fit's steps draw (``drawn``), made once, two
    views at a time (render/view_threads.py)."""
    views = list(dict.fromkeys(drawn))
    with torch.no_grad():
        images = list(map_views(lambda j: render_3dgs(g, cams[j], background=(0, 0, 0), backend="torch").image, views))
    return dict(zip(views, images))


def sh_transform_basis(scene: GaussianScene, cfg: GaussianEncoderConfig) -> np.ndarray | None:
    """float64 [n, n] B of the transform the coding will fit to ``scene``'s SH rest (values in band steps =
    B @ coefficients; encoder/gaussians/sh_transform.py), fitted here to the values before the fit; None
    where the coding will not use one."""
    if not cfg.sh_transform or scene.sh_degree == 0:
        return None
    band_steps = np.repeat(_rest_band_steps(scene.sh.shape[1], cfg), 3)  # per value: coefficient-major, colour-minor
    u = scene.sh[:, 1:].reshape(scene.num_gaussians, -1).astype(np.float64) / band_steps
    transform = sht.chosen_transform(u, cfg.sh_transform, scene.sh_degree)
    return None if transform is None else sht.value_matrix(transform)


def fit_to_renders(grid: GaussianScene, g: Gaussians3DGS, cams: list[Camera], cfg: GaussianEncoderConfig,
                   stats: PrepareStats, say, progress: bool, sensitivity: np.ndarray | None = None) -> GaussianScene:
    """``fit_iterations`` steps tuning the kept Gaussians to renders of the source Gaussians
    ``g`` with their quantization simulated and their estimated bits weighed in (module doc)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    drawn = [int(rng.integers(len(cams))) for _ in range(cfg.fit_iterations)]  # the view of each step
    targets = source_renders(g, cams, drawn)
    from .gaussian_rd import scene_step_adjust

    fit = _Fit(grid, cfg, scene_step_adjust(grid, sensitivity, cfg), sh_transform_basis(grid, cfg))
    fit.init_rate_model()
    optimizer = _Optimizer.of(fit, cfg)
    bar = progress_bar(range(cfg.fit_iterations), desc="fit", unit="it", disable=not progress, leave=False)
    last = time.perf_counter()
    losses = []
    for it in bar:
        j = drawn[it]
        losses.append(optimizer.step(fit, cams[j], targets[j]))
        if time.perf_counter() - last > 10 or it + 1 == cfg.fit_iterations:
            last = time.perf_counter()
            done = it + 1
            eta = (last - t0) / done * (cfg.fit_iterations - done)
            say(f"fit: {done}/{cfg.fit_iterations} steps, PSNR {-10 * math.log10(max(np.mean(losses[-20:]), 1e-12)):.2f} "
                f"dB on the fit views, ETA {eta:.0f} s")
    stats.time_fit_s = time.perf_counter() - t0
    stats.fit_final_mse = float(np.mean(losses[-20:]))
    return fit.scene(grid)


def trim_steps(fitted: GaussianScene, weights: np.ndarray, sensitivity: np.ndarray | None, cfg: GaussianEncoderConfig,
               stats: PrepareStats, say, renders: SceneRenders | None = None) -> GaussianEncoderConfig:
    """With a quality asked for, the attribute steps moved onto it again (what the fit gained
    becomes fewer bytes; ``renders``: the fitted scene's); the settings as they are otherwise."""
    if not cfg.target_psnr > 0:
        return cfg
    from .gaussian_rd import trim_to_target

    t0 = time.perf_counter()
    cfg, before, after = trim_to_target(fitted, weights, cfg, sensitivity=sensitivity, log=say, renders=renders)
    stats.time_trim_s, stats.trim_bits_before, stats.trim_bits_after = time.perf_counter() - t0, before.bits, after.bits
    return cfg


def whole_scene_check(scene: GaussianScene, weights: np.ndarray, sensitivity: np.ndarray | None,
                      cfg: GaussianEncoderConfig, stats: PrepareStats, say,
                      renders: SceneRenders | None = None) -> GaussianEncoderConfig:
    """Settings chosen on a sample, checked against the target on the whole prepared scene and
    moved onto it where they miss (encoder/gaussians/gaussian_rd.py ``meet_on_whole_scene``;
    ``renders``: the scene's); it takes the place of the trim (``trim_steps``)."""
    if not cfg.target_psnr > 0:
        return cfg
    from .gaussian_rd import meet_on_whole_scene

    t0 = time.perf_counter()
    cfg, trials = meet_on_whole_scene(scene, weights, cfg, sensitivity=sensitivity, log=say, renders=renders)
    stats.time_whole_check_s, stats.whole_check_trials = time.perf_counter() - t0, len(trials)
    return cfg


def land_on_target(scene: GaussianScene, source: GaussianScene, weights: np.ndarray, sensitivity: np.ndarray | None,
                   cfg: GaussianEncoderConfig, views: SceneViews, stats: PrepareStats, say) -> GaussianEncoderConfig:
    """With a quality asked for, the prepared scene's attribute steps moved onto it by one common
    factor (``meet_on_whole_scene``) on ``landing_views`` views of ``landing_resolution`` px of the
    landing set (SceneViews.held): larger views than the search's, which no other stage renders, in
    the place of the trim and the whole-scene check. Measured against the ``source``'s renders, not
    the prepared scene's as the trim and the check measure: what the grid, the pruning and the fit
    moved counts too (on the room at low, the prepared scene's renders read 1.3 dB above what the
    stream showed against the source). The settings as they are otherwise."""
    if not cfg.target_psnr > 0:
        return cfg
    from .gaussian_rd import SceneRenders, meet_on_whole_scene

    t0 = time.perf_counter()
    on_landing = dataclasses.replace(cfg, search_views=cfg.landing_views, search_resolution=cfg.landing_resolution)
    chosen, trials = meet_on_whole_scene(scene, weights, on_landing, sensitivity=sensitivity, log=say,
                                         renders=SceneRenders(source, views.held(LANDING_VIEWS)),
                                         where=f"on {cfg.landing_views} landing views of {cfg.landing_resolution} px")
    stats.time_landing_s, stats.landing_trials = time.perf_counter() - t0, len(trials)
    return dataclasses.replace(chosen, search_views=cfg.search_views, search_resolution=cfg.search_resolution)


def needs_preparation(cfg: GaussianEncoderConfig) -> bool:
    """Whether the settings ask for anything that renders (a search, pruning, a fit); the fast
    preset asks for none and is coded as it comes."""
    return cfg.rd_lambda > 0 or cfg.target_psnr > 0 or cfg.fit_iterations > 0 or cfg.prune_share > 0


def prepare_gaussians(scene: GaussianScene, cfg: GaussianEncoderConfig, *, views: SceneViews | None = None,
                      log=None, progress: bool = False) -> PreparedGaussians:
    """Contribution, pruning, grid and fit (module doc), all measured from ``views``
    (gaussian_views.py; None: ``cfg.views`` decides, free_space.py where it is auto); ``log(msg)``
    gets a line per stage (progress in logs)."""
    say = log or (lambda *a: None)
    cfg = cfg.validate()
    scene.validate()
    stats = PrepareStats(gaussians_in=scene.num_gaussians)
    t0 = time.perf_counter()
    if cfg.sh_degree is not None and cfg.sh_degree < scene.sh_degree:
        scene = scene.with_sh_degree(cfg.sh_degree)
    if views is None:
        views = scene_views(scene, cfg.views)
    say(f"views: {views.kind}: {views.reason}")
    stats.views, stats.views_reason = views.kind, views.reason
    g = gaussians_from_scene(scene)
    contrib_cams = views.contribution_cameras(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px)
    contrib = pruning_key(measure_contributions(g, contrib_cams, progress, pruning_regions(views)), views)
    cams = views.cameras(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px)
    stats.time_contributions_s = time.perf_counter() - t0
    sens_views = sensitivity_views(cfg, scene.num_gaussians)
    sens_cams = cams if sens_views == cfg.fit_views else \
        views.cameras(scene, sens_views, cfg.fit_resolution, cfg.resolve_px)
    sensitivity = measure_sensitivities(scene, sens_cams, cfg, stats, progress)
    cfg, sample = search_for_settings(scene, contrib, sensitivity, cfg, views, stats, say)
    grid, weights, keep = pruned_on_grid(scene, contrib, cfg, stats, len(contrib_cams), say)
    sensitivity = None if sensitivity is None else sensitivity[keep]
    if cfg.fit_iterations > 0:
        grid = fit_to_renders(grid, g, cams, fit_steps(cfg, grid.num_gaussians), stats, say, progress, sensitivity)
    from .gaussian_rd import SceneRenders
    if cfg.landing_views > 0:
        cfg = land_on_target(grid, scene, weights, sensitivity, cfg, views, stats, say)
    elif sample is not None:
        # no trim on the sample first: a trim moves the attribute steps by one common factor, as the
        # check does, against the ratio measured before the fit (off by -0.4 to +1.4 dB after it at
        # 300k and 1M), and costs 2 whole renders per view besides its trials (tools/results/scale.md)
        cfg = whole_scene_check(grid, weights, sensitivity, cfg, stats, say, SceneRenders(grid, views))
    elif cfg.fit_iterations > 0:
        cfg = trim_steps(grid, weights, sensitivity, cfg, stats, say, SceneRenders(grid, views))
    stats.time_total_s = time.perf_counter() - t0
    return PreparedGaussians(grid, weights, sensitivity, cfg, stats, views)


def check_on_held_back_views(source: GaussianScene, decoded: GaussianScene, views: SceneViews,
                             cfg: GaussianEncoderConfig, stats: PrepareStats, say) -> None:
    """The decoded scene against the source on ``cfg.check_views`` views of the kind the encoder
    looked from that none of its stages used (``SceneViews.whole_views``, held back): the PSNR of
    their mean squared error, which is what the target asks for, and the worst view's."""
    if cfg.check_views <= 0:
        return
    from .gaussian_rd import whole_scene_renders

    t0 = time.perf_counter()
    cams = views.held(CHECK_VIEWS).whole_views(source, cfg.check_views, cfg.check_resolution)
    if not cams:
        return
    mse = [float(((a.clamp(0, 1) - b.clamp(0, 1)) ** 2).double().mean())
           for a, b in zip(whole_scene_renders(decoded, cams), whole_scene_renders(source, cams))]
    psnr = lambda e: -10 * math.log10(max(e, 1e-12))  # noqa: E731
    stats.held_back_views, stats.held_back_psnr, stats.held_back_worst_psnr = len(cams), psnr(np.mean(mse)), psnr(max(mse))
    stats.time_held_back_s = time.perf_counter() - t0
    asked = f" (target {cfg.target_psnr:g} dB on the encoder's views)" if cfg.target_psnr > 0 else ""
    say(f"check: {stats.held_back_psnr:.2f} dB against the source on {len(cams)} {views.kind} views of "
        f"{cfg.check_resolution} px the encoder did not use{asked}, worst view {stats.held_back_worst_psnr:.2f} dB")


# The fewest views (orbit views, and as many crops where they are added) of the sensitivities on a
# large scene (``sensitivity_views``).
MIN_SENSITIVITY_VIEWS = 8


def sensitivity_views(cfg: GaussianEncoderConfig, num_gaussians: int) -> int:
    """The orbit views of the sensitivities: ``fit_views``, cut on a scene above
    ``fit_reference_gaussians`` to fit_views x reference / N (at least MIN_SENSITIVITY_VIEWS), each
    view rendering every Gaussian forward and backward."""
    ref = cfg.fit_reference_gaussians
    if ref <= 0 or num_gaussians <= ref:
        return cfg.fit_views
    return min(cfg.fit_views, max(MIN_SENSITIVITY_VIEWS, math.floor(cfg.fit_views * ref / num_gaussians + 0.5)))


def fit_steps(cfg: GaussianEncoderConfig, num_gaussians: int) -> GaussianEncoderConfig:
    """``cfg`` with the fit's steps for a scene of ``num_gaussians``: fit_iterations, cut on a scene
    above ``fit_reference_gaussians`` to fit_iterations x reference / N (each step renders every
    Gaussian forward and backward)."""
    ref = cfg.fit_reference_gaussians
    if ref <= 0 or num_gaussians <= ref:
        return cfg
    return dataclasses.replace(cfg, fit_iterations=max(1, math.floor(cfg.fit_iterations * ref / num_gaussians + 0.5)))
