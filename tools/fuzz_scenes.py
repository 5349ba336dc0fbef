"""Structure-aware fuzzing: build scenes with extreme geometry, counts, channel sizes and values,
RE-ENCODE them through the encoder (geometry included), and check that the decoder gives back
exactly the encoded scene; the fresh streams then seed byte-level mutation (lghcc.conformance.fuzz).

Byte mutation of a fixed set of streams never reaches most of the decoder's value space: the
hierarchy, the Ball k-NN and GG-Conv only see the coordinates, extents and models the seed
streams happen to carry (issue 14: the crash of a GG-Conv stream whose extent exceeds 1.75e9 was
out of the byte mutator's reach). Here every case is a new, valid stream:

* scenes (``random_scene``): 1 to a few thousand anchors laid out as clouds, dense cubes, lines,
  planes, clusters far from the origin, anchors at the corners -2^31 and 2^31 - 1 (extents beyond
  GG-Conv's limit included); C from 1 to 1024 and K from 1 to 64 (N * M kept small for speed);
  values from 0 to 1e12 and outliers up to 2^51 quantization steps (escapes of every class);
  constant channels, offset masks from never to always live, render MLPs of extreme magnitude,
  voxel sizes and origins up to the binary32 limits;
* encoder settings (``random_config``): every preset's steps and extremes (1e-30 .. 3e38), tiles,
  MLP weight bits 2..24, chunks of 1 row to all rows, the hierarchy with coarse voxels of 2 to
  2^20, the parent MLP and GG-Conv fitted for a step or two (so the fit is cheap and the
  integer model is whatever it is);
* hand-built integer context models (``hand_context_model``): GG-Conv and parent-MLP parameters
  drawn at their syntax extremes (k 1..64, radius_sq up to 2^62 - 1, tables and weights at
  +-2^15, shifts 0..31, h_shift 0..40, grids 2..16, random parent_base) replace the fitted model;
  the level-2 unit is re-coded with their means, levels and step adjustments (which reach every
  clamp), and the stream's hash is recomputed.

* explicit-Gaussian scenes (``gaussian_scene_case``, a third of the cases): SH degree 0..3,
  neighbour prediction (1..16 LoDs, 1..32 neighbours, 1..16 buckets), step adjustment (max 0..7,
  from a random sensitivity), tiles of 1 to 200 points, chunks of 1 row to all;
* beside each fresh tiled stream's full decode (``partial_decodes``): a box around one tile's cell
  (inside it or on its faces), a box meeting no cell, the level-1 preview (of the box too) and
  the tiles decoded by 2 worker processes; a box decode must be the full decode's rows of the
  tiles it selects (conformance/fuzz.py ``partial_mismatch``).

Oracle: a fresh stream must decode, in the sandbox, to its own hash (the encoder's decoded scene);
anything else is a bug of the encoder or the decoder. The encoder may refuse a scene (InputError:
a value beyond 2^52 steps, a world position beyond binary32); an encoder exception of another
class is a bug.

Every choice comes from one ``random.Random``, so a case is reproducible from its seed; the
hypothesis test (tests/test_fuzz_scenes.py) draws that Random (st.randoms), so it can shrink.
Informative tooling: it imports the encoder (hence it lives in tools/, not in lghcc.conformance).
"""

from __future__ import annotations

import math
import random
import traceback
from dataclasses import dataclass, field

import numpy as np

COORD_MIN, COORD_MAX = -(1 << 31), (1 << 31) - 1
MAX_VALUES = 40_000  # N * M of one generated scene (speed: a case takes tens of milliseconds)


@dataclass
class SceneCase:
    """A generated stream and what went into it. ``data`` None: the encoder refused the scene
    (``refused`` says why) or hit a bug (``bug``: the traceback)."""

    data: bytes | None
    what: str
    refused: str = ""
    bug: str = ""
    decodes: list = field(default_factory=list)  # decode_stream options of its box/preview/worker decodes


def _choice(rng: random.Random, options, weights=None):
    return rng.choices(options, weights=weights)[0]


# --- geometry -----------------------------------------------------------------------------------

def random_coords(rng: random.Random, n: int) -> tuple[np.ndarray, str]:
    """n distinct int64 coordinates in [-2^31, 2^31) in one of several layouts (fewer when the
    layout cannot hold n)."""
    g = np.random.default_rng(rng.getrandbits(64))
    layout = _choice(rng, ["cloud", "cube", "line", "plane", "cluster_far", "corners", "huge_extent", "sparse_wide"],
                     [30, 15, 8, 8, 10, 10, 9, 10])
    if layout == "cloud":
        spread = _choice(rng, [1, 2, 4, 10, 100, 10_000, 1 << 20])
        c = g.integers(-spread, spread + 1, size=(2 * n + 8, 3))
    elif layout == "cube":
        side = max(1, math.ceil(n ** (1 / 3)))
        ax = np.arange(side)
        c = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3) * _choice(rng, [1, 1, 2, 3, 1 << 10])
    elif layout == "line":
        c = np.zeros((n, 3), np.int64)
        c[:, rng.randrange(3)] = np.arange(n) * _choice(rng, [1, 2, 7, 1 << 20])
    elif layout == "plane":
        side = max(1, math.ceil(math.sqrt(n)))
        ax = np.arange(side)
        p = np.stack(np.meshgrid(ax, ax, indexing="ij"), -1).reshape(-1, 2)
        c = np.insert(p, rng.randrange(3), rng.randrange(-5, 6), axis=1)
    elif layout == "cluster_far":
        centre = np.array([_choice(rng, [COORD_MIN + 50, COORD_MAX - 50, 0, 1 << 30]) for _ in range(3)])
        c = centre + g.integers(-50, 51, size=(2 * n + 8, 3))
    elif layout == "corners":  # a cluster plus anchors at the coordinate range's corners
        c = g.integers(-8, 9, size=(2 * n + 8, 3))
        corners = np.array([[COORD_MIN] * 3, [COORD_MAX] * 3, [COORD_MIN, COORD_MAX, 0], [0, 0, COORD_MAX]])
        c = np.concatenate([corners[:rng.randint(1, 4)], c])
    elif layout == "huge_extent":  # beyond GG-Conv's Ball k-NN extent (spec clause 8) on one axis
        c = g.integers(-6, 7, size=(2 * n + 8, 3))
        far = np.zeros((2, 3), np.int64)
        axis = rng.randrange(3)
        far[0, axis], far[1, axis] = -(1 << 30) - rng.randrange(1 << 20), (1 << 30) + rng.randrange(1 << 20)
        c = np.concatenate([far, c])
    else:  # sparse_wide: anywhere in the 32-bit range
        c = g.integers(COORD_MIN, COORD_MAX, size=(2 * n + 8, 3), endpoint=True)
    c = np.clip(np.asarray(c, np.int64), COORD_MIN, COORD_MAX)
    _, first = np.unique(c, axis=0, return_index=True)
    c = c[np.sort(first)][:n]
    return c, layout


# --- scenes ---------------------------------------------------------------------------------------

def random_values(rng: random.Random, g: np.random.Generator, shape, step: float) -> np.ndarray:
    """Values of a channel group quantized with ``step``: mostly within 2^52 steps (the encoder
    refuses more), some far beyond (a refusal is a case too)."""
    kind = _choice(rng, ["normal", "zero", "constant", "uniform", "outliers", "huge"], [40, 8, 8, 14, 27, 3])
    scale = step * _choice(rng, [1e-3, 0.3, 1.0, 30.0, 1e4, 1e8])
    if kind == "zero":
        v = np.zeros(shape)
    elif kind == "constant":
        v = np.full(shape, step * _choice(rng, [-7.5, 1.0, 1e6, -3e9]))
    elif kind == "uniform":
        v = g.uniform(-scale, scale, size=shape)
    else:
        v = g.normal(0.0, scale, size=shape)
    if kind == "outliers" and v.size:  # escapes: magnitudes up to 2^51 quantization steps
        idx = g.integers(0, v.size, size=max(1, v.size // 50))
        v.flat[idx] = g.choice([-1.0, 1.0], size=idx.size) * step * 2.0 ** g.integers(3, 52, size=idx.size)
    if kind == "huge":
        v = v * 1e12
    with np.errstate(over="ignore"):
        return v.astype(np.float32)


def random_mlps(rng: random.Random, g: np.random.Generator, c: int, k: int) -> dict:
    from lghcc.common.scene import MLP_ROLES, RenderMLP

    mlps = {}
    outs = {"opacity": k, "cov": 7 * k, "color": 3 * k, "feature_bank": 3}
    for role in MLP_ROLES:
        if rng.random() < 0.5:
            continue
        layers = rng.randint(1, 3)
        dims = [c + 4] + [rng.randint(1, 16) for _ in range(layers - 1)] + [outs[role]]
        mag = _choice(rng, [0.0, 1e-8, 1.0, 1e4, 1e8])
        ws = [(mag * g.normal(size=(o, i))).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
        bs = [(mag * g.normal(size=o)).astype(np.float32) for o in dims[1:]]
        acts = [_choice(rng, ["none", "relu", "tanh", "sigmoid"]) for _ in ws]
        mlps[role] = RenderMLP(ws, bs, acts)
    return mlps


def random_scene(rng: random.Random, steps: tuple[float, float, float] = (0.02, 0.02, 0.02),
                 max_anchors: int = 3000):
    """-> (AnchorScene, description); ``steps``: the quantization steps the encoder will use."""
    from lghcc.common.scene import AnchorScene

    g = np.random.default_rng(rng.getrandbits(64))
    n = min(max_anchors, _choice(rng, [1, rng.randint(2, 16), rng.randint(17, 300), rng.randint(301, 3000)],
                                 [5, 35, 45, 15]))
    coords, layout = random_coords(rng, n)
    n = coords.shape[0]
    c = _choice(rng, [1, 2, 3, 8, 50, rng.randint(1, 1024)], [15, 15, 15, 20, 20, 15])
    k = _choice(rng, [1, 2, 3, 10, rng.randint(1, 64)], [25, 20, 20, 20, 15])
    while n * (c + 6 + 3 * k) > MAX_VALUES and (c > 1 or k > 1):
        c, k = max(1, c // 2), max(1, k // 2)
    if n * (c + 6 + 3 * k) > MAX_VALUES:
        coords, n = coords[:MAX_VALUES // 10], min(n, MAX_VALUES // 10)
    mask = None
    if rng.random() < 0.35:
        p = _choice(rng, [0.0, 0.01, 0.5, 0.99, 1.0])
        mask = g.random((n, k)) < p
    scene = AnchorScene(
        coords=coords, voxel_size=float(_choice(rng, [1e-30, 1e-6, 0.01, 1.0, 1e6, 1e30], [3, 10, 60, 15, 7, 5])),
        origin=np.array([_choice(rng, [0.0, 0.0, 1e6, -1e6, 3e38, -3e38], [50, 20, 10, 10, 5, 5]) for _ in range(3)],
                        np.float32),
        features=random_values(rng, g, (n, c), steps[0]), scalings=random_values(rng, g, (n, 6), steps[1]),
        offsets=random_values(rng, g, (n, k, 3), steps[2]), offset_mask=mask,
        mlps=random_mlps(rng, g, c, k) if rng.random() < 0.4 else {})
    return scene, f"N={n} ({layout}) C={c} K={k}{' masks' if mask is not None else ''}"


def random_config(rng: random.Random):
    """-> (EncoderConfig, description)."""
    from lghcc.encoder.stream.config import load_config

    preset = _choice(rng, ["low", "medium", "high"])
    over: dict = {}
    if rng.random() < 0.3:
        for name in ("feature_step", "scaling_step", "offset_step"):
            over[name] = _choice(rng, [1e-30, 1e-6, 1e-3, 0.02, 1.0, 1e3, 3e38])
    if rng.random() < 0.2:
        over["mlp_weight_bits"] = rng.randint(2, 24)
    over["rows_per_chunk"] = _choice(rng, [1, 2, 7, 64, 65536], [10, 10, 20, 20, 40])
    if rng.random() < 0.5:
        over["hierarchy"] = True
        over["coarse_voxel_scale"] = _choice(rng, [2, 3, 4, 16, 1 << 12, 1 << 20], [20, 10, 25, 20, 10, 15])
        model = _choice(rng, ["per_channel", "parent_mlp", "ggconv"], [60, 15, 25])
        if model != "per_channel":
            over.update(context_model=model, context_float_steps=rng.randint(1, 3), context_qat_steps=rng.randint(0, 1),
                        context_fallback=False, context_parent_base=_choice(rng, ["choose", "parent"]),
                        context_neighbour_level=rng.randint(1, 2), context_k=_choice(rng, [1, 2, 8, 64]),
                        context_weight_bits=_choice(rng, [8, 16]), context_channels=rng.randint(1, 4),
                        context_feat_hidden=rng.randint(1, 8), context_head_hidden=rng.randint(1, 8))
    if rng.random() < 0.4:  # tiles (format version 1): small ones, the scenes here are small
        over["tile_points"] = _choice(rng, [1, 2, 5, 20, 100])
    cfg = load_config(preset, overrides=over)
    return cfg, f"{preset} {over}"


# --- hand-built integer context models --------------------------------------------------------------

def _int_layers(rng: random.Random, g: np.random.Generator, widths: list[int]):
    from lghcc.common.intnn import IntLinear, int_range

    layers = []
    for l, (i, o) in enumerate(zip(widths[:-1], widths[1:])):
        bits = _choice(rng, [8, 16])
        lo, hi = int_range(bits)
        kind = _choice(rng, ["small", "extreme", "zero"], [60, 30, 10])
        if kind == "small":
            w = g.integers(-3, 4, size=(o, i))
        elif kind == "extreme":
            w = g.choice([lo, hi, -1, 0, 1], size=(o, i))
        else:
            w = np.zeros((o, i), np.int64)
        b = g.choice([-(1 << 31), (1 << 31) - 1, 0, 1, -1, 1 << 20, int(g.integers(-1000, 1000))], size=o)
        shift = _choice(rng, [0, 1, 2, 8, rng.randint(0, 31), 31])
        layers.append(IntLinear(w, b, shift, l < len(widths) - 2, bits))
    return layers


def hand_context_model(rng: random.Random, num_features: int, m: int):
    """A GG-Conv or parent-MLP parameter set drawn at the syntax extremes -> (model_id, params)."""
    from lghcc.common.context.ggconv import GGConvParams
    from lghcc.common.context.parent_mlp import ParentMlpParams
    from lghcc.common.intnn import IntMLP
    from lghcc.common.units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP

    g = np.random.default_rng(rng.getrandbits(64))
    base = g.integers(0, 2, size=m) if rng.random() < 0.7 else None
    head_hidden = [rng.randint(1, 8) for _ in range(rng.randint(0, 2))]
    if rng.random() < 0.3:
        head = IntMLP(_int_layers(rng, g, [3 + m] + head_hidden + [3 * m]))
        return CONTEXT_PARENT_MLP, ParentMlpParams(num_features, head, base)
    ch, d = rng.randint(1, 6), rng.randint(2, 16)
    table = g.choice([-32768, 32767, 0, 5, -5], size=(d, d, d, ch)) if rng.random() < 0.4 else \
        g.integers(-200, 201, size=(d, d, d, ch))
    feat_hidden = [rng.randint(1, 8) for _ in range(rng.randint(0, 2))]
    feat = IntMLP(_int_layers(rng, g, [num_features + 3] + feat_hidden + [ch]))
    head = IntMLP(_int_layers(rng, g, [ch + 4 + m] + head_hidden + [3 * m]))
    p = GGConvParams(num_features=num_features, k=_choice(rng, [1, 2, 4, 8, 64]),
                     radius_sq=_choice(rng, [1, 2, 3, 12, 48, 1 << 20, 1 << 40, (1 << 62) - 1]), table=table,
                     h_shift=_choice(rng, [0, 1, 8, 24, 40]), feat_mlp=feat, head_mlp=head,
                     neighbour_level=rng.randint(1, 2), parent_base=base)
    return CONTEXT_GGCONV, p


def replace_context_model(data: bytes, decoded, rng: random.Random) -> tuple[bytes, str] | None:
    """Re-code the level-2 unit of a hierarchical stream with a hand-built integer model (its
    means, levels and step adjustments); the quantized values stay, the decoded level 2 follows
    the step adjustments, the hash is recomputed. None when the scene has no level 2, or the
    model's steps would make a value non-finite."""
    from lghcc.common import attributes as attr
    from lghcc.common.container import DataUnit, UnitType, read_container, write_container
    from lghcc.common.context.model_unit import write_context_model_unit
    from lghcc.common.context.models import level2_coding_params, read_context_model
    from lghcc.common.errors import BitstreamError
    from lghcc.common.hashing import scene_digest
    from lghcc.common.hierarchy import build_hierarchy
    from lghcc.common.scene import AnchorScene
    from lghcc.common.units import LEVEL_1, LEVEL_2, AttributeUnitHeader, DecodedSceneHashUnit, SceneParameterSet

    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    types = [u.unit_type for u in units]
    if types.count(UnitType.ATTRIBUTE) != 2 or types.count(UnitType.GEOMETRY) != 1:
        return None  # one tile with its two levels (two tiles without the hierarchy also have two units)
    sps = SceneParameterSet.from_bytes(units[0].payload)
    if not sps.hierarchy_enabled_flag:
        return None
    layout = attr.layout_of(sps)
    m = layout.num_channels
    coords = decoded.coords
    hier = build_hierarchy(coords, sps.coarse_voxel_scale)
    a1 = types.index(UnitType.ATTRIBUTE)
    a2 = a1 + 1
    values = np.empty((sps.num_points, m), np.float32)
    _, _, q1 = attr.read_attribute_unit(units[a1].payload, layout, layout.steps(sps), hier.num_level1, LEVEL_1,
                                        values, hier.level1_idx, keep_q=True)
    h2, mask2, q2 = _level2_q(units[a2].payload, sps, hier, q1, coords, units, types, values)
    model_id, params = hand_context_model(rng, sps.feature_dim, m)
    unit = write_context_model_unit(model_id, *params.to_syntax())
    model = read_context_model(unit, layout)
    try:
        cp = level2_coding_params(model, coords[hier.level1_idx], q1, coords[hier.level2_idx], hier.parent_of_level2,
                                  sps.coarse_voxel_scale).materialize()
    except BitstreamError:  # beyond the extent limit: not a stream this model can code
        return None
    live = layout.live_channels(mask2, hier.num_level2)
    q2 = q2 if live is None else q2 * live
    with np.errstate(over="ignore", invalid="ignore"):
        recon = attr.reconstruct(q2, layout.steps(sps), cp.step_adjust)
    if not np.isfinite(recon).all():
        return None
    h = AttributeUnitHeader(num_channels=m, num_offsets=sps.num_offsets, offset_mask_present=h2.offset_mask_present,
                            num_rows=hier.num_level2, attribute_level=LEVEL_2, context_model_id=model_id,
                            mask_live_prob=list(h2.mask_live_prob), rows_per_chunk_minus1=h2.rows_per_chunk_minus1)
    units[a2] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(h, layout, q2, mask2, cp))
    if UnitType.CONTEXT_MODEL in types:
        units[types.index(UnitType.CONTEXT_MODEL)] = DataUnit(UnitType.CONTEXT_MODEL, unit)
    else:
        units.insert(types.index(UnitType.GEOMETRY), DataUnit(UnitType.CONTEXT_MODEL, unit))
    all_values = layout.join(decoded.features, decoded.scalings, decoded.offsets)
    all_values[hier.level2_idx] = recon
    f, s, o = layout.split(all_values)
    scene = AnchorScene(coords=coords, voxel_size=decoded.voxel_size, origin=decoded.origin, features=f, scalings=s,
                        offsets=o, offset_mask=decoded.offset_mask, mlps=decoded.mlps)
    j = [u.unit_type for u in units].index(UnitType.DECODED_SCENE_HASH)
    units[j] = DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=scene_digest(scene)).to_bytes())
    ggconv = hasattr(params, "feat_mlp")
    name = "GG-Conv" if ggconv else "parent MLP"
    extra = (f" k={params.k} radius_sq={params.radius_sq} D={params.grid_size} Ch={params.context_channels} "
             f"h_shift={params.h_shift} neighbour_level={params.neighbour_level}") if ggconv else ""
    return write_container(units), f"hand {name}{extra}"


def _level2_q(payload, sps, hier, q1, coords, units, types, values):
    """The level-2 unit's header, masks and quantized values, whatever model coded it."""
    from lghcc.common import attributes as attr
    from lghcc.common.context.models import level2_coding_params, read_context_model
    from lghcc.common.container import UnitType
    from lghcc.common.units import LEVEL_2

    context = None
    if UnitType.CONTEXT_MODEL in types:
        model = read_context_model(units[types.index(UnitType.CONTEXT_MODEL)].payload, attr.layout_of(sps))

        def context(model_id):
            return level2_coding_params(model, coords[hier.level1_idx], q1, coords[hier.level2_idx],
                                        hier.parent_of_level2, sps.coarse_voxel_scale)
    layout = attr.layout_of(sps)
    return attr.read_attribute_unit(payload, layout, layout.steps(sps), hier.num_level2, LEVEL_2, values,
                                    hier.level2_idx, context, keep_q=True)


# --- explicit-Gaussian scenes (neighbour prediction, step adjustment, tiles) -----------------------------

def random_gaussian_scene(rng: random.Random, max_points: int = 3000):
    """-> (GaussianScene on a grid, description): SH degree 0..3, values as random_values draws them
    (constant, outliers, escapes), voxel sizes and origins up to the binary32 limits."""
    from lghcc.common.attributes import GaussianLayout
    from lghcc.common.scene import GaussianScene

    g = np.random.default_rng(rng.getrandbits(64))
    n = min(max_points, _choice(rng, [1, rng.randint(2, 16), rng.randint(17, 300), rng.randint(301, 3000)],
                                [5, 30, 45, 20]))
    coords, layout = random_coords(rng, n)
    n, degree = coords.shape[0], rng.randint(0, 3)
    lay = GaussianLayout(degree)
    # SH and opacity as random_values draws them; scales and rotations within what the encoder takes
    # (a finite positive scale, a non-zero quaternion), mostly, with constant and outlier channels
    values = np.concatenate([random_values(rng, g, (n, lay.sh_channels + 1), 0.03),
                             g.uniform(-12, 4, size=(n, 3)) if rng.random() < 0.9 else random_values(rng, g, (n, 3), 0.1),
                             g.normal(size=(n, 4)) + (rng.random() < 0.2)], axis=1).astype(np.float32)
    sh, opacity, log_scales, rotations = lay.split(values)
    voxel = float(_choice(rng, [1e-6, 0.01, 1.0, 1e6], [10, 70, 15, 5]))
    origin = [_choice(rng, [0.0, 1e6, -1e6, 3e30], [60, 15, 15, 10]) for _ in range(3)]
    scene = GaussianScene.on_grid(coords, voxel, origin, sh.copy(), opacity.copy(), log_scales.copy(), rotations.copy())
    return scene, f"Gaussians N={n} ({layout}) sh_degree={degree}"


def random_gaussian_config(rng: random.Random):
    """-> (GaussianEncoderConfig, description): neighbour prediction (LoDs, neighbours, buckets at
    their extremes), step adjustment up to max 7 (its indices as flags or symbols), per-Gaussian SH
    degrees, rotations as a length index, several small tiles, chunks of 1 row to all."""
    from lghcc.encoder.stream.config import load_config

    over: dict = {"rows_per_chunk": _choice(rng, [1, 7, 64, 65536], [10, 20, 20, 50]),
                  "channel_prediction": rng.random() < 0.5}
    if rng.random() < 0.8:
        over.update(neighbour_prediction=True, prediction_lods=rng.randint(1, 16),
                    prediction_neighbours=_choice(rng, [1, 2, 6, 32]), prediction_buckets=rng.randint(1, 16))
        if rng.random() < 0.6:
            over.update(step_adjust_max=rng.randint(0, 7), step_adjust_quantile=_choice(rng, [0.01, 0.5, 0.9, 1.0]),
                        step_adjust_flags=rng.random() < 0.7)  # version 1.5's flags, or 1.2's symbols
        if rng.random() < 0.3:  # per-Gaussian SH degrees (version 1.3; with the sensitivities, see gaussian_scene_case)
            over["sh_degree_choice"] = True
    else:
        over["neighbour_prediction"] = False
    if rng.random() < 0.6:
        over["tile_points"] = _choice(rng, [1, 5, 30, 200])
    over["rotation_length"] = rng.random() < 0.7  # rotations as a length index and x, y, z (version 1.4), or 4 channels
    return load_config(_choice(rng, ["low", "medium", "high"]), overrides=over, kind="gaussians"), f"{over}"


def gaussian_scene_case(rng: random.Random, max_points: int = 3000) -> SceneCase:
    """Build and encode one random explicit-Gaussian scene (at most ``max_points`` Gaussians), with a
    random sensitivity (so that RDOQ and step adjustment choose per Gaussian) when step adjustment is on."""
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene

    cfg, cwhat = random_gaussian_config(rng)
    scene, what = random_gaussian_scene(rng, max_points=min(max_points, 3000 if cfg.rows_per_chunk > 7 else 400))
    what = f"{what}; {cwhat}"
    g = np.random.default_rng(rng.getrandbits(64))
    m = scene.sh.shape[1] * 3 + 8
    sens = None
    if cfg.step_adjust_max or cfg.sh_degree_choice or rng.random() < 0.3:
        sens = (10.0 ** (-3 * g.random((scene.num_gaussians, 1)))) * g.uniform(0.1, 10, size=(1, m))
    return encoded_case(rng, [what], lambda _: encode_gaussian_scene(scene, cfg, sensitivity=sens).data)


def encoded_case(rng: random.Random, whats: list[str], encode) -> SceneCase:
    """The case of ``encode(whats)`` (the stream; it may append to ``whats``, the case's description)
    with its partial decodes; or the encoder's refusal (InputError), or its bug with the traceback."""
    from lghcc.common.errors import InputError

    try:
        data = encode(whats)
        decodes = partial_decodes(rng, data)
    except InputError as e:
        return SceneCase(None, "; ".join(whats), refused=str(e))
    except Exception:  # noqa: BLE001 - an encoder (or generator) bug: reported with its traceback
        return SceneCase(None, "; ".join(whats), bug=traceback.format_exc())
    return SceneCase(data, "; ".join(whats), decodes=decodes)


# --- partial decodes and tile workers --------------------------------------------------------------------

def partial_decodes(rng: random.Random, data: bytes) -> list[dict]:
    """decode_stream options to try on a fresh tiled stream besides its full decode (clause 13.3):
    a box around one random tile's cell (its faces on the cell's faces, or within it), a box that
    meets no cell, the level-1 preview (with the hierarchy; of the box too), and the tiles decoded
    by 2 worker processes."""
    from lghcc.common.tiles import Box
    from lghcc.decoder.decode import parse_stream

    s = parse_stream(data)
    if len(s.tiles) < 2:
        return []
    ps, cell = s.ps, s.tiles[rng.randrange(len(s.tiles))].cell
    o, ts, vs = [float(x) for x in ps.origin], ps.tile_size, float(ps.voxel_size)
    lo = [float(c * ts) * vs + oa for c, oa in zip(cell, o)]
    hi = [float((c + 1) * ts) * vs + oa for c, oa in zip(cell, o)]
    if rng.random() < 0.5:  # strictly inside the cell, or its faces exactly
        lo, hi = [a + (b - a) / 4 for a, b in zip(lo, hi)], [b - (b - a) / 4 for a, b in zip(lo, hi)]
    out = [{"box": Box(tuple(lo), tuple(hi))}, {"box": Box((1.0e308,) * 3, (1.7976931348623157e308,) * 3)}]
    if ps.hierarchy_enabled_flag:
        out += [{"max_level": 1}, {"max_level": 1, "box": out[0]["box"]}]
    out.append({"jobs": 2, "exact_jobs": True})
    return out


# --- one case -----------------------------------------------------------------------------------------

def scene_case(rng: random.Random) -> SceneCase:
    """Build, encode (and sometimes re-code level 2 with a hand-built model) one random scene: an
    anchor scene, or (a third of the cases) an explicit-Gaussian one."""
    if rng.random() < 1 / 3:
        return gaussian_scene_case(rng)
    return anchor_scene_case(rng)


def anchor_scene_case(rng: random.Random, max_points: int = 3000) -> SceneCase:
    """One random anchor scene of at most ``max_points`` anchors, encoded (and sometimes level 2
    re-coded with a hand-built model)."""
    from lghcc.encoder.stream.encode import encode_scene

    cfg, cwhat = random_config(rng)
    # chunks of a few rows cost the decoder ~1 ms each with a context model: a few hundred anchors
    # then, so that a slow decode is not mistaken for a hang (the sandbox's bound is 5 s a case)
    scene, what = random_scene(rng, (cfg.feature_step, cfg.scaling_step, cfg.offset_step),
                               max_anchors=min(max_points, 3000 if cfg.rows_per_chunk > 7 else 400))
    what = f"{what}; {cwhat}"
    hand = rng.random() < 0.5

    def encode(whats: list[str]) -> bytes:
        res = encode_scene(scene, cfg)
        if hand and cfg.hierarchy:
            out = replace_context_model(res.data, res.decoded, rng)
            if out is not None:
                whats.append(out[1])
                return out[0]
        return res.data

    return encoded_case(rng, [what], encode)
