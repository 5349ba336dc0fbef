"""A differentiable tile-based Gaussian rasterizer in pure torch (CPU), after 3DGS.

Stages:

1. ``project_gaussians`` (autograd): camera-space means; cull behind ``near`` / beyond
   ``far``; EWA splatting cov2d = J W Sigma W^T J^T + eps2d I (eps2d = 0.3 px as in 3DGS;
   J with 3DGS's clamping of x/z, y/z to the image edges plus 0.3 x tan(fov/2), i.e. 1.3x
   the half field of view for a centred principal point, as 3DGS and gsplat); conic = cov2d^-1.
   Computed in float64 (huge and tiny scales stay finite), returned in the input dtype.
2. Footprint: a Gaussian reaches pixel p only while its power
   0.5 d^T conic d <= t = min(sigma_cutoff^2 / 2, ln(255 opacity)), i.e. inside
   ``sigma_cutoff`` (3) standard deviations and where alpha >= 1/255 (3DGS's skip rule,
   here exact). The bounding box of that ellipse gives the tiles it touches (square, 4, 8
   or 16 pixels a side, the side of least work chosen per view: ``choose_tile_size``);
   Gaussians touching none are culled; those whose footprint cannot reach the image by a
   bound from their largest scale are culled before the projection (``_may_reach_image``).
   As the cutoff is applied per pixel, the image does not depend on the tile size but for
   float rounding (in 3DGS it does slightly).
3. ``_Composite`` (custom autograd Function): per tile, Gaussians sorted by depth,
   front-to-back alpha compositing with alpha = min(0.99, o exp(-power)), early
   termination where the transmittance would fall below 1e-4 (the Gaussian that would
   bring it there is not drawn, as in 3DGS). Tiles are processed in batches padded to
   the same length (tiles grouped by their Gaussian count; very long tiles are split
   along depth carrying the transmittance), with the power of every (Gaussian, pixel)
   pair from one matrix product against a quadratic pixel basis; a batch of long tiles goes
   in parts along depth, each tile leaving it where its transmittance or its Gaussians ran out
   (``_batch_weights_in_parts``; the same bits). The backward pass recomputes each batch and
   applies the 3DGS gradient formulas (no per-pixel state is kept between passes).

``rasterize`` returns the image on a background colour, the accumulated alpha and
optionally the alpha-weighted depth; gradients reach means, quats, scales, opacities
and colours (and anything upstream, e.g. the neural-Gaussian MLPs).

``rasterize_gsplat`` does the same with gsplat's CUDA rasterizer (``pip install
'lghcc[gsplat]'`` and a CUDA GPU); ``render_scene(backend=...)`` chooses: 'auto' (the
default) takes gsplat when CUDA and gsplat are both usable, else this module ('torch').
Results come back on the device and in the dtype of the caller's colours. Conventions are
the same (quaternions (w, x, y, z), world-to-camera OpenCV view matrix, pixel centres at
+0.5, eps2d dilation, depth-sorted front-to-back compositing stopping before the
transmittance drops below 1e-4, background added as (1 - alpha) bg). Known differences:

* gsplat clamps alpha at 0.999, this module (as 3DGS) at 0.99: they differ where
  opacity x exp(-power) > 0.99.
* gsplat with its opacity-aware bounding box (recent releases; older ones bound by 3 sigma
  of the major axis, by tile) draws every pixel with alpha >= 1/255, i.e. out to
  sqrt(2 ln(255 o)) <= 3.33 standard deviations; this module stops at
  ``sigma_cutoff`` (default 3) as well. ``sigma_cutoff=GSPLAT_SIGMA_CUTOFF`` (3.33) makes
  the footprints equal; at 3, a pixel between 3 and 3.33 sigma lacks alpha <= o e^-4.5
  (<= 0.011) per Gaussian.
* float32 throughout in gsplat (fast exp); this module projects in float64. Near the
  alpha >= 1/255 and transmittance thresholds a rounding can draw or skip one Gaussian
  at a pixel (<= 1/255 per such pixel).
* zero quaternions (identity here), non-finite colours (0 here) and opacities outside
  [0, 1] (clamped here) are sanitized by ``rasterize_gsplat`` before gsplat sees them.

tests/test_render_rasterizer.py::test_gsplat_matches_cpu_rasterizer states the measured
agreement (skipped without CUDA and gsplat).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import torch

from .camera import Camera

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
LOG_T_MIN = math.log(T_MIN)
DEFAULT_CHUNK_ELEMENTS = 1 << 21  # (Gaussian, pixel) pairs per batch
# Tile sides the rasterizer chooses from (tile_size None): every (Gaussian, tile) pair costs its
# tile's pixels plus a fixed overhead worth about PAIR_OVERHEAD_PX pixels (indexing, the
# Gaussian's coefficients), so small footprints want small tiles and large ones large tiles.
# Measured on 8-16 views each (torch CPU, 2 threads): the 150k-Gaussian PlayCanvas logo sample at
# 128 px 11.8 s with 16-pixel tiles, 5.6 s with 8, 4.3 s with 4; the donut at 320 px 4.8, 4.1
# and 4.4 s; the overhead fitted to the donut's three times.
TILE_SIZES = (4, 8, 16)
PAIR_OVERHEAD_PX = 18


# --------------------------------------------------------------------------------------
# Projection
# --------------------------------------------------------------------------------------

def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """[M, 4] (w, x, y, z), any norm (zero -> identity) -> [M, 3, 3]."""
    n = torch.linalg.vector_norm(q, dim=1, keepdim=True)
    q = torch.where(n > 0, q / n.clamp_min(1e-30), torch.tensor([1.0, 0, 0, 0], dtype=q.dtype, device=q.device))
    w, x, y, z = q.unbind(1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], dim=1).reshape(-1, 3, 3)


@dataclass
class Projection:
    """Per Gaussian (all M, in input order); only entries with ``valid`` are meaningful."""
    means2d: torch.Tensor  # [M, 2] pixel coordinates
    conics: torch.Tensor  # [M, 3] (a, b, c): power = 0.5 a dx^2 + b dx dy + 0.5 c dy^2
    depths: torch.Tensor  # [M] camera z
    cov2d: torch.Tensor  # [M, 3] (xx, xy, yy)
    valid: torch.Tensor  # [M] bool: in front of the camera, finite


def project_gaussians(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, camera: Camera,
                      eps2d: float = 0.3) -> Projection:
    """EWA projection of 3D Gaussians into ``camera`` (see the module doc)."""
    dt = means.dtype
    m, q, s = means.double(), quats.double(), scales.double()
    r = torch.as_tensor(camera.rotation, dtype=torch.float64, device=means.device)
    t = torch.as_tensor(camera.translation, dtype=torch.float64, device=means.device)
    pc = m @ r.T + t
    x, y, z = pc.unbind(1)
    valid = (z > camera.near) & (z < camera.far) & torch.isfinite(pc).all(1)
    zs = torch.where(valid, z, torch.ones_like(z))
    # 3DGS / gsplat: tan_fov = 0.5 W / fx; limits = image edges + 0.3 tan_fov
    tan_x, tan_y = 0.5 * camera.width / camera.fx, 0.5 * camera.height / camera.fy
    lim_xp = (camera.width - camera.cx) / camera.fx + 0.3 * tan_x
    lim_xn = camera.cx / camera.fx + 0.3 * tan_x
    lim_yp = (camera.height - camera.cy) / camera.fy + 0.3 * tan_y
    lim_yn = camera.cy / camera.fy + 0.3 * tan_y
    tx = torch.clamp(x / zs, -lim_xn, lim_xp) * zs
    ty = torch.clamp(y / zs, -lim_yn, lim_yp) * zs
    fx, fy = camera.fx, camera.fy
    zero = torch.zeros_like(zs)
    jac = torch.stack([fx / zs, zero, -fx * tx / zs ** 2, zero, fy / zs, -fy * ty / zs ** 2], 1).reshape(-1, 2, 3)
    rot = quat_to_rotmat(q)
    s = torch.where(torch.isfinite(s), s.abs(), torch.zeros_like(s)).clamp(max=1e30)
    ms = rot * s[:, None, :]  # R S
    jw = jac @ r  # [M, 2, 3]
    tmat = jw @ ms  # J W R S
    cov = tmat @ tmat.transpose(1, 2)
    a = cov[:, 0, 0] + eps2d
    b = cov[:, 0, 1]
    c = cov[:, 1, 1] + eps2d
    det = a * c - b * b
    valid = valid & (det > 0) & torch.isfinite(det)
    det = torch.where(valid, det, torch.ones_like(det))
    a, b, c = (torch.where(valid, v, torch.ones_like(v) if v is not b else torch.zeros_like(v)) for v in (a, b, c))
    conics = torch.stack([c / det, -b / det, a / det], 1)
    u = fx * x / zs + camera.cx
    v = fy * y / zs + camera.cy
    means2d = torch.stack([u, v], 1)
    valid = valid & torch.isfinite(means2d).all(1)
    means2d = torch.where(valid[:, None], means2d, torch.zeros_like(means2d))
    return Projection(means2d.to(dt), conics.to(dt), z.to(dt), torch.stack([a, b, c], 1).to(dt), valid)


# --------------------------------------------------------------------------------------
# Tiles
# --------------------------------------------------------------------------------------

@dataclass
class TilePlan:
    """Gaussian-tile pairs sorted by (tile, depth), and batches of tiles to process."""
    tile_size: int
    tiles_x: int
    tiles_y: int
    gauss: torch.Tensor  # [P] int64, Gaussian index per pair (index into the compacted arrays)
    tile_start: torch.Tensor  # [T] int64, first pair of each tile
    tile_count: torch.Tensor  # [T] int64
    batches: list = field(default_factory=list)  # (tile ids [B], length L, chunk length Lc)

    @property
    def num_pairs(self) -> int:
        return int(self.gauss.numel())


def _tile_ranges(md: torch.Tensor, ex: torch.Tensor, ey: torch.Tensor, width: int, height: int, tile_size: int):
    """Per Gaussian, the tiles its footprint box meets: (x0, y0, nx, ny) and the tiles per row and column."""
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    x0 = torch.floor((md[:, 0] - ex) / tile_size).clamp(0, tiles_x)
    x1 = torch.floor((md[:, 0] + ex) / tile_size + 1).clamp(0, tiles_x)
    y0 = torch.floor((md[:, 1] - ey) / tile_size).clamp(0, tiles_y)
    y1 = torch.floor((md[:, 1] + ey) / tile_size + 1).clamp(0, tiles_y)
    return x0, y0, (x1 - x0).long(), (y1 - y0).long(), tiles_x, tiles_y


def choose_tile_size(md: torch.Tensor, ex: torch.Tensor, ey: torch.Tensor, drawn: torch.Tensor, width: int,
                     height: int) -> int:
    """The side of TILE_SIZES with the least compositing work: pairs x (pixels per tile + PAIR_OVERHEAD_PX)."""
    return _least_work_ranges(md, ex, ey, drawn, width, height)[0]


def _least_work_ranges(md, ex, ey, drawn, width: int, height: int) -> tuple[int, tuple]:
    """(``choose_tile_size``'s side, its ``_tile_ranges``): the plan reuses the ranges measured."""
    best = None
    for ts in TILE_SIZES:
        ranges = _tile_ranges(md, ex, ey, width, height, ts)
        work = float((ranges[2] * ranges[3])[drawn].sum()) * (ts * ts + PAIR_OVERHEAD_PX)
        if best is None or work < best[0]:
            best = (work, ts, ranges)
    return best[1], best[2]


def _plan_tiles(means2d: torch.Tensor, cov2d: torch.Tensor, thresh: torch.Tensor, depths: torch.Tensor,
                width: int, height: int, tile_size: int | None, chunk_elements: int):
    """Bounding boxes of the footprints -> sorted pairs and batches (``tile_size`` None: chosen,
    ``choose_tile_size``). Returns (plan, keep) where keep [M] says which Gaussians touch at
    least one tile."""
    with torch.no_grad():
        md = means2d.detach().double()
        cv = cov2d.detach().double()
        tt = thresh.double().clamp_min(0)
        ex = torch.sqrt(2 * tt * cv[:, 0])
        ey = torch.sqrt(2 * tt * cv[:, 2])
        if tile_size is None:
            tile_size, ranges = _least_work_ranges(md, ex, ey, thresh > 0, width, height)
        else:
            ranges = _tile_ranges(md, ex, ey, width, height, tile_size)
        x0, y0, nx, ny, tiles_x, tiles_y = ranges
        keep = (thresh > 0) & (nx > 0) & (ny > 0)
        kidx = torch.nonzero(keep).squeeze(1)
        # depth order among the kept Gaussians
        order = kidx[torch.argsort(depths.detach()[kidx], stable=True)]
        cnt = (nx * ny)[order]
        total = int(cnt.sum())
        gid = torch.repeat_interleave(order, cnt)
        first = torch.cumsum(cnt, 0) - cnt
        local = torch.arange(total, dtype=torch.int64) - torch.repeat_interleave(first, cnt)
        nxg = nx[gid]
        tx = x0.long()[gid] + local % nxg
        ty = y0.long()[gid] + torch.div(local, nxg, rounding_mode="floor")
        tile = ty * tiles_x + tx
        tile_sorted, perm = torch.sort(tile, stable=True)
        gauss = gid[perm]
        ntiles = tiles_x * tiles_y
        tile_count = torch.bincount(tile_sorted, minlength=ntiles)
        tile_start = torch.cumsum(tile_count, 0) - tile_count
        # batches: tiles by decreasing count; a batch holds B tiles padded to the longest
        batches = []
        per_tile = tile_size * tile_size
        lmax_chunk = max(1, chunk_elements // per_tile)
        nonempty = torch.nonzero(tile_count > 0).squeeze(1)
        srt = nonempty[torch.argsort(tile_count[nonempty], descending=True, stable=True)]
        counts = tile_count[srt].tolist()
        i = 0
        while i < len(counts):
            length = counts[i]
            lc = min(length, lmax_chunk)
            nb = max(1, chunk_elements // (lc * per_tile))
            batches.append((srt[i:i + nb], length, lc))
            i += nb
        plan = TilePlan(tile_size, tiles_x, tiles_y, gauss, tile_start, tile_count, batches)
    return plan, keep


def _pixel_basis(tile_size: int, dtype: torch.dtype) -> torch.Tensor:
    """[6, P] rows (1, px, py, px^2, py^2, px py), pixel centres relative to the tile centre."""
    r = torch.arange(tile_size, dtype=torch.float64) + 0.5 - tile_size / 2
    py, px = torch.meshgrid(r, r, indexing="ij")
    px, py = px.reshape(-1), py.reshape(-1)
    return torch.stack([torch.ones_like(px), px, py, px * px, py * py, px * py]).to(dtype)


def _coefficients(mx: torch.Tensor, my: torch.Tensor, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor):
    """Power = coef . basis for a Gaussian at tile-local (mx, my) with conic (a, b, c)."""
    return torch.stack([0.5 * a * mx * mx + 0.5 * c * my * my + b * mx * my,
                        -(a * mx + b * my), -(c * my + b * mx), 0.5 * a, 0.5 * c, b], -1)


def _composite_forward(md, cn, op, ft, th, plan: TilePlan, m: int, acc: torch.Tensor | None = None,
                       weight_sum: WeightSum | None = None) -> list:
    """The front-to-back compositing of every tile batch (padded inputs, Gaussian m the pad):
    w_i = alpha_i T_i per pixel; adds sum_i w_i f_i into ``acc`` [tiles, pixels, d] and, when
    given, each Gaussian's sum of w_i over the pixels of each region into ``weight_sum``. Returns
    the transmittance carries at each chunk start (the backward pass recomputes from them)."""
    dt = md.dtype
    npx = plan.tile_size ** 2
    basis = _pixel_basis(plan.tile_size, dt)
    carries = []
    with torch.no_grad():
        for tiles, length, lc in plan.batches:
            idx, centres = _batch_index(plan, tiles, length, m)
            if lc == length and length >= 2 * PART_GAUSSIANS:
                w = _batch_weights_in_parts(idx, centres, plan.tile_count[tiles], md, cn, op, th, basis)
                _add_weighted(w, idx, tiles, ft, acc, weight_sum)
                carries.append([torch.zeros(len(tiles), npx, 1, dtype=dt)])
                continue
            carry = torch.zeros(len(tiles), npx, 1, dtype=dt)
            saved = []
            for s0 in range(0, length, lc):
                saved.append(carry)
                g = idx[:, s0:s0 + lc]
                alpha, _, _ = _alpha(g, centres, md, cn, op, th, basis)  # [B, P, L]
                la = torch.log1p(-alpha)
                cs = torch.cumsum(la, 2).add_(carry)
                _add_weighted(_weights(cs, la, alpha), g, tiles, ft, acc, weight_sum)
                carry = cs[:, :, -1:]
            carries.append(saved)
    return carries


def _weights(cs: torch.Tensor, la: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """w_i = alpha_i T_i from the log transmittance after each Gaussian (``cs``) and its log(1 - alpha_i)."""
    return (cs - la).clamp_(min=-80.0).exp_().mul_(alpha).mul_(cs >= LOG_T_MIN)


@dataclass
class WeightSum:
    """Per Gaussian and region of the picture, the sum of w_i over the region's pixels: ``sums``
    float64 [(m + 1) * regions] (Gaussian g's region r at g * regions + r), ``tile_region`` int64
    [tiles] the region of each tile."""
    sums: torch.Tensor
    tile_region: torch.Tensor
    regions: int

    def add(self, w: torch.Tensor, g: torch.Tensor, tiles: torch.Tensor) -> None:
        at = g * self.regions + self.tile_region[tiles][:, None] if self.regions > 1 else g
        self.sums.index_add_(0, at.reshape(-1), w.sum(1).reshape(-1).to(self.sums.dtype))


def _add_weighted(w, g, tiles, ft, acc, weight_sum: WeightSum | None) -> None:
    if acc is not None:
        acc[tiles] += torch.bmm(w, ft[g])
    if weight_sum is not None:
        weight_sum.add(w, g, tiles)


# A batch of tiles longer than twice this is composited in at most BATCH_PARTS parts along depth,
# each this long at least (``_batch_weights_in_parts``): at least 12, where torch's CPU matrix
# product gives each column the bits it gives it in a longer one; more parts drop used-up tiles
# sooner, fewer cost less in calls.
PART_GAUSSIANS = 64
BATCH_PARTS = 16


def _batch_weights_in_parts(idx, centres, counts, md, cn, op, th, basis) -> torch.Tensor:
    """w [B, P, L] of one batch (``_composite_forward``'s single-chunk case) in equal parts along
    depth (PART_GAUSSIANS, BATCH_PARTS), the last taking the remainder: after each part the tiles whose
    transmittance fell below T_MIN at every pixel, or whose Gaussians ran out (the rest is padding),
    leave the batch; their later weights are 0, as the whole batch at once computes them. The
    log transmittance runs on in float64 from part to part, as torch's CPU cumsum accumulates a
    float32 one, so every weight has the bits of the single pass (tests/test_render_rasterizer.py).
    On the search's views (128 px, 4-pixel tiles) a third of the (tile, Gaussian) slots of a sample's
    batches were padding and a third behind used-up transmittance."""
    nb, length = idx.shape
    w = torch.zeros(nb, basis.shape[1], length, dtype=md.dtype)
    rows = torch.arange(nb)
    run = torch.zeros(nb, basis.shape[1], 1, dtype=torch.float64)  # log T so far, as cumsum holds it
    parts = min(length // PART_GAUSSIANS, BATCH_PARTS)
    size = length // parts
    for i in range(parts):
        s0, s1 = i * size, length if i == parts - 1 else (i + 1) * size
        alpha, _, _ = _alpha(idx[rows, s0:s1], centres[rows], md, cn, op, th, basis)
        la = torch.log1p(-alpha)
        run = torch.cumsum(torch.cat([run, la.double()], 2), 2)[:, :, 1:]
        cs = run.to(md.dtype)
        w[rows, :, s0:s1] = _weights(cs, la, alpha)
        live = (cs[:, :, -1] >= LOG_T_MIN).any(1) & (counts[rows] > s1)
        rows, run = rows[live], run[:, :, -1:][live]
        if rows.numel() == 0:
            break
    return w


class _Composite(torch.autograd.Function):
    """acc[tile, pixel, :] = sum_i w_i f_i with w_i = alpha_i T_i (front to back)."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, thresh, plan: TilePlan):
        dt = feats.dtype
        m, d = feats.shape
        acc = torch.zeros(plan.tiles_x * plan.tiles_y, plan.tile_size ** 2, d, dtype=dt)
        # padding Gaussian at index m: never drawn (threshold below any power)
        md, cn, op, ft, th = _padded(means2d, conics, opacities, feats, thresh)
        carries = _composite_forward(md, cn, op, ft, th, plan, m, acc=acc)
        ctx.plan, ctx.carries = plan, carries
        ctx.save_for_backward(means2d, conics, opacities, feats, thresh)
        return acc

    @staticmethod
    def backward(ctx, grad_acc):
        means2d, conics, opacities, feats, thresh = ctx.saved_tensors
        plan = ctx.plan
        dt = feats.dtype
        m, d = feats.shape
        ts = plan.tile_size
        basis = _pixel_basis(ts, dt)
        md, cn, op, ft, th = _padded(means2d, conics, opacities, feats, thresh)
        g_md = torch.zeros(m + 1, 2, dtype=dt)
        g_cn = torch.zeros(m + 1, 3, dtype=dt)
        g_op = torch.zeros(m + 1, dtype=dt)
        g_ft = torch.zeros(m + 1, d, dtype=dt)
        grad_acc = grad_acc.contiguous()
        for (tiles, length, lc), saved in zip(plan.batches, ctx.carries):
            idx, centres = _batch_index(plan, tiles, length, m)
            centres = centres.to(dt)
            gout = grad_acc[tiles]  # [B, npx, d]
            suffix = torch.zeros(len(tiles), ts * ts, 1, dtype=dt)  # sum over later chunks of gf_j w_j
            for ci in range(len(saved) - 1, -1, -1):
                s0 = ci * lc
                g = idx[:, s0:s0 + lc]
                alpha, gexp, pmask = _alpha(g, centres, md, cn, op, th, basis)
                la = torch.log1p(-alpha)  # [B, P, Lc]
                cs = torch.cumsum(la, 2).add_(saved[ci])
                incl = cs >= LOG_T_MIN
                t_ex = (cs - la).clamp_(min=-80.0).exp_()  # drawn pairs have cs >= ln 1e-4
                w = t_ex * alpha * incl
                fg = ft[g]  # [B, Lc, d]
                g_ft.index_add_(0, g.reshape(-1), torch.bmm(w.transpose(1, 2), gout).reshape(-1, d))
                gf = torch.bmm(gout, fg.transpose(1, 2))  # [B, P, Lc] dL/dw
                gw = gf * w
                csum = torch.cumsum(gw, 2)
                total = csum[:, :, -1:]
                s_after = (total - csum).add_(suffix)
                suffix = suffix + total
                # dL/dalpha = T_i gf_i - S_i / (1 - alpha_i), on drawn, unclamped entries
                g_alpha = (gf * t_ex - s_after / (1 - alpha)) * (incl & pmask)
                g_op.index_add_(0, g.reshape(-1), (g_alpha * gexp).sum(1).reshape(-1))
                g_pow = -(g_alpha * alpha)  # dL/dpower [B, P, Lc]
                gcoef = torch.matmul(basis, g_pow).transpose(1, 2)  # [B, Lc, 6]
                mx = md[g, 0] - centres[:, None, 0]
                my = md[g, 1] - centres[:, None, 1]
                a, b, c = cn[g, 0], cn[g, 1], cn[g, 2]
                g0, g1, g2, g3, g4, g5 = gcoef.unbind(-1)
                gmx = g0 * (a * mx + b * my) - g1 * a - g2 * b
                gmy = g0 * (c * my + b * mx) - g1 * b - g2 * c
                ga = g0 * 0.5 * mx * mx - g1 * mx + 0.5 * g3
                gb = g0 * mx * my - g1 * my - g2 * mx + g5
                gc = g0 * 0.5 * my * my - g2 * my + 0.5 * g4
                flat = g.reshape(-1)
                g_md.index_add_(0, flat, torch.stack([gmx, gmy], -1).reshape(-1, 2))
                g_cn.index_add_(0, flat, torch.stack([ga, gb, gc], -1).reshape(-1, 3))
        return g_md[:m], g_cn[:m], g_op[:m], g_ft[:m], None, None


def _padded(means2d, conics, opacities, feats, thresh):
    dt = feats.dtype
    md = torch.cat([means2d.detach(), torch.zeros(1, 2, dtype=dt)])
    cn = torch.cat([conics.detach(), torch.ones(1, 3, dtype=dt)])
    op = torch.cat([opacities.detach(), torch.zeros(1, dtype=dt)])
    ft = torch.cat([feats.detach(), torch.zeros(1, feats.shape[1], dtype=dt)])
    th = torch.cat([thresh.to(dt), torch.full((1,), -1.0, dtype=dt)])
    return md, cn, op, ft, th


def _batch_index(plan: TilePlan, tiles: torch.Tensor, length: int, pad: int):
    """[B, L] Gaussian indices (pad where a tile has fewer) and tile centres [B, 2]."""
    ar = torch.arange(length, dtype=torch.int64)
    cnt = plan.tile_count[tiles]
    pos = plan.tile_start[tiles][:, None] + ar[None, :]
    ok = ar[None, :] < cnt[:, None]
    idx = torch.where(ok, plan.gauss[pos.clamp(max=max(plan.num_pairs - 1, 0))], torch.full_like(pos, pad))
    ts = plan.tile_size
    centres = torch.stack([(tiles % plan.tiles_x).double() * ts + ts / 2,
                           torch.div(tiles, plan.tiles_x, rounding_mode="floor").double() * ts + ts / 2], 1)
    return idx, centres


def _alpha(g, centres, md, cn, op, th, basis):
    """alpha [B, P, L] (pixels x Gaussians; 0 where not drawn), o*exp(-power) and the unclamped-drawn mask."""
    dt = md.dtype
    c = centres.to(dt)
    mx = md[g, 0] - c[:, None, 0]
    my = md[g, 1] - c[:, None, 1]
    coef = _coefficients(mx, my, cn[g, 0], cn[g, 1], cn[g, 2])  # [B, L, 6]
    # clamp to [0, 80]: exp(-80) is still a normal float32 (denormals are very slow on CPUs);
    # the cutoff is <= 4.5, so the clamp changes no drawn pair
    power = torch.matmul(basis.T, coef.transpose(1, 2)).clamp_(0.0, 80.0)  # [B, P, L]
    drawn = power <= th[g][:, None, :]
    gexp = power.neg_().exp_().mul_(drawn)  # G (0 where not drawn)
    alpha = gexp * op[g][:, None, :]
    unclamped = drawn & (alpha < ALPHA_MAX)
    alpha = alpha.clamp_(max=ALPHA_MAX)
    return alpha, gexp, unclamped


# --------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------

@dataclass
class RenderResult:
    image: torch.Tensor  # [H, W, C] on the background
    alpha: torch.Tensor  # [H, W] accumulated opacity (1 - final transmittance)
    depth: torch.Tensor | None  # [H, W] alpha-weighted camera depth sum_i w_i z_i (divide by alpha for mean)
    stats: dict


def _check_gaussians(means, quats, scales, opacities, colors) -> tuple[int, int]:
    """The shapes every backend requires: means [M, 3], quats [M, 4], scales [M, 3],
    opacities [M], colors [M, C]. Returns (M, C); ValueError naming the tensor otherwise."""
    if means.ndim != 2 or means.shape[1] != 3:
        raise ValueError(f"means must be [M, 3], got {list(means.shape)}")
    mcount = means.shape[0]
    for name, t, shape in (("quats", quats, (mcount, 4)), ("scales", scales, (mcount, 3)),
                           ("opacities", opacities, (mcount,))):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must be {list(shape)}, got {list(t.shape)}")
    if colors.ndim != 2 or colors.shape[0] != mcount:
        raise ValueError(f"colors must be [M, C], got {list(colors.shape)}")
    return mcount, colors.shape[1]


def rasterize(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
              colors: torch.Tensor, camera: Camera, *, background=None, tile_size: int | None = None,
              sigma_cutoff: float = 3.0, eps2d: float = 0.3, render_depth: bool = False,
              chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> RenderResult:
    """Render Gaussians (means [M, 3], quats [M, 4] (w, x, y, z), scales [M, 3] (not log),
    opacities [M] in [0, 1], colors [M, C]) into ``camera``. ``background``: C values (default
    zeros). Differentiable with respect to all five tensors. The dtype of ``colors`` sets
    the compositing precision (float64 for gradient checks)."""
    dt = colors.dtype
    h, w = camera.height, camera.width
    mcount, nch = _check_gaussians(means, quats, scales, opacities, colors)
    bg = torch.zeros(nch, dtype=dt) if background is None else torch.as_tensor(background, dtype=dt).reshape(-1)
    if bg.shape != (nch,):
        raise ValueError(f"background must have {nch} values, got {list(bg.shape)}")
    op = opacities.to(dt)
    drawn = _project_and_plan(means, quats, scales, op, camera, tile_size, sigma_cutoff, eps2d, chunk_elements)
    kidx, plan = drawn.kidx, drawn.plan
    feats = colors[kidx].to(dt)
    feats = torch.where(torch.isfinite(feats), feats, torch.zeros_like(feats))
    extra = [torch.ones(kidx.numel(), 1, dtype=dt)]
    if render_depth:
        extra.append(drawn.depths.to(dt)[:, None])
    feats = torch.cat([feats] + extra, 1)
    acc = _Composite.apply(drawn.means2d.to(dt), drawn.conics.to(dt), op[kidx].clamp(0, 1), feats,
                           drawn.thresh.to(dt), plan)
    ts = plan.tile_size
    img = acc.reshape(plan.tiles_y, plan.tiles_x, ts, ts, -1).permute(0, 2, 1, 3, 4)
    img = img.reshape(plan.tiles_y * ts, plan.tiles_x * ts, -1)[:h, :w]
    alpha = img[..., nch]
    image = img[..., :nch] + (1 - alpha)[..., None] * bg
    depth = img[..., nch + 1] if render_depth else None
    stats = {"gaussians": mcount, "in_front": drawn.in_front, "rasterized": int(kidx.numel()),
             "tile_size": plan.tile_size, "tile_pairs": plan.num_pairs, "batches": len(plan.batches), "backend": "torch"}
    return RenderResult(image, alpha, depth, stats)


@dataclass
class _Drawn:
    """The Gaussians a view draws (``_project_and_plan``): their indices into the input, their
    projection and drawing threshold in that order, and the tile plan over them (indices into them)."""
    kidx: torch.Tensor
    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    thresh: torch.Tensor
    plan: TilePlan
    in_front: int  # Gaussians in front of the camera (the projection's ``valid``)


def _project_and_plan(means, quats, scales, op, camera: Camera, tile_size: int | None, sigma_cutoff: float,
                      eps2d: float, chunk_elements: int) -> _Drawn:
    """Projection of the Gaussians that may reach the image (``_may_reach_image``), each one's
    drawing threshold (power below ln(255 o), within the sigma cutoff; -1 for those never drawn)
    and the tile plan, compacted to the Gaussians it draws."""
    rows = _may_reach_image(means, scales, camera, sigma_cutoff, eps2d, tile_size)
    part = (lambda t: t) if rows is None else (lambda t: t[rows])
    proj = project_gaussians(part(means), part(quats), part(scales), camera, eps2d)
    with torch.no_grad():
        o = part(op).detach().double()
        finite_o = torch.isfinite(o) & (o > 0)
        lo = torch.log(255.0 * torch.where(finite_o, o, torch.ones_like(o)).clamp(max=1.0))
        thresh = torch.minimum(lo, torch.full_like(lo, 0.5 * sigma_cutoff ** 2))
        thresh = torch.where(proj.valid & finite_o & (o * 255.0 >= 1.0), thresh, torch.full_like(thresh, -1.0))
    plan, keep = _plan_tiles(proj.means2d, proj.cov2d, thresh, proj.depths, camera.width, camera.height, tile_size,
                             chunk_elements)
    k = torch.nonzero(keep).squeeze(1)
    remap = torch.full((keep.numel() + 1,), -1, dtype=torch.int64)
    remap[k] = torch.arange(k.numel())
    plan.gauss = remap[plan.gauss]
    culled = 0 if rows is None else means.shape[0] - rows.numel()
    return _Drawn(k if rows is None else rows[k], proj.means2d[k], proj.conics[k], proj.depths[k], thresh[k], plan,
                  int(proj.valid.sum()) + culled)


def _may_reach_image(means, scales, camera: Camera, sigma_cutoff: float, eps2d: float,
                     tile_size: int | None) -> torch.Tensor | None:
    """int64 [M']: all but the Gaussians in front of the camera whose footprint cannot reach the
    image's tiles, or None where that is all of them. The footprint's half-width is at most
    sigma_cutoff sqrt(cov2d_xx) (``_plan_tiles``) and cov2d_xx at most |J row 0|^2 max(scale)^2 +
    eps2d, J's row clamped as ``project_gaussians`` clamps it (likewise in y); with 1% and a pixel
    to spare, the culled ones are those ``_plan_tiles`` would drop, and the others project with the
    bits they had among all. In the magnified crops of the search's views of a large scene 4-27%
    of the Gaussians reach the image."""
    with torch.no_grad():
        pc = means.detach().double() @ torch.as_tensor(camera.rotation, dtype=torch.float64).T + \
            torch.as_tensor(camera.translation, dtype=torch.float64)
        x, y, z = pc.unbind(1)
        s = scales.detach().double()
        smax = torch.where(torch.isfinite(s), s.abs(), torch.full_like(s, math.inf)).amax(1)
        front = (z > camera.near) & (z < camera.far)
        zs = torch.where(front, z, torch.ones_like(z))
        margin = max(TILE_SIZES + (tile_size or 0,)) + 1.0
        out = torch.zeros_like(front)
        for p, f, c, size, lim in ((x, camera.fx, camera.cx, camera.width, _jacobian_limit(camera, 0)),
                                   (y, camera.fy, camera.cy, camera.height, _jacobian_limit(camera, 1))):
            half = 1.01 * sigma_cutoff * torch.sqrt((abs(f) / zs) ** 2 * (1 + lim ** 2) * smax ** 2 + eps2d) + 1.0
            u = f * p / zs + c
            out |= (u + half < -1.0) | (u - half > size + margin)
        out &= front
        return None if not bool(out.any()) else torch.nonzero(~out).squeeze(1)


def _jacobian_limit(camera: Camera, axis: int) -> float:
    """The largest |x / z| (axis 0) or |y / z| (axis 1) ``project_gaussians`` lets the Jacobian see."""
    if axis == 0:
        tan_x = 0.5 * camera.width / camera.fx
        return max(abs((camera.width - camera.cx) / camera.fx), abs(camera.cx / camera.fx)) + 0.3 * abs(tan_x)
    tan_y = 0.5 * camera.height / camera.fy
    return max(abs((camera.height - camera.cy) / camera.fy), abs(camera.cy / camera.fy)) + 0.3 * abs(tan_y)


def compositing_weights(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                        camera: Camera, *, regions: int = 1, tile_size: int | None = None, sigma_cutoff: float = 3.0,
                        eps2d: float = 0.3, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """float64 [M]: each Gaussian's compositing weight alpha_i T_i summed over the pixels of
    ``camera``, as ``rasterize`` draws it (one forward pass, no gradient). With ``regions`` > 1,
    float64 [M, regions^2]: the sums over each of a regions x regions grid of parts of the picture
    (row-major; the parts are whole tiles, split as evenly as the tiles allow)."""
    mcount = means.shape[0]
    with torch.no_grad():
        op = opacities.detach().float()
        drawn = _project_and_plan(means.detach(), quats.detach(), scales.detach(), op, camera, tile_size,
                                  sigma_cutoff, eps2d, chunk_elements)
        kidx = drawn.kidx
        k = kidx.numel()
        md, cn, opp, ft, th = _padded(drawn.means2d.float(), drawn.conics.float(), op[kidx].clamp(0, 1),
                                      torch.zeros(k, 1), drawn.thresh.float())
        plan, r = drawn.plan, regions * regions
        t = torch.arange(plan.tiles_x * plan.tiles_y)
        tile_region = (t // plan.tiles_x) * regions // plan.tiles_y * regions + (t % plan.tiles_x) * regions // plan.tiles_x
        ws = WeightSum(torch.zeros((k + 1) * r, dtype=torch.float64), tile_region, r)
        _composite_forward(md, cn, opp, ft, th, plan, k, weight_sum=ws)
        out = torch.zeros(mcount, r, dtype=torch.float64)
        out[kidx] = ws.sums.view(k + 1, r)[:k]
    return out[:, 0] if regions == 1 else out


def render_scene(scene, camera: Camera, *, background=None, cull: bool = True, margin: float = 0.15,
                 dtype: torch.dtype = torch.float32, backend: Backend = "auto", **kw) -> RenderResult:
    """Neural Gaussians of ``scene`` (AnchorScene or SceneTensors) for ``camera``, rasterized.
    ``backend``: 'torch' (this module, CPU), 'gsplat' (CUDA; see ``rasterize_gsplat``) or
    'auto' (gsplat when CUDA and gsplat are usable, else torch; ``select_backend``). The
    image is on the device of the scene's tensors (the CPU for an AnchorScene) either way."""
    from .neural_gaussians import generate_neural_gaussians

    fn = rasterize if select_backend(backend) == "torch" else rasterize_gsplat
    sigma = kw.get("sigma_cutoff", 3.0)
    ng = generate_neural_gaussians(scene, camera, cull=cull, margin=margin, sigma_cutoff=sigma, dtype=dtype)
    res = fn(ng.means, ng.quats, ng.scales, ng.opacities, ng.colors, camera, background=background, **kw)
    res.stats.update({f"ng_{k}": v for k, v in ng.stats.items()})
    return res


def composite_reference(means2d, conics, opacities, feats, thresh, width: int, height: int):
    """Plain-autograd compositing of all Gaussians over all pixels, one Gaussian at a time in
    the given (depth) order: the definition the tiled path must match. Small images only.
    Returns acc [H, W, C] = sum_i w_i f_i (no background)."""
    dt = feats.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5,
                            indexing="ij")
    acc = torch.zeros(height, width, feats.shape[1], dtype=dt)
    logt = torch.zeros(height, width, dtype=dt)
    for i in range(means2d.shape[0]):
        dx, dy = means2d[i, 0] - xs, means2d[i, 1] - ys
        a, b, c = conics[i]
        power = 0.5 * a * dx * dx + 0.5 * c * dy * dy + b * dx * dy
        drawn = power <= thresh[i]
        alpha = torch.where(drawn, torch.clamp(opacities[i] * torch.exp(-power), max=ALPHA_MAX),
                            torch.zeros((), dtype=dt))
        la = torch.log1p(-alpha)
        ok = (logt + la) >= LOG_T_MIN
        w = torch.where(ok, alpha * torch.exp(logt), torch.zeros((), dtype=dt))
        acc = acc + w[..., None] * feats[i]
        logt = logt + la
    return acc


# --------------------------------------------------------------------------------------
# Optional CUDA backend
# --------------------------------------------------------------------------------------

Backend = Literal["auto", "torch", "gsplat"]
# gsplat's footprint: alpha >= 1/255 reaches sqrt(2 ln(255 o)) <= sqrt(2 ln 255) standard deviations
GSPLAT_SIGMA_CUTOFF = math.sqrt(2.0 * math.log(255.0))
_GSPLAT_IMPORT: list = []  # [bool]: whether ``import gsplat`` worked (tried once)


def gsplat_available() -> bool:
    """True when gsplat imports and torch sees a CUDA device."""
    if not _GSPLAT_IMPORT:
        try:
            import gsplat  # noqa: F401  # pyright: ignore[reportMissingImports] (optional: lghcc[gsplat])
            _GSPLAT_IMPORT.append(True)
        except Exception:  # noqa: BLE001 - ImportError, or a gsplat build that fails to load
            _GSPLAT_IMPORT.append(False)
    return _GSPLAT_IMPORT[0] and torch.cuda.is_available()


def select_backend(backend: Backend = "auto") -> str:
    """'torch' or 'gsplat' for a requested backend: 'auto' takes gsplat when
    ``gsplat_available()``, else torch; 'gsplat' raises RuntimeError when it is not usable."""
    if backend == "auto":
        return "gsplat" if gsplat_available() else "torch"
    if backend == "torch":
        return "torch"
    if backend == "gsplat":
        if not gsplat_available():
            raise RuntimeError("the gsplat backend needs gsplat (pip install 'lghcc[gsplat]') and a CUDA GPU; "
                               "use backend='torch' or 'auto'")
        return "gsplat"
    raise ValueError(f"unknown backend {backend!r} (auto, torch or gsplat)")


Device = Literal["cpu", "cuda"]
DEVICES: tuple[str, ...] = ("cpu", "cuda")


def select_device(device: str = "cpu") -> str:
    """The rasterizer backend for a command's ``--device`` (lghcc-train, the transcoder of
    lghcc-enc): the one seam between a device name and ``select_backend``. 'cpu' -> 'torch'
    (this module); 'cuda' -> 'gsplat' (gsplat's CUDA rasterizer; the MLPs, the optimizer and
    everything else stay on the CPU, the rasterizer's inputs and outputs are copied, gradients
    flow through the copies). Raises InputError before any work: 'no CUDA device: ...' when
    torch sees no GPU, or naming what is missing when gsplat is not usable."""
    from ..common.errors import InputError

    if device == "cpu":
        return select_backend("torch")
    if device != "cuda":
        raise InputError(f"unknown device {device!r}: choose one of {', '.join(DEVICES)}")
    if not torch.cuda.is_available():
        build = torch.version.cuda
        raise InputError(f"no CUDA device: torch {torch.__version__} "
                         + (f"(built for CUDA {build}) finds no GPU" if build else "is a CPU-only build")
                         + "; use --device cpu, or a machine with an NVIDIA GPU and a CUDA build of torch")
    try:
        return select_backend("gsplat")
    except RuntimeError as e:
        raise InputError(f"--device cuda: {e}") from None


def rasterize_with(backend: str):
    """``rasterize`` or ``rasterize_gsplat`` for a backend that ``select_backend`` returned."""
    return rasterize if backend == "torch" else rasterize_gsplat


def rasterize_gsplat(means, quats, scales, opacities, colors, camera: Camera, *, background=None,
                     tile_size: int | None = None, eps2d: float = 0.3, render_depth: bool = False,
                     sigma_cutoff: float = 3.0, chunk_elements: int | None = None) -> RenderResult:
    """``rasterize`` with ``gsplat.rasterization`` (CUDA, float32): the same arguments and
    result. Inputs may be on the CPU or a CUDA device; the image, alpha and depth come back
    on the device and in the dtype of ``colors`` (differentiable through the copies).
    ``sigma_cutoff`` and ``chunk_elements`` are ignored (gsplat's footprint is alpha >= 1/255,
    see the module doc for the known differences)."""
    if not gsplat_available():
        raise RuntimeError("the gsplat backend needs gsplat (pip install 'lghcc[gsplat]') and a CUDA GPU")
    from gsplat import rasterization  # pyright: ignore[reportMissingImports] (optional: lghcc[gsplat])

    out_dev, dt = colors.device, colors.dtype
    mcount, nch = _check_gaussians(means, quats, scales, opacities, colors)
    dev = means.device if means.is_cuda else torch.device("cuda")
    f32 = torch.float32
    bg = torch.zeros(nch, dtype=f32, device=dev) if background is None else \
        torch.as_tensor(background, dtype=f32).reshape(-1).to(dev)
    if bg.shape != (nch,):
        raise ValueError(f"background must have {nch} values, got {list(bg.shape)}")
    if mcount == 0:  # nothing to draw: the background (as the CPU path)
        h, w = camera.height, camera.width
        img = bg.to(out_dev, dt).expand(h, w, nch) + colors.sum() * 0
        zero = torch.zeros(h, w, dtype=dt, device=out_dev)
        return RenderResult(img, zero, zero.clone() if render_depth else None,
                            {"gaussians": 0, "backend": "gsplat", "rasterized": 0})
    # the CPU path's sanitizing: zero quaternion -> identity, |scale|, finite colours, o in [0, 1]
    q = quats.to(dev, f32)
    qn = torch.linalg.vector_norm(q, dim=1, keepdim=True)
    q = torch.where(qn > 0, q / qn.clamp_min(1e-30), torch.tensor([1.0, 0, 0, 0], dtype=f32, device=dev))
    s = scales.to(dev, f32)
    s = torch.where(torch.isfinite(s), s.abs(), torch.zeros_like(s))
    c = colors.to(dev, f32)
    c = torch.where(torch.isfinite(c), c, torch.zeros_like(c))
    o = opacities.to(dev, f32).clamp(0, 1)
    viewmat = torch.as_tensor(camera.world_to_camera, dtype=f32).to(dev)[None]  # world -> camera (OpenCV)
    k = torch.as_tensor(camera.K, dtype=f32).to(dev)[None]
    out, alphas, meta = rasterization(
        means.to(dev, f32), q, s, o, c, viewmat, k, camera.width, camera.height,
        near_plane=camera.near, far_plane=camera.far, eps2d=eps2d, tile_size=tile_size or 16, backgrounds=bg[None],
        render_mode="RGB+ED" if render_depth else "RGB", packed=False, rasterize_mode="classic", sh_degree=None)
    img, alpha = out[0], alphas[0, ..., 0]
    depth = img[..., nch] * alpha if render_depth else None  # expected depth -> alpha-weighted sum
    img = img[..., :nch]
    radii = meta["radii"]
    drawn = (radii.reshape(radii.shape[0], radii.shape[1], -1) > 0).any(-1)
    stats = {"gaussians": int(mcount), "backend": "gsplat", "rasterized": int(drawn.sum())}
    back = lambda t: None if t is None else t.to(out_dev, dt)  # noqa: E731
    return RenderResult(back(img), back(alpha), back(depth), stats)
