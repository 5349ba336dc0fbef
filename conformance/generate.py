"""The generator of the conformance suite: conformance/streams/<id>/ from conformance/sources.yaml.

    python -m lghcc.conformance.generate                   # (re)write every stream (a format change)
    python -m lghcc.conformance.generate c020_idcm_mode_2  # only these streams (a stream added or fixed)
    python -m lghcc.conformance.generate --check           # generate in memory, write nothing: see below
    python -m lghcc.conformance.generate --metadata        # only test.yaml, from the frozen streams
    python -m lghcc.conformance.generate --renders         # only the reference renders (informative) of
                                                           # the streams with `renders` in sources.yaml

The streams are frozen reference material (conformance/README.md): the encoder makes each base
stream, the edits of ``post`` (this module and stream_edits.py) make from it what an encoder never
writes, and the result is committed with its SHA-256 in conformance/manifest.yaml, which every mode
that writes rewrites. An encoder change never requires them to be made again; regenerate when the
bitstream format changes (all of them), or for the streams added or changed in sources.yaml.

Every stream is checked against sources.yaml when generated: a stream that must decode decodes
to the encoder's hash; an error stream is rejected by the reference decoder with
`expect_error` and a message holding `expect_message`; an isolated error stream (`condition`) is
decoded by the decoder without that one check (conformance/conditions.py). test.yaml's `tools` are
derived from what the reference decoder did with the stream (tags below), and for an error stream
the decoding stage that rejects it, which sources.yaml declares (`rejected_in`); the `tools` of
sources.yaml state the intent and must be among them.

--check (the integration tier runs it) writes nothing and fails (exit 1) when the generator could no
longer make the suite with today's encoder and decoder (an edit that no longer applies, a stream
that no longer isolates its condition, a stream whose derived tools miss its intent), or when a
frozen test.yaml is not what the generator derives from its frozen stream. Whether today's
encoder reproduces a frozen stream byte for byte is reported, never required.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np
import yaml

from . import load_yaml
from .manifest import write_manifest

HERE = Path(__file__).resolve().parent
SOURCES = HERE / "sources.yaml"
STREAMS = HERE / "streams"


def random_mlp(rng, dims: list[int], final: str, zero_bias: bool):
    from ..common.scene import RenderMLP

    ws = [(rng.normal(size=(o, i)) / np.sqrt(i)).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
    bs = [np.zeros(o, np.float32) if zero_bias else (0.1 * rng.normal(size=o)).astype(np.float32)
          for o in dims[1:]]
    return RenderMLP(ws, bs, ["relu"] * (len(ws) - 1) + [final])


def spec_mlp(rng, in_dim: int, spec: dict):
    """A render MLP from an explicit layer list: spec = {layers: [{out, act, weight, bias}, ...]},
    weight/bias: a number (scale of N(0, 1) values; 0 gives a tensor of zeros)."""
    from ..common.scene import RenderMLP

    ws, bs, acts = [], [], []
    fan_in = in_dim
    for layer in spec["layers"]:
        out = int(layer["out"])
        ws.append((float(layer.get("weight", 1.0)) * rng.normal(size=(out, fan_in))).astype(np.float32))
        bs.append((float(layer.get("bias", 0.1)) * rng.normal(size=out)).astype(np.float32))
        acts.append(layer.get("act", "none"))
        fan_in = out
    return RenderMLP(ws, bs, acts)


def random_scene(s: dict):
    """Small random scene with the knobs the sources use."""
    from ..common.scene import AnchorScene

    rng = np.random.default_rng(s["seed"])
    n, c, k = s["num_anchors"], s["feature_dim"], s["num_offsets"]
    spread = int(s.get("spread", 64))
    coords = np.unique(rng.integers(-spread, spread, size=(2 * n + 8, 3), endpoint=True), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]].astype(np.int64)
    if s.get("shift_to_zero"):  # bounding-box minimum 0 on every axis
        coords -= coords.min(axis=0)
    for j, xyz in enumerate(s.get("extra_coords", [])):  # given coordinates replace the first rows
        coords[j] = xyz
    if len(np.unique(coords, axis=0)) != n:
        raise ValueError("extra_coords repeat a coordinate of the scene")
    scale = float(s.get("value_scale", 1.0))
    feats = (scale * rng.normal(size=(n, c))).astype(np.float32)
    if "constant" in s:
        feats[:] = s["constant"]
    for row, col, value in s.get("outliers", []):
        feats[row, col] = value
    finals = {"opacity": "tanh", "cov": "none", "color": "sigmoid", "feature_bank": "relu"}
    outs = {"opacity": k, "cov": 7 * k, "color": 3 * k, "feature_bank": 3}
    layers = int(s.get("mlp_layers", 2))
    mlps = {}
    for role in s.get("mlps", ["opacity", "cov", "color"]):
        if role in s.get("mlp_spec", {}):  # explicit shapes and magnitudes
            spec = s["mlp_spec"][role]
            mlps[role] = spec_mlp(rng, int(spec.get("in", c + 4)), spec)
            continue
        dims = [c + 4] + [c] * (layers - 1) + [outs[role]]
        mlps[role] = random_mlp(rng, dims, finals[role], bool(s.get("zero_bias", False)))
    if "feature_bank" in mlps and "feature_bank" not in s.get("mlp_spec", {}):
        mlps["feature_bank"].activations[0] = "sigmoid"  # exercise the remaining activation in a hidden layer
    if "cov" in mlps and layers > 2 and "cov" not in s.get("mlp_spec", {}):
        mlps["cov"].activations[1] = "tanh"
    scalings = rng.normal(size=(n, 6)).astype(np.float32)
    offsets = rng.normal(size=(n, k, 3)).astype(np.float32)
    if "constant_scalings" in s:
        scalings[:] = s["constant_scalings"]
    if "constant_offsets" in s:
        offsets[:] = s["constant_offsets"]
    mask = None
    if s.get("mask"):
        mask = rng.random((n, k)) < 0.6
        mask[:, s.get("dead_slots", [])] = False  # slots that are never live: mask_live_prob at its minimum
        mask[:, s.get("live_slots", [])] = True  # slots that are always live: mask_live_prob at its maximum
    return AnchorScene(
        coords=coords, voxel_size=float(s.get("voxel_size", 0.01)),
        origin=np.asarray(s.get("origin", [0.0, 0.0, 0.0]), dtype=np.float32),
        features=feats, scalings=scalings, offsets=offsets, offset_mask=mask, mlps=mlps)


def random_gaussian_scene(s: dict):
    """Small random explicit-Gaussian scene: SH degree ``sh_degree``; with ``correlated`` the
    colours of each SH coefficient and the three scales move together (cross-channel prediction
    pays off); positions on a grid of ``voxel_size`` within +-``spread`` voxels."""
    from ..common.scene import GaussianScene

    rng = np.random.default_rng(s["seed"])
    n, d = s["num_gaussians"], s.get("sh_degree", 0)
    k = (d + 1) ** 2
    spread = int(s.get("spread", 64))
    coords = np.unique(rng.integers(-spread, spread, size=(2 * n + 8, 3), endpoint=True), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]].astype(np.int64)
    scale = float(s.get("value_scale", 1.0))
    if s.get("zero_attributes"):  # every value 0 but the rotations (identity): a zero quaternion is invalid
        sh, log_scales = np.zeros((n, k, 3)), np.zeros((n, 3))
        rot = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        return GaussianScene.on_grid(coords, float(s.get("voxel_size", 0.01)), s.get("origin", [0.0, 0.0, 0.0]),
                                     sh.astype(np.float32), np.zeros(n, np.float32), log_scales.astype(np.float32),
                                     rot.astype(np.float32))
    if s.get("smooth"):
        return _smooth_gaussian_scene(s, rng, coords, spread)
    if s.get("correlated"):
        sh = rng.normal(size=(n, k, 1)) + 0.1 * rng.normal(size=(n, k, 3))
        log_scales = rng.normal(-4, 1, size=(n, 1)) + 0.2 * rng.normal(size=(n, 3))
    else:
        sh = rng.normal(size=(n, k, 3))
        log_scales = rng.normal(-4, 1, size=(n, 3))
    sh[:, 1:] *= 0.2
    f = lambda a: (scale * np.asarray(a)).astype(np.float32)  # noqa: E731
    scene = GaussianScene.on_grid(coords, float(s.get("voxel_size", 0.01)), s.get("origin", [0.0, 0.0, 0.0]),
                                  f(sh), f(rng.normal(0, 2, size=n)), f(log_scales), f(rng.normal(size=(n, 4))))
    for row, col, value in s.get("outliers", []):  # [row, channel of the Gaussian layout, value]
        from ..common.attributes import GaussianLayout

        lay = GaussianLayout(d)
        v = lay.join(scene)
        v[row, col] = value
        sh2, op, ls, rot = lay.split(v)
        scene = GaussianScene.on_grid(coords, scene.voxel_size, scene.origin, sh2.copy(), op.copy(), ls.copy(),
                                      rot.copy())
    return scene


def _smooth_gaussian_scene(s: dict, rng, coords: np.ndarray, spread: int):
    """Attributes that vary smoothly with the position (neighbour prediction, version 1.1, pays
    off): every channel a sum of two plane waves over the scene (wavelengths of about the scene's
    size) plus ``noise`` (relative) of its own (with ``correlated``, the colours of each SH
    coefficient and the three scales follow one channel's field); the channels of ``noise_channels`` (indices of the
    Gaussian layout, clause 11.1) are white noise alone (their neighbours do not predict them).
    ``extra_coords`` replace the first positions (e.g. far corners: the extent limit)."""
    from ..common.attributes import GaussianLayout
    from ..common.scene import GaussianScene

    lay = GaussianLayout(s.get("sh_degree", 0))
    m, n = lay.num_channels, coords.shape[0]
    for j, xyz in enumerate(s.get("extra_coords", [])):
        coords[j] = xyz
    if len(np.unique(coords, axis=0)) != n:
        raise ValueError("extra_coords repeat a coordinate of the scene")
    x = (coords - coords.mean(axis=0)) / max(spread, 1)
    waves = sum(np.sin(x @ (np.pi * rng.normal(size=(3, m))) + rng.uniform(0, 2 * np.pi, size=m))
                for _ in range(2))
    v = waves + float(s.get("noise", 0.05)) * rng.normal(size=(n, m))
    if s.get("correlated"):  # the colours of each SH coefficient, and the three scales, move together
        for lo, hi in [(c, c + 3) for c in range(0, lay.sh_channels, 3)] + [(lay.scale_start, lay.rotation_start)]:
            v[:, lo + 1:hi] = v[:, lo:lo + 1] + 0.2 * v[:, lo + 1:hi]
    v[:, list(s.get("noise_channels", []))] = rng.normal(size=(n, len(s.get("noise_channels", []))))
    v *= float(s.get("value_scale", 1.0))
    v[:, lay.scale_start:lay.rotation_start] -= 4.0  # log scales around e^-4
    v[:, lay.rotation_start] += 2.0  # rotations away from the zero quaternion
    sh, op, ls, rot = lay.split(v.astype(np.float32))
    return GaussianScene.on_grid(coords, float(s.get("voxel_size", 0.01)), s.get("origin", [0.0, 0.0, 0.0]),
                                 sh.copy(), op.copy(), ls.copy(), rot.copy())


def build_scene(s: dict):
    from ..formats.procedural import make_procedural_scene

    if s["generator"] == "gaussians":
        return random_gaussian_scene(s)
    if s["generator"] == "procedural":
        return make_procedural_scene(s["num_anchors"], seed=s.get("seed", 0), with_mask=s.get("with_mask", False),
                                     feature_dim=s.get("feature_dim", 50), num_offsets=s.get("num_offsets", 10))
    if s["generator"] == "random":
        return random_scene(s)
    raise ValueError(f"unknown scene generator {s['generator']!r}")


def _unit_index(units, unit_type, nth: int = 0) -> int:
    return [j for j, u in enumerate(units) if u.unit_type == unit_type][nth]


def _empty_chunks(units, chunks: list[dict]):
    """Replace chunks of the (single, level-0) attribute unit by 0 bytes (spec 10.6.4: an empty
    chunk decodes as bin 0 of every symbol's table). chunks: [{chunk: i, mask: bool}, ...]."""
    from ..common import attributes as attr
    from ..common.bitio import BitReader
    from ..common.container import DataUnit, UnitType
    from ..common.units import AttributeUnitHeader, SceneParameterSet

    sps = SceneParameterSet.from_bytes(units[_unit_index(units, UnitType.SCENE_PARAMETER_SET)].payload)
    j = _unit_index(units, UnitType.ATTRIBUTE)
    payload = units[j].payload
    r = BitReader(payload)
    h = AttributeUnitHeader.parse(r, num_channels=attr.layout_of(sps).num_channels, num_offsets=sps.num_offsets,
                                  offset_mask_present=sps.offset_mask_present_flag, num_rows=sps.num_points)
    mask_sizes = h.mask_chunk_size if h.offset_mask_present else [0] * h.num_chunks
    sizes = [x for pair in zip(mask_sizes, h.chunk_size) for x in pair]
    pieces = attr.split_chunks(payload[r.bit_position // 8:], sizes, "attribute unit")
    for c in chunks:
        i = int(c["chunk"])
        pieces[2 * i + 1] = b""
        h.chunk_size[i] = 0
        if c.get("mask"):
            pieces[2 * i] = b""
            h.mask_chunk_size[i] = 0
    units[j] = DataUnit(UnitType.ATTRIBUTE, h.to_bytes() + b"".join(pieces))


def _ggconv_feature_inputs(c: int) -> int:
    """The input count of GG-Conv's feature MLP for C features (C plus the geometric inputs of
    the normative model, whatever their number): the first width GGConvParams accepts."""
    from ..common.context.ggconv import GGConvParams
    from ..common.intnn import IntLinear, IntMLP

    for n in range(c, c + 64):
        try:
            GGConvParams(num_features=c, k=1, radius_sq=1, table=np.zeros((2, 2, 2, 1), np.int64), h_shift=0,
                         feat_mlp=IntMLP([IntLinear(np.zeros((1, n), np.int64), np.zeros(1, np.int64), 0, False, 8)]),
                         head_mlp=IntMLP([IntLinear(np.zeros((3 * (c + 9), 5 + c + 9), np.int64),
                                                    np.zeros(3 * (c + 9), np.int64), 0, False, 8)]))
            return n
        except ValueError:
            continue
    raise ValueError("no feature-MLP input count fits GGConvParams")


def _hand_ggconv_params(spec: dict, c: int, m: int):
    """The hand-built GG-Conv model of ``_hand_ggconv`` for C features and M channels."""
    from ..common.context.ggconv import GGConvParams
    from ..common.intnn import IntLinear, IntMLP

    ch, d = int(spec.get("channels", 1)), int(spec.get("grid", 2))
    rng = np.random.default_rng(int(spec.get("seed", 0)))
    table = rng.integers(-64, 64, size=(d, d, d, ch), endpoint=True)
    feat_in = _ggconv_feature_inputs(c)
    n_feat, n_head = int(spec.get("feat_layers", 1)), int(spec.get("head_layers", 1))
    # feature MLP: small random layers (ReLU between them), Ch outputs
    widths = [feat_in] + [ch] * n_feat
    feat_shifts = list(spec.get("feat_shifts", [0] * n_feat))  # every layer's shift (a syntax element)
    head_shifts = list(spec.get("head_shifts", [0] * n_head))  # the last head layer's shift shall be 0
    feat_layers = [IntLinear(rng.integers(-3, 3, size=(o, i), endpoint=True), np.zeros(o, np.int64), feat_shifts[l],
                             l < n_feat - 1, 8) for l, (i, o) in enumerate(zip(widths[:-1], widths[1:]))]
    # head inputs: h (Ch), local position (3), n_valid (1), parent attributes (M); outputs mean, level, adjust.
    # Deeper heads carry n_valid (>= 0, unchanged by ReLU) through 1-wide identity layers.
    head_layers = []
    if n_head > 1:
        w0 = np.zeros((1, ch + 4 + m), np.int64)
        w0[0, ch + 3] = 1
        head_layers.append(IntLinear(w0, np.zeros(1, np.int64), head_shifts[0], True, 8))
        head_layers += [IntLinear(np.ones((1, 1), np.int64), np.zeros(1, np.int64), head_shifts[l], True, 8)
                        for l in range(1, n_head - 1)]
    w = np.zeros((3 * m, ch + 4 + m if n_head == 1 else 1), np.int64)
    w[m:2 * m, ch + 3 if n_head == 1 else 0] = 1  # level grows with the number of valid neighbours
    bias = np.concatenate([np.zeros(m), np.full(m, int(spec.get("level", 8))), np.zeros(m)]).astype(np.int64)
    head_layers.append(IntLinear(w, bias, head_shifts[-1], False, 8))
    p = GGConvParams(num_features=c, neighbour_level=int(spec.get("neighbour_level", 2)), k=int(spec.get("k", 2)),
                     radius_sq=int(spec.get("radius_sq", 64)),
                     table=table, h_shift=0, feat_mlp=IntMLP(feat_layers), head_mlp=IntMLP(head_layers),
                     parent_base=np.arange(m) % 2)  # both kinds of channel mean (Annex H.5.3 step 6)
    return p


def _hand_ggconv_arrays(p, override: dict):
    """(hyperparameters, arrays) of the model's unit, with ``override``'s arrays in place of the model's."""
    from ..common.context.model_unit import NamedIntArray

    arrays = []
    hp, model_arrays = p.to_syntax()
    unknown = set(override) - {a.name for a in model_arrays}
    if unknown:  # hyperparameters out of range: set_elements after the model is written
        raise ValueError(f"hand_ggconv override: no array {sorted(unknown)}")
    for a in model_arrays:
        v, bits = np.asarray(a.values), a.bits
        if a.name in override:
            o = override[a.name]
            v = np.full(o["shape"], o.get("fill", 0), np.int64)
            bits = max(bits, int(v.max()).bit_length() if v.size else 1, 1)
            if "bits" in o:  # a declared width of its own (e.g. beyond the model's)
                bits = int(o["bits"])
        arrays.append(NamedIntArray(a.name, v, bits, a.signed))
    return hp, arrays


def _hand_ggconv(units, spec: dict):
    """Code level 2 with a hand-built GG-Conv model instead of the per-channel prior: one-layer
    feature and head MLPs (``feat_layers``, ``head_layers`` deeper), Ch context channels, every
    layer's shift 0 (or ``feat_shifts``, ``head_shifts``: one per layer; a shift of the head's last
    layer scales the levels down). Its step adjustment is 0, so the quantized values, and the decoded scene, are
    those of the per-channel stream. ``override``: {array: {shape, fill, bits}}, arrays that a
    conforming model cannot have (with ``unchecked``: level 2 keeps the per-channel chunks; with
    ``model_only``: only the context_model unit is added, which level 2 does not use)."""
    from ..common import attributes as attr
    from ..common.container import DataUnit, UnitType
    from ..common.context.model_unit import write_context_model_unit
    from ..common.context.models import level2_coding_params, read_context_model
    from ..common.geometry import decode_geometry
    from ..common.hierarchy import build_hierarchy
    from ..common.units import CONTEXT_GGCONV, LEVEL_1, LEVEL_2, AttributeUnitHeader, SceneParameterSet

    sps = SceneParameterSet.from_bytes(units[_unit_index(units, UnitType.SCENE_PARAMETER_SET)].payload)
    layout = attr.layout_of(sps)
    m, c = layout.num_channels, sps.feature_dim
    coords = decode_geometry(units[_unit_index(units, UnitType.GEOMETRY)].payload, sps.num_points)
    hier = build_hierarchy(coords, sps.coarse_voxel_scale)
    values = np.empty((sps.num_points, m), np.float32)
    a1, a2 = _unit_index(units, UnitType.ATTRIBUTE, 0), _unit_index(units, UnitType.ATTRIBUTE, 1)
    steps = layout.steps(sps)
    _, _, q1 = attr.read_attribute_unit(units[a1].payload, layout, steps, hier.num_level1, LEVEL_1, values,
                                        hier.level1_idx, keep_q=True)
    h2, mask2, q2 = attr.read_attribute_unit(units[a2].payload, layout, steps, hier.num_level2, LEVEL_2, values,
                                             hier.level2_idx, keep_q=True)
    p = _hand_ggconv_params(spec, c, m)
    override = spec.get("override", {})  # error streams: arrays a conforming model cannot have
    hp, arrays = _hand_ggconv_arrays(p, override)
    unit = write_context_model_unit(CONTEXT_GGCONV, hp, arrays)
    if spec.get("model_only"):  # the unit alone: no level-2 unit uses it (clause 8.3 rule 3)
        units.insert(_unit_index(units, UnitType.GEOMETRY), DataUnit(UnitType.CONTEXT_MODEL, unit))
        return
    h = AttributeUnitHeader(num_channels=m, num_offsets=sps.num_offsets, offset_mask_present=h2.offset_mask_present,
                            num_rows=hier.num_level2, attribute_level=LEVEL_2, context_model_id=CONTEXT_GGCONV,
                            mask_live_prob=list(h2.mask_live_prob), rows_per_chunk_minus1=h2.rows_per_chunk_minus1)
    if spec.get("unchecked"):
        # an error stream: the decoder must stop (at a level limit or at the model's parameters)
        # before it evaluates the model, so the level-2 chunks are those of the per-channel stream
        from ..common.bitio import BitReader

        r = BitReader(units[a2].payload)
        AttributeUnitHeader.parse(r, num_channels=m, num_offsets=sps.num_offsets,
                                  offset_mask_present=h2.offset_mask_present, num_rows=hier.num_level2)
        h.mask_chunk_size, h.chunk_size = list(h2.mask_chunk_size), list(h2.chunk_size)
        units[a2] = DataUnit(UnitType.ATTRIBUTE, h.to_bytes() + units[a2].payload[r.bit_position // 8:])
        units.insert(_unit_index(units, UnitType.GEOMETRY), DataUnit(UnitType.CONTEXT_MODEL, unit))
        return
    model = read_context_model(unit, layout)
    params = level2_coding_params(model, coords[hier.level1_idx], q1, coords[hier.level2_idx], hier.parent_of_level2,
                                  sps.coarse_voxel_scale).materialize()
    assert params.step_adjust is None or not params.step_adjust.any()
    units[a2] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(h, layout, q2, mask2, params))
    units.insert(_unit_index(units, UnitType.GEOMETRY), DataUnit(UnitType.CONTEXT_MODEL, unit))


def _rehash(data: bytes) -> bytes:
    """Replace the decoded scene hash by the hash of what the stream decodes to (for edits that
    change the decoded scene on purpose; tests/test_spec_and_conformance.py checks those values)."""
    from ..common.container import DataUnit, UnitType, read_container, write_container
    from ..common.hashing import digest_of
    from ..common.units import DecodedSceneHashUnit
    from ..decoder.decode import decode_stream

    digest = digest_of(decode_stream(data, verify_hash=False).scene)
    container = read_container(data)
    units = [DataUnit(u.unit_type, u.payload) for u in container.units]
    j = _unit_index(units, UnitType.DECODED_SCENE_HASH)
    units[j] = DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=digest).to_bytes())
    return write_container(units, container.header)


def _set_render_mlp(units, edits: list[dict]):
    """Rewrite fields of render MLP headers (e.g. exponents at their limits); the coded integers
    stay, so the decoded weights change by powers of two (rehash the stream).
    edits: [{mlp: m, layer: l, weight_exponent: e, bias_exponent: e}, ...]."""
    from ..common.container import DataUnit, UnitType
    from ..common.units import RenderModelUnit

    j = _unit_index(units, UnitType.RENDER_MODEL)
    unit = RenderModelUnit.from_bytes(units[j].payload)
    for e in edits:
        h = unit.mlps[int(e["mlp"])]
        for key in ("weight_exponent", "bias_exponent", "weight_level", "bias_level"):
            if key in e:
                getattr(h, key)[int(e["layer"])] = int(e[key])
    units[j] = DataUnit(UnitType.RENDER_MODEL, unit.to_bytes())


def _set_prior_mean(units, means: dict):
    """Overwrite prior means of the (single, level-0) attribute unit: {channel: mean}. The coded
    residuals stay, so the channel's decoded values move with the mean (rehash the stream)."""
    from ..common import attributes as attr
    from ..common.bitio import BitReader
    from ..common.container import DataUnit, UnitType
    from ..common.units import AttributeUnitHeader, SceneParameterSet

    sps = SceneParameterSet.from_bytes(units[_unit_index(units, UnitType.SCENE_PARAMETER_SET)].payload)
    j = _unit_index(units, UnitType.ATTRIBUTE)
    r = BitReader(units[j].payload)
    h = AttributeUnitHeader.parse(r, num_channels=attr.layout_of(sps).num_channels, num_offsets=sps.num_offsets,
                                  offset_mask_present=sps.offset_mask_present_flag, num_rows=sps.num_points)
    for c, m in means.items():
        h.prior_mean[int(c)] = int(m)
    units[j] = DataUnit(UnitType.ATTRIBUTE, h.to_bytes() + units[j].payload[r.bit_position // 8:])


def _insert_raw_unit(data: bytes, spec: dict) -> bytes:
    """Insert a data unit framed by hand (valid size and CRC-32) before unit ``index``: for unit
    types the writer refuses (type 0)."""
    import zlib

    from ..common.container import read_container

    units = read_container(data).units
    i = int(spec["index"])
    pos = units[i].offset if i < len(units) else len(data)
    payload = spec.get("payload", "").encode()
    body = bytes([int(spec["type"])]) + len(payload).to_bytes(4, "big") + payload
    return data[:pos] + body + zlib.crc32(body).to_bytes(4, "big") + data[pos:]


def _rewrite_gaussian_attributes(units, edit: dict):
    """Re-code the (single, level-0) attribute unit of a Gaussian stream: with the cross-channel
    predictions ``entries`` [[target, source, weight], ...] in place of the encoder's (lossless: the
    decoded scene is unchanged), and/or with the quantized value at ``set_q`` [row, channel, value]
    changed (the hash then no longer matches: for error streams, or give ``rehash``); ``set_q`` may
    also be a list of such triples."""
    from ..common import attributes as attr
    from ..common.container import DataUnit, UnitType
    from ..common.units import GaussianParameterSet

    gps = GaussianParameterSet.from_bytes(units[_unit_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    layout = attr.gaussian_layout_of(gps)
    a = _unit_index(units, UnitType.ATTRIBUTE)
    values = np.empty((gps.num_gaussians, layout.num_channels), np.float32)
    h, _, q = attr.read_attribute_unit(units[a].payload, layout, layout.steps(gps), gps.num_gaussians, 0, values,
                                       keep_q=True)
    if "set_q" in edit:
        triples = edit["set_q"] if isinstance(edit["set_q"][0], list) else [edit["set_q"]]
        for row, ch, value in triples:
            q[row, ch] = value
    pred = attr.ChannelPrediction.from_header(h, "edit")
    if "entries" in edit:
        e = np.asarray(edit["entries"], np.int64).reshape(-1, 3)
        pred = attr.ChannelPrediction(e[:, 0], e[:, 1], e[:, 2])
    h2 = attr.new_attribute_header(layout, gps.num_gaussians, 0)
    h2.rows_per_chunk_minus1 = h.rows_per_chunk_minus1
    h2.prior_mean, h2.prior_level = list(h.prior_mean), list(h.prior_level)
    units[a] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(h2, layout, q, None, attr.prior_params(h2),
                                                                      pred))


def _edit_tile_index(units, edits: list[dict]) -> None:
    from ..common.bitio import BitReader
    from ..common.container import DataUnit, UnitType
    from ..common.units import TileIndex

    j = _unit_index(units, UnitType.TILE_INDEX)
    index = TileIndex.parse(BitReader(units[j].payload),
                            num_points=1 << 24)
    for e in edits:
        cur = getattr(index, e["name"])
        if e.get("drop"):  # remove tile t's entry
            del cur[e["t"]]
        elif e.get("add_last"):  # tile t also counts the last tile's points (the count stays N)
            cur[e["t"]] += cur[-1] + 1
        elif "copy" in e:  # tile t's value is tile copy's
            cur[e["t"]] = cur[e["copy"]]
        elif "t" in e:
            cur[e["t"]] = e["value"] if "value" in e else cur[e["t"]] + e["add"]
        else:
            setattr(index, e["name"], e["value"] if "value" in e else cur + e["add"])
    index.num_points = 1 << 24
    units[j] = DataUnit(UnitType.TILE_INDEX, index.to_bytes())


def _set_scene_hashes(units, hashes: tuple[bytes, ...]) -> None:
    """Write ``hashes`` into the decoded_scene_hash units, in stream order (one per tile); the
    rest of each payload (hash_type, any trailing byte) stays as the edits left it."""
    from ..common.container import DataUnit, UnitType

    at = [j for j, u in enumerate(units) if u.unit_type == UnitType.DECODED_SCENE_HASH]
    for j, digest in zip(at, hashes):
        p = units[j].payload
        units[j] = DataUnit(UnitType.DECODED_SCENE_HASH, p[:1] + digest + p[33:])


def _insert_units(units, spec) -> None:
    """One unit or a list, inserted in order; payload as text, or hex bytes."""
    from ..common.container import DataUnit

    for p in spec if isinstance(spec, list) else [spec]:
        payload = bytes.fromhex(p["hex"]) if "hex" in p else p["payload"].encode()
        units.insert(p["index"], DataUnit(int(p["type"]), payload))


def _insert_empty_render_model(units, index: int) -> None:
    """num_mlps = 0, coded_size = 0: the same decoded scene."""
    from ..common.container import DataUnit, UnitType
    from ..common.units import RenderModelUnit

    units.insert(index, DataUnit(UnitType.RENDER_MODEL, RenderModelUnit().to_bytes()))


def _recode_geometry(units, idcm_mode: int) -> None:
    """The geometry coded again, losslessly, with another IDCM mode."""
    from ..common.container import DataUnit, UnitType
    from ..common.geometry import decode_geometry, encode_geometry
    from ..common.units import SceneParameterSet

    j = _unit_index(units, UnitType.GEOMETRY)
    n = SceneParameterSet.from_bytes(units[0].payload).num_anchors
    coords = decode_geometry(units[j].payload, n)
    units[j] = DataUnit(UnitType.GEOMETRY, encode_geometry(coords, int(idcm_mode)))
    assert np.array_equal(decode_geometry(units[j].payload, n), coords)


def _set_parameter_set(unit_type, units, fields: dict) -> None:
    """Fields of the parameter set in the unit of ``unit_type`` overwritten."""
    from ..common.container import DataUnit, UnitType
    from ..common.units import GaussianParameterSet, SceneParameterSet

    cls = GaussianParameterSet if unit_type == UnitType.GAUSSIAN_PARAMETER_SET else SceneParameterSet
    j = _unit_index(units, unit_type)
    ps = cls.from_bytes(units[j].payload)
    for k, v in fields.items():
        setattr(ps, k, v)
    units[j] = DataUnit(unit_type, ps.to_bytes())


def _set_gps(units, fields: dict) -> None:
    from ..common.container import UnitType

    _set_parameter_set(UnitType.GAUSSIAN_PARAMETER_SET, units, fields)


def _set_sps(units, fields: dict) -> None:
    from ..common.container import UnitType

    _set_parameter_set(UnitType.SCENE_PARAMETER_SET, units, fields)


def _swap_units(units, pair) -> None:
    a, b = pair
    units[a], units[b] = units[b], units[a]


def _duplicate_unit(units, i) -> None:
    """A copy of unit i inserted right after it."""
    from ..common.container import DataUnit

    i = int(i)
    units.insert(i + 1, DataUnit(units[i].unit_type, units[i].payload))


def _drop_unit(units, i) -> None:
    del units[i]


def _edit_payload(units, index: int, edit) -> None:
    from ..common.container import DataUnit

    units[index] = DataUnit(units[index].unit_type, edit(units[index].payload))


def _append_to_unit(units, p: dict) -> None:
    """Trailing bytes inside a payload (with a valid CRC)."""
    _edit_payload(units, p["index"], lambda payload: payload + bytes.fromhex(p["hex"]))


def _prepend_to_unit(units, p: dict) -> None:
    """Bytes before a payload's first element (with a valid CRC)."""
    _edit_payload(units, p["index"], lambda payload: bytes.fromhex(p["hex"]) + payload)


def _truncate_unit(units, p: dict) -> None:
    """The last bytes of a payload dropped (with a valid CRC): a truncated structure."""
    _edit_payload(units, p["index"], lambda payload: payload[:len(payload) - int(p["bytes"])])


def _corrupt_hash(units, wanted) -> None:
    from ..common.container import DataUnit, UnitType

    if not wanted:
        return
    i = _unit_index(units, UnitType.DECODED_SCENE_HASH)
    payload = bytearray(units[i].payload)
    payload[-1] ^= 0xFF
    units[i] = DataUnit(units[i].unit_type, bytes(payload))


def _apply_stream_edits(units, post: dict) -> None:
    from . import stream_edits  # values the encoder never writes, one broken rule each

    stream_edits.apply_edits(units, post)


def _flip_byte(out: bytes, at) -> bytes:
    """One byte damaged without fixing the CRC."""
    b = bytearray(out)
    b[int(at)] ^= 0x01
    return bytes(b)


def _container_bytes(out: bytes, spec) -> bytes:
    """Container-header bytes the writer refuses (a wrong magic)."""
    from . import stream_edits

    return stream_edits.raw_container_edit(out, spec)


# The edits of an entry's `post`, each (key, edit), in the order they apply. Edits of the units
# (with valid CRCs) first; None: the edits of stream_edits.py, which read the whole `post`.
UNIT_EDITS = (
    ("insert_unit", _insert_units),
    ("insert_empty_render_model", _insert_empty_render_model),
    ("geometry_idcm_mode", _recode_geometry),
    ("empty_chunks", _empty_chunks),
    ("hand_ggconv", _hand_ggconv),
    ("set_prior_mean", _set_prior_mean),
    ("set_render_mlp", _set_render_mlp),
    ("gaussian_attributes", _rewrite_gaussian_attributes),
    ("tile_index", _edit_tile_index),  # [{name, t (a tile, or none), value or add}]
    (None, _apply_stream_edits),
    ("set_gps", _set_gps),  # after the edits, as set_sps
    ("set_sps", _set_sps),
    ("swap_units", _swap_units),
    ("duplicate_unit", _duplicate_unit),
    ("drop_unit", _drop_unit),
    ("append_to_unit", _append_to_unit),
    ("prepend_to_unit", _prepend_to_unit),
    ("truncate_unit", _truncate_unit),
    ("corrupt_hash", _corrupt_hash),
)
# Then, on the written container's bytes (these may break the framing on purpose)
BYTE_EDITS = (
    ("rehash", lambda out, wanted: _rehash(out) if wanted else out),
    ("insert_raw_unit", _insert_raw_unit),
    ("container_bytes", _container_bytes),
    ("flip_byte", _flip_byte),
    ("truncate", lambda out, n: out[:len(out) - int(n)]),  # this many bytes dropped from the end
    ("keep_bytes", lambda out, n: out[:int(n)]),  # only the first bytes of the stream
    ("append_bytes", lambda out, hex_: out + bytes.fromhex(hex_)),  # bytes after the last unit (not a whole one)
)


def post_process(data: bytes, post: dict, hashes: tuple[bytes, ...] | None = None) -> bytes:
    """Edits applied to an encoded stream, in this order: unit edits (which keep valid CRCs),
    then the rehash, then raw byte edits (which may break the framing on purpose). ``hashes``:
    the scene hashes written after the unit edits (an isolated error stream, ``isolate``)."""
    from ..common.container import ContainerHeader, DataUnit, read_container, write_container

    if not post:
        return data
    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    for key, edit in UNIT_EDITS:
        if key is None:
            edit(units, post)
        elif key in post:
            edit(units, post[key])
    if hashes is not None:
        _set_scene_hashes(units, hashes)
    header = ContainerHeader(**post["container_header"]) if "container_header" in post else None
    out = write_container(units, header)
    for key, edit in BYTE_EDITS:
        if key in post:
            out = edit(out, post[key])
    return out


def synthetic_sensitivity(scene, spec: dict | None) -> np.ndarray | None:
    """The pictures' sensitivity to each value (encoder/gaussians/rdoq.py) as an entry's ``sensitivity``
    gives it, so that RDOQ and step adjustment run without renders: per Gaussian a visibility
    10^(spread * u), u uniform in [-1, 0] (seeded), times a per-channel level drawn once. None
    without the key (plain rounding, as every stream of version 1.1)."""
    if not spec:
        return None
    rng = np.random.default_rng(int(spec["seed"]))
    from ..common.attributes import GaussianLayout

    n, m = scene.num_gaussians, GaussianLayout(scene.sh_degree).num_channels
    visibility = 10.0 ** (float(spec.get("spread", 3)) * -rng.random(n))
    return visibility[:, None] * 10.0 ** rng.uniform(2, 4, size=m)[None, :]


def synthetic_sh_degrees(scene, spec: dict | None) -> np.ndarray | None:
    """Each Gaussian's SH degree (format 1.3) as an entry's ``sh_degrees`` gives it: {rule} of
    stream_edits.py's sh_degrees_of_rule, from the source's SH-rest energy (the sum of the
    squares of its coefficients of bands 1 .. d). None without the key (every band coded)."""
    if not spec:
        return None
    from .stream_edits import sh_degrees_of_rule

    energy = (scene.sh[:, 1:].astype(np.float64) ** 2).sum(axis=(1, 2))
    return sh_degrees_of_rule(energy, scene.sh_degree, str(spec.get("rule", "energy")))


def generate(entry: dict) -> tuple[bytes, str | None]:
    """-> (stream bytes, decoded scene SHA-256 hex or None when the stream must be rejected)."""
    import torch

    from ..encoder.stream.config import load_config
    from ..encoder.stream.encode import encode_scene
    from ..encoder.gaussians.gaussians import encode_gaussian_scene

    post = entry.get("post", {})
    if entry["scene"]["generator"] in ("forge_dense", "forge_box"):  # zero attributes (conformance/forge.py)
        from ..common.geometry import normative_order
        from .forge import dense_zero_stream

        s = entry["scene"]
        coords = None
        if s["generator"] == "forge_box":  # a box [dims] of which each voxel is kept with probability density
            ax = [np.arange(int(d)) for d in s["dims"]]
            box = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
            box = box[np.random.default_rng(int(s["seed"])).random(len(box)) < float(s["density"])]
            coords = box[normative_order(box)]
        encoded = dense_zero_stream(int(s.get("side", 1)), int(s["feature_dim"]), int(s["num_offsets"]),
                                    exact_hash=True, coords=coords)
        data = edit_stream(entry, encoded)
        if entry.get("expect") == "error":
            return data, None
        from ..common.container import UnitType, read_container
        from ..common.units import DecodedSceneHashUnit

        unit = [u for u in read_container(data).units if u.unit_type == UnitType.DECODED_SCENE_HASH][0]
        return data, DecodedSceneHashUnit.from_bytes(unit.payload).scene_hash.hex()
    before = torch.get_num_threads()
    torch.set_num_threads(1)  # context-model training in float must be reproducible byte for byte
    try:
        if entry["scene"]["generator"] == "gaussians":  # the preset's steps; no search, no fit
            # neighbour prediction (version 1.1), rotation lengths (version 1.4) and the SH transform
            # (version 1.6) only where the entry asks for them: the streams of the versions before keep
            # their coding
            overrides = {"neighbour_prediction": False, "rotation_length": False, "sh_transform": False,
                         **(entry.get("config") or {})}
            cfg = load_config(entry.get("preset", "medium"), overrides=overrides, kind="gaussians")
            scene = build_scene(entry["scene"])
            result = encode_gaussian_scene(scene, cfg, sensitivity=synthetic_sensitivity(scene, entry.get("sensitivity")),
                                           sh_degrees=synthetic_sh_degrees(scene, entry.get("sh_degrees")))
        else:
            cfg = load_config(entry.get("preset", "medium"), overrides=entry.get("config"))
            result = encode_scene(build_scene(entry["scene"]), cfg)
    finally:
        torch.set_num_threads(before)
    data = edit_stream(entry, result.data)
    if entry.get("expect") == "error":
        return data, None
    if post.get("rehash"):  # the edit changed the decoded scene: the stream carries its new hash
        from ..common.container import UnitType, read_container
        from ..common.units import DecodedSceneHashUnit

        unit = [u for u in read_container(data).units if u.unit_type == UnitType.DECODED_SCENE_HASH][0]
        return data, DecodedSceneHashUnit.from_bytes(unit.payload).scene_hash.hex()
    return data, result.scene_hash.hex()


def edit_stream(entry: dict, encoded: bytes) -> bytes:
    """The entry's ``post`` edits of the encoded stream; an isolated error stream (``condition``)
    with the hashes of the decoder without that check (``isolate``)."""
    return isolate(entry, encoded) if entry.get("condition") else post_process(encoded, entry.get("post", {}))


def isolate(entry: dict, encoded: bytes) -> bytes:
    """An isolated error stream (issue 35, conformance/conditions.py): the stream that ``post``
    makes from ``encoded``, with the decoded scene hashes (one per tile) that the decoder without
    the check of ``condition`` computes, so that this decoder accepts it. ``edit_without_check``:
    the edits themselves run with the check removed. E53's stream (the hash itself) keeps its
    hashes. SystemExit when that decoder rejects the stream (it breaks more than its condition)."""
    from .conditions import CHECK_REMOVALS, HASH_CONDITION, call_without_check, mutant_decode

    cond, post = entry["condition"], entry.get("post", {})
    mutation = entry.get("check_removal") or CHECK_REMOVALS[cond]

    def edited(hashes: tuple[bytes, ...] | None = None) -> bytes:
        if entry.get("edit_without_check"):  # e.g. a k-NN of points beyond the extent limit
            return call_without_check(mutation, post_process, encoded, post, hashes)
        return post_process(encoded, post, hashes)

    data = edited()
    res = mutant_decode(mutation, data)
    if not res.decoded:
        raise SystemExit(f"{entry['id']}: not isolated: without the check of {cond} ({mutation}) the decoder "
                         f"still rejects it: {res.describe()}")
    return data if cond == HASH_CONDITION else edited(res.digests)


def load_sources() -> list[dict]:
    return load_yaml(SOURCES.read_text())["streams"]


# --- what a stream exercises, from what the reference decoder decoded -----------------------------

TOOL_TAGS = """\
Tags of test.yaml `tools`, derived from the reference decoder's result (never written by hand):
  geometry_idcm_<m>     geometry coded with geom_idcm_mode m
  render_model          a render-model unit (render_model_empty: one with no MLPs)
  hierarchy             hierarchy_enabled_flag = 1 (two attribute units per tile with a level 2)
  tiles                 a tiled stream (tiles_enabled_flag 1, a tile_index unit; version 1)
  tile_without_level2   a tile of a hierarchy stream whose level 2 is empty (one attribute unit)
  per_channel_prior, parent_mlp_context, ggconv_context   the context_model_id of an attribute unit
  ggconv_neighbour_level_<n>   a GG-Conv model whose neighbours are the level-n anchors (Annex H.5)
  context_parent_base_<b>      a context model with a channel whose parent_base is b (Annex H.5.3)
  context_model_unit    a context-model unit
  neighbour_prediction  a neighbour_prediction unit (version 1.1, clause 7.3.12): attributes coded by LoD
  step_adjust           a step_adjust unit (version 1.2, clause 7.3.13): a step-adjustment index per Gaussian
  sh_degree             an sh_degree unit (version 1.3, clause 7.3.14): an SH degree per Gaussian
  rotation_length       a rotation_length unit (version 1.4, clause 7.3.15): rotations as a length index and x, y, z
  sh_transform          an sh_transform unit (version 1.6, clause 7.3.17): the SH rest as transform coefficients
  step_adjust_flags     a step_adjust_flags unit (version 1.5, clause 7.3.16): the step-adjustment indices as flags
  gaussians             an explicit-Gaussian scene (gaussian_parameter_set), sh_degree_<d> its SH degree
  channel_prediction    an attribute unit with cross-channel predictions (clause 11.6)
  offset_mask           offset_mask_present_flag = 1
  chunks                an attribute unit with more than one chunk; empty_chunk: a chunk of 0 bytes
  escape                the decoder decoded an escaped residual (spec 10.5) in some unit
  ancillary_unit        an ancillary unit (type >= 0x80; one the decoder does not know is skipped)
  source_info           a source_info unit (0x80, clause 7.3.10) the decoder interpreted;
                        source_info_ignored: one it ignored (malformed, or not the first: clause 6.3)
  container_version     a version_minor other than this document's
  maximum_values        an element at its maximum (its profile/level limit, the largest value of its
                        width, or the largest finite binary32; the 'maximum' class of conformance/coverage.py)
  error streams: container (rejected by the container layer: framing, CRC, version, profile,
  unit types, order), hash (HashMismatchError), level_limits (N * M above the limit), the stage
  that rejects it as sources.yaml declares it (rejected_in: attributes, geometry, render_model,
  hierarchy, context_model; scene_parameter_set or gaussian_parameter_set: an element of the
  parameter set out of its range), and the tags of the parts that parse (hierarchy, offset_mask, ...)."""


class EscapeCounter:
    """Counts escaped residuals while decoding: wraps lghcc.common.entropy.symbol_coder.decode_symbols
    wherever lghcc modules hold it, and compares each residual with its level's half width (spec 10.4:
    escaped iff |r| > L_i). Restores the originals on exit. (A counter in the decoder itself would be
    the cleaner hook; see the conformance report.)"""

    def __enter__(self):
        from ..common.entropy import symbol_coder
        from ..common.entropy.tables import HALF_WIDTHS

        self.count = 0
        orig = symbol_coder.decode_symbols

        def counting(data, levels, *a, **k):
            r = orig(data, levels, *a, **k)
            if np.size(r):
                self.count += int((np.abs(r) > HALF_WIDTHS[np.asarray(levels, np.int64)]).sum())
            return r

        self._patched = [(m, orig) for m in list(sys.modules.values())
                         if getattr(m, "__name__", "").startswith("lghcc.") and getattr(m, "decode_symbols", None) is orig]
        for m, _ in self._patched:
            m.decode_symbols = counting
        return self

    def __exit__(self, *exc):
        for m, orig in self._patched:
            m.decode_symbols = orig


def _structure_tags(data: bytes) -> set[str]:
    """Tags of a stream's parts that parse without decoding (container, sps, unit types)."""
    from ..common import attributes as attr
    from ..common.container import UnitType, read_container
    from ..common.errors import LghccError
    from ..common.units import MAX_ATTRIBUTE_VALUES, GaussianParameterSet, SceneParameterSet

    units = read_container(data).units
    tags = set()
    types = {u.unit_type for u in units}
    unit_tags = {UnitType.RENDER_MODEL: "render_model", UnitType.CONTEXT_MODEL: "context_model_unit",
                 UnitType.NEIGHBOUR_PREDICTION: "neighbour_prediction", UnitType.STEP_ADJUST: "step_adjust",
                 UnitType.SH_DEGREE: "sh_degree", UnitType.ROTATION_LENGTH: "rotation_length",
                 UnitType.SH_TRANSFORM: "sh_transform",
                 UnitType.STEP_ADJUST_FLAGS: "step_adjust_flags"}
    tags.update(tag for unit_type, tag in unit_tags.items() if unit_type in types)
    if any(u.is_ancillary for u in units):
        tags.add("ancillary_unit")
    sps_units = [u for u in units if u.unit_type == UnitType.SCENE_PARAMETER_SET]
    try:
        sps = SceneParameterSet.from_bytes(sps_units[0].payload) if sps_units else None
    except LghccError:  # an sps element out of its range: the stream is rejected there
        tags.add("scene_parameter_set")
        sps = None
    if sps is not None:
        if sps.hierarchy_enabled_flag:
            tags.add("hierarchy")
        if sps.offset_mask_present_flag:
            tags.add("offset_mask")
        if sps.num_points * attr.layout_of(sps).num_channels > MAX_ATTRIBUTE_VALUES:
            tags.add("level_limits")
    gps_units = [u for u in units if u.unit_type == UnitType.GAUSSIAN_PARAMETER_SET]
    try:
        gps = GaussianParameterSet.from_bytes(gps_units[0].payload) if gps_units else None
    except LghccError:  # a gps element out of its range: the stream is rejected there
        tags |= {"gaussians", "gaussian_parameter_set"}
        gps = None
    if gps is not None:
        tags |= {"gaussians", f"sh_degree_{gps.sh_degree}"}
        if gps.hierarchy_enabled_flag:
            tags.add("hierarchy")
        if gps.num_gaussians * attr.gaussian_layout_of(gps).num_channels > MAX_ATTRIBUTE_VALUES:
            tags.add("level_limits")
    return tags


REJECTION_STAGES = ("attributes", "geometry", "render_model", "hierarchy", "context_model")


def derive_tools(data: bytes, rejected_in: str | None = None) -> list[str]:
    """The `tools` of a stream, from what the reference decoder does with it (TOOL_TAGS);
    ``rejected_in``: for a stream the decoder rejects, the decoding stage that rejects it, as
    sources.yaml declares it (one of REJECTION_STAGES, or None)."""
    if rejected_in is not None and rejected_in not in REJECTION_STAGES:
        raise SystemExit(f"rejected_in: {rejected_in!r} is not one of {', '.join(REJECTION_STAGES)}")
    from ..common.container import read_container
    from ..common.errors import HashMismatchError, LghccError
    from ..decoder.decode import decode_stream, organize_units

    try:
        container = read_container(data)
        organize_units(container)
    except LghccError:
        return _undeclared(["container"], rejected_in)
    tags = _structure_tags(data)
    try:
        with EscapeCounter() as esc:
            res = decode_stream(data, trace=True)
    except HashMismatchError:
        return _undeclared(sorted(tags | {"hash"}), rejected_in)
    except LghccError:  # rejected while decoding: the stage sources.yaml declares
        return sorted(tags | ({rejected_in} if rejected_in else set()))
    _undeclared([], rejected_in)
    tags |= _unit_tags(container, res, "hierarchy" in tags) | _context_model_tags(container, res.scene)
    if esc.count:
        tags.add("escape")
    return sorted(tags | _trace_tags(res.trace))


def _unit_tags(container, res, hierarchy: bool) -> set[str]:
    """Tags of the decoded stream's units: its version, tiles, source_info."""
    from ..common.container import UnitType, version_minor_of

    tags = set()
    if container.header.version_minor != version_minor_of(container.units):
        tags.add("container_version")
    if any(u.unit_type == UnitType.TILE_INDEX for u in container.units):
        tags.add("tiles")
    letters = [u.unit_type for u in container.units]
    if letters.count(UnitType.ATTRIBUTE) < 2 * letters.count(UnitType.GEOMETRY) and hierarchy:
        tags.add("tile_without_level2")
    if res.source_info is not None:
        tags.add("source_info")
    if res.notes:
        tags.add("source_info_ignored")
    return tags


def _context_model_tags(container, sc) -> set[str]:
    """Tags of the context-model units: GG-Conv's neighbour level, the channels' parent bases."""
    from ..common.attributes import ChannelLayout, GaussianLayout
    from ..common.container import UnitType
    from ..common.context.models import read_context_model
    from ..common.scene import GaussianScene
    from ..common.units import CONTEXT_GGCONV

    tags = set()
    for u in container.units:
        if u.unit_type == UnitType.CONTEXT_MODEL:
            layout = GaussianLayout(sc.sh_degree) if isinstance(sc, GaussianScene) else \
                ChannelLayout(sc.feature_dim, sc.num_offsets)
            model_id, params = read_context_model(u.payload, layout)
            if model_id == CONTEXT_GGCONV:
                tags.add(f"ggconv_neighbour_level_{params.neighbour_level}")
            tags.update(f"context_parent_base_{b}" for b in np.unique(params.parent_base).tolist())
    return tags


# Tags of single syntax elements in the decoder's trace: element name -> tag of its value (or None)
TRACE_TAGS = {
    "geometry_header.geom_idcm_mode": lambda v: f"geometry_idcm_{v}",
    "attribute_unit_header.context_model_id":
        lambda v: {0: "per_channel_prior", 1: "parent_mlp_context", 2: "ggconv_context"}[int(v)],
    "render_model_unit.num_mlps": lambda v: "render_model_empty" if v == 0 else None,
    "attribute_unit_header.num_channel_predictions": lambda v: "channel_prediction" if v > 0 else None,
    "attribute_unit_header.mask_chunk_size": lambda v: "empty_chunk" if v == 0 else None,
}


def _trace_tags(trace) -> set[str]:
    """Tags of the syntax elements the decoder read: modes, ids, chunks, values at their maximum."""
    from .coverage import _trace_values, element_infos, value_class

    infos = element_infos()
    tags, chunk_sizes = set(), []
    for name, value, ctx in _trace_values(trace):
        if name in TRACE_TAGS:
            tags.add(TRACE_TAGS[name](value))
        elif name == "attribute_unit_header.rows_per_chunk_minus1":
            chunk_sizes.append(0)
        elif name == "attribute_unit_header.chunk_size":
            chunk_sizes[-1] += 1
            if value == 0:
                tags.add("empty_chunk")
        info = infos.get(name)
        if info is not None and info.kind not in ("enum", "bytes") and value_class(info, value, ctx) == "maximum" \
                and name != "attribute_unit_header.rows_per_chunk_minus1":
            tags.add("maximum_values")
    if any(c > 1 for c in chunk_sizes):
        tags.add("chunks")
    return tags - {None}


def _undeclared(tools: list[str], rejected_in: str | None) -> list[str]:
    """``tools`` of a stream that no decoding stage rejects; SystemExit when one is declared."""
    if rejected_in is not None:
        raise SystemExit(f"rejected_in: {rejected_in} declared for a stream that no decoding stage rejects "
                         f"(its tools: {tools or 'those of a decoded stream'})")
    return tools


def check_expectation(entry: dict, data: bytes, decoded: str | None) -> None:
    """The reference decoder must do with the stream what sources.yaml says: decode it to
    ``decoded``, or reject it with ``expect_error`` whose message holds ``expect_message``."""
    from ..common.errors import LghccError
    from ..common.hashing import digest_of
    from ..decoder.decode import decode_stream

    try:
        digest = digest_of(decode_stream(data).scene).hex()
    except LghccError as e:
        if entry.get("expect") != "error":
            raise SystemExit(f"{entry['id']}: the reference decoder rejects the stream: {e}") from None
        kind, msg = type(e).__name__, str(e)
        if kind != entry.get("expect_error") or entry.get("expect_message", "\0") not in msg:
            raise SystemExit(f"{entry['id']}: the reference decoder says {kind}: {msg!r}; sources.yaml expects "
                             f"{entry.get('expect_error')}: {entry.get('expect_message')!r}") from None
        return
    if entry.get("expect") == "error":
        raise SystemExit(f"{entry['id']}: the reference decoder decodes a stream that must be rejected")
    if digest != decoded:
        raise SystemExit(f"{entry['id']}: decodes to {digest}, not the encoder's {decoded}")


# --- reference renders (informative) ----------------------------------------------------------------

RENDER_DEFAULTS = {"background": "black", "min_psnr_db": 50.0, "max_abs_error": 2 / 255}
RENDER_NOTE = ("informative: the renderer is not normative (float rendering differs across machines and "
               "libraries), so each image is compared with its reference within the tolerance, never by hash; "
               "images are .npy uint16 [H, W, 3], value / 65535")


def renders_meta(entry: dict) -> dict | None:
    spec = entry.get("renders")
    if not spec:
        return None
    r = {"note": RENDER_NOTE, "cameras": spec["cameras"], "size": spec["size"],
         "background": spec.get("background", RENDER_DEFAULTS["background"])}
    n = int(str(spec["cameras"]).split(":")[1])
    r["images"] = [f"render_{i:03d}.npy" for i in range(n)]
    r["min_psnr_db"] = float(spec.get("min_psnr_db", RENDER_DEFAULTS["min_psnr_db"]))
    r["max_abs_error"] = float(spec.get("max_abs_error", RENDER_DEFAULTS["max_abs_error"]))
    return r


def write_renders(entry: dict, data: bytes, folder: Path) -> None:
    """Render the decoded scene from the stream's cameras; write the reference images."""
    import torch

    from .runner import render_views, to_uint16
    from ..decoder.decode import decode_stream

    r = renders_meta(entry)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        imgs = render_views(decode_stream(data).scene, r["cameras"], r["size"], r["background"])
    finally:
        torch.set_num_threads(before)
    for name, img in zip(r["images"], imgs):
        np.save(folder / name, to_uint16(img))


def source_info_meta(data: bytes) -> dict | None:
    """test.yaml's ``source_info`` (informative, clauses 6.3 and 7.3.10) of a stream with a
    source_info unit: the source_sh_degree a decoder that interprets source_info outputs (that
    of the first source_info unit when it is well formed, else null) and how many source_info
    units it ignores (a malformed first one, and every one after the first); None for a stream
    without one."""
    from ..common.container import AncillaryUnitType, read_container
    from ..decoder.decode import decode_stream

    if not any(u.unit_type == AncillaryUnitType.SOURCE_INFO for u in read_container(data).units):
        return None
    res = decode_stream(data)
    degree = None if res.source_info is None else int(res.source_info.source_sh_degree)
    return {"source_sh_degree": degree, "ignored": len(res.notes)}


def partial_decodes_meta(entry: dict, data: bytes) -> list[dict] | None:
    """test.yaml's ``partial_decodes`` (version 1, clause 13.3): for each partial decode sources.yaml
    asks for (``box``: the tiles whose cell meets a box; ``level: 1``: the level-1 preview; both: the
    preview of those tiles), how many tiles the reference decoder decodes, with a box which ones
    (``tiles``: their indices in stream order), and the SHA-256 of what it outputs; ``refused``: the
    preview of a stream without the hierarchy, which the reference decoder refuses (UsageError)."""
    from ..common.errors import UsageError
    from ..common.hashing import digest_of
    from ..common.tiles import Box
    from ..decoder.decode import decode_stream, parse_stream, selected_tiles

    out = []
    for p in entry.get("partial_decodes", []):
        if p.get("refused"):
            try:
                decode_stream(data, max_level=1)
            except UsageError:
                out.append(dict(p))
                continue
            raise SystemExit(f"{entry['id']}: the reference decoder decodes a preview that must be refused")
        box = Box(tuple(p["box"][:3]), tuple(p["box"][3:])) if "box" in p else None
        res = decode_stream(data, box=box, max_level=int(p.get("level", 2)))
        meta = {**p, "tiles_decoded": res.tiles_decoded}
        if box is not None:
            s = parse_stream(data)
            meta["tiles"] = selected_tiles(s.tiles, s.ps, box)
        out.append({**meta, "decoded_sha256": digest_of(res.scene).hex()})
    return out or None


def rejection_condition(data: bytes) -> str | None:
    """The row of clause 8.2 the reference decoder's rejection of ``data`` names (test.yaml
    ``expect_condition``; a stream that breaks several may name any of them, clause 8.2)."""
    from ..common.errors import BitstreamError
    from ..decoder.decode import decode_stream

    try:
        decode_stream(data)
    except BitstreamError as e:
        return e.condition
    return None


def test_yaml(entry: dict, data: bytes, decoded: str | None) -> dict:
    meta = {"id": entry["id"], "purpose": entry["purpose"], "profile": "main",
            "tools": derive_tools(data, entry.get("rejected_in")),
            "expect": entry.get("expect", "decode")}
    if entry.get("expect") == "error":
        meta["expect_error"] = entry["expect_error"]
        meta["expect_message"] = entry["expect_message"]
        meta["expect_condition"] = rejection_condition(data)
    if entry.get("condition"):  # an isolated error stream: the one condition of clause 8.2 it breaks
        meta["condition"] = entry["condition"]
        for key in ("bound", "check_removal"):  # the bound of the condition it breaks, when it has several
            if entry.get(key):
                meta[key] = entry[key]
    meta["stream_bytes"] = len(data)
    meta["stream_sha256"] = hashlib.sha256(data).hexdigest()
    if decoded:
        meta["decoded_sha256"] = decoded
    info = source_info_meta(data) if decoded else None
    if info is not None:
        meta["source_info"] = info
    partial = partial_decodes_meta(entry, data) if decoded else None
    if partial:
        meta["partial_decodes"] = partial
    r = renders_meta(entry)
    if r:
        meta["renders"] = r
    derived = set(meta["tools"])
    derived |= {"geometry"} if any(t.startswith("geometry_idcm_") for t in derived) else set()
    derived |= {"container"} if derived & {"ancillary_unit", "container_version"} else set()
    missing = set(entry.get("tools", [])) - derived if meta["expect"] == "decode" else set()
    if missing:  # sources.yaml's tools are the intent; the derived ones must include them
        raise SystemExit(f"{entry['id']}: sources.yaml says it exercises {sorted(missing)}, but the reference "
                         f"decoder's result shows only {meta['tools']}")
    return meta


def yaml_text(meta: dict) -> str:
    return yaml.safe_dump(meta, sort_keys=False)


def _write(entry: dict, folder: Path) -> str:
    """Generate the entry's stream and write its folder (stream, test.yaml, renders). A stream made
    again to the same bytes keeps its reference renders (float renders of the same scene can differ
    in their last bits from machine to machine: they are informative, compared within a tolerance)."""
    data, decoded = generate(entry)
    check_expectation(entry, data, decoded)
    folder.mkdir(parents=True, exist_ok=True)
    same = (folder / "stream.lghcc").is_file() and (folder / "stream.lghcc").read_bytes() == data
    (folder / "stream.lghcc").write_bytes(data)
    if entry.get("renders") and not (same and all((folder / n).is_file() for n in renders_meta(entry)["images"])):
        write_renders(entry, data, folder)
    (folder / "test.yaml").write_text(yaml_text(test_yaml(entry, data, decoded)))
    return f"{len(data):,} bytes" + (", the same as before" if same else "")


def _frozen(folder: Path) -> tuple[bytes, dict]:
    """The committed stream and its test.yaml."""
    return (folder / "stream.lghcc").read_bytes(), load_yaml((folder / "test.yaml").read_text())


def _write_metadata(entry: dict, folder: Path, renders: bool) -> str:
    """test.yaml (with ``renders``: and the reference renders) from the frozen stream."""
    data, meta = _frozen(folder)
    if renders:
        write_renders(entry, data, folder)
    (folder / "test.yaml").write_text(yaml_text(test_yaml(entry, data, meta.get("decoded_sha256"))))
    return f"{len(renders_meta(entry)['images'])} reference renders" if renders else "test.yaml"


def _check(entry: dict, folder: Path) -> tuple[list[str], bool]:
    """(problems, whether today's encoder reproduces the frozen stream byte for byte): the frozen
    test.yaml must be what the generator derives from the frozen stream, and a fresh generation
    must meet sources.yaml (generate, isolate and test_yaml raise SystemExit when it does not)."""
    if not (folder / "stream.lghcc").is_file():
        return [f"no stream in {folder} (generate it)"], False
    frozen, meta = _frozen(folder)
    problems = []
    if yaml_text(test_yaml(entry, frozen, meta.get("decoded_sha256"))) != (folder / "test.yaml").read_text():
        problems.append("test.yaml is not what the generator derives from the frozen stream (--metadata)")
    try:
        data, decoded = generate(entry)
        check_expectation(entry, data, decoded)
        if data != frozen or decoded != meta.get("decoded_sha256"):  # else derived from the frozen stream above
            test_yaml(entry, data, decoded)
    except SystemExit as e:
        problems.append(f"the generator can no longer make it: {e}")
        return problems, False
    return problems, data == frozen


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lghcc.conformance.generate", description=__doc__ + "\n" + TOOL_TAGS,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true",
                      help="generate in memory and check, writing nothing (see above); exit 1 on a problem")
    mode.add_argument("--metadata", action="store_true",
                      help="only rewrite test.yaml from the frozen streams (sources.yaml's purpose or the tags "
                           "changed), and the manifest")
    mode.add_argument("--renders", action="store_true",
                      help="only (re)write the reference renders (and test.yaml) of streams with `renders` in "
                           "sources.yaml, from the frozen streams, and the manifest")
    ap.add_argument("ids", nargs="*", help="only these stream ids")
    args = ap.parse_args(argv)
    entries = load_sources()
    unknown = sorted(set(args.ids) - {e["id"] for e in entries})
    if unknown:
        print(f"generate: error: no such stream in {SOURCES.name}: {', '.join(unknown)}", file=sys.stderr)
        return 2
    failures = reproduced = checked = 0
    for entry in (e for e in entries if not args.ids or e["id"] in args.ids):
        folder = STREAMS / entry["id"]
        if args.check:
            problems, same = _check(entry, folder)
            failures, reproduced, checked = failures + bool(problems), reproduced + same, checked + 1
            note = "reproduced byte for byte" if same else "a different stream today (allowed: the streams are frozen)"
            print(f"{entry['id']}: {'; '.join(problems) if problems else 'ok'}; {note}")
        elif args.renders and not entry.get("renders"):
            if args.ids:
                print(f"{entry['id']}: no renders in {SOURCES.name}")
        else:
            done = _write_metadata(entry, folder, args.renders) if args.renders or args.metadata else \
                _write(entry, folder)
            print(f"{entry['id']}: {done}")
    if args.check:
        print(f"{checked} streams checked, {failures} with problems; today's encoder reproduces {reproduced} "
              f"of them byte for byte")
        return 1 if failures else 0
    write_manifest(STREAMS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
