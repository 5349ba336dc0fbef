"""A deterministic procedural anchor scene (informative): anchors on surfaces (a torus,
a sphere and a ground plane, voxelized), spatially smooth features, scalings and
offsets, and render MLPs of the Scaffold-GS shapes. Used by the demo, tests,
conformance sources and benchmarks; the same seed gives the same scene.
"""

from __future__ import annotations

import sys

from typing import TYPE_CHECKING, Callable

import numpy as np

from ..common.scene import (DEFAULT_FEATURE_DIM, DEFAULT_NUM_OFFSETS, AnchorScene, GaussianScene, RenderMLP,
                            sh_coeffs_per_channel)

if TYPE_CHECKING:
    from ..render.camera import Camera


def surface_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points on a torus (45%), a sphere (25%) and a ground plane (30%), in [-1, 1]^3."""
    nt, ns = int(0.45 * n), int(0.25 * n)
    npl = n - nt - ns
    u, v = rng.uniform(0, 2 * np.pi, (2, nt))
    torus = np.stack([(0.55 + 0.18 * np.cos(v)) * np.cos(u), (0.55 + 0.18 * np.cos(v)) * np.sin(u),
                      0.18 * np.sin(v) + 0.1], axis=1)
    d = rng.normal(size=(ns, 3))
    sphere = 0.25 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([0.0, 0.0, 0.2])
    plane = np.stack([rng.uniform(-1, 1, npl), rng.uniform(-1, 1, npl),
                      -0.35 + 0.03 * np.sin(3 * rng.uniform(-1, 1, npl))], axis=1)
    return np.concatenate([torus, sphere, plane])


def _smooth_field(rng: np.random.Generator, p: np.ndarray, channels: int, freq: float,
                  tick: Callable[[], None] = lambda: None) -> np.ndarray:
    """channels smooth functions of position: random Fourier features, unit variance.
    ``tick`` is called once per channel done (progress). The per-channel loop stays: computing
    several channels, or blocks of rows, at once is faster but not bit-identical (BLAS blocking),
    and the scenes of the conformance sources must not change."""
    nf = 8
    w = rng.normal(scale=freq, size=(channels, nf, 3))
    phase = rng.uniform(0, 2 * np.pi, (channels, nf))
    amp = rng.normal(size=(channels, nf)) / np.sqrt(nf / 2)
    out = np.empty((p.shape[0], channels))
    for c in range(channels):  # one channel at a time: memory O(N * nf), not O(N * C * nf)
        out[:, c] = np.sin(p @ w[c].T + phase[c]) @ amp[c]
        tick()
    return out


def _mlp(rng: np.random.Generator, dims: list[int], final: str) -> RenderMLP:
    ws = [(rng.normal(size=(o, i)) / np.sqrt(i)).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
    bs = [(0.05 * rng.normal(size=o)).astype(np.float32) for o in dims[1:]]
    return RenderMLP(ws, bs, ["relu"] * (len(ws) - 1) + [final])


def make_procedural_scene(num_anchors: int = 20000, seed: int = 0, feature_dim: int = DEFAULT_FEATURE_DIM,
                          num_offsets: int = DEFAULT_NUM_OFFSETS, with_mask: bool = False,
                          noise: float = 0.05, progress: bool = False) -> AnchorScene:
    """About ``num_anchors`` anchors (voxelization merges a few), voxel size chosen for the count.
    ``progress``: show a progress bar on stderr (one step per generated attribute channel); the
    scene is the same with or without it."""
    if num_anchors < 1:
        raise ValueError("num_anchors must be at least 1")
    from ..app.progress import progress_bar

    channels = 2 + feature_dim + 6 + 3 * num_offsets + (num_offsets if with_mask else 0)
    bar = progress_bar(total=channels, desc="procedural scene", unit="ch", disable=not progress, leave=False,
               file=sys.stderr)
    rng = np.random.default_rng(seed)
    # Surface area ~ 8.6 units^2: pick the voxel so that the surfaces hold ~num_anchors voxels.
    voxel = float(np.sqrt(8.6 / num_anchors))
    pts = surface_points(rng, 4 * num_anchors + 16)
    bar.update()
    coords = np.unique(np.floor(pts / voxel).astype(np.int64), axis=0)
    bar.update()
    if coords.shape[0] > num_anchors:
        coords = coords[np.sort(rng.choice(coords.shape[0], num_anchors, replace=False))]
    n = coords.shape[0]
    p = (coords + 0.5) * voxel
    feats = 0.8 * _smooth_field(rng, p, feature_dim, 3.0, bar.update) + noise * rng.normal(size=(n, feature_dim))
    scal = np.log(voxel) + 0.3 * _smooth_field(rng, p, 6, 2.0, bar.update) + noise * rng.normal(size=(n, 6))
    offs = (0.5 * _smooth_field(rng, p, 3 * num_offsets, 2.5, bar.update)
            + noise * rng.normal(size=(n, 3 * num_offsets)))
    mask = None
    if with_mask:
        mask = _smooth_field(rng, p, num_offsets, 2.0, bar.update) > -0.6
    bar.close()
    c = feature_dim
    mlps = {
        "opacity": _mlp(rng, [c + 4, c, num_offsets], "tanh"),
        "cov": _mlp(rng, [c + 4, c, 7 * num_offsets], "none"),
        "color": _mlp(rng, [c + 4, c, 3 * num_offsets], "sigmoid"),
    }
    return AnchorScene(
        coords=coords,
        voxel_size=voxel,
        origin=np.zeros(3, np.float32),
        features=feats.astype(np.float32),
        scalings=scal.astype(np.float32),
        offsets=offs.reshape(n, num_offsets, 3).astype(np.float32),
        offset_mask=mask,
        mlps=mlps,
    )


def smooth_gaussian_scene(n: int, degree: int, seed: int = 0) -> GaussianScene:
    """n Gaussians of SH degree ``degree`` on a surface whose attributes vary slowly (what
    neighbour prediction is for; used by the tests)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    means = np.stack([u, v, 0.2 * np.sin(6 * u)], 1).astype(np.float32)
    k = (degree + 1) ** 2
    sh = (np.sin(4 * u)[:, None, None] + 0.5 * np.cos(3 * v)[:, None, None] * np.ones((1, k, 3))
          + 0.05 * rng.normal(size=(n, k, 3))).astype(np.float32)
    sh[:, 1:] *= 0.1
    f = np.float32
    return GaussianScene(means, sh, (2 * np.cos(5 * v) + 0.1 * rng.normal(size=n)).astype(f),
                         (-4 + np.sin(3 * u)[:, None] + 0.1 * rng.normal(size=(n, 3))).astype(f),
                         np.column_stack([np.ones(n), 0.3 * np.sin(2 * u), 0.2 * v, 0.1 * rng.normal(size=n)]).astype(f))


# --- a room, watched from inside -------------------------------------------------------------
# A closed box room (z up, floor at z = 0) with furniture standing in it, as flat Gaussians on the
# surfaces, and a sparse plain exterior shell WALL_THICKNESS outside its walls and ceiling, so that
# an orbit camera sees a closed box. The geometry is fixed; the seed moves the Gaussians within
# their surfaces and draws the smooth colour, opacity and SH fields.

SH_C0 = 0.28209479177387814  # colour = 0.5 + SH_C0 * dc (3DGS)
ROOM_LO = (-3.0, -2.5, 0.0)
ROOM_HI = (3.0, 2.5, 3.0)
WALL_THICKNESS = 0.5  # the exterior shell lies this far outside the walls and the ceiling
ROOM_PARTS = ("floor", "ceiling", "walls", "furniture", "exterior")  # room_scene_parts' labels index this
# The exterior's spacing (Gaussians of 0.7 x 0.18 m, a quarter of WALL_THICKNESS) and the most of the
# scene it takes. Splatting sorts by centre depth: a Gaussian of the shell that is nearer the camera
# than the wall in front of it is drawn over that wall wherever its footprint reaches, so a few hundred
# large ones (0.4 m) veil every inside view; Gaussians under about WALL_THICKNESS / 3 do not.
EXTERIOR_SPACING = 0.18
EXTERIOR_MAX_SHARE = 0.1
EYE_HEIGHT = 1.6
EYE_POINTS = ((-0.5, 0.3), (0.8, -0.5), (-0.9, -0.7))  # where room_inside_cameras stand (x, y)
# Furniture: axis-aligned boxes (name, lo, hi, material, base colour), each a surface of Gaussians
# on its sides and top (its bottom stands on the floor).
_WOOD, _DARK_WOOD = (0.62, 0.42, 0.24), (0.42, 0.28, 0.17)
FURNITURE = (
    ("table top", (0.40, 0.60, 0.72), (1.60, 1.40, 0.78), "wood", _WOOD),
    ("table leg 1", (0.45, 0.65, 0.0), (0.51, 0.71, 0.72), "wood", _DARK_WOOD),
    ("table leg 2", (1.49, 0.65, 0.0), (1.55, 0.71, 0.72), "wood", _DARK_WOOD),
    ("table leg 3", (0.45, 1.29, 0.0), (0.51, 1.35, 0.72), "wood", _DARK_WOOD),
    ("table leg 4", (1.49, 1.29, 0.0), (1.55, 1.35, 0.72), "wood", _DARK_WOOD),
    ("cabinet", (-2.95, 1.60, 0.0), (-1.90, 2.45, 2.00), "paint", (0.32, 0.45, 0.62)),
    ("crate", (2.00, -2.30, 0.0), (2.80, -1.60, 0.60), "planks", (0.78, 0.62, 0.36)),
    ("side cabinet", (2.30, 1.50, 0.0), (2.90, 2.40, 0.90), "paint", (0.90, 0.88, 0.80)),
    ("sofa seat", (-2.20, -2.40, 0.0), (-0.20, -1.50, 0.45), "fabric", (0.58, 0.16, 0.18)),
    ("sofa back", (-2.20, -2.45, 0.45), (-0.20, -2.15, 0.95), "fabric", (0.52, 0.14, 0.16)),
    ("sofa arm 1", (-2.20, -2.15, 0.45), (-1.98, -1.50, 0.65), "fabric", (0.52, 0.14, 0.16)),
    ("sofa arm 2", (-0.42, -2.15, 0.45), (-0.20, -1.50, 0.65), "fabric", (0.52, 0.14, 0.16)),
)
# The walls, in the order _room_surfaces makes them: x = lo, x = hi, y = lo, y = hi. On each, u runs
# along the wall (metres, as the wall's u edge) and v is the height.
WALL_COLOURS = ((0.82, 0.79, 0.70), (0.62, 0.74, 0.82), (0.82, 0.73, 0.56), (0.70, 0.80, 0.66))
DOOR = (3, 4.0, 0.0, 0.9, 2.05)  # wall, u, v of its lower left corner, width, height
PICTURES = (  # wall, u, v of the lower left corner, width, height, pattern (frame included)
    (0, 1.4, 1.1, 1.2, 0.8, "checker"),
    (1, 1.6, 1.0, 1.6, 1.0, "rings"),
    (2, 3.6, 1.2, 1.3, 0.7, "stripes"),
    (3, 1.8, 1.3, 1.1, 0.75, "waves"),
)
LAMP = (0.0, 0.0, 0.35)  # ceiling lamp: centre x, y and radius


def furniture_contains(points: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """[N] bool: which points lie in a furniture box grown by ``margin`` on every side."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    inside = np.zeros(p.shape[0], bool)
    for _, lo, hi, _, _ in FURNITURE:
        inside |= ((p >= np.subtract(lo, margin)) & (p <= np.add(hi, margin))).all(axis=1)
    return inside


def room_contains(points: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """[N] bool: which points lie in the room's box (``margin`` > 0 shrinks it, < 0 grows it)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    return ((p >= np.add(ROOM_LO, margin)) & (p <= np.subtract(ROOM_HI, margin))).all(axis=1)


def _box_faces(lo, hi, part: int, material: str, key, bottom: bool = False) -> list[tuple]:
    """Surfaces (origin, u edge, v edge, part, material, key) of a box's faces, cross(u, v) pointing
    out of the box; the bottom face only when ``bottom``."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    ext, eye, out = hi - lo, np.eye(3), []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        eb, ec = eye[b] * ext[b], eye[c] * ext[c]  # cross(e_b, e_c) = e_a
        if a < 2 or bottom:
            out.append((lo, ec, eb, part, material, key))
        top = lo + eye[a] * ext[a]
        out.append((top, eb, ec, part, material, key))
    return out


def _room_surfaces() -> list[tuple]:
    """Every surface of the room scene: (origin, u edge, v edge, part index, material, key); the
    Gaussians' side of each is cross(u, v) (into the room for its inner faces)."""
    lo, hi = np.asarray(ROOM_LO), np.asarray(ROOM_HI)
    dx, dy, dz = hi - lo
    x, y, z = np.eye(3)
    walls = [((lo[0], lo[1], 0.0), y * dy, z * dz), ((hi[0], hi[1], 0.0), -y * dy, z * dz),
             ((hi[0], lo[1], 0.0), -x * dx, z * dz), ((lo[0], hi[1], 0.0), x * dx, z * dz)]
    out = [(np.array([lo[0], lo[1], lo[2]]), x * dx, y * dy, 0, "floor", None),
           (np.array([lo[0], lo[1], hi[2]]), y * dy, x * dx, 1, "ceiling", None)]
    out += [(np.array(o) + np.array([0.0, 0.0, lo[2]]), u, v, 2, "wall", i) for i, (o, u, v) in enumerate(walls)]
    for _, flo, fhi, material, colour in FURNITURE:
        out += _box_faces(flo, fhi, 3, material, colour)
    t = WALL_THICKNESS
    out += _box_faces(lo - np.array([t, t, 0.0]), hi + t, 4, "exterior", None)
    return out


def _split_counts(n: int, surfaces: list[tuple]) -> np.ndarray:
    """Gaussians per surface: the exterior's (EXTERIOR_SPACING apart, at most EXTERIOR_MAX_SHARE of
    n), the rest in proportion to the inner surfaces' areas (largest remainders; exactly n in all)."""
    area = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v, *_ in surfaces])
    ext = np.array([s[3] == ROOM_PARTS.index("exterior") for s in surfaces])
    n_ext = min(int(np.ceil(area[ext].sum() / EXTERIOR_SPACING ** 2)), max(5, int(EXTERIOR_MAX_SHARE * n)))
    counts = np.zeros(len(surfaces), np.int64)
    for mask, total in ((ext, n_ext), (~ext, n - n_ext)):
        q = total * area[mask] / area[mask].sum()
        c = np.floor(q).astype(np.int64)
        order = np.argsort(-(q - c), kind="stable")
        c[order[:total - int(c.sum())]] += 1
        counts[mask] = c
    return counts


def _face_grid(m: int, a: float, b: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """m points on an a x b rectangle, evenly: rows of (nearly) equal counts, staggered and
    jittered. (uv in metres [m, 2], local spacing [m])."""
    nv = int(np.clip(round(np.sqrt(m * b / a)), 1, m))
    edges = (np.arange(nv + 1) * m) // nv
    counts = np.diff(edges)
    row = np.repeat(np.arange(nv), counts)
    i = np.arange(m) - edges[row]
    c = counts[row]
    jit = rng.uniform(-0.2, 0.2, (m, 2))
    u = (i + 0.5 + jit[:, 0] + np.where(row % 2 == 1, 0.25, -0.25)) / c * a
    v = (row + 0.5 + jit[:, 1]) / nv * b
    return np.stack([np.clip(u, 0, a), v], axis=1), np.sqrt((a / c) * (b / nv))


def _fourier(rng: np.random.Generator, channels: int, freq: float) -> tuple[np.ndarray, ...]:
    """Coefficients of ``channels`` smooth fields (4 random sines each) for _eval_fourier."""
    return (rng.normal(scale=freq, size=(channels, 4, 3)), rng.uniform(0, 2 * np.pi, (channels, 4)),
            rng.normal(size=(channels, 4)) / np.sqrt(2.0))


def _eval_fourier(coef: tuple[np.ndarray, ...], p: np.ndarray) -> np.ndarray:
    """[N, channels] fields at points p, elementwise (no BLAS: bit-identical for any thread count)."""
    w, phase, amp = (c.astype(np.float32) for c in coef)
    out = np.zeros((p.shape[0], w.shape[0]), np.float32)
    x, y, z = p.astype(np.float32).T
    for c in range(w.shape[0]):
        for k in range(w.shape[1]):
            out[:, c] += amp[c, k] * np.sin(x * w[c, k, 0] + y * w[c, k, 1] + z * w[c, k, 2] + phase[c, k])
    return out


def _rect(uv: np.ndarray, u0: float, v0: float, w: float, h: float) -> np.ndarray:
    """[N] bool: uv within the rectangle of lower left corner (u0, v0), w x h."""
    return (uv[:, 0] >= u0) & (uv[:, 0] <= u0 + w) & (uv[:, 1] >= v0) & (uv[:, 1] <= v0 + h)


def _picture_rgb(kind: str, s: np.ndarray, t: np.ndarray, w: float, h: float) -> np.ndarray:
    """High-frequency picture patterns at local coordinates (s, t) in metres, [N, 3]."""
    if kind == "checker":
        on = ((np.floor(s / 0.05) + np.floor(t / 0.05)) % 2)[:, None]
        return on * np.array([0.92, 0.82, 0.18]) + (1 - on) * np.array([0.16, 0.30, 0.72])
    if kind == "rings":
        r = np.hypot(s - w / 2, t - h / 2)
        on = (0.5 + 0.5 * np.sin(r * 2 * np.pi / 0.07))[:, None]
        return on * np.array([0.95, 0.95, 0.90]) + (1 - on) * np.array([0.15, 0.55, 0.30])
    if kind == "stripes":
        on = (np.sin((s + t) * 2 * np.pi / 0.06) > 0)[:, None]
        return np.where(on, np.array([0.85, 0.20, 0.20]), np.array([0.95, 0.90, 0.82]))
    a, b = np.sin(s * 70 + 3 * np.sin(t * 9)), np.sin(t * 55 + 2 * np.sin(s * 7))  # "waves"
    return np.stack([0.55 + 0.35 * a, 0.5 + 0.3 * b, 0.6 - 0.25 * a * b], axis=1)


def _wall_rgb(wall: int, uv: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Wall colour: smooth variation of the wall's colour, its framed pictures and the door."""
    rgb = np.asarray(WALL_COLOURS[wall]) * (1 + 0.08 * field)[:, None]
    for w_, u0, v0, w, h, kind in PICTURES:
        if w_ != wall:
            continue
        rgb[_rect(uv, u0, v0, w, h)] = (0.22, 0.15, 0.10)  # the frame; the picture inside it
        m, f = _rect(uv, u0 + 0.06, v0 + 0.06, w - 0.12, h - 0.12), 0.06
        rgb[m] = _picture_rgb(kind, uv[m, 0] - u0 - f, uv[m, 1] - v0 - f, w - 2 * f, h - 2 * f)
    if wall == DOOR[0]:
        _, u0, v0, w, h = DOOR
        rgb[_rect(uv, u0 - 0.07, v0, w + 0.14, h + 0.07)] = (0.95, 0.95, 0.93)  # the trim
        door = _rect(uv, u0, v0, w, h)
        panel = _rect(uv, u0 + 0.12, v0 + 0.15, w - 0.24, h - 0.3) & ~_rect(uv, u0, v0 + 0.95, w, 0.1)
        rgb[door] = np.where(panel[door, None], (0.50, 0.30, 0.17), (0.42, 0.24, 0.13))
        rgb[np.hypot(uv[:, 0] - (u0 + w - 0.1), uv[:, 1] - 1.0) < 0.04] = (0.88, 0.76, 0.30)  # the knob
    return rgb


def _floor_rgb(p: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Checker tiles of 0.5 m with grout lines."""
    tile = 0.5
    on = ((np.floor(p[:, 0] / tile) + np.floor(p[:, 1] / tile)) % 2)[:, None]
    rgb = (on * np.array([0.84, 0.80, 0.72]) + (1 - on) * np.array([0.46, 0.34, 0.25])) * (1 + 0.05 * field)[:, None]
    d = p[:, :2] % tile
    rgb[np.minimum(d, tile - d).min(axis=1) < 0.012] = (0.30, 0.30, 0.29)  # grout lines
    return rgb


def _ceiling_rgb(p: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Off-white with a round lamp and its metal ring at LAMP."""
    rgb = np.array([0.86, 0.86, 0.83]) * (1 + 0.04 * field)[:, None]
    r = np.hypot(p[:, 0] - LAMP[0], p[:, 1] - LAMP[1])
    rgb[r < LAMP[2] + 0.06] = (0.45, 0.45, 0.47)
    rgb[r < LAMP[2]] = (1.0, 0.97, 0.86)
    return rgb


def _furniture_rgb(material: str, base, p: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Wood grain, painted fronts with seams, planks or fabric with seams, on the base colour."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if material == "wood":
        shade = 0.88 + 0.12 * np.sin(45 * (x + 0.3 * y) + 4 * np.sin(5 * y + 3 * z))
    elif material == "paint":
        shade = np.where((z % 0.4) < 0.025, 0.6, 1.0) * (1 + 0.03 * field)
    elif material == "planks":
        shade = np.where((z % 0.15) < 0.015, 0.55, 0.92 + 0.08 * np.sin(30 * (x + y)))
    else:  # fabric
        shade = np.where(((x + 2.2) % 0.665) < 0.02, 0.7, 0.95 + 0.05 * np.sin(90 * (x + y + z)))
    return np.asarray(base) * shade[:, None]


def _surface_rgb(s: tuple, p: np.ndarray, uv: np.ndarray, field: np.ndarray) -> np.ndarray:
    """The colour [N, 3] of surface ``s``'s points."""
    material, key = s[4], s[5]
    if material == "floor":
        return _floor_rgb(p, field)
    if material == "ceiling":
        return _ceiling_rgb(p, field)
    if material == "wall":
        return _wall_rgb(key, uv, field)
    if material == "exterior":  # plain: a lighter render on the walls, a darker roof
        roof = np.cross(s[1], s[2])[2] > 0
        return np.array((0.62, 0.42, 0.36) if roof else (0.74, 0.72, 0.68)) * (1 + 0.03 * field)[:, None]
    return _furniture_rgb(material, key, p, field)


def _frame_quaternion(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of the rotation taking the local axes x, y, z to u, v and u x v (unit)."""
    t1, t2 = u / np.linalg.norm(u), v / np.linalg.norm(v)
    r = np.stack([t1, t2, np.cross(t1, t2)], axis=1)
    tr = np.trace(r)
    if tr > 0:
        s = 2 * np.sqrt(1 + tr)
        return np.array([s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2 * np.sqrt(1 + r[i, i] - r[j, j] - r[k, k])
    q = np.empty(4)
    q[0], q[1 + i] = (r[k, j] - r[j, k]) / s, s / 4
    q[1 + j], q[1 + k] = (r[j, i] + r[i, j]) / s, (r[k, i] + r[i, k]) / s
    return q


def _twisted(q: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """[N, 4]: q followed by a turn of theta about the local z axis (q * (cos, 0, 0, sin)), w >= 0."""
    c, s = np.cos(theta / 2), np.sin(theta / 2)
    w, x, y, z = q
    out = np.stack([w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s], axis=1)
    return np.where(out[:, :1] < 0, -out, out)


def _room_geometry(n: int, rng: np.random.Generator, colour_field) -> tuple[np.ndarray, ...]:
    """Per Gaussian: means, rgb, tangent spacing, rotation and part index, surface by surface."""
    surfaces = _room_surfaces()
    counts = _split_counts(n, surfaces)
    cols: list[list[np.ndarray]] = [[], [], [], [], []]
    for s, m in zip(surfaces, counts):
        if m == 0:
            continue
        o, u, v = s[0], s[1], s[2]
        a, b = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        uv, spacing = _face_grid(int(m), a, b, rng)
        p = o + uv[:, :1] * (u / a) + uv[:, 1:] * (v / b)
        rgb = _surface_rgb(s, p, uv, colour_field(p))
        rot = _twisted(_frame_quaternion(u, v), rng.uniform(0, 2 * np.pi, int(m)))
        for col, val in zip(cols, (p, rgb, spacing, rot, np.full(int(m), s[3], np.int8))):
            col.append(val)
    return tuple(np.concatenate(c) for c in cols)


def room_scene_parts(n: int = 60_000, sh_degree: int = 0, seed: int = 0) -> tuple[GaussianScene, np.ndarray]:
    """``make_room_scene``'s scene and, per Gaussian, its part: an index into ROOM_PARTS (int8)."""
    if n < 100:
        raise ValueError(f"a room needs at least 100 Gaussians, got {n}")
    k = sh_coeffs_per_channel(sh_degree)
    rng = np.random.default_rng(seed)
    colour_coef, opacity_coef = _fourier(rng, 1, 1.2), _fourier(rng, 1, 2.0)
    sh_coef = None
    if k > 1:  # 6 smooth fields, mixed per coefficient: mostly the same for R, G and B (grey-ish sheen)
        mix = 0.8 * rng.normal(size=(6, k - 1, 1)) + 0.6 * rng.normal(size=(6, k - 1, 3))
        sh_coef = (_fourier(rng, 6, 1.5), mix / np.sqrt(6.0))
    means, rgb, spacing, rot, part = _room_geometry(n, rng, lambda p: _eval_fourier(colour_coef, p)[:, 0])
    rgb = np.clip(rgb + rng.normal(scale=0.01, size=rgb.shape), 0.02, 0.98)
    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0] = (rgb - 0.5) / SH_C0
    if sh_coef is not None:  # view dependence: a few percent of the DC, smooth over the surfaces
        base, mix = _eval_fourier(sh_coef[0], means), sh_coef[1].astype(np.float32)
        mix /= np.floor(np.sqrt(np.arange(1, k, dtype=np.float32)))[:, None]  # 1 / band
        rest = sh[:, 1:]
        for b in range(base.shape[1]):  # 6 smooth fields mixed per coefficient, elementwise (no BLAS)
            rest += base[:, b, None, None] * mix[b]
        rest *= np.float32(0.008) + np.float32(0.016) * np.abs(sh[:, :1])  # colour: about 2 % of it
    opacity = np.clip(4.0 + 0.6 * _eval_fourier(opacity_coef, means)[:, 0] + rng.normal(scale=0.2, size=n), 2.5, 5.5)
    tangent = np.log(0.7 * spacing)[:, None] + rng.normal(scale=0.08, size=(n, 2))
    log_scales = np.concatenate([tangent, tangent.mean(axis=1, keepdims=True) - np.log(10.0)], axis=1)
    f = np.float32
    scene = GaussianScene(means.astype(f), sh, opacity.astype(f), log_scales.astype(f), rot.astype(f))
    return scene, part


def make_room_scene(n: int = 60_000, sh_degree: int = 0, seed: int = 0) -> GaussianScene:
    """A closed room of exactly ``n`` (>= 100) Gaussians, watched from inside (``room_inside_cameras``):
    a box ROOM_LO..ROOM_HI (6 x 5 x 3, z up, floor at z = 0) of tiled floor, walls with framed
    PICTURES and a DOOR, a ceiling with a LAMP, the FURNITURE in it, and a plain exterior shell
    WALL_THICKNESS outside the walls and the ceiling (EXTERIOR_SPACING apart, at most
    EXTERIOR_MAX_SHARE of the Gaussians: 4,105 from n = 41,050 on) so that an orbit camera sees a
    closed box and not what is in it. Flat Gaussians (tangent scales 0.7 x the local spacing, the
    normal axis, scale index 2, 10x thinner, turned at random about the normal), spread evenly over
    the surfaces in proportion to their areas (n = 60,000: about 5 cm apart); mostly opaque (logits
    2.5..5.5). SH degree ``sh_degree``: bands a few percent of the DC, smooth over the surfaces. The
    same seed gives the same arrays; the seed moves the Gaussians within their surfaces and draws
    the smooth fields, the geometry stays. ``room_scene_parts`` tells which Gaussian is which part."""
    return room_scene_parts(n, sh_degree, seed)[0]


def room_inside_cameras(scene_or_none=None, n: int = 18, size: int = 256, fov_deg: float = 90.0,
                        seed: int = 0) -> list[Camera]:
    """``n`` cameras of a person standing in the room of ``make_room_scene``: at EYE_HEIGHT over the
    three EYE_POINTS in turn (jittered by up to 0.1 m), turned to yaws spread over the circle
    (2 pi i / n, jittered), pitched up or down by up to 35 degrees; square images of ``size``,
    ``fov_deg`` across, near plane 0.05. Deterministic for ``seed``. ``scene_or_none`` is accepted
    beside the other camera makers (orbit_cameras takes the points); the room's geometry is fixed,
    so the cameras do not depend on it."""
    from ..render.camera import Camera

    if n < 1:
        raise ValueError(f"need at least one camera, got {n}")
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        x, y = EYE_POINTS[i % len(EYE_POINTS)]
        eye = np.array([x, y, EYE_HEIGHT]) + rng.uniform(-0.1, 0.1, 3)
        yaw = 2 * np.pi * i / n + rng.uniform(-0.5, 0.5) * np.pi / n
        pitch = np.radians(rng.uniform(-35.0, 35.0))
        d = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
        cams.append(Camera.look_at(eye, eye + d, (0.0, 0.0, 1.0), width=size, height=size, fov_x_deg=fov_deg,
                                   near=0.05, far=100.0, name=f"inside_{i:03d}"))
    return cams
