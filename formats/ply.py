"""Minimal, vectorized PLY I/O for point elements with scalar properties (the layout of
3DGS and Scaffold-GS files). Reads binary (either endianness) and ASCII; writes binary
little-endian, atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..app.fileio import atomic_output

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
MAX_HEADER_BYTES = 1 << 20


def _parse_header(path: Path, head: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int]:
    """(format, [(element, count, [(dtype or 'list', property)])], byte offset of the body)."""
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file (no 'ply' magic or no end_header)")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for parts in (line.split() for line in head[:end].decode("ascii", "replace").splitlines()[1:]):
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise InputError(f"{path}: property before any element")
            elements[-1][2].append(_property(path, parts))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise InputError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements, head.index(b"\n", end) + 1


def _property(path: Path, parts: list[str]) -> tuple[str, str]:
    if parts[1] == "list":
        return "list", parts[-1]
    if parts[1] not in _PLY_TYPES:
        raise InputError(f"{path}: unknown property type {parts[1]!r}")
    return _PLY_TYPES[parts[1]], parts[2]


def _read_ascii(path: Path, body: bytes, element: str, count: int, props: list[tuple[str, str]]) -> dict[str, np.ndarray]:
    vals = np.asarray(body.decode("ascii", "replace").split()[: count * len(props)], dtype=np.float64)
    if vals.size != count * len(props):
        raise InputError(f"{path}: file ends before {count} {element} rows")
    vals = vals.reshape(count, len(props))
    return {p: vals[:, i].astype(t) for i, (t, p) in enumerate(props)}


def _read_binary(path: Path, f, offset: int, size: int, count: int, dtype: np.dtype) -> dict[str, np.ndarray]:
    """The element's rows only (np.fromfile at its offset: the rest of the file is never read)."""
    nbytes = dtype.itemsize * count
    if offset + nbytes > size:
        raise InputError(f"{path}: file is truncated ({size - offset} bytes for {count} rows of "
                         f"{dtype.itemsize} bytes)")
    f.seek(offset)
    arr = np.fromfile(f, dtype=dtype, count=count)
    return {p: arr[p].astype(arr[p].dtype.newbyteorder("=")) for p in dtype.names}


def read_ply(path: str | os.PathLike, element: str = "vertex") -> dict[str, np.ndarray]:
    """Return {property name: array} for one element. Raises InputError naming the file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            fmt, elements, offset = _parse_header(path, f.read(MAX_HEADER_BYTES))
            size = os.fstat(f.fileno()).st_size
            for name, count, props in elements:
                if any(t == "list" for t, _ in props):
                    if name == element:
                        raise InputError(f"{path}: element {element!r} has list properties, which are not supported")
                    raise InputError(f"{path}: element {name!r} with list properties precedes {element!r}")
                if fmt == "ascii":
                    if name != element:
                        raise InputError(f"{path}: ASCII PLY with elements before {element!r} is not supported")
                    f.seek(offset)
                    return _read_ascii(path, f.read(), element, count, props)
                dtype = np.dtype([(p, ("<" if fmt == "binary_little_endian" else ">") + t) for t, p in props])
                if name == element:
                    return _read_binary(path, f, offset, size, count, dtype)
                offset += dtype.itemsize * count
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    raise InputError(f"{path}: no element {element!r}")


# rows per block: a block's rows of the source arrays stay in the cache while its columns are copied
# (3x faster than 2^16 rows for a 1M SH-3 scene of strided views, tools/results/decode.md)
WRITE_BLOCK_ROWS = 1 << 12


def read_ply_header_lines(path: str | os.PathLike) -> list[str]:
    """The lines of a PLY file's header before ``end_header`` (reading only the header);
    InputError naming the file when it cannot be read or is not a PLY file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(MAX_HEADER_BYTES)
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file (no 'ply' magic or no end_header)")
    return head[:end].decode("ascii", "replace").splitlines()


def read_ply_comments(path: str | os.PathLike) -> list[str]:
    """The text of the header's ``comment`` lines (without the keyword), reading only the header."""
    return [line[len("comment "):] for line in read_ply_header_lines(path) if line.startswith("comment ")]


def write_ply(path: str | os.PathLike, columns: dict[str, np.ndarray], comments: list[str] = ()) -> None:
    """Binary little-endian float32 columns, written atomically in blocks of rows: the memory
    it needs beyond the columns themselves is one block, whatever the row count."""
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 0
    for k in names:
        if len(columns[k]) != n:
            raise ValueError(f"PLY column {k!r} has {len(columns[k])} rows, expected {n}")
    for c in comments:
        if "\n" in c or "\r" in c or not c.isascii():
            raise ValueError(f"PLY comment {c!r} must be one line of ASCII")
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments), f"element vertex {n}"]
    header += [f"property float {k}" for k in names]
    header.append("end_header\n")
    block = np.empty((min(n, WRITE_BLOCK_ROWS), len(names)), dtype="<f4")  # rows as the file lays them out
    with atomic_output(path) as f:
        f.write("\n".join(header).encode("ascii"))
        for lo in range(0, n, WRITE_BLOCK_ROWS):
            hi = min(n, lo + WRITE_BLOCK_ROWS)
            out = block[: hi - lo]
            for j, k in enumerate(names):
                out[:, j] = columns[k][lo:hi]
            f.write(out.data)
