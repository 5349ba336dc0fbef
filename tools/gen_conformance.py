#!/usr/bin/env python3
"""Generate the conformance streams from conformance/sources.yaml, or check them.

    python tools/gen_conformance.py            # (re)write conformance/streams/<id>/
    python tools/gen_conformance.py --check    # the encoder must reproduce every stream byte for byte

Streams are frozen once committed: regenerate only when the bitstream format changes
on purpose, and say so in the commit.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ROOT / "conformance" / "sources.yaml"
STREAMS = ROOT / "conformance" / "streams"


def random_mlp(rng, dims: list[int], final: str, zero_bias: bool):
    from lghcc.common.scene import RenderMLP

    ws = [(rng.normal(size=(o, i)) / np.sqrt(i)).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
    bs = [np.zeros(o, np.float32) if zero_bias else (0.1 * rng.normal(size=o)).astype(np.float32)
          for o in dims[1:]]
    return RenderMLP(ws, bs, ["relu"] * (len(ws) - 1) + [final])


def spec_mlp(rng, in_dim: int, spec: dict):
    """A render MLP from an explicit layer list: spec = {layers: [{out, act, weight, bias}, ...]},
    weight/bias: a number (scale of N(0, 1) values; 0 gives a tensor of zeros)."""
    from lghcc.common.scene import RenderMLP

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
    from lghcc.common.scene import AnchorScene

    rng = np.random.default_rng(s["seed"])
    n, c, k = s["num_anchors"], s["feature_dim"], s["num_offsets"]
    spread = int(s.get("spread", 64))
    coords = np.unique(rng.integers(-spread, spread, size=(2 * n + 8, 3), endpoint=True), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]].astype(np.int64)
    if s.get("shift_to_zero"):  # bounding-box minimum 0 on every axis
        coords -= coords.min(axis=0)
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
    mask = None
    if s.get("mask"):
        mask = rng.random((n, k)) < 0.6
        mask[:, s.get("dead_slots", [])] = False  # slots that are never live: mask_live_prob at its minimum
    return AnchorScene(
        coords=coords, voxel_size=float(s.get("voxel_size", 0.01)),
        origin=np.asarray(s.get("origin", [0.0, 0.0, 0.0]), dtype=np.float32),
        features=feats, scalings=scalings, offsets=offsets, offset_mask=mask, mlps=mlps)


def build_scene(s: dict):
    from lghcc.common.procedural import make_procedural_scene

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
    from lghcc.common import attributes as attr
    from lghcc.common.bitio import BitReader
    from lghcc.common.container import DataUnit, UnitType
    from lghcc.common.units import AttributeUnitHeader, SceneParameterSet

    sps = SceneParameterSet.from_bytes(units[_unit_index(units, UnitType.SCENE_PARAMETER_SET)].payload)
    j = _unit_index(units, UnitType.ATTRIBUTE)
    payload = units[j].payload
    r = BitReader(payload)
    h = AttributeUnitHeader.parse(r, num_channels=attr.layout_of(sps).num_channels, num_offsets=sps.num_offsets,
                                  offset_mask_present=sps.offset_mask_present_flag, num_rows=sps.num_anchors)
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
    from lghcc.common.context.ggconv import GGConvParams
    from lghcc.common.intnn import IntLinear, IntMLP

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


def _hand_ggconv(units, spec: dict):
    """Code level 2 with a hand-built GG-Conv model instead of the per-channel prior: one-layer
    feature and head MLPs, Ch context channels, scalars as [1]-shaped arrays and shifts as 1-bit
    arrays (the smallest shapes and widths the syntax allows). Its step adjustment is 0, so the
    quantized values, and the decoded scene, are those of the per-channel stream."""
    from lghcc.common import attributes as attr
    from lghcc.common.container import DataUnit, UnitType
    from lghcc.common.context.ggconv import GGConvParams
    from lghcc.common.context.model_unit import NamedIntArray, write_context_model_unit
    from lghcc.common.context.models import level2_coding_params, read_context_model
    from lghcc.common.geometry import decode_geometry
    from lghcc.common.hierarchy import build_hierarchy
    from lghcc.common.intnn import IntLinear, IntMLP
    from lghcc.common.units import CONTEXT_GGCONV, LEVEL_1, LEVEL_2, AttributeUnitHeader, SceneParameterSet

    sps = SceneParameterSet.from_bytes(units[_unit_index(units, UnitType.SCENE_PARAMETER_SET)].payload)
    layout = attr.layout_of(sps)
    m, c = layout.num_channels, sps.feature_dim
    coords = decode_geometry(units[_unit_index(units, UnitType.GEOMETRY)].payload, sps.num_anchors)
    hier = build_hierarchy(coords, sps.coarse_voxel_scale)
    values = np.empty((sps.num_anchors, m), np.float32)
    a1, a2 = _unit_index(units, UnitType.ATTRIBUTE, 0), _unit_index(units, UnitType.ATTRIBUTE, 1)
    _, _, q1 = attr.read_attribute_unit(units[a1].payload, sps, hier.num_level1, LEVEL_1, values,
                                        hier.level1_idx, keep_q=True)
    h2, mask2, q2 = attr.read_attribute_unit(units[a2].payload, sps, hier.num_level2, LEVEL_2, values,
                                             hier.level2_idx, keep_q=True)
    ch, d = int(spec.get("channels", 1)), int(spec.get("grid", 2))
    rng = np.random.default_rng(int(spec.get("seed", 0)))
    table = rng.integers(-64, 64, size=(d, d, d, ch), endpoint=True)
    feat_in = _ggconv_feature_inputs(c)
    feat = IntLinear(rng.integers(-3, 3, size=(ch, feat_in), endpoint=True), np.zeros(ch, np.int64), 0, False, 8)
    # head inputs: h (Ch), local position (3), n_valid (1), parent attributes (M); outputs mean, level, adjust
    w = np.zeros((3 * m, ch + 4 + m), np.int64)
    w[m:2 * m, ch + 3] = 1  # level grows with the number of valid neighbours
    bias = np.concatenate([np.zeros(m), np.full(m, int(spec.get("level", 8))), np.zeros(m)]).astype(np.int64)
    head = IntLinear(w, bias, 0, False, 8)
    p = GGConvParams(num_features=c, k=int(spec.get("k", 2)), radius_sq=int(spec.get("radius_sq", 64)),
                     table=table, h_shift=0, feat_mlp=IntMLP([feat]), head_mlp=IntMLP([head]))
    arrays = []
    for a in p.to_arrays():
        v = np.asarray(a.values)
        if v.ndim == 0:
            v = v.reshape(1)
        bits = 1 if a.name.endswith(".shift") or a.name == "h_shift" else a.bits
        arrays.append(NamedIntArray(a.name, v, bits, a.signed))
    unit = write_context_model_unit(CONTEXT_GGCONV, arrays, 1, 1)
    model = read_context_model(unit, layout)
    params = level2_coding_params(model, coords[hier.level2_idx], q1[hier.parent_of_level2], sps.coarse_voxel_scale)
    assert params.step_adjust is None or not params.step_adjust.any()
    h = AttributeUnitHeader(num_channels=m, num_offsets=sps.num_offsets, offset_mask_present=h2.offset_mask_present,
                            num_rows=hier.num_level2, attribute_level=LEVEL_2, context_model_id=CONTEXT_GGCONV,
                            mask_live_prob=list(h2.mask_live_prob), rows_per_chunk_minus1=h2.rows_per_chunk_minus1)
    units[a2] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(h, layout, q2, mask2, params))
    units.insert(a1, DataUnit(UnitType.CONTEXT_MODEL, unit))


def _rehash(data: bytes) -> bytes:
    """Replace the decoded scene hash by the hash of what the stream decodes to (for edits that
    change the decoded scene on purpose; tests/test_spec_and_conformance.py checks those values)."""
    from lghcc.common.container import DataUnit, UnitType, read_container, write_container
    from lghcc.common.hashing import scene_digest
    from lghcc.common.units import DecodedSceneHashUnit
    from lghcc.decoder.decode import decode_stream

    digest = scene_digest(decode_stream(data, verify_hash=False).scene)
    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    j = _unit_index(units, UnitType.DECODED_SCENE_HASH)
    units[j] = DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=digest).to_bytes())
    return write_container(units)


def post_process(data: bytes, post: dict) -> bytes:
    """Edits applied to an encoded stream, in this order: unit edits (which keep valid CRCs),
    then the rehash, then raw byte edits (which may break the framing on purpose)."""
    from lghcc.common.container import ContainerHeader, DataUnit, UnitType, read_container, write_container
    from lghcc.common.geometry import decode_geometry, encode_geometry
    from lghcc.common.units import RenderModelUnit, SceneParameterSet

    if not post:
        return data
    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    if "insert_unit" in post:
        p = post["insert_unit"]
        units.insert(p["index"], DataUnit(int(p["type"]), p["payload"].encode()))
    if "insert_empty_render_model" in post:  # num_mlps = 0, coded_size = 0: the same decoded scene
        units.insert(post["insert_empty_render_model"], DataUnit(UnitType.RENDER_MODEL, RenderModelUnit().to_bytes()))
    if "geometry_idcm_mode" in post:  # re-code the geometry losslessly with another IDCM mode
        j = _unit_index(units, UnitType.GEOMETRY)
        n = SceneParameterSet.from_bytes(units[0].payload).num_anchors
        coords = decode_geometry(units[j].payload, n)
        units[j] = DataUnit(UnitType.GEOMETRY, encode_geometry(coords, int(post["geometry_idcm_mode"])))
        assert np.array_equal(decode_geometry(units[j].payload, n), coords)
    if "empty_chunks" in post:
        _empty_chunks(units, post["empty_chunks"])
    if "hand_ggconv" in post:
        _hand_ggconv(units, post["hand_ggconv"])
    if "set_sps" in post:  # overwrite scene parameter set fields
        j = _unit_index(units, UnitType.SCENE_PARAMETER_SET)
        sps = SceneParameterSet.from_bytes(units[j].payload)
        for k, v in post["set_sps"].items():
            setattr(sps, k, v)
        units[j] = DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())
    if "swap_units" in post:
        a, b = post["swap_units"]
        units[a], units[b] = units[b], units[a]
    if "drop_unit" in post:
        del units[post["drop_unit"]]
    if "append_to_unit" in post:  # trailing bytes inside a payload (with a valid CRC)
        p = post["append_to_unit"]
        units[p["index"]] = DataUnit(units[p["index"]].unit_type, units[p["index"]].payload + bytes.fromhex(p["hex"]))
    if post.get("corrupt_hash"):
        i = _unit_index(units, UnitType.DECODED_SCENE_HASH)
        payload = bytearray(units[i].payload)
        payload[-1] ^= 0xFF
        units[i] = DataUnit(units[i].unit_type, bytes(payload))
    header = ContainerHeader(**post["container_header"]) if "container_header" in post else None
    out = write_container(units, header)
    if post.get("rehash"):
        out = _rehash(out)
    if "flip_byte" in post:  # damage one byte without fixing the CRC
        b = bytearray(out)
        b[int(post["flip_byte"])] ^= 0x01
        out = bytes(b)
    if "truncate" in post:  # drop this many bytes from the end
        out = out[:len(out) - int(post["truncate"])]
    return out


def generate(entry: dict) -> tuple[bytes, str | None]:
    """-> (stream bytes, decoded scene SHA-256 hex or None when the stream must be rejected)."""
    import torch

    from lghcc.encoder.config import load_config
    from lghcc.encoder.encode import encode_scene

    torch.set_num_threads(1)  # context-model training in float must be reproducible byte for byte
    cfg = load_config(entry.get("preset", "medium"), overrides=entry.get("config"))
    result = encode_scene(build_scene(entry["scene"]), cfg)
    post = entry.get("post", {})
    data = post_process(result.data, post)
    if entry.get("expect") == "error":
        return data, None
    if post.get("rehash"):  # the edit changed the decoded scene: the stream carries its new hash
        from lghcc.common.container import UnitType, read_container
        from lghcc.common.units import DecodedSceneHashUnit

        unit = [u for u in read_container(data).units if u.unit_type == UnitType.DECODED_SCENE_HASH][0]
        return data, DecodedSceneHashUnit.from_bytes(unit.payload).scene_hash.hex()
    return data, result.scene_hash.hex()


def load_sources() -> list[dict]:
    return yaml.safe_load(SOURCES.read_text())["streams"]


def test_yaml(entry: dict, data: bytes, decoded: str | None) -> dict:
    meta = {"id": entry["id"], "purpose": entry["purpose"], "profile": "main", "tools": entry.get("tools", []),
            "expect": entry.get("expect", "decode"), "stream_bytes": len(data),
            "stream_sha256": hashlib.sha256(data).hexdigest()}
    if decoded:
        meta["decoded_sha256"] = decoded
    return meta


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="verify the committed streams instead of writing")
    ap.add_argument("ids", nargs="*", help="only these stream ids")
    args = ap.parse_args(argv)
    failures = 0
    for entry in load_sources():
        if args.ids and entry["id"] not in args.ids:
            continue
        data, decoded = generate(entry)
        folder = STREAMS / entry["id"]
        if args.check:
            stored = (folder / "stream.lghcc").read_bytes() if (folder / "stream.lghcc").is_file() else None
            ok = stored == data
            failures += not ok
            print(f"{entry['id']}: {'reproduced byte for byte' if ok else 'DIFFERS from the committed stream'}")
            continue
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "stream.lghcc").write_bytes(data)
        (folder / "test.yaml").write_text(yaml.safe_dump(test_yaml(entry, data, decoded), sort_keys=False))
        print(f"{entry['id']}: {len(data):,} bytes")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
