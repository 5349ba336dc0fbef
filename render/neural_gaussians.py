"""Anchors -> neural Gaussians for one view (Scaffold-GS ``generate_neural_gaussians``).

For each anchor visible in the view (position p, feature f, log scalings s[0:6], K offsets o_k):

    d = p - camera_centre;  dist = |d|;  v = d / dist                (Scaffold-GS ob_view, ob_dist)
    x = [f, v, dist] if an MLP's input size is C + 4, [f, v] if C + 3
    (feature bank, when present: f mixed at 3 resolutions with softmax(bank([v, dist])) weights)
    opacity_k = tanh-MLP(x)[k]                 Gaussians with opacity <= 0 are never built
    scale_k   = exp(s[3:6]) * sigmoid(cov(x)[7k : 7k + 3])
    quat_k    = normalize(cov(x)[7k + 3 : 7k + 7])                   (w, x, y, z)
    colour_k  = color-MLP(x)[3k : 3k + 3]      (Sigmoid)
    mean_k    = p + o_k * exp(s[0:3])

Only what the view needs is built: anchors whose bounding sphere (all their Gaussians out
to ``sigma_cutoff`` standard deviations) lies outside the view frustum, widened by a
margin, are culled before any MLP runs; offsets masked dead (``offset_mask``) and offsets
with opacity <= 0 are never built; the covariance and colour MLPs run only on anchors with
at least one live Gaussian.

Everything is torch; ``SceneTensors`` holds the scene as tensors (optionally requiring
grad) and the MLPs as ``torch.nn.Module``s, so that training can backpropagate into
features, offsets, scalings, positions and MLP weights.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from ..common.errors import InputError
from ..common.scene import AnchorScene, RenderMLP
from .camera import Camera


class TorchMLP(nn.Module):
    """A RenderMLP as a torch module (Linear layers, each followed by its activation)."""

    def __init__(self, layers: list[nn.Linear], activations: list[str]):
        super().__init__()
        self.layers = nn.ModuleList(layers)
        self.activations = list(activations)

    @classmethod
    def from_render_mlp(cls, mlp: RenderMLP, dtype: torch.dtype = torch.float32,
                        requires_grad: bool = False) -> "TorchMLP":
        layers = []
        for w, b in zip(mlp.weights, mlp.biases):
            lin = nn.Linear(w.shape[1], w.shape[0], dtype=dtype)
            with torch.no_grad():
                lin.weight.copy_(torch.from_numpy(np.asarray(w)))
                lin.bias.copy_(torch.from_numpy(np.asarray(b)))
            lin.requires_grad_(requires_grad)
            layers.append(lin)
        return cls(layers, mlp.activations)

    def to_render_mlp(self) -> RenderMLP:
        return RenderMLP([l.weight.detach().cpu().float().numpy() for l in self.layers],
                         [l.bias.detach().cpu().float().numpy() for l in self.layers], list(self.activations))

    @property
    def in_dim(self) -> int:
        return self.layers[0].in_features

    @property
    def out_dim(self) -> int:
        return self.layers[-1].out_features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for lin, a in zip(self.layers, self.activations):
            x = lin(x)
            if a == "relu":
                x = torch.relu(x)
            elif a == "tanh":
                x = torch.tanh(x)
            elif a == "sigmoid":
                x = torch.sigmoid(x)
        return x


class SceneTensors(nn.Module):
    """An anchor scene as torch tensors: positions [N, 3], features [N, C], scalings [N, 6]
    (log), offsets [N, K, 3], offset_mask [N, K] bool or None, and the render MLPs."""

    def __init__(self, positions: torch.Tensor, features: torch.Tensor, scalings: torch.Tensor,
                 offsets: torch.Tensor, mlps: dict[str, nn.Module], offset_mask: torch.Tensor | None = None):
        super().__init__()
        n = positions.shape[0]
        if positions.shape != (n, 3) or features.ndim != 2 or features.shape[0] != n:
            raise InputError(f"positions {list(positions.shape)} and features {list(features.shape)} disagree")
        if scalings.shape != (n, 6) or offsets.ndim != 3 or offsets.shape[0] != n or offsets.shape[2] != 3:
            raise InputError(f"scalings {list(scalings.shape)} / offsets {list(offsets.shape)} do not fit {n} anchors")
        if offset_mask is not None and offset_mask.shape != offsets.shape[:2]:
            raise InputError(f"offset mask {list(offset_mask.shape)} does not fit offsets {list(offsets.shape)}")
        for role in ("opacity", "cov", "color"):
            if role not in mlps:
                raise InputError(f"the scene has no {role} MLP; it cannot be rendered")
        self.positions, self.features, self.scalings, self.offsets = positions, features, scalings, offsets
        self.offset_mask = offset_mask
        self.mlps = nn.ModuleDict(mlps)
        c, k = features.shape[1], offsets.shape[1]
        for role, out in (("opacity", k), ("cov", 7 * k), ("color", 3 * k)):
            m = self.mlps[role]
            if m.in_dim not in (c + 3, c + 4):
                raise InputError(f"{role} MLP takes {m.in_dim} inputs; expected C+3={c + 3} ([feature, view]) "
                                 f"or C+4={c + 4} ([feature, view, distance]); appearance embeddings are not supported")
            if m.out_dim != out:
                raise InputError(f"{role} MLP gives {m.out_dim} outputs; expected {out} for K={k} offsets")
        if "feature_bank" in self.mlps:
            fb = self.mlps["feature_bank"]
            if fb.in_dim != 4 or fb.out_dim != 3 or c % 4:
                raise InputError(f"feature bank MLP must map 4 -> 3 and C ({c}) must be a multiple of 4")

    @classmethod
    def from_scene(cls, scene: AnchorScene, dtype: torch.dtype = torch.float32,
                   requires_grad: bool = False) -> "SceneTensors":
        def t(a):
            x = torch.as_tensor(np.ascontiguousarray(a), dtype=dtype).clone()
            return nn.Parameter(x, requires_grad=True) if requires_grad else x

        # Positions: exactly the float32 world positions the codec defines, then cast.
        mlps = {r: TorchMLP.from_render_mlp(m, dtype, requires_grad) for r, m in scene.mlps.items()}
        mask = None if scene.offset_mask is None else torch.as_tensor(np.asarray(scene.offset_mask, bool))
        return cls(t(scene.positions()), t(scene.features), t(scene.scalings), t(scene.offsets), mlps, mask)

    @property
    def num_anchors(self) -> int:
        return int(self.positions.shape[0])

    @property
    def num_offsets(self) -> int:
        return int(self.offsets.shape[1])


@dataclass
class NeuralGaussians:
    means: torch.Tensor  # [M, 3]
    quats: torch.Tensor  # [M, 4] unit, (w, x, y, z)
    scales: torch.Tensor  # [M, 3] (not log)
    opacities: torch.Tensor  # [M] in (0, 1)
    colors: torch.Tensor  # [M, 3]
    anchor_index: torch.Tensor  # [M] int64: which anchor built each Gaussian
    offset_index: torch.Tensor  # [M] int64: which of its K offsets
    stats: dict = field(default_factory=dict)

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])


def _frustum_bounds(camera: Camera, margin: float) -> tuple[float, float, float, float]:
    mx, my = margin * camera.width, margin * camera.height
    return ((-mx - camera.cx) / camera.fx, (camera.width + mx - camera.cx) / camera.fx,
            (-my - camera.cy) / camera.fy, (camera.height + my - camera.cy) / camera.fy)


@torch.no_grad()
def anchor_bounding_radii(scalings: torch.Tensor, offsets: torch.Tensor, live: torch.Tensor | None,
                          sigma_cutoff: float = 3.0) -> torch.Tensor:
    """Radius [N] of a sphere around each anchor that holds all its Gaussians out to
    ``sigma_cutoff`` standard deviations: max_k |o_k * exp(s[0:3])| + cutoff * max exp(s[3:6])
    (the covariance MLP's sigmoid is <= 1)."""
    s = torch.exp(scalings.detach().double().clamp(max=80.0))
    reach = torch.linalg.vector_norm(offsets.detach().double() * s[:, None, :3], dim=2)
    if live is not None:
        reach = torch.where(live, reach, torch.zeros((), dtype=reach.dtype))
    return reach.amax(dim=1) + sigma_cutoff * s[:, 3:6].amax(dim=1)


@torch.no_grad()
def visible_anchors(positions: torch.Tensor, radii: torch.Tensor, camera: Camera,
                    margin: float = 0.15) -> torch.Tensor:
    """Bool [N]: anchors whose bounding sphere meets the view frustum widened by ``margin``
    (a fraction of the image size on each side) and lying between near and far."""
    r = torch.as_tensor(camera.rotation, dtype=torch.float64)
    t = torch.as_tensor(camera.translation, dtype=torch.float64)
    pc = positions.detach().double() @ r.T + t
    x, y, z = pc.unbind(1)
    rad = radii.double()
    ok = (z + rad >= camera.near) & (z - rad <= camera.far)
    xl, xr, yt, yb = _frustum_bounds(camera, margin)
    # Planes through the centre: x - xr z <= 0 inside, -x + xl z <= 0 inside, same for y.
    for a, b, coord in ((1.0, -xr, x), (-1.0, xl, x), (1.0, -yb, y), (-1.0, yt, y)):
        dist = (a * coord + b * z) / float(np.hypot(a, b))
        ok &= dist <= rad
    return ok & torch.isfinite(pc).all(dim=1)


def _as_scene_tensors(scene: AnchorScene | SceneTensors, dtype: torch.dtype) -> SceneTensors:
    if isinstance(scene, SceneTensors):
        return scene
    if isinstance(scene, AnchorScene):
        return SceneTensors.from_scene(scene, dtype)
    raise TypeError(f"expected an AnchorScene or SceneTensors, got {type(scene).__name__}")


def _feature_bank(fb: nn.Module, feat: torch.Tensor, cat_view: torch.Tensor) -> torch.Tensor:
    """Scaffold-GS multi-resolution feature: f[::4] x4, f[::2] x2, f weighted by softmax(bank)."""
    w = torch.softmax(fb(cat_view), dim=1)  # [n, 3]
    c = feat.shape[1]
    f4 = feat[:, ::4].repeat(1, 4)[:, :c]
    f2 = feat[:, ::2].repeat(1, 2)[:, :c]
    return f4 * w[:, :1] + f2 * w[:, 1:2] + feat * w[:, 2:]


def _mlp_input(m: nn.Module, feat: torch.Tensor, view: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    c = feat.shape[1]
    return torch.cat([feat, view, dist], 1) if m.in_dim == c + 4 else torch.cat([feat, view], 1)


def anchor_mlp_features(st: SceneTensors, idx: torch.Tensor, view: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """The feature the MLPs see for anchors ``idx`` viewed along ``view`` [n, 3] (unit) from
    distance ``dist`` [n, 1]: the anchor feature, mixed by the feature bank when present."""
    feat = st.features[idx]
    if "feature_bank" in st.mlps:
        feat = _feature_bank(st.mlps["feature_bank"], feat, torch.cat([view, dist], 1))
    return feat


def gaussian_geometry(st: SceneTensors, anchor: torch.Tensor, ki: torch.Tensor,
                      cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Means, scales and unit quaternions of the Gaussians (anchor[i], offset ki[i]) from
    their covariance-MLP outputs ``cov`` [M, 7]: mean = p + o_k exp(s[0:3]),
    scale = exp(s[3:6]) sigmoid(cov[0:3]), quat = normalize(cov[3:7])."""
    # clamp as anchor_bounding_radii does: exp(>= 88.8) overflows float32 and the Inf would
    # reach the gradients (0 * Inf); exp(80) ~ 5.5e34 is still finite
    s = torch.exp(st.scalings[anchor].clamp(max=80.0))
    means = st.positions[anchor] + st.offsets[anchor, ki] * s[:, :3]
    scales = s[:, 3:6] * torch.sigmoid(cov[:, :3])
    quats = torch.nn.functional.normalize(cov[:, 3:7], dim=1)
    return means, scales, quats


def evaluate_anchors(scene: AnchorScene | SceneTensors, idx: torch.Tensor, view: torch.Tensor, dist: torch.Tensor,
                     dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Raw MLP outputs of anchors ``idx`` [n] (repeats allowed) for given unit view directions
    ``view`` [n, 3] (camera centre -> anchor) and distances ``dist`` [n, 1], for all K offsets:
    opacity [n, K] (tanh), covariance [n, K, 7] (3 scale logits, 4 quaternion values) and
    colour [n, K, 3], exactly as ``generate_neural_gaussians`` computes them for a camera at
    position - dist * view. No masking: dead offsets and opacity <= 0 are the caller's business."""
    st = _as_scene_tensors(scene, dtype)
    k = st.num_offsets
    feat = anchor_mlp_features(st, idx, view, dist)
    op = st.mlps["opacity"](_mlp_input(st.mlps["opacity"], feat, view, dist))
    cov = st.mlps["cov"](_mlp_input(st.mlps["cov"], feat, view, dist)).reshape(-1, k, 7)
    col = st.mlps["color"](_mlp_input(st.mlps["color"], feat, view, dist)).reshape(-1, k, 3)
    return op, cov, col


def generate_neural_gaussians(scene: AnchorScene | SceneTensors, camera: Camera, *, cull: bool = True,
                              margin: float = 0.15, sigma_cutoff: float = 3.0,
                              dtype: torch.dtype = torch.float32, mask_opacity: bool = True) -> NeuralGaussians:
    """The neural Gaussians an anchor scene produces for ``camera`` (see the module doc).
    ``scene``: an AnchorScene (converted with ``SceneTensors.from_scene``; pass a SceneTensors
    to avoid converting per view or to differentiate). Statistics in ``.stats``.
    ``mask_opacity=False`` is for benchmarks only: it also builds Gaussians with opacity <= 0
    (which the rasterizer then skips), to measure what Scaffold-GS's opacity mask saves."""
    st = _as_scene_tensors(scene, dtype)
    n, k = st.num_anchors, st.num_offsets
    pos, dev = st.positions, st.positions.device
    live = st.offset_mask.to(dev) if st.offset_mask is not None else None
    if cull and n:
        radii = anchor_bounding_radii(st.scalings, st.offsets, live, sigma_cutoff)
        vis = visible_anchors(pos, radii, camera, margin)
        idx = torch.nonzero(vis).squeeze(1)
    else:
        idx = torch.arange(n, device=dev)
    n_view = int(idx.numel())
    if live is not None:  # anchors with no live offset never run an MLP
        idx = idx[live[idx].any(dim=1)]
    nv = int(idx.numel())
    p = pos[idx]
    centre = torch.as_tensor(camera.center, dtype=p.dtype, device=dev)
    d = p - centre
    dist = torch.linalg.vector_norm(d, dim=1, keepdim=True)
    view = d / dist.clamp_min(1e-12)
    feat = anchor_mlp_features(st, idx, view, dist)
    op = st.mlps["opacity"](_mlp_input(st.mlps["opacity"], feat, view, dist))  # [nv, K]
    # mask_opacity=False (for measuring what the mask saves) builds Gaussians with opacity <= 0 too
    keep = op > 0 if mask_opacity else torch.ones_like(op, dtype=torch.bool)
    if live is not None:
        keep &= live[idx]
    # Anchors with at least one Gaussian: the only ones the covariance and colour MLPs see.
    has = keep.any(dim=1)
    a_loc = torch.nonzero(has).squeeze(1)
    keep_a = keep[a_loc]
    ai_loc, ki = torch.nonzero(keep_a, as_tuple=True)  # row-major: anchor by anchor, offset order
    sub = a_loc
    feat_s, view_s, dist_s = feat[sub], view[sub], dist[sub]
    cov = st.mlps["cov"](_mlp_input(st.mlps["cov"], feat_s, view_s, dist_s)).reshape(-1, k, 7)
    col = st.mlps["color"](_mlp_input(st.mlps["color"], feat_s, view_s, dist_s)).reshape(-1, k, 3)
    cov, col = cov[ai_loc, ki], col[ai_loc, ki]
    anchor = idx[sub[ai_loc]]
    means, scales, quats = gaussian_geometry(st, anchor, ki, cov)
    opac = op[a_loc[ai_loc], ki]
    m = int(means.shape[0])
    stats = {
        "anchors": n,
        "anchors_in_view": n_view,  # after frustum culling
        "anchors_run": nv,  # in view with at least one live offset: the opacity MLP runs on these
        "anchors_with_gaussians": int(a_loc.numel()),  # the covariance and colour MLPs run on these
        "offsets_live_in_view": nv * k if live is None else int(live[idx].sum()),
        "gaussians": m,
    }
    return NeuralGaussians(means, quats, scales, opac, col, anchor, ki, stats)
