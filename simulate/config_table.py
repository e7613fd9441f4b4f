"""Typed access to one TOML table whose errors name the file and the dotted field (simulate configs).

``Table(data, "fiber", "red.toml").number("radius_um", gt=0)`` returns the value or raises
:class:`ConfigError` ``red.toml: fiber.radius_um must be a number > 0, got -1``; :meth:`Table.done`
refuses fields nobody read (a misspelt key is an error, not a silent default). A table made with
its ``fields`` (the schema's keys) refuses unknown keys at once, BEFORE any field is read, so a typo
(``rms_slop``) is named as such, with a suggestion from :func:`difflib.get_close_matches`
(``red.toml: surface.rms_slop is not a known field (did you mean rms_slope?)``), instead of surfacing as
"rms_slope is required". The acquisition plan's field reader (``gonio.acquisition.plan``)
follows the same rules.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable
from typing import Any, Literal, overload

__all__ = ["ConfigError", "Table", "show", "is_number"]


class ConfigError(ValueError):
    """A simulation config is missing, unreadable or has a bad field (the message names both)."""


def show(value: Any) -> str:
    """A value as an error message quotes it (strings quoted, long values cut)."""
    text = f'"{value}"' if isinstance(value, str) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def is_number(value: Any) -> bool:
    """A finite int or float (not a bool) below 1e15 in magnitude."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return math.isfinite(value) and abs(value) < 1e15


class Table:
    """One TOML table with checks whose errors name the file and the dotted field."""

    def __init__(self, data: Any, where: str, file: str, fields: Iterable[str] | None = None):
        self.file, self.where = file, where
        if not isinstance(data, dict):
            raise ConfigError(f"{file}: {where} must be a table, got {show(data)}")
        self.data = data
        self.used: set[str] = set()
        self.asked: set[str] = set()
        self.fields = frozenset(fields) if fields is not None else None
        if self.fields is not None:
            self._refuse_unknown(self.fields)

    def name(self, key: str) -> str:
        """The dotted field name of ``key`` in this table (``fiber.radius_um``), as errors show it."""
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str, message: str) -> ConfigError:
        """The error ``FILE: where.key message`` (returned, for the caller to raise)."""
        return ConfigError(f"{self.file}: {self.name(key)} {message}")

    def has(self, key: str) -> bool:
        """Whether the table gives ``key`` (the key then counts as known to :meth:`done`'s suggestion)."""
        self.asked.add(key)
        return key in self.data

    def raw(self, key: str, default: Any = None, required: bool = False) -> Any:
        """The value of ``key`` unchecked (``default`` when absent; an error when ``required``), marked used."""
        self.used.add(key)
        if key not in self.data:
            if required:
                raise self.fail(key, "is required")
            return default
        return self.data[key]

    # the value is a float when a default is given or the key is required, else possibly None
    @overload
    def number(self, key: str, default: float, *, required: bool = False, gt: float | None = None,
               ge: float | None = None, lt: float | None = None, le: float | None = None) -> float: ...

    @overload
    def number(self, key: str, default: None = None, *, required: Literal[True], gt: float | None = None,
               ge: float | None = None, lt: float | None = None, le: float | None = None) -> float: ...

    @overload
    def number(self, key: str, default: None = None, *, required: bool = False, gt: float | None = None,
               ge: float | None = None, lt: float | None = None, le: float | None = None) -> float | None: ...

    def number(self, key: str, default: float | None = None, *, required: bool = False,
               gt: float | None = None, ge: float | None = None, lt: float | None = None,
               le: float | None = None) -> float | None:
        """``key`` as a finite float within the bounds given (``default`` when absent; None stays None)."""
        value = self.raw(key, default, required)
        if value is None:
            return None
        bounds = " and ".join(s for s in (
            f"> {gt:g}" if gt is not None else "", f">= {ge:g}" if ge is not None else "",
            f"< {lt:g}" if lt is not None else "", f"<= {le:g}" if le is not None else "") if s)
        what = f"a number {bounds}" if bounds else "a finite number"
        ok = is_number(value) and not (
            (gt is not None and not value > gt) or (ge is not None and not value >= ge)
            or (lt is not None and not value < lt) or (le is not None and not value <= le))
        if not ok:
            raise self.fail(key, f"must be {what}, got {show(value)}")
        return float(value)

    def integer(self, key: str, default: int, *, ge: int = 0, le: int = 2**63 - 1) -> int:
        """``key`` as an integer in ``[ge, le]`` (a bool is refused), ``default`` when absent."""
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not ge <= value <= le:
            raise self.fail(key, f"must be an integer in [{ge}, {le}], got {show(value)}")
        return int(value)

    # the value is a string when a default is given or the key is required, else possibly None
    @overload
    def string(self, key: str, default: str, *, choices: tuple[str, ...] | None = None,
               required: bool = False) -> str: ...

    @overload
    def string(self, key: str, default: None = None, *, choices: tuple[str, ...] | None = None,
               required: Literal[True]) -> str: ...

    @overload
    def string(self, key: str, default: None = None, *, choices: tuple[str, ...] | None = None,
               required: bool = False) -> str | None: ...

    def string(self, key: str, default: str | None = None, *, choices: tuple[str, ...] | None = None,
               required: bool = False) -> str | None:
        """``key`` as a non-empty string, one of ``choices`` when given (``default`` when absent)."""
        value = self.raw(key, default, required)
        if value is None:
            return None
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, f"must be a non-empty string, got {show(value)}")
        if choices is not None and value not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}, got {show(value)}")
        return value

    def numbers(self, key: str, *, ge: float | None = None, required: bool = True) -> list[float]:
        """``key`` as a non-empty list of finite floats, each ``>= ge`` when given."""
        value = self.raw(key, None, required)
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"must be a non-empty list of numbers, got {show(value)}")
        for k, x in enumerate(value):
            if not is_number(x) or (ge is not None and x < ge):
                bound = f" >= {ge:g}" if ge is not None else ""
                raise self.fail(key, f"item {k} must be a finite number{bound}, got {show(x)}")
        return [float(x) for x in value]

    def sub(self, key: str, required: bool = False, fields: Iterable[str] | None = None) -> Table | None:
        """The sub-table ``key``; with ``fields`` (its schema's keys) its unknown keys are refused first."""
        if required and key not in self.data:
            self._refuse_unknown(self.fields or (), near=key)
        value = self.raw(key, None, required)
        if value is None:
            return None
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table, got {show(value)}")
        return Table(value, self.name(key), self.file, fields)

    def _refuse_unknown(self, known: Iterable[str], near: str | None = None) -> None:
        """Refuse the first key not in ``known`` (with ``near``: only keys close to that missing one)."""
        known = set(known)
        for key in sorted(set(self.data) - known):
            if near is not None and not difflib.get_close_matches(key, [near], n=1, cutoff=0.6):
                continue
            raise self.unknown(key, known | ({near} if near else set()))

    def unknown(self, key: str, known: Iterable[str]) -> ConfigError:
        """``FILE: where.key is not a known field (did you mean X?)``."""
        guess = difflib.get_close_matches(key, sorted(known), n=1, cutoff=0.6)
        hint = (f"did you mean {guess[0]}?" if guess
                else "check the spelling; the schema is docs/reference/config.md")
        return self.fail(key, f"is not a known field ({hint})")

    def done(self) -> None:
        """Refuse the first key of the table that no check read, with a suggestion of a known one."""
        extra = sorted(set(self.data) - self.used)
        if extra:
            raise self.unknown(extra[0], self.used | self.asked | (self.fields or set()))
