"""Pinhole cameras and loaders for posed image sets (informative).

Convention (OpenCV / COLMAP): camera x right, y down, z forward; ``world_to_camera``
maps world points to camera points; pixel (i, j) has its centre at (i + 0.5, j + 0.5)
in image coordinates u = fx * x / z + cx, v = fy * y / z + cy.

Loaders: NeRF-synthetic (``transforms_<split>.json``), LLFF (``poses_bounds.npy``),
COLMAP sparse models (``cameras``/``images``/``points3D`` as ``.bin`` or ``.txt``); and,
cameras only, the captures 3DGS scenes come with: the INRIA trainer's ``cameras.json``, a
nerfstudio / instant-ngp ``transforms.json`` (``load_capture_cameras`` takes any of them).
Every problem with the input raises ``InputError`` naming the file.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from .imageio import composite_background, png_size, read_image

log = logging.getLogger(__name__)

# OpenGL/Blender camera axes (x right, y up, z back) -> OpenCV (x right, y down, z forward).
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class Camera:
    world_to_camera: np.ndarray  # [4, 4] float64, OpenCV axes
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float = 0.01
    far: float = 1e10
    name: str = ""
    image: np.ndarray | None = None  # [H, W, 3] float32 in [0, 1], background already composited
    distortion: tuple[float, ...] = field(default_factory=tuple)  # ignored by the renderer (logged)

    def __post_init__(self) -> None:
        m = np.asarray(self.world_to_camera, np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise InputError(f"camera {self.name!r}: world_to_camera must be a finite 4x4 matrix")
        self.world_to_camera = m
        for k in ("fx", "fy", "cx", "cy", "near", "far"):
            v = float(getattr(self, k))
            if not math.isfinite(v) and k != "far":
                raise InputError(f"camera {self.name!r}: {k} must be finite, got {v}")
            setattr(self, k, v)
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"camera {self.name!r}: focal lengths must be positive, got {self.fx}, {self.fy}")
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera {self.name!r}: image size must be positive, got {self.width}x{self.height}")
        if not 0 < self.near < self.far:
            raise InputError(f"camera {self.name!r}: need 0 < near < far, got {self.near}, {self.far}")

    # --- geometry -----------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        return self.world_to_camera[:3, 3]

    @property
    def camera_to_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_to_camera)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates: -R^T t."""
        return -self.rotation.T @ self.translation

    @property
    def forward(self) -> np.ndarray:
        """Viewing direction (camera +z) in world coordinates."""
        return self.rotation[2].copy()

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], np.float64)

    @property
    def fov_x(self) -> float:
        return 2.0 * math.atan(0.5 * self.width / self.fx)

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(0.5 * self.height / self.fy)

    def world_to_camera_points(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) @ self.rotation.T + self.translation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates [N, 2] and depths [N] of world points (no clipping)."""
        pc = self.world_to_camera_points(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], axis=1)
        return uv, z

    def view_directions(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions from the camera centre to the points [N, 3] and distances [N]
        (Scaffold-GS's ``ob_view``, ``ob_dist``)."""
        d = np.asarray(points, np.float64) - self.center
        dist = np.linalg.norm(d, axis=1)
        return d / np.maximum(dist, 1e-12)[:, None], dist

    def scaled(self, factor: float) -> "Camera":
        """The same view at ``factor`` times the resolution (image dropped unless factor is 1)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                       width=w, height=h, image=self.image if (w, h) == (self.width, self.height) else None)

    @classmethod
    def from_camera_to_world(cls, c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                             width: int, height: int, convention: str = "opencv", **kw) -> "Camera":
        """Build from a camera-to-world matrix ([3, 4] or [4, 4]) in OpenCV or OpenGL axes."""
        m = np.eye(4)
        c2w = np.asarray(c2w, np.float64)
        if c2w.shape not in ((3, 4), (4, 4)):
            raise InputError(f"camera-to-world matrix must be 3x4 or 4x4, got {c2w.shape}")
        m[:3, :] = c2w[:3, :]
        if convention == "opengl":
            m = m @ _GL_TO_CV
        elif convention != "opencv":
            raise InputError(f"unknown camera convention {convention!r} (opencv or opengl)")
        if not np.isfinite(m).all():
            raise InputError("camera-to-world matrix has NaN or Inf")
        r = m[:3, :3]
        if abs(abs(np.linalg.det(r)) - 1.0) > 1e-3:
            raise InputError(f"camera-to-world rotation is not orthonormal (det {np.linalg.det(r):.4f})")
        w2c = np.eye(4)
        w2c[:3, :3] = r.T
        w2c[:3, 3] = -r.T @ m[:3, 3]
        return cls(w2c, fx, fy, cx, cy, width, height, **kw)

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0, 1.0), *, width: int = 64, height: int = 64,
                fov_x_deg: float = 60.0, **kw) -> "Camera":
        """A camera at ``eye`` looking at ``target``; ``up`` is the world's up direction."""
        eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
        z = target - eye
        if np.linalg.norm(z) == 0:
            raise InputError("look_at: eye and target coincide")
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
        f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
        return cls.from_camera_to_world(c2w, f, f, width / 2, height / 2, width, height, **kw)


# --- NeRF-synthetic --------------------------------------------------------------------

def _image_file(root: Path, file_path: str) -> Path | None:
    """The image file a frame's ``file_path`` names, as given or with .png, .jpg or .jpeg
    appended (NeRF-synthetic leaves the extension off); None when there is none."""
    p = root / file_path
    for q in (p, *(p.with_name(p.name + ext) for ext in (".png", ".jpg", ".jpeg"))):
        if q.suffix.lower() in (".png", ".jpg", ".jpeg", ".exr") and q.is_file():
            return q
    return None


def _resolve_image(root: Path, file_path: str, json_path: Path) -> Path:
    p = root / file_path
    if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".exr"):
        return p
    found = _image_file(root, file_path)
    if found is None:
        raise InputError(f"{json_path}: image for frame {file_path!r} not found (tried .png, .jpg, .jpeg)")
    return found


def _json_number(meta: dict, key: str, jp: Path | str, kind: str) -> float:
    """``meta[key]`` checked: kind 'angle' (radians in (0, pi)), 'positive', 'finite' or 'size'
    (positive integer). Raises InputError naming the file and the field."""
    v = meta[key]
    want = {"angle": "an angle in radians, 0 < angle < pi", "positive": "a positive number",
            "finite": "a finite number", "size": "a positive integer"}[kind]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{jp}: '{key}' must be {want}, got {v!r}")
    x = float(v)
    ok = math.isfinite(x) and {"angle": 0 < x < math.pi, "positive": x > 0, "finite": True,
                               "size": x > 0 and x == int(x)}[kind]
    if not ok:
        raise InputError(f"{jp}: '{key}' must be {want}, got {v!r}")
    return x


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height): from the header for PNG, else by reading the image."""
    if path.suffix.lower() == ".png":
        return png_size(path)
    img = read_image(path)
    return img.shape[1], img.shape[0]


_INTRINSIC_KINDS = {"camera_angle_x": "angle", "camera_angle_y": "angle", "fl_x": "positive", "fl_y": "positive",
                    "cx": "finite", "cy": "finite", "w": "size", "h": "size"}


def _read_json(jp: Path):
    """The JSON of file ``jp``; InputError naming the file."""
    if not jp.is_file():
        raise InputError(f"{jp}: file not found")
    try:
        return json.loads(jp.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{jp}: not valid JSON ({e})") from None


def _intrinsics(meta: dict, where: Path | str, kinds: dict = _INTRINSIC_KINDS) -> dict:
    """The fields of ``kinds`` that ``meta`` gives, checked; InputError naming ``where``."""
    intr = {k: _json_number(meta, k, where, kind) for k, kind in kinds.items() if k in meta}
    if ("w" in intr) != ("h" in intr):
        raise InputError(f"{where}: 'w' and 'h' must be given together")
    return intr


def _need_focal(intr: dict, where: Path | str) -> None:
    """A focal length is given, in pixels (``fl_x``) or as an angle (``camera_angle_x``)."""
    if "camera_angle_x" not in intr and "fl_x" not in intr:
        raise InputError(f"{where}: neither 'camera_angle_x' nor 'fl_x' given")


def _read_transforms(jp: Path) -> tuple[dict, dict, tuple[int, int] | None]:
    """(the file's JSON, its top-level intrinsics checked, its (w, h) or None); InputError
    naming the file."""
    meta = _read_json(jp)
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise InputError(f"{jp}: no 'frames' list")
    intr = _intrinsics(meta, jp)
    return meta, intr, ((int(intr["w"]), int(intr["h"])) if "w" in intr else None)


def _json_matrix(e: dict, key: str, shape: tuple[int, ...], where: Path | str) -> np.ndarray:
    """``e[key]`` as a finite float64 array of ``shape``; InputError naming ``where``."""
    try:
        a = np.asarray(e[key], np.float64)
    except (ValueError, TypeError):
        a = np.zeros(0)
    if a.shape != shape or not np.isfinite(a).all():
        what = f"{shape[0]}-vector" if len(shape) == 1 else "x".join(map(str, shape)) + " matrix"
        raise InputError(f"{where} {key} is not a finite {what}")
    return a


def _frame_pose(jp: Path, i: int, fr) -> tuple[str, np.ndarray]:
    """(file_path, camera-to-world 4x4) of frame ``i``, checked."""
    if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
        raise InputError(f"{jp}: frame {i} needs 'file_path' and 'transform_matrix'")
    fp = fr["file_path"]
    if not isinstance(fp, str) or not fp.strip():
        raise InputError(f"{jp}: frame {i}: 'file_path' must be a non-empty string, got {fp!r}")
    return fp, _json_matrix(fr, "transform_matrix", (4, 4), f"{jp}: frame {i}")


def _frame_image(jp: Path, ip: Path, load_images: bool, background, size0) -> tuple[np.ndarray | None, int, int]:
    """(the composited image or None, width, height): the image's own size where there is one."""
    if load_images:
        img = composite_background(read_image(ip), background)
        return img, img.shape[1], img.shape[0]
    if ip.is_file():
        return None, *_image_size(ip)
    if size0 is not None:
        return None, *size0
    raise InputError(f"{jp}: image {ip} not found")


def _size_scale(jp: Path, i: int, ip: Path, w: int, h: int, size0) -> tuple[float, float]:
    """The factors from the file's w x h to the image's (a downscaled copy); another aspect ratio
    raises InputError."""
    if size0 is None or (w, h) == size0:
        return 1.0, 1.0
    sx, sy = w / size0[0], h / size0[1]
    if abs(sx / sy - 1.0) > 0.01:
        raise InputError(f"{jp}: frame {i}: image {ip} is {w}x{h}, but the file gives w={size0[0]}, "
                         f"h={size0[1]} (another aspect ratio); fix 'w'/'h' or the image")
    return sx, sy


def _pixel_intrinsics(intr: dict, w: int, h: int, sx: float, sy: float) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels of the w x h image."""
    if "fl_x" in intr:
        fx = intr["fl_x"] * sx
        fy = intr.get("fl_y", intr["fl_x"]) * sy
    else:
        fx = 0.5 * w / math.tan(0.5 * intr["camera_angle_x"])
        fy = 0.5 * h / math.tan(0.5 * intr["camera_angle_y"]) if "camera_angle_y" in intr else fx
    cx = intr["cx"] * sx if "cx" in intr else w / 2
    cy = intr["cy"] * sy if "cy" in intr else h / 2
    return fx, fy, cx, cy


def _check_principal_point(where: str, cx: float, cy: float, w: int, h: int, image: Path) -> None:
    """With the size taken from the image, a principal point outside it means intrinsics for
    another image size."""
    if not (0 <= cx <= w and 0 <= cy <= h):
        raise InputError(f"{where}: principal point ({cx:g}, {cy:g}) lies outside the {w}x{h} image "
                         f"{image.name}: the intrinsics are for another image size; give 'w' and 'h'")


def load_nerf_synthetic(root: str | os.PathLike, split: str = "test", background: str | tuple = "white",
                        load_images: bool = True, near: float = 0.01, far: float = 1e10,
                        max_frames: int | None = None) -> list[Camera]:
    """Cameras of ``<root>/transforms_<split>.json`` (Blender/NeRF layout, OpenGL axes).
    Images (RGBA) are composited on ``background`` ('white', 'black' or RGB).

    Intrinsics: ``fl_x`` (``fl_y``, ``cx``, ``cy``) in pixels of a ``w`` x ``h`` image, else
    ``camera_angle_x`` (``camera_angle_y``) in radians. Each camera takes the size of its
    image (header only when ``load_images`` is False; ``w``/``h`` where the image is absent),
    so rendering views and training agree. When ``w``/``h`` are given and the image has
    another size with the same aspect ratio (a downscaled copy), the pixel intrinsics are
    scaled to it; another aspect ratio raises InputError."""
    root = Path(root)
    jp = root / f"transforms_{split}.json"
    meta, intr, size0 = _read_transforms(jp)
    _need_focal(intr, jp)
    frames = meta["frames"][:max_frames] if max_frames else meta["frames"]
    cams = []
    for i, fr in enumerate(frames):
        fp, c2w = _frame_pose(jp, i, fr)
        ip = _resolve_image(root, fp, jp)
        img, w, h = _frame_image(jp, ip, load_images, background, size0)
        sx, sy = _size_scale(jp, i, ip, w, h, size0)
        if not cams and (sx, sy) != (1.0, 1.0):
            log.info("%s: images are %dx%d, the file says %dx%d: intrinsics scaled by %.4g", jp, w, h, *size0, sx)
        fx, fy, cx, cy = _pixel_intrinsics(intr, w, h, sx, sy)
        if size0 is None:
            _check_principal_point(f"{jp}: frame {i}", cx, cy, w, h, ip)
        try:
            cam = Camera.from_camera_to_world(c2w, fx, fy, cx, cy, w, h, convention="opengl", near=near, far=far,
                                              name=Path(fp).name, image=img)
        except InputError as e:
            raise InputError(f"{jp}: frame {i}: {e}") from None
        cams.append(cam)
    return cams


# --- LLFF ----------------------------------------------------------------------------------

_IMAGE_EXTS = (".png", ".jpg", ".jpeg")


def load_llff(root: str | os.PathLike, images_dir: str = "images", load_images: bool = True,
              near_factor: float = 0.9, background: str | tuple = "black") -> list[Camera]:
    """Cameras of ``<root>/poses_bounds.npy`` ([N, 17]: a 3x5 matrix [R | t | (H, W, focal)] per
    view with rotation columns (down, right, backwards), then near and far bounds), images
    in ``<root>/<images_dir>`` in sorted order. When the images are smaller than the poses'
    H, W (``images_4`` etc.), the intrinsics are scaled to them. Images with an alpha channel
    are composited on ``background`` ('white', 'black' or RGB; the trainer passes its own)."""
    root = Path(root)
    pb = root / "poses_bounds.npy"
    if not pb.is_file():
        raise InputError(f"{pb}: file not found")
    try:
        arr = np.load(pb, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise InputError(f"{pb}: cannot read ({e})") from None
    if arr.ndim != 2 or arr.shape[1] != 17:
        raise InputError(f"{pb}: expected an [N, 17] array, got {list(arr.shape)}")
    if not np.isfinite(arr).all():
        raise InputError(f"{pb}: contains NaN or Inf")
    poses = arr[:, :15].reshape(-1, 3, 5).astype(np.float64)
    bounds = arr[:, 15:].astype(np.float64)
    idir = root / images_dir
    files = sorted(p for p in idir.iterdir() if p.suffix.lower() in _IMAGE_EXTS) if idir.is_dir() else []
    if load_images and not files:
        raise InputError(f"{idir}: no images found")
    if files and len(files) != len(poses):
        raise InputError(f"{pb}: {len(poses)} poses but {len(files)} images in {idir}")
    cams = []
    for i, p in enumerate(poses):
        h0, w0, f = p[:, 4]
        if h0 <= 0 or w0 <= 0 or f <= 0:
            raise InputError(f"{pb}: view {i} has a non-positive height, width or focal length")
        img = None
        w, h = int(round(w0)), int(round(h0))
        if load_images:
            img = composite_background(read_image(files[i]), background)
            h, w = img.shape[:2]
        s = w / w0
        if abs(h / h0 - s) > 0.02:
            raise InputError(f"{pb}: view {i}: image {files[i] if files else ''} is {w}x{h}, "
                             f"not a scaled copy of {int(w0)}x{int(h0)}")
        c2w = np.eye(4)
        r = p[:, :3]
        c2w[:3, :3] = np.stack([r[:, 1], r[:, 0], -r[:, 2]], axis=1)  # (down, right, back) -> (right, down, fwd)
        c2w[:3, 3] = p[:, 3]
        near = max(float(bounds[i, 0]) * near_factor, 1e-3)
        far = max(float(bounds[i, 1]) / near_factor, near * 2)
        try:
            cams.append(Camera.from_camera_to_world(c2w, f * s, f * s, w / 2, h / 2, w, h, near=near, far=far,
                                                    name=files[i].name if files else f"view_{i:03d}",
                                                    image=img))
        except InputError as e:
            raise InputError(f"{pb}: view {i}: {e}") from None
    return cams


# --- COLMAP ----------------------------------------------------------------------------------

# model id -> (name, number of parameters)
COLMAP_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
_MODEL_IDS = {name: (i, n) for i, (name, n) in COLMAP_MODELS.items()}
# Models the pinhole renderer can use: (fx, fy, cx, cy) from params, the rest is distortion.
_SUPPORTED = {
    "SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2], ()),
    "PINHOLE": lambda p: (p[0], p[1], p[2], p[3], ()),
    "SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], tuple(p[3:])),
    "RADIAL": lambda p: (p[0], p[0], p[1], p[2], tuple(p[3:])),
    "OPENCV": lambda p: (p[0], p[1], p[2], p[3], tuple(p[4:])),
}


@dataclass
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    image_id: int
    qvec: np.ndarray  # (w, x, y, z), world-to-camera
    tvec: np.ndarray
    camera_id: int
    name: str


@dataclass
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points_xyz: np.ndarray  # [P, 3] float64
    points_rgb: np.ndarray  # [P, 3] uint8
    points_error: np.ndarray  # [P] float64
    points_id: np.ndarray  # [P] int64


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, np.float64) / max(np.linalg.norm(q), 1e-300)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class _Reader:
    def __init__(self, path: Path):
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def read(self, fmt: str):
        n = struct.calcsize(fmt)
        if self.pos + n > len(self.data):
            raise InputError(f"{self.path}: truncated at byte {self.pos} (needs {n} more bytes)")
        v = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += n
        return v

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        n = np.dtype(dtype).itemsize * count
        if count < 0 or self.pos + n > len(self.data):
            raise InputError(f"{self.path}: truncated at byte {self.pos} (array of {count} records)")
        a = np.frombuffer(self.data, dtype, count, self.pos)
        self.pos += n
        return a

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"{self.path}: truncated image name at byte {self.pos}")
        s = self.data[self.pos:end].decode("utf-8", "replace")
        self.pos = end + 1
        return s

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise InputError(f"{self.path}: {len(self.data) - self.pos} unexpected bytes after the last record")


def _check_camera(path: Path, cam: ColmapCamera, nparams: int) -> ColmapCamera:
    if len(cam.params) != nparams:
        raise InputError(f"{path}: camera {cam.camera_id} ({cam.model}) has {len(cam.params)} parameters, "
                         f"expected {nparams}")
    if cam.width <= 0 or cam.height <= 0:
        raise InputError(f"{path}: camera {cam.camera_id} has size {cam.width}x{cam.height}")
    if not np.isfinite(cam.params).all():
        raise InputError(f"{path}: camera {cam.camera_id} has NaN or Inf parameters")
    return cam


def _read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(path)
    (n,) = r.read("<Q")
    out = {}
    for _ in range(n):
        cid, mid, w, h = r.read("<iiQQ")
        if mid not in COLMAP_MODELS:
            raise InputError(f"{path}: camera {cid} has unknown model id {mid}")
        name, np_ = COLMAP_MODELS[mid]
        params = np.array(r.read(f"<{np_}d"), np.float64)
        out[cid] = _check_camera(path, ColmapCamera(cid, name, int(w), int(h), params), np_)
    r.finish()
    return out


def _data_lines(path: Path) -> list[str]:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    return [ln for ln in text.splitlines() if not ln.lstrip().startswith("#")]


def _read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    out = {}
    for ln in _data_lines(path):
        f = ln.split()
        if not f:
            continue
        try:
            cid, model, w, h = int(f[0]), f[1], int(f[2]), int(f[3])
            params = np.array([float(x) for x in f[4:]], np.float64)
        except (ValueError, IndexError):
            raise InputError(f"{path}: cannot parse camera line {ln!r}") from None
        if model not in _MODEL_IDS:
            raise InputError(f"{path}: camera {cid} has unknown model {model!r}")
        out[cid] = _check_camera(path, ColmapCamera(cid, model, w, h, params), _MODEL_IDS[model][1])
    return out


def _read_images_bin(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(path)
    (n,) = r.read("<Q")
    out = {}
    for _ in range(n):
        iid, qw, qx, qy, qz, tx, ty, tz, cid = r.read("<idddddddi")
        name = r.cstring()
        (npts,) = r.read("<Q")
        r.array(np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]), npts)
        out[iid] = ColmapImage(iid, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cid, name)
    r.finish()
    return out


def _read_images_txt(path: Path) -> dict[int, ColmapImage]:
    lines = _data_lines(path)
    out, i = {}, 0
    while i < len(lines):
        f = lines[i].split()
        i += 1
        if not f:
            continue
        try:
            iid = int(f[0])
            q = np.array([float(x) for x in f[1:5]])
            t = np.array([float(x) for x in f[5:8]])
            cid = int(f[8])
            name = " ".join(f[9:])
        except (ValueError, IndexError):
            raise InputError(f"{path}: cannot parse image line {lines[i - 1]!r}") from None
        if len(q) != 4 or len(t) != 3 or not name:
            raise InputError(f"{path}: image line {lines[i - 1]!r} needs ID, 4 quaternion values, "
                             "3 translation values, camera ID and name")
        i += 1  # the POINTS2D line (may be empty)
        out[iid] = ColmapImage(iid, q, t, cid, name)
    return out


def _read_points_bin(path: Path):
    r = _Reader(path)
    (n,) = r.read("<Q")
    ids, xyz, rgb, err = np.zeros(n, np.int64), np.zeros((n, 3)), np.zeros((n, 3), np.uint8), np.zeros(n)
    for k in range(n):
        pid, x, y, z, cr, cg, cb, e, tl = r.read("<QdddBBBdQ")
        r.array(np.dtype([("img", "<i4"), ("idx", "<i4")]), tl)
        ids[k], xyz[k], rgb[k], err[k] = pid, (x, y, z), (cr, cg, cb), e
    r.finish()
    return ids, xyz, rgb, err


def _read_points_txt(path: Path):
    rows = []
    for ln in _data_lines(path):
        f = ln.split()
        if not f:
            continue
        if len(f) < 8 or (len(f) - 8) % 2:
            raise InputError(f"{path}: cannot parse point line {ln[:80]!r}")
        try:
            rows.append((int(f[0]), float(f[1]), float(f[2]), float(f[3]), int(f[4]), int(f[5]), int(f[6]),
                         float(f[7])))
        except ValueError:
            raise InputError(f"{path}: cannot parse point line {ln[:80]!r}") from None
    a = np.array(rows, np.float64).reshape(-1, 8)
    return a[:, 0].astype(np.int64), a[:, 1:4], a[:, 4:7].clip(0, 255).astype(np.uint8), a[:, 7]


def read_colmap_model(sparse_dir: str | os.PathLike) -> ColmapModel:
    """Read cameras, images and points3D from a COLMAP sparse folder (``.bin`` preferred,
    else ``.txt``)."""
    d = Path(sparse_dir)
    if not d.is_dir():
        raise InputError(f"{d}: COLMAP sparse folder not found")

    def pick(stem: str) -> Path:
        for ext in (".bin", ".txt"):
            if (d / (stem + ext)).is_file():
                return d / (stem + ext)
        raise InputError(f"{d}: neither {stem}.bin nor {stem}.txt found")

    cp, ip = pick("cameras"), pick("images")
    cams = _read_cameras_bin(cp) if cp.suffix == ".bin" else _read_cameras_txt(cp)
    imgs = _read_images_bin(ip) if ip.suffix == ".bin" else _read_images_txt(ip)
    for im in imgs.values():
        if im.camera_id not in cams:
            raise InputError(f"{ip}: image {im.image_id} ({im.name}) refers to camera {im.camera_id}, "
                             f"which {cp.name} does not define")
        if not (np.isfinite(im.qvec).all() and np.isfinite(im.tvec).all()) or np.linalg.norm(im.qvec) == 0:
            raise InputError(f"{ip}: image {im.image_id} ({im.name}) has an invalid pose")
    try:
        pp = pick("points3D")
        pid, xyz, rgb, err = _read_points_bin(pp) if pp.suffix == ".bin" else _read_points_txt(pp)
    except InputError as e:
        if "neither" not in str(e):
            raise
        pid, xyz, rgb, err = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0)
    return ColmapModel(cams, imgs, xyz, rgb, err, pid)


def sparse_folder(root: Path) -> Path | None:
    """The COLMAP model folder of a dataset (``sparse/0``, ``sparse``) or the folder itself
    when it holds ``cameras.bin``/``.txt``; None when there is none."""
    for d in (root / "sparse" / "0", root / "sparse", root):
        if (d / "cameras.bin").is_file() or (d / "cameras.txt").is_file():
            return d
    return None


def load_colmap(sparse_dir: str | os.PathLike, images_dir: str | os.PathLike | None = None,
                load_images: bool = False, near: float = 0.01, far: float = 1e10,
                background: str | tuple = "black", image_paths: dict[str, Path] | None = None,
                model: ColmapModel | None = None) -> tuple[list[Camera], ColmapModel]:
    """Cameras (sorted by image name) of a COLMAP sparse model, and the model itself (points3D).
    Loaded images with an alpha channel are composited on ``background`` ('white', 'black'
    or RGB; the trainer passes its own).
    Pinhole models are used as they are; SIMPLE_RADIAL, RADIAL and OPENCV are rendered as
    pinhole cameras with their distortion ignored (a warning is logged: undistort the images
    with ``colmap image_undistorter`` for exact results); other models raise InputError.
    ``image_paths``: the image file of each image name (default ``images_dir / name``);
    ``model``: the model when already read."""
    model = model if model is not None else read_colmap_model(sparse_dir)
    if load_images and images_dir is None:
        raise InputError("load_colmap: load_images needs images_dir")
    out, warned = [], set()
    for im in sorted(model.images.values(), key=lambda m: m.name):
        cc = model.cameras[im.camera_id]
        if cc.model not in _SUPPORTED:
            raise InputError(f"{sparse_dir}: camera {cc.camera_id} uses the {cc.model} model, which the pinhole "
                             f"renderer does not support (supported: {', '.join(_SUPPORTED)}); undistort "
                             "the images first")
        fx, fy, cx, cy, dist = _SUPPORTED[cc.model](cc.params)
        if any(abs(x) > 0 for x in dist) and cc.camera_id not in warned:
            log.warning("COLMAP camera %d (%s): distortion %s ignored by the pinhole renderer",
                        cc.camera_id, cc.model, dist)
            warned.add(cc.camera_id)
        w2c = np.eye(4)
        w2c[:3, :3] = qvec_to_rotmat(im.qvec)
        w2c[:3, 3] = im.tvec
        img, w, h = None, cc.width, cc.height
        if load_images:
            ip = image_paths[im.name] if image_paths else Path(images_dir) / im.name
            img = composite_background(read_image(ip), background)
            ih, iw = img.shape[:2]
            if (iw, ih) != (w, h):
                s = iw / w
                if abs(ih / h - s) > 0.02:
                    raise InputError(f"{ip}: image is {iw}x{ih}, camera "
                                     f"{cc.camera_id} is {w}x{h}")
                fx, fy, cx, cy, w, h = fx * s, fy * s, cx * s, cy * s, iw, ih
        out.append(Camera(w2c, fx, fy, cx, cy, w, h, near=near, far=far, name=im.name, image=img,
                          distortion=tuple(float(x) for x in dist)))
    return out, model


def write_colmap_text(folder: str | os.PathLike, cameras: list[ColmapCamera], images: list[ColmapImage],
                      points_xyz: np.ndarray | None = None, points_rgb: np.ndarray | None = None) -> None:
    """Write a COLMAP text model (cameras.txt, images.txt, points3D.txt), without 2D tracks."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    (d / "cameras.txt").write_text("# Camera list\n" + "".join(
        f"{c.camera_id} {c.model} {c.width} {c.height} " + " ".join(repr(float(x)) for x in c.params) + "\n"
        for c in cameras))
    (d / "images.txt").write_text("# Image list\n" + "".join(
        f"{m.image_id} " + " ".join(repr(float(x)) for x in (*m.qvec, *m.tvec)) + f" {m.camera_id} {m.name}\n\n"
        for m in images))
    xyz = np.zeros((0, 3)) if points_xyz is None else points_xyz
    rgb = np.zeros((len(xyz), 3), np.uint8) if points_rgb is None else points_rgb
    (d / "points3D.txt").write_text("# 3D point list\n" + "".join(
        f"{i + 1} {float(x[0])!r} {float(x[1])!r} {float(x[2])!r} {int(c[0])} {int(c[1])} {int(c[2])} 0.0\n" for i, (x, c) in enumerate(zip(xyz, rgb))))


def write_colmap_binary(folder: str | os.PathLike, cameras: list[ColmapCamera], images: list[ColmapImage],
                        points_xyz: np.ndarray | None = None, points_rgb: np.ndarray | None = None) -> None:
    """Write a COLMAP binary model (cameras.bin, images.bin, points3D.bin), without 2D tracks."""
    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    b = [struct.pack("<Q", len(cameras))]
    for c in cameras:
        b.append(struct.pack("<iiQQ", c.camera_id, _MODEL_IDS[c.model][0], c.width, c.height))
        b.append(struct.pack(f"<{len(c.params)}d", *c.params))
    (d / "cameras.bin").write_bytes(b"".join(b))
    b = [struct.pack("<Q", len(images))]
    for m in images:
        b.append(struct.pack("<idddddddi", m.image_id, *m.qvec, *m.tvec, m.camera_id))
        b.append(m.name.encode() + b"\0" + struct.pack("<Q", 0))
    (d / "images.bin").write_bytes(b"".join(b))
    xyz = np.zeros((0, 3)) if points_xyz is None else points_xyz
    rgb = np.zeros((len(xyz), 3), np.uint8) if points_rgb is None else points_rgb
    b = [struct.pack("<Q", len(xyz))]
    for i, (x, c) in enumerate(zip(xyz, rgb)):
        b.append(struct.pack("<QdddBBBdQ", i + 1, *x, *(int(v) for v in c), 0.0, 0))
    (d / "points3D.bin").write_bytes(b"".join(b))


# --- Capture cameras (what a 3DGS scene was trained from) ----------------------------------------

_INRIA_KEYS = ("id", "img_name", "width", "height", "position", "rotation", "fx", "fy")


def _inria_camera(jp: Path, i: int, e, near: float, far: float) -> Camera:
    """Entry ``i`` of an INRIA ``cameras.json``, checked; InputError naming the file and the entry."""
    where = f"{jp}: camera {i}"
    if not isinstance(e, dict):
        raise InputError(f"{where}: expected an object with {', '.join(_INRIA_KEYS)}, got {e!r:.60}")
    missing = [k for k in _INRIA_KEYS if k not in e]
    if missing:
        raise InputError(f"{where}: missing {', '.join(repr(k) for k in missing)}")
    if not isinstance(e["img_name"], str):
        raise InputError(f"{where}: 'img_name' must be a string, got {e['img_name']!r:.60}")
    w, h = (int(_json_number(e, k, where, "size")) for k in ("width", "height"))
    fx, fy = (_json_number(e, k, where, "positive") for k in ("fx", "fy"))
    c2w = np.eye(4)
    c2w[:3, :3] = _json_matrix(e, "rotation", (3, 3), where)
    c2w[:3, 3] = _json_matrix(e, "position", (3,), where)
    try:
        return Camera.from_camera_to_world(c2w, fx, fy, w / 2, h / 2, w, h, convention="opencv", near=near,
                                           far=far, name=e["img_name"])
    except InputError as err:
        raise InputError(f"{where}: {err}") from None


def load_inria_cameras(path: str | os.PathLike, near: float = 0.01, far: float = 1e10) -> list[Camera]:
    """Cameras of the ``cameras.json`` that the INRIA gaussian-splatting trainer writes beside its
    model (train and test views): a list of {id, img_name, width, height, position, rotation,
    fx, fy}, where ``position`` is the camera centre in world coordinates and ``rotation`` the
    camera-to-world rotation (rows) in OpenCV axes (utils/camera_utils.py, camera_to_JSON); the
    principal point is the image centre."""
    jp = Path(path)
    entries = _read_json(jp)
    if not isinstance(entries, list):
        raise InputError(f"{jp}: expected a JSON list of cameras (INRIA cameras.json), got {type(entries).__name__}")
    return [_inria_camera(jp, i, e, near, far) for i, e in enumerate(entries)]


# nerfstudio's OpenCV distortion coefficients, in COLMAP's order where it has them
_DISTORTION_KINDS = {k: "finite" for k in ("k1", "k2", "p1", "p2", "k3", "k4")}


def _transforms_camera(jp: Path, i: int, fr, meta: dict, top: dict, near: float, far: float) -> Camera:
    """Frame ``i`` of a transforms file: the file's intrinsics ``top`` overridden by the frame's own."""
    where = f"{jp}: frame {i}"
    fp, c2w = _frame_pose(jp, i, fr)
    intr = {**top, **_intrinsics(fr, where, _INTRINSIC_KINDS | _DISTORTION_KINDS)}
    _need_focal(intr, where)
    model = fr.get("camera_model", meta.get("camera_model", "PINHOLE"))
    if not isinstance(model, str) or model not in _SUPPORTED:
        raise InputError(f"{where}: camera_model {model!r} is not one the pinhole renderer can use "
                         f"({', '.join(_SUPPORTED)})")
    if "w" in intr:
        w, h = int(intr["w"]), int(intr["h"])
    else:
        ip = _image_file(jp.parent, fp)
        if ip is None:
            raise InputError(f"{where}: no image size: give 'w' and 'h' (the image {fp!r} is not there to read "
                             "it from)")
        w, h = _image_size(ip)
    fx, fy, cx, cy = _pixel_intrinsics(intr, w, h, 1.0, 1.0)
    if "w" not in intr:
        _check_principal_point(where, cx, cy, w, h, Path(fp))
    distortion = tuple(intr.get(k, 0.0) for k in _DISTORTION_KINDS)
    try:
        return Camera.from_camera_to_world(c2w, fx, fy, cx, cy, w, h, convention="opengl", near=near, far=far,
                                           name=Path(fp).name, distortion=distortion if any(distortion) else ())
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def load_transforms_cameras(path: str | os.PathLike, near: float = 0.01, far: float = 1e10) -> list[Camera]:
    """Cameras (no images) of a nerfstudio / instant-ngp ``transforms.json`` (any file name):
    frames with ``file_path`` and ``transform_matrix`` (camera-to-world, OpenGL axes);
    intrinsics ``fl_x`` (``fl_y``, ``cx``, ``cy``) in pixels of a ``w`` x ``h`` image, or
    ``camera_angle_x`` (``camera_angle_y``), at the top level or per frame (a frame's own win).
    A camera has the size ``w`` x ``h``; without it, the size of the image the frame names,
    else InputError. Distortion (``k1``, ``k2``, ``p1``, ``p2``, ...) is kept on the camera and
    ignored by the pinhole renderer (a warning); a non-pinhole ``camera_model`` is refused.

    The cameras are in the transforms file's frame: nerfstudio's ``dataparser_transforms.json``
    (the transform and scale its trainer applied to them) is not applied, so a scene that a
    nerfstudio trainer exported in its own frame needs that transform to line up with them."""
    jp = Path(path)
    meta, top, _ = _read_transforms(jp)
    top |= _intrinsics(meta, jp, _DISTORTION_KINDS)
    cams = [_transforms_camera(jp, i, fr, meta, top, near, far) for i, fr in enumerate(meta["frames"])]
    if any(c.distortion for c in cams):
        log.warning("%s: lens distortion ignored by the pinhole renderer (undistort the images for exact "
                    "results)", jp)
    return cams


_CAPTURE_INPUTS = ("an INRIA cameras.json, a transforms.json (nerfstudio, instant-ngp, NeRF-synthetic), a COLMAP "
                   "sparse folder (cameras and images .bin or .txt), or a folder holding one of them "
                   "(cameras.json, transforms.json, transforms_train/test.json, sparse/0, sparse)")


def _capture_folder_cameras(d: Path) -> list[Camera]:
    """The cameras a folder holds (``load_capture_cameras``)."""
    if (d / "cameras.json").is_file():
        return load_inria_cameras(d / "cameras.json")
    sparse = sparse_folder(d)
    if sparse is not None and (d / "transforms.json").is_file():
        raise InputError(f"{d}: holds both transforms.json and the COLMAP model {sparse}, which need not share "
                         "a world frame: give the one the scene was trained from")
    if sparse is not None:
        return load_colmap(sparse)[0]
    if (d / "transforms.json").is_file():
        return load_transforms_cameras(d / "transforms.json")
    splits = [d / f"transforms_{s}.json" for s in ("train", "test") if (d / f"transforms_{s}.json").is_file()]
    if not splits:
        raise InputError(f"{d}: no cameras found; expected {_CAPTURE_INPUTS}")
    return [c for jp in splits for c in load_transforms_cameras(jp)]


def load_capture_cameras(path: str | os.PathLike) -> list[Camera]:
    """All the views (train and test) of the cameras a 3DGS scene was trained from or with: an
    INRIA ``cameras.json``, a transforms JSON (told apart by content: a list or an object
    with ``frames``), a COLMAP sparse folder, or a folder holding one of them: its
    ``cameras.json`` first (the trainer's own record, in the scene's frame), else its sparse
    model (``sparse/0``, ``sparse``) or its ``transforms.json`` (both there: InputError), else
    its ``transforms_train.json`` and ``transforms_test.json``. No cameras: InputError."""
    p = Path(path)
    if p.is_dir():
        cams = _capture_folder_cameras(p)
    elif p.is_file() and p.suffix.lower() == ".json":
        data = _read_json(p)
        if isinstance(data, list):
            cams = load_inria_cameras(p)
        elif isinstance(data, dict) and "frames" in data:
            cams = load_transforms_cameras(p)
        else:
            raise InputError(f"{p}: neither a list of cameras (INRIA cameras.json) nor an object with 'frames' "
                             "(transforms.json)")
    else:
        raise InputError(f"{p}: {'not found' if not p.exists() else 'not a camera file'}; expected {_CAPTURE_INPUTS}")
    if not cams:
        raise InputError(f"{p}: no cameras")
    return cams


def find_capture_cameras(scene_path: str | os.PathLike) -> Path | None:
    """The ``cameras.json`` a 3DGS training output keeps with its scene: beside the scene file
    or one folder up, or ``<model>/cameras.json`` for the INRIA layout
    ``<model>/point_cloud/iteration_<N>/point_cloud.ply``; for a folder, the one in it (a model
    folder). None when there is none there: no further guessing."""
    p = Path(scene_path)
    if p.is_dir():
        places = [p]
    else:
        places = [p.parent, p.parent.parent]
        if re.fullmatch(r"iteration_\d+", p.parent.name) and p.parent.parent.name == "point_cloud":
            places.append(p.parent.parent.parent)
    return next((d / "cameras.json" for d in places if (d / "cameras.json").is_file()), None)
