"""Dotted TOML paths into a config document, and the TOML writer (``simulate fit --free``, ``sweep --param``).

A path names one field of a config's TOML document by its tables and list indices
(``particles.volume_fraction``, ``fiber.dye.bands[0].peak_per_um``, ``fiber.dye.log10_per_um[3]``,
``structure.twist_deg`` once a config has that table: any numeric field is a path); an alias names
several (:func:`expand`: ``volume_fraction``, ``radius``, ``rms_slope``, ``dye``, ``dye-peaks``; for a
``knots`` dye, ``dye`` and ``dye-peaks`` are its knot values). A blend's population is named by its name
(``populations.yellow.dye``, ``populations.yellow.share``, ``populations.yellow.dye_depth_um``: its dye,
share and dye depth, :func:`population_path`) or by its index (``populations[0].share``).
:func:`toml_dumps` writes a document back (what ``tomllib`` read), so a changed document can be
parsed by :func:`simulate.config.parse_config` exactly as a file would be.
"""

from __future__ import annotations

import json
import re
from typing import Any

__all__ = ["ALIASES", "POPULATION_FIELDS", "PathError", "split", "get", "set_value", "numeric_leaves", "expand",
           "population_path", "toml_dumps"]

#: The aliases :func:`expand` knows.
ALIASES = ("volume_fraction", "radius", "rms_slope", "dye", "dye-peaks")
#: What a fit frees of one population of a blend (``populations.NAME.FIELD``, :func:`population_path`)
POPULATION_FIELDS = ("dye", "dye-peaks", "share", "dye_depth_um")
_POPULATION = re.compile(r"^populations\.([A-Za-z_][A-Za-z0-9_-]*)\.(.+)$")


class PathError(ValueError):
    """A path that is not a config path, or an alias the config cannot expand (one line)."""


_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_-]*)(?:\[(\d+)\])?$")


def split(path: str) -> list[str | int]:
    """The keys and list indices of ``path``.

    >>> split("fiber.dye.bands[1].peak_per_um")
    ['fiber', 'dye', 'bands', 1, 'peak_per_um']
    """
    parts: list[str | int] = []
    for piece in path.split("."):
        m = _TOKEN.match(piece)
        if not m:
            raise PathError(f"{path!r} is not a parameter name (dotted config path such as "
                            "particles.volume_fraction or fiber.dye.bands[0].peak_per_um)")
        parts.append(m.group(1))
        if m.group(2) is not None:
            parts.append(int(m.group(2)))
    return parts


def get(data: Any, path: str) -> Any:
    """The value at ``path`` (KeyError when the document has no such field)."""
    node = data
    for key in split(path):
        if isinstance(key, int):
            if not isinstance(node, list) or key >= len(node):
                raise KeyError(path)
        elif not isinstance(node, dict) or key not in node:
            raise KeyError(path)
        node = node[key]
    return node


def set_value(data: Any, path: str, value: float) -> None:
    """Set the field at ``path`` (it must exist up to its last key)."""
    keys = split(path)
    node = data
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value


def numeric_leaves(node: Any, prefix: str) -> list[str]:
    """Paths of every number under ``node`` (tables and lists of tables), ``prefix`` first."""
    out: list[str] = []
    if isinstance(node, dict):
        for k, v in node.items():
            out += numeric_leaves(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(node, list) and node and all(isinstance(v, dict) for v in node):
        for i, v in enumerate(node):
            out += numeric_leaves(v, f"{prefix}[{i}]")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        out.append(prefix)
    return out


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for these characters
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _inline(v: Any) -> bool:
    """A small table written inline (``{ a = 1, b = [2, 3] }``): no nested tables in it."""
    return isinstance(v, dict) and all(
        not isinstance(x, dict) and not (isinstance(x, list) and any(isinstance(y, dict) for y in x))
        for x in v.values())


def toml_dumps(data: dict, header: str = "") -> str:
    """TOML text of a config document (tables, inline tables, arrays; what ``tomllib`` read).

    Examples
    --------
    >>> import tomllib
    >>> doc = {"name": "x", "fiber": {"radius_um": 10.0, "dye": {"bands": [{"center_nm": 520}]}}}
    >>> tomllib.loads(toml_dumps(doc)) == doc
    True
    """
    lines = [header.rstrip()] if header else []

    def table(node: dict, name: str) -> None:
        # top-level tables are [sections]; inside a section small tables are written inline
        scalars = [(k, v) for k, v in node.items() if not isinstance(v, dict) or (name and _inline(v))]
        subs = [(k, v) for k, v in node.items() if isinstance(v, dict) and not (name and _inline(v))]
        if name and (scalars or not subs):
            lines.append("")
            lines.append(f"[{name}]")
        for k, v in scalars:
            lines.append(f"{k} = {_toml_value(v)}")
        for k, v in subs:
            table(v, f"{name}.{k}" if name else k)

    table(data, "")
    return "\n".join(lines).lstrip("\n") + "\n"


def population_path(name: str, data: dict) -> str | None:
    """``populations.NAME.REST`` as the indexed path ``populations[k].REST``; None for another name.

    ``k`` is the population named ``NAME`` in the document ``data``. ``REST`` is one of
    :data:`POPULATION_FIELDS` (``dye`` and ``dye-peaks`` become ``populations[k].fiber.dye``, which
    :func:`expand` expands, ``dye_depth_um`` ``populations[k].fiber.dye_depth_um``) or a path inside the
    population's table.

    >>> population_path("populations.yellow.share", {"populations": [{"name": "blue"}, {"name": "yellow"}]})
    'populations[1].share'
    """
    m = _POPULATION.match(name)
    if not m:
        return None
    who, rest = m.group(1), m.group(2)
    pops = data.get("populations")
    if not isinstance(pops, list) or not pops:
        raise PathError(f"{name}: the config has no [[populations]] (one fiber): free its dye with dye, "
                        "or declare the populations of a blend")
    names = [str(p.get("name", f"population {k + 1}")) if isinstance(p, dict) else "" for k, p in enumerate(pops)]
    if who not in names:
        listed = ", ".join(repr(n) for n in names)
        raise PathError(f"{name}: the config has no population named {who!r} (populations: {listed}; a population "
                        "without a name of letters, digits, _ and - is named populations[INDEX], from 0)")
    k = names.index(who)
    if rest in ("dye", "dye-peaks"):
        return f"populations[{k}].fiber.{'dye' if rest == 'dye' else 'dye-peaks'}"
    if rest == "dye_depth_um":
        return f"populations[{k}].fiber.dye_depth_um"
    return f"populations[{k}].{rest}"


_INDEXED_DYE = re.compile(r"^populations\[(\d+)\]\.fiber\.(dye|dye-peaks)$")


def expand(alias: str, data: dict) -> list[str]:
    """The paths an alias stands for in the document ``data`` (a plain path: itself).

    A population's name (``populations.NAME....``, :func:`population_path`) is replaced by its index first; its
    ``dye`` expands as the config's ``dye`` does, in the population's own ``[populations.fiber.dye]``.
    """
    indexed = population_path(alias, data)
    if indexed is not None:
        alias = indexed
    m = _INDEXED_DYE.match(alias)
    if m:
        k = int(m.group(1))
        pops = data.get("populations") or []
        pop = pops[k] if k < len(pops) and isinstance(pops[k], dict) else {}
        dye = (pop.get("fiber") or {}).get("dye")
        label = str(pop.get("name", f"populations[{k}]"))
        if dye is None:
            raise PathError(f"{alias}: population {label!r} has no dye of its own (it takes [fiber.dye]); give it "
                            "one in [populations.fiber.dye], or fit with --dye knots, which gives each population "
                            "its own knots")
        return _dye_paths(m.group(2), dye, f"populations[{k}].fiber.dye")
    if alias == "volume_fraction":
        return ["particles.volume_fraction"]
    if alias == "rms_slope":
        return ["surface.rms_slope"]
    if alias == "radius":
        p = data.get("particles", {})
        return ["particles.radius_um" if "radius_um" in p else "particles.size.median_radius_um"]
    if alias in ("dye", "dye-peaks"):
        return _dye_paths(alias, data.get("fiber", {}).get("dye"), "fiber.dye")
    return [alias]


def _dye_paths(alias: str, dye: Any, prefix: str) -> list[str]:
    """The free paths of the dye table ``dye`` at ``prefix``.

    ``dye``: every coefficient; ``dye-peaks``: the ``*_per_um`` ones; a ``knots`` dye: its knot values.
    """
    if not isinstance(dye, dict) or "curve" not in dye:
        raise PathError(f"{alias}: the dye {prefix} is "
                        f"{'absent' if dye is None else 'a table'}; a fit frees the coefficients of a "
                        f"named smooth curve ({prefix}.curve = gaussian-bands, logistic-edge or knots; "
                        "--dye knots makes one)")
    if dye["curve"] == "knots":  # the knots' values (their wavelengths stay put)
        return [f"{prefix}.log10_per_um[{k}]" for k in range(len(dye.get("log10_per_um", [])))]
    names = numeric_leaves(dye, prefix)
    if alias == "dye-peaks":
        names = [n for n in names if n.endswith("_per_um")]
    return names
