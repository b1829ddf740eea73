"""User-facing errors: one line naming the file and the field, never a traceback."""
from __future__ import annotations

from pathlib import Path


class GeneratorError(Exception):
    """Base class of every error the `generate-scene` command reports as one clear line."""


class SpecError(GeneratorError):
    """A scene spec, preset, or manifest entry is malformed."""

    def __init__(self, source: str | Path, field: str, message: str) -> None:
        self.source = str(source)
        self.field = field
        self.message = message
        where = f"{self.source}: {field}" if field else self.source
        super().__init__(f"{where}: {message}")


class AssetError(GeneratorError):
    """An asset is missing, fails its checksum, or is not a usable mesh."""


class WorkerError(GeneratorError):
    """The Blender worker failed; the message carries its log path."""
