"""Read and write the Scaffold-GS checkpoint layout (the interchange format of anchor-based 3DGS).

    <model>/point_cloud/iteration_<N>/point_cloud.ply   anchors
    <model>/point_cloud/iteration_<N>/checkpoint.pth    {'opacity_mlp': state_dict, 'cov_mlp': ..., 'color_mlp': ...}
    <model>/cfg_args                                     Namespace(..., voxel_size=0.001, ...) (Scaffold-GS, HAC)

PLY fields per anchor: x,y,z, nx,ny,nz, f_offset_0..3K-1 (index = axis*K + k),
f_anchor_feat_0..C-1, opacity, scale_0..5 (log), rot_0..3; HAC adds f_mask_0..K-1.
MLPs may also come as HAC's names (mlp_opacity, ...), in a file named checkpoints.pth,
or as traced modules (opacity_mlp.pt, ...) from older Scaffold-GS versions.

lghcc writes the scene's voxel size and origin into the PLY header as comment lines
(``comment lghcc voxel_size 0x1.0c9b1ep-4``, ``comment lghcc origin X Y Z``, exact
float.hex values), which Scaffold-GS tools ignore; reading them back makes decode then
re-encode give the same scene, whatever the origin. A model without them states its voxel size
in cfg_args (the training arguments Scaffold-GS and HAC save); else the voxel size is inferred
from the float32 anchor positions (grid_inference: a grid through the origin).
"""

from __future__ import annotations

import ast
import math
import os
import re
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..app.fileio import atomic_output
from .grid_inference import grid_error, infer_voxel_size, on_grid
from .ply import read_ply, read_ply_comments, write_ply
from ..common.scene import NUM_SCALINGS, AnchorScene, RenderMLP

# Output activation of each role in Scaffold-GS (hidden layers use ReLU).
ROLE_FINAL_ACTIVATION = {"opacity": "tanh", "cov": "none", "color": "sigmoid", "feature_bank": "none"}
STATE_DICT_NAMES = {
    "opacity": ("opacity_mlp", "mlp_opacity"),
    "cov": ("cov_mlp", "mlp_cov"),
    "color": ("color_mlp", "mlp_color"),
    "feature_bank": ("mlp_feature_bank", "feature_bank_mlp"),
}
PLY_NAME = "point_cloud.ply"
CHECKPOINT_NAME = "checkpoint.pth"
CHECKPOINT_NAMES = (CHECKPOINT_NAME, "checkpoints.pth")  # read in this order; the first found is used
TRACED_MLP_NAMES = tuple(f"{names[0]}.pt" for names in STATE_DICT_NAMES.values())
PLY_COMMENT_PREFIX = "lghcc "
CFG_ARGS_NAME = "cfg_args"  # Scaffold-GS's and HAC's training arguments in the model folder: a printed Namespace
CFG_ARGS_MAX_BYTES = 1 << 20


class MissingMlpWarning(UserWarning):
    """A Scaffold-GS folder without a recognised render-MLP file: the scene is read without MLPs."""


def _numbered(cols: dict[str, np.ndarray], prefix: str) -> list[str]:
    names = [k for k in cols if re.fullmatch(re.escape(prefix) + r"\d+", k)]
    return sorted(names, key=lambda k: int(k[len(prefix):]))


def locate_ply(path: str | os.PathLike) -> Path:
    """Accept a .ply file, an iteration folder, or a model folder (highest iteration wins)."""
    p = Path(path)
    if p.is_file():
        return p
    if (p / PLY_NAME).is_file():
        return p / PLY_NAME
    its = sorted((int(m.group(1)), d) for d in (p / "point_cloud").glob("iteration_*")
                 if (m := re.fullmatch(r"iteration_(\d+)", d.name)) and (d / PLY_NAME).is_file())
    if its:
        return its[-1][1] / PLY_NAME
    raise InputError(f"{p}: no {PLY_NAME} found (give a .ply file, an iteration folder or a Scaffold-GS "
                     "model folder with point_cloud/iteration_<N>/)")


def quantize_positions(positions: np.ndarray, voxel_size: float, origin: np.ndarray) -> np.ndarray:
    c = np.round((positions.astype(np.float64) - origin) / voxel_size)
    if not np.isfinite(c).all() or np.abs(c).max(initial=0) >= 2 ** 31:
        raise InputError("anchor positions / voxel size exceed the coordinate range of +-2^31 voxels")
    return c.astype(np.int64)


def _mlp_from_state_dict(role: str, sd: dict) -> RenderMLP:
    layer_ids = sorted({int(k.split(".")[0]) for k in sd if k.endswith(".weight")})
    if not layer_ids:
        raise InputError(f"{role} MLP: no Linear weights in its state dict")
    ws = [np.asarray(sd[f"{i}.weight"].detach().cpu().numpy(), dtype=np.float32) for i in layer_ids]
    bs = [np.asarray(sd[f"{i}.bias"].detach().cpu().numpy(), dtype=np.float32) for i in layer_ids]
    acts = ["relu"] * (len(ws) - 1) + [ROLE_FINAL_ACTIVATION[role]]
    return RenderMLP(ws, bs, acts)


def read_mlps(folder: Path) -> dict[str, RenderMLP]:
    """The render MLPs of an iteration folder: from checkpoint.pth (or checkpoints.pth), else from
    traced modules. Warns (MissingMlpWarning, naming the folder) when no MLP file is recognised."""
    import torch

    mlps: dict[str, RenderMLP] = {}
    ckpt = next((folder / name for name in CHECKPOINT_NAMES if (folder / name).is_file()), None)
    if ckpt is not None:
        try:
            data = torch.load(ckpt, map_location="cpu", weights_only=True)
        except Exception as e:
            raise InputError(f"{ckpt}: cannot load ({e})") from None
        if not isinstance(data, dict):
            raise InputError(f"{ckpt}: not a dictionary of state dicts")
        for role, names in STATE_DICT_NAMES.items():
            for name in names:
                if name in data:
                    try:
                        mlps[role] = _mlp_from_state_dict(role, data[name])
                    except InputError as e:
                        raise InputError(f"{ckpt}: {e}") from None
                    break
        if not mlps:
            warnings.warn(f"{ckpt}: no render MLP found in it (expected keys "
                          f"{', '.join(n for names in STATE_DICT_NAMES.values() for n in names)}); "
                          "the scene has no render MLPs", MissingMlpWarning, stacklevel=3)
        return mlps
    for role, names in STATE_DICT_NAMES.items():
        f = folder / f"{names[0]}.pt"
        if f.is_file():
            try:
                mlps[role] = _mlp_from_state_dict(role, torch.jit.load(str(f), map_location="cpu").state_dict())
            except Exception as e:
                raise InputError(f"{f}: cannot load traced module ({e})") from None
    if not mlps:
        warnings.warn(f"{folder}: no render-MLP file recognised (looked for {' or '.join(CHECKPOINT_NAMES)}, "
                      f"or {', '.join(TRACED_MLP_NAMES)}); the scene has no render MLPs", MissingMlpWarning,
                      stacklevel=3)
    return mlps


def _header_grid(ply: Path) -> tuple[float | None, np.ndarray | None]:
    """The voxel size and origin lghcc wrote into the PLY header, when it did."""
    voxel, origin = None, None
    for c in read_ply_comments(ply):
        if not c.startswith(PLY_COMMENT_PREFIX):
            continue
        key, _, value = c[len(PLY_COMMENT_PREFIX):].partition(" ")
        try:
            if key == "voxel_size":
                voxel = float.fromhex(value.strip())
            elif key == "origin":
                origin = np.array([float.fromhex(v) for v in value.split()], dtype=np.float64)
                if origin.shape != (3,):
                    raise ValueError("three values expected")
        except ValueError as e:
            raise InputError(f"{ply}: unreadable header comment {c!r} ({e})") from None
    if voxel is not None and not (np.isfinite(voxel) and voxel > 0):
        raise InputError(f"{ply}: header comment voxel_size {voxel} is not a positive finite number")
    if origin is not None and not np.isfinite(origin).all():
        raise InputError(f"{ply}: header comment origin {origin} is not finite")
    return voxel, origin


def read_cfg_args(path: Path) -> dict[str, object]:
    """The keyword values of a printed argparse Namespace (Scaffold-GS's and HAC's cfg_args,
    ``Namespace(..., voxel_size=0.001, ...)``): parsed, never evaluated; a value that is no Python
    literal is left out. InputError when the file is no such text."""
    try:
        if path.stat().st_size > CFG_ARGS_MAX_BYTES:
            raise ValueError(f"over {CFG_ARGS_MAX_BYTES} bytes")
        call = ast.parse(path.read_text(encoding="utf-8"), mode="eval").body
    except (OSError, UnicodeDecodeError, SyntaxError, ValueError, RecursionError) as e:
        raise InputError(f"{path}: unreadable ({e})") from None
    if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == "Namespace"):
        raise InputError(f"{path}: not a printed argparse Namespace(...)")
    values: dict[str, object] = {}
    for kw in call.keywords:
        try:
            values[str(kw.arg)] = ast.literal_eval(kw.value)
        except (ValueError, TypeError, SyntaxError, RecursionError):
            pass
    return values


def stated_voxel_size(ply: Path) -> tuple[float | None, str]:
    """The voxel size that the cfg_args of the model folder holding ``ply``
    (<model>/point_cloud/iteration_<N>/) states, and that file; (None, why not) when none does.
    Scaffold-GS and HAC take voxel_size <= 0 to mean one chosen from the points: not stated."""
    folder = ply.absolute().parent  # a relative path may stop inside the model folder
    cfg = folder.parent.parent / CFG_ARGS_NAME
    if not (re.fullmatch(r"iteration_\d+", folder.name) and folder.parent.name == "point_cloud" and cfg.is_file()):
        return None, "no cfg_args in the model folder"
    try:
        v = read_cfg_args(cfg).get("voxel_size")
    except InputError as e:
        return None, str(e)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        return None, f"{cfg} states no positive voxel_size (voxel_size={v!r})"
    return float(v), str(cfg)


def anchor_grid(ply: Path, positions: np.ndarray, voxel_size: float | None,
                origin: np.ndarray | None) -> tuple[float, np.ndarray, str]:
    """(voxel size, origin, where the voxel size came from) of the anchors of ``ply``. The voxel size:
    the argument, else lghcc's header comment, else the model's cfg_args (the positions must lie on
    its grid), else inferred from the positions. The origin: the argument, the header comment, or 0."""
    header_voxel, header_origin = _header_grid(ply)
    if origin is None:
        origin = np.zeros(3) if header_origin is None else header_origin
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape != (3,) or not np.isfinite(origin).all():
        raise InputError(f"the origin must be 3 finite numbers, got {origin}")
    if voxel_size is not None:
        return float(voxel_size), origin, "as given (--voxel-size)"
    if header_voxel is not None:
        return header_voxel, origin, "from lghcc's header comment in the PLY"
    stated, cfg = stated_voxel_size(ply)
    if stated is not None:
        if not on_grid(positions, stated, origin):
            raise InputError(f"{cfg}: voxel_size={stated!r}, but the anchor positions of {ply} are not on a grid of "
                             f"that spacing (an error of {grid_error(positions - origin, stated):.3g} voxels, more "
                             "than float32 storage explains); pass the voxel size explicitly (--voxel-size)")
        return stated, origin, f"from {cfg}"
    try:
        return infer_voxel_size(positions, origin), origin, f"inferred from the anchor grid ({cfg})"
    except InputError as e:
        raise InputError(f"{ply}: {e}") from None


def _anchor_properties(ply: Path, cols: dict[str, np.ndarray]) -> tuple[list[str], list[str], list[str]]:
    """The feature, offset and scaling properties of a Scaffold-GS anchor PLY, checked."""
    for req in ("x", "y", "z"):
        if req not in cols:
            raise InputError(f"{ply}: no '{req}' property: not an anchor point cloud")
    feats = _numbered(cols, "f_anchor_feat_")
    offs = _numbered(cols, "f_offset_")
    scales = _numbered(cols, "scale_")
    if not feats:
        raise InputError(f"{ply}: no f_anchor_feat_* properties: not a Scaffold-GS anchor file "
                         "(a plain 3DGS PLY must be converted first)")
    if not offs or len(offs) % 3:
        raise InputError(f"{ply}: expected 3K f_offset_* properties, found {len(offs)}")
    if len(scales) != NUM_SCALINGS:
        raise InputError(f"{ply}: expected scale_0..5, found {len(scales)} scale properties")
    return feats, offs, scales


def read_scaffold(path: str | os.PathLike, voxel_size: float | None = None, origin: np.ndarray | None = None,
                  log: Callable[[str], None] | None = None) -> AnchorScene:
    """Read a Scaffold-GS PLY (and the MLPs beside it) and validate the scene; every error names
    the file. The voxel size and origin: ``anchor_grid``; ``log`` is told the voxel size and where
    it came from. Anchors sharing a voxel are allowed here (the encoder rejects or merges them)."""
    if voxel_size is not None and not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"the voxel size must be a positive finite number, got {voxel_size}")
    ply = locate_ply(path)
    cols = read_ply(ply)
    feats, offs, scales = _anchor_properties(ply, cols)
    n = len(cols["x"])
    k = len(offs) // 3
    positions = np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)
    if not np.isfinite(positions).all():
        raise InputError(f"{ply}: anchor positions contain NaN or Inf")
    vs, origin, source = anchor_grid(ply, positions, voxel_size, origin)
    if log is not None:
        log(f"{ply}: voxel size {np.float32(vs)!s} {source}")  # the float32 the scene codes
    try:
        coords = quantize_positions(positions, vs, origin)
    except InputError as e:
        raise InputError(f"{ply}: {e}") from None
    offsets = np.stack([cols[c] for c in offs], axis=1).astype(np.float32).reshape(n, 3, k).transpose(0, 2, 1)
    mask_cols = _numbered(cols, "f_mask_")
    mask = None
    if mask_cols:
        if len(mask_cols) != k:
            raise InputError(f"{ply}: {len(mask_cols)} f_mask_* properties for {k} offsets")
        m = np.stack([cols[c] for c in mask_cols], axis=1).astype(np.float64)
        # Binary masks are taken as they are; HAC's raw mask logits are binarized as HAC does.
        mask = (m > 0.5) if np.isin(m, (0.0, 1.0)).all() else (1 / (1 + np.exp(-m)) > 0.01)
    extra = {}
    if "opacity" in cols:
        extra["opacity"] = cols["opacity"].astype(np.float32)
    if "opacity_accum" in cols:  # training statistic (lghcc-train), used by NAAP
        extra["opacity_accum"] = cols["opacity_accum"].astype(np.float32)
    rots = _numbered(cols, "rot_")
    if len(rots) == 4:
        extra["rotation"] = np.stack([cols[c] for c in rots], axis=1).astype(np.float32)
    scene = AnchorScene(
        coords=coords,
        voxel_size=vs,
        origin=origin.astype(np.float32),
        features=np.stack([cols[c] for c in feats], axis=1).astype(np.float32),
        scalings=np.stack([cols[c] for c in scales], axis=1).astype(np.float32),
        offsets=np.ascontiguousarray(offsets),
        offset_mask=mask,
        mlps=read_mlps(ply.parent),
        extra=extra,
    )
    try:
        return scene.validate(check_unique=False)
    except InputError as e:
        raise InputError(f"{ply}: {e}") from None


def write_scaffold(scene: AnchorScene, model_dir: str | os.PathLike, iteration: int = 0) -> Path:
    """Write the Scaffold-GS layout; returns the folder holding the PLY and the MLPs. MLP files
    left in that folder by an earlier scene (checkpoint.pth when this scene has no MLPs,
    checkpoints.pth, traced modules) are removed, so the folder never mixes two scenes. The MLPs
    are written without importing torch (formats/torch_checkpoint.py)."""
    from .torch_checkpoint import checkpoint_bytes

    folder = Path(model_dir) / "point_cloud" / f"iteration_{iteration}"
    n, k = scene.num_anchors, scene.num_offsets
    pos = scene.positions()
    cols: dict[str, np.ndarray] = {"x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2]}
    for c in ("nx", "ny", "nz"):
        cols[c] = np.zeros(n, np.float32)
    # f_offset_(axis*K + k) = offsets[:, k, axis]: strided views, no copy of the offsets
    cols.update({f"f_offset_{a * k + j}": scene.offsets[:, j, a] for a in range(3) for j in range(k)})
    cols.update({f"f_anchor_feat_{i}": scene.features[:, i] for i in range(scene.feature_dim)})
    cols["opacity"] = scene.extra.get("opacity", np.zeros(n, np.float32))
    cols.update({f"scale_{i}": scene.scalings[:, i] for i in range(NUM_SCALINGS)})
    rot = scene.extra.get("rotation", np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)))
    cols.update({f"rot_{i}": rot[:, i] for i in range(4)})
    if "opacity_accum" in scene.extra:  # training statistic (lghcc-train), used by NAAP
        cols["opacity_accum"] = np.asarray(scene.extra["opacity_accum"], np.float32).reshape(n)
    if scene.offset_mask is not None:
        cols.update({f"f_mask_{i}": scene.offset_mask[:, i].astype(np.float32) for i in range(k)})
    grid = [f"{PLY_COMMENT_PREFIX}voxel_size {float(np.float32(scene.voxel_size)).hex()}",
            f"{PLY_COMMENT_PREFIX}origin " + " ".join(float(v).hex() for v in np.asarray(scene.origin, np.float32))]
    write_ply(folder / PLY_NAME, cols, comments=grid)
    for stale in CHECKPOINT_NAMES[1:] + TRACED_MLP_NAMES + (() if scene.mlps else (CHECKPOINT_NAME,)):
        if (folder / stale).is_file():
            (folder / stale).unlink()
    if scene.mlps:
        state = {}
        for role, mlp in scene.mlps.items():
            sd = {}
            for l, (w, b) in enumerate(zip(mlp.weights, mlp.biases)):
                sd[f"{2 * l}.weight"] = np.asarray(w)
                sd[f"{2 * l}.bias"] = np.asarray(b)
            state[STATE_DICT_NAMES[role][0]] = sd
        data = checkpoint_bytes(state)
        with atomic_output(folder / CHECKPOINT_NAME) as f:
            f.write(data)
    return folder
