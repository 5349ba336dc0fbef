"""Writing a PyTorch checkpoint (torch.save's zip format) of state dicts of float arrays, without
importing torch (informative). lghcc-dec writes an anchor scene's render MLPs as checkpoint.pth;
importing torch for it took longer than decoding a one-tile box of a 100k-anchor stream
(tools/results/decode.md), so the decoder's path does not load it. torch.load(...,
weights_only=True) reads the result as it reads torch.save's (tests/test_decode_jobs.py).

The format: a stored (uncompressed) zip whose records sit under one folder, ``archive/``:
data.pkl (the object, pickle protocol 2, each tensor a call of torch._utils._rebuild_tensor_v2
on a persistent storage id), data/<key> (each storage's bytes, little-endian, aligned to 64
bytes as torch aligns them), byteorder, version, .format_version and .storage_alignment.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from collections import OrderedDict

import numpy as np

_STORAGE = {np.dtype(np.float32): "FloatStorage", np.dtype(np.float64): "DoubleStorage",
            np.dtype(np.int64): "LongStorage", np.dtype(np.int32): "IntStorage", np.dtype(np.uint8): "ByteStorage",
            np.dtype(np.bool_): "BoolStorage"}
ALIGNMENT = 64  # torch's .storage_alignment: each storage's bytes start at a multiple of it
ARCHIVE = "archive"


class _Global:
    """A global of torch named in the pickle (opcode GLOBAL) without importing it."""

    def __init__(self, module: str, name: str) -> None:
        self.module, self.name = module, name

    def __call__(self, *args):  # pickle's save_reduce asks for a callable; never called here
        raise TypeError(f"{self.module}.{self.name} stands for torch's, which is not loaded")


class _Storage:
    def __init__(self, key: str, array: np.ndarray) -> None:
        self.key, self.array = key, array


class _Tensor:
    """A tensor as torch pickles it: _rebuild_tensor_v2(storage, offset, size, stride,
    requires_grad, backward_hooks)."""

    def __init__(self, storage: _Storage) -> None:
        self.storage = storage

    def __reduce__(self):
        a = self.storage.array
        stride = tuple(s // a.itemsize for s in a.strides)
        return (_Global("torch._utils", "_rebuild_tensor_v2"),
                (self.storage, 0, tuple(a.shape), stride, False, OrderedDict()))


class _Pickler(pickle._Pickler):  # the Python pickler: its dispatch table can name a global freely
    dispatch = dict(pickle._Pickler.dispatch)

    def _save_global_name(self, obj: _Global) -> None:
        self.write(pickle.GLOBAL + f"{obj.module}\n{obj.name}\n".encode("ascii"))
        self.memoize(obj)

    dispatch[_Global] = _save_global_name

    def persistent_id(self, obj):
        if isinstance(obj, _Storage):
            kind = _Global("torch", _STORAGE[obj.array.dtype])
            return ("storage", kind, obj.key, "cpu", int(obj.array.size))
        return None


def checkpoint_bytes(state: dict[str, dict[str, np.ndarray]]) -> bytes:
    """torch.save(state) of a dict of state dicts (name -> array), as bytes, without torch. Raises
    ValueError for an array dtype torch's checkpoints do not name here."""
    storages: list[_Storage] = []
    obj = {}
    for name, sd in state.items():
        obj[name] = {}
        for key, a in sd.items():
            a = np.ascontiguousarray(a)
            if a.dtype not in _STORAGE:
                raise ValueError(f"{name}.{key}: dtype {a.dtype} is not written into checkpoints")
            storages.append(_Storage(str(len(storages)), a.astype(a.dtype.newbyteorder("<"), copy=False)))
            obj[name][key] = _Tensor(storages[-1])
    pkl = io.BytesIO()
    _Pickler(pkl, protocol=2).dump(obj)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        _record(z, "data.pkl", pkl.getvalue())
        _record(z, ".format_version", b"1")
        _record(z, ".storage_alignment", str(ALIGNMENT).encode())
        _record(z, "byteorder", b"little")
        for s in storages:
            _record(z, f"data/{s.key}", s.array.tobytes(), align=True)
        _record(z, "version", b"3\n")
    return buf.getvalue()


def _record(z: zipfile.ZipFile, name: str, data: bytes, align: bool = False) -> None:
    """One stored record; ``align``: its bytes padded (an extra field in the local header, as
    torch's writer pads) to start at a multiple of ALIGNMENT."""
    info = zipfile.ZipInfo(f"{ARCHIVE}/{name}", date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_STORED
    if align:
        start = z.fp.tell() + 30 + len(info.filename.encode()) + 4  # local header, name, extra field's header
        pad = -start % ALIGNMENT
        info.extra = b"FB" + pad.to_bytes(2, "little") + b"Z" * pad
    z.writestr(info, data)
