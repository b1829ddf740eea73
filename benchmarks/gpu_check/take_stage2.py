"""``python -m benchmarks.gpu_check.take_stage2 RUN DONOR MODE PROFILE SEED [KEY=VALUE ...]``: give
RUN the finished Stage-2 checkpoint of DONOR (eval.shared_stage2), so a second backend's Stage 3
starts from the very model the first one's did."""
from __future__ import annotations

import sys
from pathlib import Path

from eval.shared_stage2 import take_finished_stage2
from smokeseer.config import make_config, parse_set_items

if __name__ == "__main__":
    run, donor, mode, profile, seed, *items = sys.argv[1:]
    sha = make_config(mode, profile, int(seed), parse_set_items(items)).stage2_sha256()
    Path(run).mkdir(parents=True, exist_ok=True)
    if not take_finished_stage2(Path(run), [donor], sha):
        print(f"take_stage2: error: {donor}: no finished Stage-2 checkpoint with these settings", file=sys.stderr)
        sys.exit(1)
