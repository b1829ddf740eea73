"""``python -m benchmarks.gpu_check.train_run MEMORY_JSON -- TRAIN-AND-EVALUATE ARGS``: one
training run in this process, then the peak GPU memory torch allocated during it and the
rasterizer backend it used, written to MEMORY_JSON (also when the run is stopped by SIGTERM, as the
check's step timeout does)."""
from __future__ import annotations

import json
import signal
import sys
from pathlib import Path


def _stop(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def main(argv: list[str]) -> int:
    if len(argv) < 2 or argv[1] != "--":
        print("train_run: error: usage: train_run MEMORY_JSON -- TRAIN-AND-EVALUATE ARGS", file=sys.stderr)
        return 2
    memory_json = Path(argv[0])
    import torch

    from smokeseer.cli import main as train
    from smokeseer.raster import gsplat_available

    cuda = torch.cuda.is_available()
    record = {"backend": "gsplat" if cuda and gsplat_available() else "torch", "completed": False}
    signal.signal(signal.SIGTERM, _stop)
    try:
        rc = train(argv[2:])
        record["completed"] = rc == 0
        return rc
    finally:
        record["peak_memory_bytes"] = torch.cuda.max_memory_allocated() if cuda else None
        memory_json.write_text(json.dumps(record) + "\n")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
