"""Reader of Mitsuba's ``tensor_file`` container (the RGL ``.bsdf`` files are such files).

Layout (little-endian): the 12 bytes ``tensor_file\\0``, version ``1, 0`` (two bytes), the field
count (uint32), then per field: name length (uint16) and name (UTF-8), number of dimensions
(uint16), dtype (uint8: 1 uint8 ... 10 float32, 11 float64), data offset (uint64), shape
(ndim x uint64); the data follow at their offsets.

References
----------
Mitsuba 3, ``src/core/tensor.cpp`` and ``src/python/python/tensor_io.py``.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from gonio.data.formats.errors import FormatError, read_file_bytes

__all__ = ["read_tensor_file"]

MAGIC = b"tensor_file\0"
_DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32,
           7: np.uint64, 8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
#: A tensor file of the RGL database holds about a dozen fields; more is a corrupt count.
MAX_FIELDS = 1024
MAX_NDIM = 16


def read_tensor_file(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Fields of the tensor file at ``path`` as numpy arrays (native byte order copies).

    Raises
    ------
    FormatError
        Naming the file, the byte offset and the problem, for any malformed content.
    """
    path = Path(path)
    data = read_file_bytes(path)
    return parse_tensor_bytes(data, path)


def parse_tensor_bytes(data: bytes, path: str | os.PathLike = "<tensor>") -> dict[str, np.ndarray]:
    """Parse the bytes of a tensor file (see :func:`read_tensor_file`)."""
    pos = 0

    def take(fmt: str, what: str):
        nonlocal pos
        size = struct.calcsize(fmt)
        if pos + size > len(data):
            raise FormatError(f"file ends inside the {what} (needs {size} bytes, "
                              f"{len(data) - pos} left)", file=path, offset=pos,
                              hint="the file is truncated; download it again")
        value = struct.unpack_from(fmt, data, pos)
        pos += size
        return value if len(value) > 1 else value[0]

    if data[:12] != MAGIC:
        raise FormatError("not a tensor file (the first 12 bytes are not 'tensor_file\\0')",
                          file=path, offset=0, hint="expected an RGL .bsdf file")
    pos = 12
    version = take("<BB", "version")
    if version != (1, 0):
        raise FormatError(f"unsupported tensor file version {version[0]}.{version[1]}",
                          file=path, offset=12, hint="this reader knows version 1.0")
    n_fields = take("<I", "field count")
    if n_fields > MAX_FIELDS:
        raise FormatError(f"field count {n_fields} is implausible (at most {MAX_FIELDS})",
                          file=path, offset=14)
    headers = []
    for _ in range(n_fields):
        start = pos
        n_name = take("<H", "field name length")
        if pos + n_name > len(data):
            raise FormatError("file ends inside a field name", file=path, offset=pos)
        try:
            name = data[pos:pos + n_name].decode("utf-8")
        except UnicodeDecodeError:
            raise FormatError("field name is not UTF-8", file=path, offset=pos) from None
        pos += n_name
        ndim = take("<H", f"header of field '{name}'")
        if ndim > MAX_NDIM:
            raise FormatError(f"field '{name}' has {ndim} dimensions (at most {MAX_NDIM})",
                              file=path, offset=pos - 2)
        code_at = pos
        code = take("<B", f"header of field '{name}'")
        if code not in _DTYPES:
            raise FormatError(f"field '{name}' has an unknown data type code {code}", file=path,
                              offset=code_at)
        offset = take("<Q", f"header of field '{name}'")
        shape = tuple(int(s) for s in np.atleast_1d(take("<" + "Q" * ndim, f"shape of '{name}'"))) \
            if ndim else ()
        headers.append((name, np.dtype(_DTYPES[code]).newbyteorder("<"), offset, shape, start))
    fields: dict[str, np.ndarray] = {}
    for name, dtype, offset, shape, start in headers:
        count = 1
        for s in shape:
            count *= s
        nbytes = count * dtype.itemsize
        if count > len(data) or offset > len(data) or offset + nbytes > len(data):
            raise FormatError(f"field '{name}' (shape {list(shape)}) claims {nbytes} bytes at "
                              f"offset {offset}, beyond the end of the {len(data)}-byte file",
                              file=path, offset=start, hint="the file is truncated or corrupt")
        array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        fields[name] = array.astype(dtype.newbyteorder("="), copy=True).reshape(shape)
    return fields
