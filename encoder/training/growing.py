"""Anchor growing and pruning of lghcc-train (Scaffold-GS; see the package docstring): the
statistics gathered per iteration, the growing and pruning every ``densify_interval``
iterations, and the pruning after growing (NAAP or opacity, encoder/anchors/naap.py)."""

from __future__ import annotations

import math

import torch


class AnchorGrowing:
    """Growing and pruning of a ``Trainer``'s anchors (training/loop.py); the parameters and
    statistics are those of ``AnchorParameters`` (training/parameters.py)."""

    def accumulate_growth_stats(self, st, ng, cam) -> None:
        """The statistics of growing (screen-space gradient norms of the drawn neural Gaussians) and
        pruning (opacity and visibility per anchor) for one rendered view."""
        from ...render.neural_gaussians import anchor_bounding_radii, visible_anchors

        k = self.cfg.num_offsets
        radii = anchor_bounding_radii(st.scalings, st.offsets, None)
        vis = visible_anchors(st.positions, radii, cam)
        self.anchor_demon[vis] += 1
        op = ng.opacities.detach().double().clamp_min(0)
        self.opacity_accum.index_add_(0, ng.anchor_index, op)
        g = ng.means.grad
        if g is None:
            return
        r = torch.as_tensor(cam.rotation, dtype=torch.float64)
        t = torch.as_tensor(cam.translation, dtype=torch.float64)
        gc = g.double() @ r.T
        z = (ng.means.detach().double() @ r.T + t)[:, 2].clamp_min(cam.near)
        gx = gc[:, 0] * z / cam.fx * (cam.width / 2)
        gy = gc[:, 1] * z / cam.fy * (cam.height / 2)
        gn = torch.sqrt(gx * gx + gy * gy)
        drawn = torch.isfinite(gn) & (gn > 0)  # Gaussians that reached the image
        flat = (ng.anchor_index * k + ng.offset_index)[drawn]
        self.offset_grad_accum.index_add_(0, flat, gn[drawn])
        self.offset_denom.index_add_(0, flat, torch.ones_like(gn[drawn]))

    def accumulate_lifetime_opacity(self, ng) -> None:
        """Opacity and views since each anchor's creation (``scene.extra["opacity_accum"]``)."""
        k = self.cfg.num_offsets
        op = ng.opacities.detach().double().clamp_min(0) / k
        self.life_opacity.index_add_(0, ng.anchor_index, op)
        seen = torch.unique(ng.anchor_index)
        self.life_views[seen] += 1

    # --- growing and pruning ---------------------------------------------------------
    @torch.no_grad()
    def adjust_anchors(self) -> None:
        cfg = self.cfg
        check = cfg.densify_interval
        grads = self.offset_grad_accum / self.offset_denom
        grads[~torch.isfinite(grads)] = 0.0
        offset_mask = self.offset_denom > check * cfg.success_threshold * 0.5
        n_before = self.num_anchors
        self._grow(grads, cfg.densify_grad_threshold, offset_mask)
        n_new = self.num_anchors - n_before
        k = cfg.num_offsets
        pad = torch.zeros(n_new * k, dtype=torch.float64)
        self.offset_denom[offset_mask] = 0
        self.offset_grad_accum[offset_mask] = 0
        self.offset_denom = torch.cat([self.offset_denom, pad])
        self.offset_grad_accum = torch.cat([self.offset_grad_accum, pad])
        pad_a = torch.zeros(n_new, dtype=torch.float64)
        self.opacity_accum = torch.cat([self.opacity_accum, pad_a])
        self.anchor_demon = torch.cat([self.anchor_demon, pad_a])
        self.life_opacity = torch.cat([self.life_opacity, pad_a])
        self.life_views = torch.cat([self.life_views, pad_a])
        prune = (self.opacity_accum < cfg.min_opacity * self.anchor_demon)
        seen_enough = self.anchor_demon > check * cfg.success_threshold
        prune &= seen_enough
        self.opacity_accum[seen_enough] = 0
        self.anchor_demon[seen_enough] = 0
        if bool(prune.all()):  # never remove every anchor
            prune[torch.argmax(self.life_opacity / self.life_views.clamp_min(1))] = False
        if bool(prune.any()):
            self.pruned += int(prune.sum())
            self.keep_anchors(~prune)

    def _grow(self, grads: torch.Tensor, threshold: float, offset_mask: torch.Tensor) -> None:
        cfg, k = self.cfg, self.cfg.num_offsets
        init_len = self.num_anchors * k
        vs = self.voxel_size
        for i in range(cfg.update_depth):
            cur_threshold = threshold * ((cfg.update_hierarchy_factor // 2) ** i)
            cand = (grads >= cur_threshold) & offset_mask
            cand &= torch.rand(cand.shape, generator=self.gen) > 0.5 ** (i + 1)
            inc = self.num_anchors * k - init_len
            if inc == 0 and i > 0 and cfg.skip_finer_levels:
                continue
            if inc:
                cand = torch.cat([cand, torch.zeros(inc, dtype=torch.bool)])
            if not bool(cand.any()):
                continue
            size_factor = max(cfg.update_init_factor // (cfg.update_hierarchy_factor ** i), 1)
            pos = self.positions().double()
            s = torch.exp(self.params["scalings"].detach().double())
            all_xyz = (pos[:, None, :] + self.params["offsets"].detach().double() * s[:, None, :3]).reshape(-1, 3)
            sel = all_xyz[cand]
            # grid of voxel size eps * size_factor, in units of eps (anchors stay on the eps grid)
            sel_grid = torch.round((sel - torch.from_numpy(self.origin).double()) / (vs * size_factor)).long()
            uniq, inverse = torch.unique(sel_grid, dim=0, return_inverse=True)
            existing = torch.round(self.coords.double() / size_factor).long()
            free = ~_rows_in(uniq, existing)
            if not bool(free.any()):
                continue
            new_coords = uniq[free] * size_factor
            feat = self.params["features"].detach()[:, None, :].expand(-1, k, -1).reshape(-1, cfg.feature_dim)[cand]
            nf = torch.full((uniq.shape[0], cfg.feature_dim), -torch.inf)
            nf = nf.scatter_reduce(0, inverse[:, None].expand(-1, cfg.feature_dim), feat, "amax")[free]
            m = new_coords.shape[0]
            self.grown += m
            new_scal = torch.full((m, 6), math.log(vs * size_factor), dtype=torch.float32)
            self.append_anchors(new_coords, nf, new_scal, torch.zeros(m, k, 3))

    # --- pruning (NAAP or opacity) -----------------------------------------------------
    @torch.no_grad()
    def prune_anchors(self) -> None:
        """NAAP or opacity pruning of the current anchors (encoder/anchors/naap.py), importance from the
        opacity accumulated since each anchor's creation; NAAP merges offsets, scalings and the
        accumulated opacity of every pruned anchor into its nearest kept neighbour (eq. 11).
        The optimizer state of the kept anchors carries over."""
        from ..anchors.naap import NaapConfig, naap_plan, opacity_plan

        cfg = self.cfg
        acc = (self.life_opacity / self.life_views.clamp_min(1)).numpy()
        if cfg.prune == "naap":
            plan = naap_plan(self.coords.numpy(), acc,
                             NaapConfig(keep_ratio=cfg.prune_keep, lam=cfg.naap_lambda, gamma=cfg.naap_gamma))
        else:
            plan = opacity_plan(acc, keep_ratio=cfg.prune_keep)
        merged = {name: torch.from_numpy(plan.merge(self.params[name].detach().numpy(), cfg.naap_gamma))
                  for name in ("scalings", "offsets")}
        merged_acc = plan.merge(acc, cfg.naap_gamma)
        keep = torch.from_numpy(plan.keep)
        self.keep_anchors(keep)
        for name, v in merged.items():
            self.params[name].copy_(v)
        self.life_opacity = torch.from_numpy(merged_acc) * self.life_views.clamp_min(1)
        self.pruned += int((~keep).sum())
        self.prune_report = str(plan.report())


def _rows_in(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Bool [len(a)]: rows of a (int64 [n, 3]) present in b ([m, 3])."""
    if b.numel() == 0 or a.numel() == 0:
        return torch.zeros(a.shape[0], dtype=torch.bool)
    both = torch.cat([b, a])
    _, inv = torch.unique(both, dim=0, return_inverse=True)
    in_b = torch.zeros(int(inv.max()) + 1, dtype=torch.bool)
    in_b[inv[: b.shape[0]]] = True
    return in_b[inv[b.shape[0]:]]
