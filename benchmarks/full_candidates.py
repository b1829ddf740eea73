"""Validation PSNR of candidate Full trainers (issue: thermal that never costs), beside the
standard Full with the floor read off the images and the committed RGB-only runs.

    python benchmarks/full_candidates.py NAME LABEL=RUN_DIR ... [--tables data/tables_standard] [--add] [--take TABLE:LABEL]

Each RUN_DIR is a finished ``train-and-evaluate DATASET --profile standard --seed S`` run; LABEL
names its trainer (``estimated-floor`` for today's standard Full, or the candidate). For every
scene and seed given, the committed RGB-only run of the same seed (trainer 6663d970) is added.
Writes ``benchmarks/results/full_candidates/NAME.csv`` (every logged validation PSNR: the curves),
``NAME_final.csv`` (last and best validation, test PSNR reported but never used to choose,
counts, wall time, and the Stage-2 and Stage-3 seconds: a run that took a finished Stage 2
of the same key from another run's checkpoint shows its Stage 2 as about 0 s) and
``NAME.png``. Choices read the validation columns only. ``--add`` keeps the rows already in
``NAME.csv`` and ``NAME_final.csv`` of every (scene, seed, trainer) the given runs do not replace,
so a table grows run by run without the folders of its earlier runs. ``--take TABLE:LABEL``
copies the rows of trainer LABEL from the table TABLE (another NAME here) for the scenes and
seeds this table holds, so a baseline trained once serves every comparison.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any, Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from contracts.atomic import atomic_path, write_rows_csv  # noqa: E402
from contracts.train_log import read_train_log  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "full_candidates"
RGB_ONLY_TRAINER = "6663d970"
RGB_ONLY_LABEL = f"rgb-only ({RGB_ONLY_TRAINER}, true-alpha floor)"


def read_run(label: str, run: Path) -> tuple[dict, list[dict]]:
    """The run's summary and its validation curve (Stage 3 iterations)."""
    doc = json.loads((run / "metrics.json").read_text())
    if doc.get("status") != "ok":
        raise ValueError(f"{run / 'metrics.json'}: status: {doc.get('status')!r}, not a finished run")
    rows = [r for r in read_train_log(run / "train_log.csv") if r.get("val_psnr") and r["stage"] == "3"]
    if not rows:
        raise ValueError(f"{run / 'train_log.csv'}: val_psnr: no Stage-3 validation row")
    curve = [{"scene": doc["scene"], "seed": int(doc["seed"]), "trainer": label, "iteration": int(r["iteration"]),
              "wall_s": round(float(r["wall_s"]), 1), "val_psnr": round(float(r["val_psnr"]), 3)} for r in rows]
    best = max(curve, key=lambda r: r["val_psnr"])
    summary = {"scene": doc["scene"], "seed": int(doc["seed"]), "trainer": label,
               "val_psnr": round(float(doc["validation"]["psnr"]), 3), "best_val_psnr": best["val_psnr"],
               "best_at": best["iteration"], "test_psnr": round(float(doc["metrics"]["psnr"]), 3),
               "surface": int(doc["stages"]["surface_gaussians"]), "smoke": int(doc["stages"]["smoke_gaussians"]),
               "wall_s": round(float(doc["wall_time_s"]["total"]), 1),
               "stage2_s": round(sum(float(doc["wall_time_s"].get(k, 0.0)) for k in ("stage2", "stage2_rgb")), 1),
               "stage3_s": round(float(doc["wall_time_s"]["stage3"]), 1),
               "digest": doc["provenance"]["source_digest"][:8], "run": run.name}
    return summary, curve


def committed_run(tables: Path, scene: str, method: str, seed: int, trainer: str) -> Path:
    """The table's finished run of ``method`` on ``scene`` at ``seed`` whose code digest starts with ``trainer``."""
    for run in sorted((tables / "runs" / scene / method).glob(f"seed{seed}-*")):
        doc = json.loads((run / "metrics.json").read_text())
        if doc.get("status") == "ok" and doc["provenance"]["source_digest"].startswith(trainer):
            return run
    raise ValueError(f"{tables / 'runs' / scene / method}: no finished seed-{seed} run of trainer {trainer}")


INT_COLUMNS = ("seed", "iteration", "best_at", "surface", "smoke")
FLOAT_COLUMNS = ("wall_s", "val_psnr", "best_val_psnr", "test_psnr", "stage2_s", "stage3_s")


def read_rows(path: Path) -> list[dict]:
    """A CSV this script wrote, its number columns parsed back, so kept rows sort and print as new ones do."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        row.update({k: int(v) for k, v in row.items() if k in INT_COLUMNS})
        row.update({k: float(v) for k, v in row.items() if k in FLOAT_COLUMNS and v != ""})  # "": not recorded
    return rows


def kept_rows(path: Path, replaced: set[tuple]) -> list[dict]:
    """The rows of ``path`` whose (scene, seed, trainer) is not in ``replaced``."""
    return [r for r in read_rows(path) if (r["scene"], r["seed"], r["trainer"]) not in replaced]


def save_panels(path: Path, titles: list[str], draw: Callable[[Any, int], None], xlabel: str, ylabel: str) -> None:
    """One panel per title, side by side, each drawn by ``draw(axes, index)``, with a grid, and one
    legend for all of them below (trainer labels can be long settings); written atomically as a PNG."""
    fig, axes = plt.subplots(1, len(titles), figsize=(4 * len(titles), 3.6), squeeze=False)
    entries: dict[str, Any] = {}
    for i, (ax, title) in enumerate(zip(axes[0], titles)):
        draw(ax, i)
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    axes[0][0].set_ylabel(ylabel)
    legend_in = 0.2 * len(entries) + 0.2
    fig.set_size_inches(fig.get_figwidth(), 3.6 + legend_in)
    fig.legend(list(entries.values()), list(entries), loc="lower left", fontsize=7, frameon=False)
    fig.tight_layout(rect=(0.0, legend_in / (3.6 + legend_in), 1.0, 1.0))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def plot(curves: list[dict], path: Path) -> None:
    scenes = list(dict.fromkeys((c["scene"], c["seed"]) for c in curves))
    labels = list(dict.fromkeys(c["trainer"] for c in curves))

    def draw(ax: Any, i: int) -> None:
        for k, label in enumerate(labels):  # one colour per trainer in every panel
            pts = [c for c in curves if (c["scene"], c["seed"], c["trainer"]) == (*scenes[i], label)]
            if pts:
                ax.plot([p["iteration"] for p in pts], [p["val_psnr"] for p in pts], "-o", ms=3, label=label,
                        color=f"C{k % 10}")
    save_panels(path, [f"{scene}, seed {seed}" for scene, seed in scenes], draw, "Stage-3 iteration",
                "validation PSNR (dB)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("name")
    p.add_argument("runs", nargs="+", help="LABEL=RUN_DIR (split at the last =)")
    p.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    p.add_argument("--add", action="store_true", help="keep the existing rows the given runs do not replace")
    p.add_argument("--take", action="append", default=[], metavar="TABLE:LABEL",
                   help="copy trainer LABEL's rows of these scenes and seeds from table TABLE")
    args = p.parse_args(argv)
    summaries, curves = [], []
    try:
        given = []
        for item in args.runs:
            label, sep, run = item.rpartition("=")  # a label may hold "=" (settings); the folder not
            if not sep or not label or not run:
                raise ValueError(f"{item}: give LABEL=RUN_DIR")
            given.append((label, Path(run)))
        for label, run in given:
            s, c = read_run(label, run)
            summaries.append(s)
            curves += c
        for scene, seed in dict.fromkeys((s["scene"], s["seed"]) for s in list(summaries)):
            s, c = read_run(RGB_ONLY_LABEL, committed_run(args.tables, scene, "rgb-only", seed, RGB_ONLY_TRAINER))
            summaries.append(s)
            curves += c
        if args.add:
            replaced = {(s["scene"], s["seed"], s["trainer"]) for s in summaries}
            summaries += kept_rows(OUT / f"{args.name}_final.csv", replaced)
            curves += kept_rows(OUT / f"{args.name}.csv", replaced)
        pairs = {(s["scene"], s["seed"]) for s in summaries}
        for item in args.take:
            table, sep, label = item.partition(":")
            if not sep or not table or not label:
                raise ValueError(f"--take {item}: give TABLE:LABEL")
            have = {(s["scene"], s["seed"], s["trainer"]) for s in summaries}
            taken = [r for r in read_rows(OUT / f"{table}_final.csv")
                     if r["trainer"] == label and (r["scene"], r["seed"]) in pairs and (r["scene"], r["seed"], label) not in have]
            keys = {(r["scene"], r["seed"], label) for r in taken}
            summaries += taken
            curves += [r for r in read_rows(OUT / f"{table}.csv") if (r["scene"], r["seed"], r["trainer"]) in keys]
    except (OSError, ValueError, KeyError) as exc:
        print(f"full_candidates: error: {exc}", file=sys.stderr)
        return 2
    summaries.sort(key=lambda s: (s["scene"], s["seed"], s["trainer"]))
    curves.sort(key=lambda c: (c["scene"], c["seed"], c["trainer"], c["iteration"]))
    OUT.mkdir(parents=True, exist_ok=True)
    write_rows_csv(OUT / f"{args.name}.csv", curves)
    columns = list(dict.fromkeys(k for row in summaries for k in row))  # tables written before a column existed lack it
    write_rows_csv(OUT / f"{args.name}_final.csv", [{k: row.get(k, "") for k in columns} for row in summaries])
    plot(curves, OUT / f"{args.name}.png")
    for s in summaries:
        print(f"{s['scene']} seed {s['seed']} {s['trainer']:>38}: validation {s['val_psnr']:.2f} dB "
              f"(best {s['best_val_psnr']:.2f} at {s['best_at']}), {s['wall_s'] / 60:.0f} min")
    print(f"wrote {OUT / args.name}.csv, _final.csv, .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
