"""``python -m benchmarks.gpu_check.take_stage2 RUN DONOR MODE PROFILE SEED [KEY=VALUE ...]``: give
RUN the finished Stage-2 checkpoints of DONOR (eval.shared_stage2), the RGB Stage 2 too where the
donor trained one, so a second backend's Stage 3 starts from the very model the first one's did
and trains no Stage 2 of its own."""
from __future__ import annotations

import sys
from pathlib import Path

from eval.shared_stage2 import rgb_stage2_sha_of, stage2_sha_of, take_finished_stage2
from contracts.set_items import parse_set_items

if __name__ == "__main__":
    run, donor, mode, profile, seed, *items = sys.argv[1:]
    overrides = parse_set_items(items)
    sha, rgb_sha = stage2_sha_of(mode, profile, int(seed), overrides), rgb_stage2_sha_of(profile, int(seed), overrides)
    Path(run).mkdir(parents=True, exist_ok=True)
    if not take_finished_stage2(Path(run), [donor], sha, rgb_sha):
        print(f"take_stage2: error: {donor}: no finished Stage-2 checkpoint with these settings", file=sys.stderr)
        sys.exit(1)
