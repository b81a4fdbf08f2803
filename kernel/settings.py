"""Strict settings: frozen dataclasses built from TOML tables.

Every settings class in the project (the daemon's sections and each backend's section,
STYLE.md rule 2) is a frozen dataclass whose fields are declared with :func:`setting`.
:func:`build` turns a TOML table into one, rejecting unknown keys, wrong types and
out-of-range values with a :class:`ConfigError` naming ``section.key``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin

from kernel.errors import ConfigError

T = TypeVar("T")

# Integers a setting or request may hold: what SQLite and numpy's int64 keep.
MAX_INT = 2**63 - 1

# ROS 2 topic names: slash-separated tokens of letters, digits and '_', none starting with
# a digit (the part of rcl's validation that needs no substitution).
ROS2_TOPIC = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")

_MISSING = dataclasses.MISSING


def setting(
    default: Any = _MISSING,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    doc: str = "",
    default_factory: Any = _MISSING,
) -> Any:
    """A dataclass field with an optional numeric range and a one-line description."""
    meta = {"ge": ge, "gt": gt, "le": le, "lt": lt, "doc": doc}
    if default_factory is not _MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    if isinstance(default, list | dict):
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """A TOML file as a dict; ConfigError naming ``what`` and the file otherwise."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"cannot read {what} {p}: {e.strerror}") from e
    except UnicodeDecodeError as e:
        raise ConfigError(f"{what} {p} is not UTF-8 text: {e}") from e
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{p}: not valid TOML: {e}") from e


def build(cls: type[T], table: Mapping[str, Any] | None, section: str) -> T:
    """Build settings class ``cls`` from ``table``; ``section`` names it in errors."""
    table = {} if table is None else table
    if not isinstance(table, Mapping):
        raise ConfigError(f"[{section}] must be a table, got {type(table).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - set(fields))
    if unknown:
        known = ", ".join(sorted(fields))
        raise ConfigError(
            f"[{section}] unknown key {unknown[0]!r} (known keys: {known})"
        )
    values: dict[str, Any] = {}
    for name, field in fields.items():
        where = f"{section}.{name}"
        if name not in table:
            if field.default is _MISSING and field.default_factory is _MISSING:
                raise ConfigError(f"[{section}] missing required key {name!r}")
            continue
        value = _convert(hints[name], table[name], where)
        _check_range(field.metadata, value, where)
        values[name] = value
    try:
        obj = cls(**values)
    except (ValueError, TypeError) as e:  # __post_init__ cross-field checks
        raise ConfigError(f"[{section}] {e}") from e
    return obj


def as_dict(obj: Any) -> Any:
    """Settings back to plain TOML-able data (the effective configuration)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: as_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, list | tuple):
        return [as_dict(v) for v in obj]
    return obj


def _shown(value: Any) -> str:
    """A value as an error message shows it: a huge one cut short."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**60:
        return f"an integer of {len(str(abs(value)))} digits"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return build(tp, value, where)  # type: ignore[arg-type]
    if origin is Literal:
        choices = get_args(tp)
        if value not in choices:
            raise ConfigError(
                f"{where}: {_shown(value)} is not one of {', '.join(repr(c) for c in choices)}"
            )
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(errors[0] if len(errors) == 1
                          else f"{where}: {_shown(value)} fits no type")
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__} "
                              f"{_shown(value)}")
        args = get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
            items = [
                _convert(a, v, f"{where}[{i}]")
                for i, (a, v) in enumerate(zip(args, value, strict=True))
            ]
        else:
            item_tp = args[0] if args else Any
            items = [_convert(item_tp, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {_shown(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {type(value).__name__} "
                              f"{_shown(value)}")
        if not -MAX_INT <= value <= MAX_INT:
            raise ConfigError(f"{where}: {_shown(value)} is out of range (an integer within "
                              f"±{MAX_INT})")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {type(value).__name__} "
                              f"{_shown(value)}")
        try:
            number = float(value)
        except OverflowError:
            raise ConfigError(f"{where}: {_shown(value)} is out of range (too large for a "
                              "number)") from None
        if not math.isfinite(number):
            raise ConfigError(f"{where}: {number!r} is not a finite number")
        return number
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {type(value).__name__} "
                              f"{_shown(value)}")
        return value
    raise ConfigError(f"{where}: unsupported setting type {_type_name(tp)}")


def _check_range(meta: Mapping[str, Any], value: Any, where: str) -> None:
    numbers = value if isinstance(value, list | tuple) else [value]
    for v in numbers:
        if isinstance(v, bool) or not isinstance(v, int | float):
            continue
        if meta.get("ge") is not None and not v >= meta["ge"]:
            raise ConfigError(f"{where}: {v!r} is out of range (must be >= {meta['ge']})")
        if meta.get("gt") is not None and not v > meta["gt"]:
            raise ConfigError(f"{where}: {v!r} is out of range (must be > {meta['gt']})")
        if meta.get("le") is not None and not v <= meta["le"]:
            raise ConfigError(f"{where}: {v!r} is out of range (must be <= {meta['le']})")
        if meta.get("lt") is not None and not v < meta["lt"]:
            raise ConfigError(f"{where}: {v!r} is out of range (must be < {meta['lt']})")
