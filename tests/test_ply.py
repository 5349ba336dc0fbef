"""formats/ply.py: every layout the reader accepts gives the columns written, and every malformed
file an InputError that names it."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.errors import InputError
from lghcc.formats.ply import read_ply, write_ply

_TYPES = {"float": "f4", "double": "f8", "uchar": "u1", "short": "i2", "int": "i4", "uint16": "u2"}


def _ply_bytes(fmt: str, columns: dict[str, np.ndarray], types: dict[str, str], before: int) -> bytes:
    """A PLY file of one 'vertex' element (after ``before`` rows of an element 'camera' when binary)."""
    n = len(next(iter(columns.values())))
    head = ["ply", f"format {fmt} 1.0", "comment made by a test"]
    if before:
        head += [f"element camera {before}", "property float f"]
    head += [f"element vertex {n}"] + [f"property {types[k]} {k}" for k in columns] + ["end_header"]
    out = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        return out + "".join(" ".join(repr(float(columns[k][i])) for k in columns) + "\n" for i in range(n)).encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    out += np.arange(before, dtype=e + "f4").tobytes()
    rec = np.empty(n, dtype=[(k, e + _TYPES[types[k]]) for k in columns])
    for k in columns:
        rec[k] = columns[k]
    return out + rec.tobytes()


@settings(max_examples=60, deadline=None)
@given(n=st.integers(0, 40), fmt=st.sampled_from(["binary_little_endian", "binary_big_endian", "ascii"]),
       names=st.lists(st.sampled_from(list(_TYPES)), min_size=1, max_size=5), before=st.integers(0, 3),
       seed=st.integers(0, 2**31 - 1))
def test_every_layout_reads_back_its_columns(tmp_path_factory, n, fmt, names, before, seed):
    rng = np.random.default_rng(seed)
    types = {f"p{i}": t for i, t in enumerate(names)}
    columns = {k: rng.integers(0, 200, size=n).astype(_TYPES[t]) for k, t in types.items()}
    path = tmp_path_factory.mktemp("ply") / "s.ply"
    path.write_bytes(_ply_bytes(fmt, columns, types, 0 if fmt == "ascii" else before))
    back = read_ply(path)
    assert list(back) == list(columns)
    for k in columns:
        assert back[k].dtype == np.dtype(_TYPES[types[k]]) and back[k].dtype.isnative
        assert np.array_equal(back[k], columns[k])


def test_write_then_read_is_exact(tmp_path):
    cols = {"x": np.array([0.1, -3e38, np.inf], np.float32), "opacity": np.array([1, 2, 3], np.float32)}
    write_ply(tmp_path / "a.ply", cols)
    back = read_ply(tmp_path / "a.ply")
    assert all(np.array_equal(back[k], v) for k, v in cols.items())


@pytest.mark.parametrize("body, message", [
    (b"not a ply", "not a PLY file"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n", "not a PLY file"),
    (b"ply\nformat weird 1.0\nelement vertex 1\nproperty float x\nend_header\n", "unsupported PLY format 'weird'"),
    (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "property before any element"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n", "unknown property type"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nend_header\n\0\0\0\0",
     "truncated"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1.0\n", "file ends before 2 vertex rows"),
    (b"ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int i\nelement vertex 1\n"
     b"property float x\nend_header\n", "with list properties precedes 'vertex'"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty list uchar int i\nend_header\n",
     "has list properties"),
    (b"ply\nformat ascii 1.0\nelement camera 1\nproperty float f\nelement vertex 1\nproperty float x\nend_header\n"
     b"1\n2\n", "ASCII PLY with elements before 'vertex'"),
    (b"ply\nformat binary_little_endian 1.0\nelement camera 1\nproperty float f\nend_header\n\0\0\0\0",
     "no element 'vertex'"),
])
def test_malformed_files_name_the_problem(tmp_path, body, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(body)
    with pytest.raises(InputError, match=message) as e:
        read_ply(path)
    assert str(path) in str(e.value)


def test_a_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_ply(tmp_path / "absent.ply")


def test_3dgs_ply_of_views_is_the_file_of_copies_at_sh_3(tmp_path, monkeypatch):
    import lghcc.formats.ply as ply_mod
    from lghcc.common.scene import GaussianScene
    from lghcc.formats.ply3dgs import read_3dgs_ply, write_3dgs_ply
    rng = np.random.default_rng(5)
    n = 1000
    values = rng.standard_normal((n, 56)).astype(np.float32)  # the SH, opacity, scales, rotations of a decoder's rows
    scene = GaussianScene(rng.standard_normal((n, 3)).astype(np.float32), values[:, :48].reshape(n, 16, 3),
                          values[:, 48], values[:, 49:52], values[:, 52:56])
    monkeypatch.setattr(ply_mod, "WRITE_BLOCK_ROWS", 7)  # blocks, the last one partial
    write_3dgs_ply(tmp_path / "views.ply", scene)
    copies = GaussianScene(*(np.ascontiguousarray(a) for a in (scene.means, scene.sh, scene.opacity,
                                                                scene.log_scales, scene.rotations)))
    monkeypatch.setattr(ply_mod, "WRITE_BLOCK_ROWS", 1 << 16)
    write_3dgs_ply(tmp_path / "copies.ply", copies)
    assert (tmp_path / "views.ply").read_bytes() == (tmp_path / "copies.ply").read_bytes()
    cols = read_ply(tmp_path / "views.ply")
    # f_rest_{c * 15 + i - 1} is coefficient i of channel c (channel-major, the INRIA layout)
    assert np.array_equal(cols["f_rest_16"], scene.sh[:, 2, 1]) and np.array_equal(cols["f_rest_44"], scene.sh[:, 15, 2])
    assert np.array_equal(read_3dgs_ply(tmp_path / "views.ply").sh, scene.sh)
