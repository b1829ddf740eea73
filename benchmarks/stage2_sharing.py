"""What one Stage 2 per geometry saves across a table, measured on its finished runs.

    python benchmarks/stage2_sharing.py [--tables data/tables_standard] [--digest PREFIX]

A run whose Stage-2 settings agree with another run of the same scene, seed and dataset
(``eval/shared_stage2.py``) can take that run's finished Stage-2 checkpoint instead of training
its own. For the finished runs of one trainer version (``--digest``, default: the version with
the most runs) this reads each run's ``harness.json`` and ``train_log.csv`` and counts:

- **taken**: Stage-2 seconds a run did not train because it took a donor's (its log holds the
  donor's Stage-2 rows, so their last ``wall_s`` is what was saved);
- **trained twice**: Stage-2 seconds a run spent on a Stage 2 that a run of the same group
  also trained (every group member after the first that trained its own, whichever finished
  first);
- the table's total training seconds, so both are read as shares.

Groups are formed with the trainer's own key (``TrainConfig.stage2_sha256`` of the run's
variant), so the count follows whatever the trainer says Stage 2 depends on. Writes
``benchmarks/results/stage2_sharing.csv`` (one row per run) and prints the summary.
"""
from __future__ import annotations

import argparse
import collections
from dataclasses import asdict, dataclass
from pathlib import Path

from contracts.atomic import write_rows_csv
from contracts.train_log import read_train_log
from eval.finished_runs import finished_runs
from eval.runs import VARIANTS
from smokeseer.config import make_config

RESULTS = Path(__file__).resolve().parent / "results"


@dataclass
class RunRow:
    scene: str
    variant: str
    seed: int
    wall_s: float
    stage2_s: float
    took_stage2: bool
    group: str
    trained_twice: bool


def stage2_seconds(run_dir: Path) -> float:
    """The last Stage-2 row's ``wall_s``: Stage 2's length, whoever trained it."""
    rows = [r for r in read_train_log(run_dir / "train_log.csv") if r["stage"] == "2"]
    return float(rows[-1]["wall_s"]) if rows else 0.0


def stage2_group(scene: str, variant: str, seed: int, profile: str) -> str:
    v = VARIANTS[variant]
    return f"{scene}/seed{seed}/" + make_config(v.mode, profile, seed, dict(v.overrides)).stage2_sha256()[:12]


def collect(tables: Path, digest: str | None, profile: str) -> tuple[str, list[RunRow]]:
    try:
        chosen, records = finished_runs(tables, VARIANTS, digest)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    rows, seen = [], set()
    for run_dir, rec in records:
        group = stage2_group(rec["scene"], rec["variant"], int(rec["seed"]), profile)
        took = bool(rec.get("stage2_from"))
        twice = not took and group in seen
        seen.add(group) if not took else None
        rows.append(RunRow(rec["scene"], rec["variant"], int(rec["seed"]), float(rec["wall_time_s"]),
                           stage2_seconds(run_dir), took, group, twice))
    return chosen, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    ap.add_argument("--digest", default=None, help="prefix of the trainer's code digest (default: most runs)")
    ap.add_argument("--profile", default="standard")
    args = ap.parse_args()
    digest, rows = collect(args.tables, args.digest, args.profile)
    total = sum(r.wall_s for r in rows)
    taken = sum(r.stage2_s for r in rows if r.took_stage2)
    twice = sum(r.stage2_s for r in rows if r.trained_twice)
    shared_groups = collections.Counter(r.group for r in rows)
    write_rows_csv(RESULTS / "stage2_sharing.csv", [asdict(r) for r in rows])
    print(f"trainer {digest[:8]}: {len(rows)} finished runs, {total / 3600:.1f} h of training "
          f"(wall time as each run logged it, donors' Stage 2 counted in the takers' own)")
    print(f"groups with one Stage 2 for several runs: {sum(n > 1 for n in shared_groups.values())}; "
          f"runs that could share: {sum(n - 1 for n in shared_groups.values())}")
    print(f"taken from a donor: {sum(r.took_stage2 for r in rows)} runs, {taken / 3600:.2f} h not trained")
    print(f"trained twice: {sum(r.trained_twice for r in rows)} runs, {twice / 3600:.2f} h "
          f"({100 * twice / total:.1f} % of the table's training)")
    by_variant = collections.defaultdict(list)
    for r in rows:
        by_variant[r.variant].append(r)
    for variant, runs in sorted(by_variant.items()):
        n = len(runs)
        print(f"  {variant:16s} {n:3d} runs, wall mean {sum(r.wall_s for r in runs) / n:6.0f} s, "
              f"Stage 2 mean {sum(r.stage2_s for r in runs) / n:6.0f} s")


if __name__ == "__main__":
    main()
