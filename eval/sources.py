"""A fingerprint of a task's source files that, unlike its code digest, does not depend on the
Python version.

Why: the cache key holds ``contracts.source.code_digest``, which reads each module's syntax tree
through ``ast.dump``, whose text differs between Python versions; a run trained on another
machine under another Python therefore lands under another key. Recording this fingerprint
beside the run lets ``eval/adopt.py`` show that such a run was made from this checkout's code.
"""
from __future__ import annotations

import hashlib

from contracts.source import PROJECT_ROOT, module_closure, package_data


def sources_sha256(*entries: str) -> str:
    """SHA-256 of the raw bytes of the files the code digest of ``entries`` reads (the closure's
    modules and their packages' data files, by name). Stricter than the digest: a comment counts."""
    h = hashlib.sha256()
    for module in module_closure(*entries):
        h.update(f"{module.name}\0".encode() + module.path.read_bytes() + b"\0")
        if module.is_package:
            for f in package_data(module):
                h.update(f"{f.relative_to(PROJECT_ROOT).as_posix()}\0".encode() + f.read_bytes() + b"\0")
    return h.hexdigest()
