"""The one error type of the importers: names the file, the byte offset or line, and the problem."""

from __future__ import annotations

import os
from pathlib import Path

from gonio.data.dataset import DatasetError

__all__ = ["FormatError", "read_file_bytes"]


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


def read_file_bytes(path: str | os.PathLike) -> bytes:
    """The bytes of a file to import; :class:`FormatError` naming the file when unreadable."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise FormatError(f"cannot be read ({exc.strerror})", file=path) from None
