"""The one error type of the importers: names the file, the byte offset or line, and the problem."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from gonio.data.dataset import DatasetError

__all__ = ["FormatError", "RegularFile", "read_file_bytes"]


class FormatError(DatasetError):
    """A file of another format is malformed. The message names file, offset or line, problem."""

    def __init__(self, problem: str, *, file: str | os.PathLike | None = None,
                 offset: int | None = None, line: int | None = None, hint: str | None = None):
        where = ""
        if offset is not None:
            where = f"byte offset {offset}: "
        elif line is not None:
            where = f"line {line}: "
        self.offset = offset
        self.line = line
        super().__init__(where + problem, file=file, hint=hint)


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


class RegularFile:
    """A file to import, opened only if it is a regular file of at most ``max_bytes``.

    Everything an importer reads goes through here, so that no input can make it wait or
    allocate without a bound: the file is opened non-blocking (a FIFO cannot hang the open), then
    anything but a regular file (a FIFO, ``/dev/zero``, a directory, a socket) is refused, and so
    is a file larger than ``max_bytes`` (from its size, before a byte is read; a sparse file of
    5 GB is refused as such). Reads are positional (:meth:`read`) and bounded by the size.
    """

    def __init__(self, path: str | os.PathLike, max_bytes: int, what: str):
        self.path = Path(path)
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            raise FormatError(f"cannot be read ({exc.strerror})", file=path) from None
        try:
            st = os.fstat(fd)
            for test, kind in _KINDS:
                if test(st.st_mode):
                    raise FormatError(f"is {kind}, not a regular file", file=path,
                                      hint=f"give the {what} file itself")
            if st.st_size > max_bytes:
                raise FormatError(f"file is {st.st_size} bytes; a {what} file is at most "
                                  f"{max_bytes} bytes here", file=path,
                                  hint="the file is not of this format, or corrupt")
        except BaseException:
            os.close(fd)
            raise
        self.fd, self.size = fd, int(st.st_size)

    def read(self, offset: int, n: int) -> bytes:
        """``n`` bytes at ``offset`` (fewer at the end of the file)."""
        n = max(0, min(n, self.size - offset))
        chunks, got = [], 0
        while got < n:
            chunk = os.pread(self.fd, n - got, offset + got)
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)

    def read_all(self) -> bytes:
        """The whole file (its size is bounded by ``max_bytes``)."""
        return self.read(0, self.size)

    def close(self) -> None:
        """Close the file descriptor (once; later calls do nothing)."""
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def __enter__(self) -> RegularFile:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_file_bytes(path: str | os.PathLike, max_bytes: int, what: str) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (:class:`RegularFile`)."""
    with RegularFile(path, max_bytes, what) as fh:
        return fh.read_all()
