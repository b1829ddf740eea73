"""``--set KEY=VALUE`` items, read the same way by every command that takes them (the trainer,
the harness, and the scene sampler's pins)."""
from __future__ import annotations

from typing import Any

import yaml


def split_set_item(item: str, flag: str = "--set") -> tuple[str, str]:
    """``KEY=VALUE`` to its key and the raw value text; a missing ``=`` or key is one clear error."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise ValueError(f"{flag}: expected KEY=VALUE, got {item!r}")
    return key.strip(), value


def read_set_value(key: str, value: str, flag: str = "--set") -> Any:
    """A value read as YAML (``3``, ``1e-3``, ``true``, ``[0.0, 1.0]``)."""
    try:
        return yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise ValueError(f"{flag}: {key}: value {value!r} is not valid YAML ({exc.problem})") from None


def parse_set_items(items: list[str], flag: str = "--set") -> dict[str, Any]:
    """``KEY=VALUE`` strings to overrides, each value read as YAML."""
    out: dict[str, Any] = {}
    for item in items:
        key, value = split_set_item(item, flag)
        out[key] = read_set_value(key, value, flag)
    return out
