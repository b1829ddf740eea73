"""One builder for a valid metrics.json, for tests that need a finished or failed run folder
without training (the real producer is smokeseer.api; this follows docs/results-format.md)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from contracts.results_format import METRIC_KEYS, PROVENANCE_KEYS, RESULTS_FORMAT, RESULTS_FORMAT_VERSION


def write_metrics(folder: Path, *, scene: str, method: str, profile: str, seed: int, status: str = "ok",
                  metrics: dict[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    """Write folder/metrics.json; metric keys left out are null, a failed run gets an error."""
    doc: dict[str, Any] = {
        "format": RESULTS_FORMAT, "format_version": RESULTS_FORMAT_VERSION, "scene": scene,
        "dataset": f"data/{profile}/{scene}", "method": method, "profile": profile, "seed": seed,
        "status": status, "provenance": {key: None for key in PROVENANCE_KEYS},
        "wall_time_s": {"total": 1.0}, "versions": {}, "config_sha256": "0" * 64}
    if status == "ok":
        doc["metrics"] = {**{key: None for key in METRIC_KEYS}, "lpips_status": "skipped", **(metrics or {})}
    else:
        doc["error"] = "diverged"
    doc.update(extra)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "metrics.json").write_text(json.dumps(doc))
    return doc
