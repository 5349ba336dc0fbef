"""The anchor scene: what the codec compresses and what the decoder rebuilds.

An anchor (Scaffold-GS) has an integer voxel position, a feature vector, 6 log
scalings (3 for its offsets, 3 for its Gaussians' base scale) and K offsets; HAC
adds a live/dead mask per offset. Small render MLPs turn anchors into Gaussians.
World position of an anchor = origin + coords * voxel_size (float32, in that order).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import InputError

NUM_SCALINGS = 6
DEFAULT_FEATURE_DIM = 50
DEFAULT_NUM_OFFSETS = 10

MLP_ROLES: tuple[str, ...] = ("opacity", "cov", "color", "feature_bank")
ACTIVATIONS: tuple[str, ...] = ("none", "relu", "tanh", "sigmoid")


@dataclass
class RenderMLP:
    """A stack of Linear layers; ``activations[l]`` follows layer l.
    Scaffold-GS: Linear(C+4, C), ReLU, Linear(C, out), then Tanh (opacity),
    none (covariance) or Sigmoid (color)."""

    weights: list[np.ndarray]  # each [out, in] float32
    biases: list[np.ndarray]  # each [out] float32
    activations: list[str]

    def __post_init__(self) -> None:
        if not (len(self.weights) == len(self.biases) == len(self.activations)) or not self.weights:
            raise InputError("a render MLP needs one weight, bias and activation per layer")
        for l, (w, b, a) in enumerate(zip(self.weights, self.biases, self.activations)):
            if w.ndim != 2 or b.shape != (w.shape[0],):
                raise InputError(f"render MLP layer {l}: weight {w.shape} and bias {b.shape} do not match")
            if l and w.shape[1] != self.weights[l - 1].shape[0]:
                raise InputError(f"render MLP layer {l}: input size {w.shape[1]} != previous output "
                                 f"{self.weights[l - 1].shape[0]}")
            if a not in ACTIVATIONS:
                raise InputError(f"render MLP layer {l}: unknown activation {a!r}")
            if not (np.isfinite(w).all() and np.isfinite(b).all()):
                raise InputError(f"render MLP layer {l} contains NaN or Inf")

    @property
    def in_dim(self) -> int:
        return int(self.weights[0].shape[1])

    @property
    def out_dim(self) -> int:
        return int(self.weights[-1].shape[0])

    def num_parameters(self) -> int:
        return sum(w.size + b.size for w, b in zip(self.weights, self.biases))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Float reference evaluation (informative; the renderer uses torch)."""
        for w, b, a in zip(self.weights, self.biases, self.activations):
            x = x @ w.T + b
            if a == "relu":
                x = np.maximum(x, 0)
            elif a == "tanh":
                x = np.tanh(x)
            elif a == "sigmoid":
                x = 1 / (1 + np.exp(-x))
        return x


@dataclass
class AnchorScene:
    coords: np.ndarray  # [N, 3] int64 voxel coordinates, unique
    voxel_size: float  # > 0
    origin: np.ndarray  # [3] float32
    features: np.ndarray  # [N, C] float32
    scalings: np.ndarray  # [N, 6] float32, log scales
    offsets: np.ndarray  # [N, K, 3] float32, in units of the offset scaling
    offset_mask: np.ndarray | None = None  # [N, K] bool: live offsets (HAC); None = all live
    mlps: dict[str, RenderMLP] = field(default_factory=dict)
    # Not coded (Scaffold-GS does not render with them); kept so transcoding loses nothing it uses.
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def num_anchors(self) -> int:
        return int(self.coords.shape[0])

    @property
    def num_points(self) -> int:  # the points of the geometry unit, as for GaussianScene
        return self.num_anchors

    @property
    def feature_dim(self) -> int:
        return int(self.features.shape[1])

    @property
    def num_offsets(self) -> int:
        return int(self.offsets.shape[1])

    def positions(self) -> np.ndarray:
        """World positions [N, 3] float32: origin + coords * voxel_size, rounded per IEEE binary32."""
        c = self.coords.astype(np.float32)
        return (c * np.float32(self.voxel_size) + self.origin.astype(np.float32)).astype(np.float32)

    def validate(self, check_unique: bool = True) -> "AnchorScene":
        """Check shapes, dtypes and values; raise InputError naming the first problem.
        ``check_unique=False`` skips the one-anchor-per-voxel check (a reader that leaves
        merging to the encoder)."""
        n = self.coords.shape[0] if self.coords.ndim == 2 else -1
        if self.coords.ndim != 2 or self.coords.shape[1] != 3:
            raise InputError(f"anchor coordinates must have shape [N, 3], got {self.coords.shape}")
        if n == 0:
            raise InputError("the scene has no anchors")
        if not np.issubdtype(self.coords.dtype, np.integer):
            raise InputError("anchor coordinates must be integers (voxel indices)")
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise InputError(f"voxel size must be a positive finite number, got {self.voxel_size}")
        if self.origin.shape != (3,) or not np.isfinite(self.origin).all():
            raise InputError(f"origin must be 3 finite numbers, got {self.origin}")
        for name, arr, shape in (
            ("features", self.features, (n, None)),
            ("scalings", self.scalings, (n, NUM_SCALINGS)),
            ("offsets", self.offsets, (n, None, 3)),
        ):
            if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
                want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
                raise InputError(f"{name} must have shape {want} for {n} anchors, got {list(arr.shape)}")
            if not np.isfinite(arr).all():
                bad = int((~np.isfinite(arr)).reshape(n, -1).any(axis=1).sum())
                raise InputError(f"{name} contain NaN or Inf (in {bad} anchors)")
        if self.features.shape[1] == 0:
            raise InputError("features must have at least one channel")
        if self.offsets.shape[1] == 0:
            raise InputError("each anchor needs at least one offset")
        if self.offset_mask is not None and self.offset_mask.shape != self.offsets.shape[:2]:
            raise InputError(f"offset mask must have shape {list(self.offsets.shape[:2])}, "
                             f"got {list(self.offset_mask.shape)}")
        with np.errstate(over="ignore", invalid="ignore"):
            if not np.isfinite(self.positions()).all():
                raise InputError(f"world positions (origin + coords * voxel size {self.voxel_size:g}) overflow "
                                 "IEEE binary32; use a smaller voxel size or origin")
        uniq = np.unique(self.coords, axis=0).shape[0] if check_unique else n
        if uniq != n:
            raise InputError(f"{n - uniq} anchors share a voxel with another anchor; merge them first "
                             "(lghcc-enc merges them when given --merge-duplicates)")
        return self


SH_DEGREE_MAX = 3


def sh_coeffs_per_channel(degree: int) -> int:
    """(d + 1)^2 SH coefficients per colour channel for degree d = 0..3."""
    if not 0 <= degree <= SH_DEGREE_MAX:
        raise InputError(f"SH degree must be 0..{SH_DEGREE_MAX}, got {degree}")
    return (degree + 1) ** 2


@dataclass
class GaussianScene:
    """An explicit 3DGS scene in the INRIA PLY conventions: what 3DGS, gsplat, SuperSplat,
    SPZ and SOG exchange, and what the decoder of an explicit-Gaussian stream outputs.

    Per Gaussian: ``means`` [N, 3], ``sh`` [N, K, 3] SH coefficients (K = (d + 1)^2,
    coefficient-major: sh[:, 0] is f_dc, sh[:, i] coefficient i of R, G, B), ``opacity`` [N]
    (logit), ``log_scales`` [N, 3], ``rotations`` [N, 4] quaternion (w, x, y, z), any norm,
    as 3DGS stores it; renderers normalize. All float32.

    A decoded explicit stream also has the grid its positions were coded on: ``coords``
    [N, 3] int64, ``voxel_size`` and ``origin``, with means = origin + coords * voxel_size
    (binary32, as ``AnchorScene.positions``)."""

    means: np.ndarray
    sh: np.ndarray
    opacity: np.ndarray
    log_scales: np.ndarray
    rotations: np.ndarray
    coords: np.ndarray | None = None
    voxel_size: float | None = None
    origin: np.ndarray | None = None

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def num_points(self) -> int:  # the points of the geometry unit, as for AnchorScene
        return self.num_gaussians

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    @classmethod
    def on_grid(cls, coords: np.ndarray, voxel_size: float, origin, sh: np.ndarray, opacity: np.ndarray,
                log_scales: np.ndarray, rotations: np.ndarray) -> "GaussianScene":
        """A scene whose positions are integer voxel coordinates: means = origin + coords * voxel_size."""
        c = np.asarray(coords, dtype=np.int64)
        o = np.asarray(origin, dtype=np.float32).reshape(3)
        with np.errstate(over="ignore", invalid="ignore"):
            means = (c.astype(np.float32) * np.float32(voxel_size) + o).astype(np.float32)
        return cls(means, sh, opacity, log_scales, rotations, c, float(voxel_size), o)

    def subset(self, idx: np.ndarray) -> "GaussianScene":
        """The Gaussians ``idx`` (indices or a boolean mask), in that order."""
        return GaussianScene(self.means[idx], self.sh[idx], self.opacity[idx], self.log_scales[idx],
                             self.rotations[idx], None if self.coords is None else self.coords[idx],
                             self.voxel_size, self.origin)

    def with_sh_degree(self, degree: int) -> "GaussianScene":
        """The scene with its SH cut to (or padded with zeros up to) ``degree``."""
        k = sh_coeffs_per_channel(degree)
        sh = np.zeros((self.num_gaussians, k, 3), np.float32)
        m = min(k, self.sh.shape[1])
        sh[:, :m] = self.sh[:, :m]
        return GaussianScene(self.means, sh, self.opacity, self.log_scales, self.rotations, self.coords,
                             self.voxel_size, self.origin)

    def validate(self, what: str = "scene") -> "GaussianScene":
        """Check shapes and values; raise InputError naming ``what`` and the first problem."""
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        if self.means.ndim != 2 or self.means.shape[1] != 3:
            raise InputError(f"{what}: positions must have shape [N, 3], got {list(self.means.shape)}")
        if n == 0:
            raise InputError(f"{what}: the scene holds no Gaussians")
        k = self.sh.shape[1] if self.sh.ndim == 3 else -1
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3 or \
                k not in [sh_coeffs_per_channel(d) for d in range(SH_DEGREE_MAX + 1)]:
            raise InputError(f"{what}: SH coefficients must have shape [N, (d+1)^2, 3] for a degree d = 0..3 and "
                             f"N = {n}, got {list(self.sh.shape)}")
        for name, arr, shape in (("opacity", self.opacity, (n,)), ("scales", self.log_scales, (n, 3)),
                                 ("rotations", self.rotations, (n, 4))):
            if arr.shape != shape:
                raise InputError(f"{what}: {name} must have shape {list(shape)}, got {list(arr.shape)}")
        # fields named as the INRIA PLY names them
        for name, arr in (("x/y/z", self.means), ("f_dc/f_rest", self.sh), ("opacity", self.opacity),
                          ("scale", self.log_scales), ("rot", self.rotations)):
            bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
            if bad.any():
                raise InputError(f"{what}: field '{name}' contains NaN or Inf (in {int(bad.sum())} Gaussians, the "
                                 f"first is Gaussian {int(np.argmax(bad))})")
        with np.errstate(over="ignore", under="ignore"):
            act = np.exp(self.log_scales.astype(np.float32))
        bad = ~((act > 0) & np.isfinite(act)).all(axis=1)
        if bad.any():
            raise InputError(f"{what}: {int(bad.sum())} Gaussians have a scale that is zero or infinite after "
                             f"activation (exp of log scale {float(self.log_scales[bad][0].min()):g} .. "
                             f"{float(self.log_scales[bad][0].max()):g}; the first is Gaussian {int(np.argmax(bad))})")
        zero = ~(np.abs(self.rotations) > 0).any(axis=1)
        if zero.any():
            raise InputError(f"{what}: {int(zero.sum())} Gaussians have a zero rotation quaternion (the first is "
                             f"Gaussian {int(np.argmax(zero))})")
        if self.coords is not None:
            if self.coords.shape != (n, 3) or not np.issubdtype(self.coords.dtype, np.integer):
                raise InputError(f"{what}: grid coordinates must be integers of shape [N, 3]")
            if not (self.voxel_size is not None and np.isfinite(self.voxel_size) and self.voxel_size > 0):
                raise InputError(f"{what}: voxel size must be a positive finite number, got {self.voxel_size}")
        return self
