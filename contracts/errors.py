"""The error every reader of the dataset format raises."""
from __future__ import annotations


class DatasetError(ValueError):
    """A dataset or capture on disk does not follow docs/dataset-format.md; the message names
    the file and the field, so every command can print it as one line."""
