r"""Reader of Mitsuba's ``tensor_file`` container (the RGL ``.bsdf`` files are such files).

Layout (little-endian): the 12 bytes ``tensor_file\0``, version ``1, 0`` (two bytes), the field
count (uint32), then per field: name length (uint16) and name (UTF-8), number of dimensions
(uint16), dtype (uint8: 1 uint8 ... 10 float32, 11 float64), data offset (uint64), shape
(ndim x uint64); the data follow at their offsets.

References
----------
Mitsuba 3, ``src/core/tensor.cpp`` and ``src/python/python/tensor_io.py``.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from gonio.data.formats.errors import FormatError, RegularFile

__all__ = ["MAX_TENSOR_BYTES", "TensorHeader", "parse_tensor_bytes", "read_tensor_file"]

MAGIC = b"tensor_file\0"
_DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32,
           7: np.uint64, 8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
#: A tensor file of the RGL database holds about a dozen fields; more is a corrupt count.
MAX_FIELDS = 1024
MAX_NDIM = 16


#: Largest tensor file read (the RGL database's files are a few MB; evaluating one holds about
#: eight times its tables in float64, so this bounds an import near 1 GB).
MAX_TENSOR_BYTES = 128 * 1024 * 1024


class TensorHeader(NamedTuple):
    """One field's header: name, dtype, data offset, shape, header offset."""

    name: str
    dtype: np.dtype
    offset: int
    shape: tuple[int, ...]
    start: int

    @property
    def nbytes(self) -> int:
        """The field's size in bytes."""
        return math.prod(self.shape) * self.dtype.itemsize


def read_tensor_file(path: str | os.PathLike, check_header: Callable[[dict[str, TensorHeader]], None]
                     | None = None) -> dict[str, np.ndarray]:
    """Fields of the tensor file at ``path`` as numpy arrays (native byte order copies).

    Bounded: the file must be a regular file of at most :data:`MAX_TENSOR_BYTES`; its header is
    read first and every field must lie inside the file, after the header, without overlapping
    another (so the arrays together never exceed the file's size), and ``check_header`` (the
    format's own plausibility checks on the declared shapes) runs before any field's data is
    read.

    Raises
    ------
    FormatError
        Naming the file, the byte offset and the problem, for any malformed content.
    """
    with RegularFile(path, MAX_TENSOR_BYTES, "tensor (.bsdf)") as fh:
        headers = _parse_headers(fh.read, fh.size, path)
        if check_header is not None:
            check_header({h.name: h for h in headers})
        return _read_fields(fh.read, headers)


def parse_tensor_bytes(data: bytes, path: str | os.PathLike = "<tensor>") -> dict[str, np.ndarray]:
    """Parse the bytes of a tensor file (see :func:`read_tensor_file`)."""
    def read(offset: int, n: int) -> bytes:
        return data[offset:offset + n]

    return _read_fields(read, _parse_headers(read, len(data), path))


def _read_fields(read: Callable[[int, int], bytes], headers: list[TensorHeader]) -> dict[str, np.ndarray]:
    fields: dict[str, np.ndarray] = {}
    for h in headers:
        count = math.prod(h.shape)
        array = np.frombuffer(read(h.offset, h.nbytes), dtype=h.dtype, count=count)
        fields[h.name] = array.astype(h.dtype.newbyteorder("="), copy=True).reshape(h.shape)
    return fields


def _parse_headers(read: Callable[[int, int], bytes], size: int,  # noqa: C901
                   path: str | os.PathLike) -> list[TensorHeader]:
    pos = 0

    def take(fmt: str, what: str):
        nonlocal pos
        n = struct.calcsize(fmt)
        raw = read(pos, n)
        if len(raw) < n:
            raise FormatError(f"file ends inside the {what} (needs {n} bytes, "
                              f"{size - pos} left)", file=path, offset=pos,
                              hint="the file is truncated; download it again")
        value = struct.unpack(fmt, raw)
        pos += n
        return value if len(value) > 1 else value[0]

    if read(0, 12) != MAGIC:
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
    headers: list[TensorHeader] = []
    for _ in range(n_fields):
        start = pos
        n_name = take("<H", "field name length")
        raw = read(pos, n_name)
        if len(raw) < n_name:
            raise FormatError("file ends inside a field name", file=path, offset=pos)
        try:
            name = raw.decode("utf-8")
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
        dims = take("<" + "Q" * ndim, f"shape of '{name}'") if ndim else ()
        shape = tuple(int(d) for d in (dims if isinstance(dims, tuple) else (dims,)))
        if any(s > size for s in shape):
            # no axis of a table stored in the file can be longer than the file (even an empty
            # field: a (0, 2**64 - 1) shape is corrupt, not a table)
            raise FormatError(f"field '{name}' declares shape {list(shape)}, an axis longer than "
                              f"the {size}-byte file", file=path, offset=start,
                              hint="the file is corrupt")
        if name in {h.name for h in headers}:
            raise FormatError(f"field '{name}' is declared twice", file=path, offset=start)
        headers.append(TensorHeader(name, np.dtype(_DTYPES[code]).newbyteorder("<"), offset,
                                    shape, start))
    end_of_header = pos
    previous: TensorHeader | None = None
    for h in sorted(headers, key=lambda h: (h.offset, h.nbytes)):
        if h.offset < end_of_header or h.offset + h.nbytes > size:
            raise FormatError(f"field '{h.name}' (shape {list(h.shape)}) claims {h.nbytes} bytes "
                              f"at offset {h.offset}, outside the data of the {size}-byte file "
                              f"(bytes {end_of_header}..{size})", file=path, offset=h.start,
                              hint="the file is truncated or corrupt")
        if previous is not None and h.nbytes and previous.offset + previous.nbytes > h.offset:
            raise FormatError(f"fields '{previous.name}' and '{h.name}' overlap (bytes "
                              f"{h.offset}..{previous.offset + previous.nbytes}); each field "
                              "has its own data", file=path, offset=h.start,
                              hint="the file is corrupt")
        if h.nbytes:
            previous = h
    return headers
