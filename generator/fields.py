"""Typed readers for YAML mappings that fail with the file and the dotted field name."""
from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, Callable, Sequence

from generator.errors import SpecError

_MISSING = object()
#: The default of a spec field that the YAML must give.
REQUIRED = _MISSING


class Fields:
    """A view of one YAML mapping at `prefix` inside `source`, for typed, checked reads.

    Every key read is remembered so that `finish()` can reject unknown keys: a typo in a
    spec must be an error, not a silently ignored setting.
    """

    def __init__(self, data: Any, source: str, prefix: str = "") -> None:
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise SpecError(source, prefix or "(top level)", f"must be a mapping, got {type(data).__name__}")
        self.data = data
        self.source = source
        self.prefix = prefix
        self._read: set[str] = set()

    def path(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str, message: str) -> SpecError:
        return SpecError(self.source, self.path(key), message)

    def raw(self, key: str, default: Any) -> Any:
        self._read.add(key)
        if key in self.data and self.data[key] is not None:
            return self.data[key]
        if default is _MISSING:
            raise self.error(key, "is required")
        return default

    def has(self, key: str) -> bool:
        return key in self.data and self.data[key] is not None

    def sub(self, key: str, required: bool = False) -> "Fields":
        value = self.raw(key, _MISSING if required else {})
        return Fields(value, self.source, self.path(key))

    def sub_list(self, key: str) -> list["Fields"]:
        value = self.raw(key, [])
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, got {type(value).__name__}")
        return [Fields(item, self.source, f"{self.path(key)}[{i}]") for i, item in enumerate(value)]

    def sub_map(self, key: str) -> dict[str, "Fields"]:
        value = self.raw(key, {})
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping, got {type(value).__name__}")
        return {str(name): Fields(item, self.source, f"{self.path(key)}.{name}") for name, item in value.items()}

    def string(self, key: str, default: Any = _MISSING, choices: Sequence[str] | None = None) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a non-empty string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}; got {value!r}")
        return value

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def number(self, key: str, default: Any = _MISSING, minimum: float | None = None,
               maximum: float | None = None, exclusive_minimum: bool = False) -> float:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value!r}")
        _check_range(self, key, float(value), minimum, maximum, exclusive_minimum)
        return float(value)

    def integer(self, key: str, default: Any = _MISSING, minimum: int | None = None,
                maximum: int | None = None) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {value!r}")
        _check_range(self, key, float(value), minimum, maximum, False)
        return int(value)

    def vector(self, key: str, length: int, default: Any = _MISSING, minimum: float | None = None,
               maximum: float | None = None) -> tuple[float, ...]:
        value = self.raw(key, default)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise self.error(key, f"must be a list of {length} numbers, got {value!r}")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item):
                raise self.error(key, f"must hold finite numbers, got {value!r}")
            _check_range(self, key, float(item), minimum, maximum, False)
            out.append(float(item))
        return tuple(out)

    def mapping(self, key: str) -> dict[str, Any]:
        value = self.raw(key, {})
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping, got {type(value).__name__}")
        return dict(value)

    def finish(self) -> None:
        unknown = sorted(set(map(str, self.data)) - self._read)
        if unknown:
            raise self.error(unknown[0], "unknown key (check the spelling against docs/scene-spec.md)")


def _check_range(fields: Fields, key: str, value: float, minimum: float | None, maximum: float | None,
                 exclusive_minimum: bool) -> None:
    if minimum is not None and (value <= minimum if exclusive_minimum else value < minimum):
        bound = "greater than" if exclusive_minimum else "at least"
        raise fields.error(key, f"must be {bound} {minimum:g}, got {value:g}")
    if maximum is not None and value > maximum:
        raise fields.error(key, f"must be at most {maximum:g}, got {value:g}")


def spec_field(default: Any, *, minimum: float | None = None, maximum: float | None = None,
               exclusive_minimum: bool = False, choices: Sequence[str] | None = None, key: str | None = None) -> Any:
    """A spec dataclass field whose metadata says how `read_fields` reads and checks it: the
    default (REQUIRED for none), the range or choices, and the YAML key when it differs."""
    metadata = {"spec": True, "minimum": minimum, "maximum": maximum, "exclusive_minimum": exclusive_minimum,
                "choices": tuple(choices) if choices is not None else None, "key": key}
    if default is REQUIRED:
        return dataclasses.field(metadata=metadata)
    if isinstance(default, dict):
        return dataclasses.field(default_factory=dict, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def read_fields(cls: type, f: Fields, defaults: Any = None, skip: Sequence[str] = (),
                nested: Callable[..., Any] | None = None) -> dict[str, Any]:
    """Read every metadata-carrying field of dataclass `cls` from `f`, typed by its annotation:
    int, float (or float | None), str, bool, a tuple of floats, a mapping, or (through `nested`) another spec
    dataclass. Defaults come from `defaults` (an instance) when given, else from the field."""
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for fld in dataclasses.fields(cls):
        if fld.name in skip or not fld.metadata.get("spec"):
            continue
        meta, kind = fld.metadata, hints[fld.name]
        key = meta["key"] or fld.name
        if defaults is not None:
            default = getattr(defaults, fld.name)
        elif fld.default is not dataclasses.MISSING:
            default = fld.default
        else:
            default = _MISSING
        bounds = (meta["minimum"], meta["maximum"])
        if dataclasses.is_dataclass(kind):
            if nested is None:
                raise TypeError(f"{cls.__name__}.{fld.name}: a nested section needs a reader")
            out[fld.name] = nested(kind, f.sub(key), default if default is not _MISSING else None)
        elif kind is bool:
            out[fld.name] = f.boolean(key, default)
        elif kind is int:
            out[fld.name] = f.integer(key, default, *bounds)
        elif kind is float:
            out[fld.name] = f.number(key, default, *bounds, exclusive_minimum=meta["exclusive_minimum"])
        elif kind == float | None:  # optional: absent or null means None
            out[fld.name] = None if f.raw(key, None) is None else f.number(
                key, default, *bounds, exclusive_minimum=meta["exclusive_minimum"])
        elif kind is str:
            out[fld.name] = f.string(key, default, meta["choices"])
        elif typing.get_origin(kind) is tuple:
            out[fld.name] = f.vector(key, len(typing.get_args(kind)), default, *bounds)
        elif typing.get_origin(kind) is dict:
            out[fld.name] = f.mapping(key)
        else:
            raise TypeError(f"{cls.__name__}.{fld.name}: no reader for {kind!r}")
    return out
