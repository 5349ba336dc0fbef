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


def random_scene(s: dict):
    """Small random scene with the knobs the sources use."""
    from lghcc.common.scene import AnchorScene

    rng = np.random.default_rng(s["seed"])
    n, c, k = s["num_anchors"], s["feature_dim"], s["num_offsets"]
    spread = int(s.get("spread", 64))
    coords = np.unique(rng.integers(-spread, spread, size=(2 * n + 8, 3), endpoint=True), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]].astype(np.int64)
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
        dims = [c + 4] + [c] * (layers - 1) + [outs[role]]
        mlps[role] = random_mlp(rng, dims, finals[role], bool(s.get("zero_bias", False)))
    if "feature_bank" in mlps:  # exercise the remaining activation in a hidden layer
        mlps["feature_bank"].activations[0] = "sigmoid"
    if "cov" in mlps and layers > 2:
        mlps["cov"].activations[1] = "tanh"
    return AnchorScene(
        coords=coords, voxel_size=float(s.get("voxel_size", 0.01)),
        origin=np.asarray(s.get("origin", [0.0, 0.0, 0.0]), dtype=np.float32),
        features=feats, scalings=rng.normal(size=(n, 6)).astype(np.float32),
        offsets=rng.normal(size=(n, k, 3)).astype(np.float32),
        offset_mask=(rng.random((n, k)) < 0.6) if s.get("mask") else None, mlps=mlps)


def build_scene(s: dict):
    from lghcc.common.procedural import make_procedural_scene

    if s["generator"] == "procedural":
        return make_procedural_scene(s["num_anchors"], seed=s.get("seed", 0), with_mask=s.get("with_mask", False),
                                     feature_dim=s.get("feature_dim", 50), num_offsets=s.get("num_offsets", 10))
    if s["generator"] == "random":
        return random_scene(s)
    raise ValueError(f"unknown scene generator {s['generator']!r}")


def post_process(data: bytes, post: dict) -> bytes:
    from lghcc.common.container import DataUnit, UnitType, read_container, write_container

    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    if "insert_unit" in post:
        p = post["insert_unit"]
        units.insert(p["index"], DataUnit(int(p["type"]), p["payload"].encode()))
    if post.get("corrupt_hash"):
        i = next(j for j, u in enumerate(units) if u.unit_type == UnitType.DECODED_SCENE_HASH)
        payload = bytearray(units[i].payload)
        payload[-1] ^= 0xFF
        units[i] = DataUnit(units[i].unit_type, bytes(payload))
    return write_container(units)


def generate(entry: dict) -> tuple[bytes, str | None]:
    """-> (stream bytes, decoded scene SHA-256 hex or None when the stream must be rejected)."""
    import torch

    from lghcc.encoder.config import load_config
    from lghcc.encoder.encode import encode_scene

    torch.set_num_threads(1)  # context-model training in float must be reproducible byte for byte
    cfg = load_config(entry.get("preset", "medium"), overrides=entry.get("config"))
    result = encode_scene(build_scene(entry["scene"]), cfg)
    data = post_process(result.data, entry.get("post", {}))
    return data, None if entry.get("expect") == "error" else result.scene_hash.hex()


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
