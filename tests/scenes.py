"""Small scene builders, hypothesis strategies and the pinned splat-transform, shared by the tests."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import strategies as st

from lghcc.common.scene import AnchorScene, RenderMLP


def random_scene(rng: np.random.Generator, n: int, c: int = 4, k: int = 2, spread: int = 50,
                 value_scale: float = 1.0, mask: bool = False, with_mlps: bool = True) -> AnchorScene:
    coords = np.unique(rng.integers(-spread, spread + 1, size=(n * 2 + 4, 3)), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]]
    n = len(coords)
    mlps = {}
    if with_mlps:
        mlps = {"opacity": RenderMLP([rng.normal(size=(c, c + 4)).astype(np.float32),
                                      rng.normal(size=(k, c)).astype(np.float32)],
                                     [rng.normal(size=c).astype(np.float32), np.zeros(k, np.float32)],
                                     ["relu", "tanh"])}
    return AnchorScene(
        coords=coords.astype(np.int64), voxel_size=0.01, origin=np.zeros(3, np.float32),
        features=(value_scale * rng.normal(size=(n, c))).astype(np.float32),
        scalings=rng.normal(size=(n, 6)).astype(np.float32),
        offsets=rng.normal(size=(n, k, 3)).astype(np.float32),
        offset_mask=(rng.random((n, k)) < 0.7) if mask else None, mlps=mlps)


@st.composite
def scenes(draw):
    """Small scenes spanning the hard cases: one anchor, far coordinates, constant and extreme values."""
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    n = draw(st.integers(1, 40))
    c = draw(st.integers(1, 6))
    k = draw(st.integers(1, 3))
    spread = draw(st.sampled_from([0, 1, 3, 1000, 10 ** 6, 2 ** 30]))
    scale = draw(st.sampled_from([0.0, 1e-3, 1.0, 1e3, 1e6]))
    s = random_scene(rng, n, c, k, spread=spread, value_scale=scale, mask=draw(st.booleans()),
                     with_mlps=draw(st.booleans()))
    s.voxel_size = draw(st.sampled_from([1e-30, 1e-6, 0.01, 1.0, 1e6, 1e30]))
    if draw(st.booleans()):
        s.features[:] = draw(st.sampled_from([0.0, 1.0, -7.5]))
    return s


def scaffold_gs_positions(coords: np.ndarray, voxel_size: float) -> np.ndarray:
    """Anchor positions as Scaffold-GS computes them (voxelize_sample: float32 voxel indices times
    the voxel size, in float32)."""
    return coords.astype(np.float32) * np.float32(voxel_size)


def write_scaffold_gs_model(model, coords: np.ndarray, voxel_size: float, *, feat_dim: int = 8, n_offsets: int = 4,
                            iteration: int = 30000, cfg_args: bool = True, mlps: str = "split", seed: int = 0):
    """A model folder as Scaffold-GS writes it -> its iteration folder: <model>/cfg_args (the printed
    argparse Namespace of its training arguments), <model>/point_cloud/iteration_<N>/point_cloud.ply
    (its attribute order, float32, no lghcc header comments) and the render MLPs beside it, as traced
    modules (its save_mlp_checkpoints mode 'split') or as checkpoints.pth (mode 'unite')."""
    import argparse
    import warnings
    from pathlib import Path

    import torch
    from lghcc.formats.ply import write_ply
    from torch import nn

    model = Path(model)
    folder = model / "point_cloud" / f"iteration_{iteration}"
    rng = np.random.default_rng(seed)
    n, k, c = len(coords), n_offsets, feat_dim
    pos = scaffold_gs_positions(coords, voxel_size)
    cols = {"x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2], **{f"n{a}": np.zeros(n, np.float32) for a in "xyz"}}
    cols.update({f"f_offset_{i}": rng.normal(size=n).astype(np.float32) for i in range(3 * k)})
    cols.update({f"f_anchor_feat_{i}": rng.normal(size=n).astype(np.float32) for i in range(c)})
    cols["opacity"] = np.zeros(n, np.float32)
    cols.update({f"scale_{i}": np.float32(np.log(voxel_size)) + rng.normal(size=n).astype(np.float32) for i in range(6)})
    cols.update({f"rot_{i}": np.full(n, float(i == 0), np.float32) for i in range(4)})
    write_ply(folder / "point_cloud.ply", cols)
    torch.manual_seed(seed)
    nets = {"opacity_mlp": nn.Sequential(nn.Linear(c + 3, c), nn.ReLU(True), nn.Linear(c, k), nn.Tanh()),
            "cov_mlp": nn.Sequential(nn.Linear(c + 3, c), nn.ReLU(True), nn.Linear(c, 7 * k)),
            "color_mlp": nn.Sequential(nn.Linear(c + 3, c), nn.ReLU(True), nn.Linear(c, 3 * k), nn.Sigmoid())}
    if mlps == "split":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)  # torch.jit.trace, as Scaffold-GS still uses it
            for name, net in nets.items():
                torch.jit.trace(net.eval(), torch.rand(1, c + 3)).save(str(folder / f"{name}.pt"))
    else:
        torch.save({name: net.state_dict() for name, net in nets.items()}, folder / "checkpoints.pth")
    if cfg_args:
        args = argparse.Namespace(sh_degree=3, feat_dim=c, n_offsets=k, voxel_size=voxel_size, update_depth=3,
                                  update_init_factor=16, update_hierachy_factor=4, use_feat_bank=False,
                                  source_path="data/mipnerf360/garden (copy, 2)", model_path=str(model),
                                  images="images", resolution=-1, white_background=False, data_device="cuda",
                                  eval=True, lod=0, appearance_dim=0, lowpoly=False, ds=1, ratio=1,
                                  undistorted=False, add_opacity_dist=False, add_cov_dist=False,
                                  add_color_dist=False)
        (model / "cfg_args").write_text(str(args))
    return folder


SPLAT_TRANSFORM = Path(__file__).resolve().parents[1] / "tools" / "node" / "node_modules" / ".bin" / "splat-transform"
SPLAT_TRANSFORM_VERSION = "3.7.0"


def splat_transform_or_skip() -> Path:
    """The pinned splat-transform of tools/node, or a skip saying what is missing."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the splat-transform interop tests need Node.js")
    pkg = SPLAT_TRANSFORM.parents[1] / "@playcanvas" / "splat-transform" / "package.json"
    if not SPLAT_TRANSFORM.exists() or not pkg.exists():
        pytest.skip("@playcanvas/splat-transform is not installed in tools/node (run `make node-tools`)")
    version = json.loads(pkg.read_text())["version"]
    if version != SPLAT_TRANSFORM_VERSION:
        pytest.skip(f"tools/node has splat-transform {version}, these tests pin {SPLAT_TRANSFORM_VERSION}")
    return SPLAT_TRANSFORM


def splat_transform(tool: Path, *args) -> None:
    """Run splat-transform quietly on the CPU (inputs, actions, the output last); fails the test on an error."""
    out = subprocess.run([str(tool), "-q", "-w", "-g", "cpu", *map(str, args)], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
