"""Where does thermal start to pay? Full against RGB-only as a function of the smoke's optical
depth (issue 49), from the density sweep's finished runs.

    python benchmarks/density_sweep.py [--datasets data/density_sweep] [--tables data/tables_density]
                                       [--digest PREFIX] [--out benchmarks/results/density_sweep]

Reads DATASETS/kK/SCENE (made by benchmarks/density_sweep_generate.sh) for each density's
optical depth and smoky input, and TABLES_kK/runs (made by benchmarks/density_sweep_train.sh)
for the runs of Full and RGB-only, one trainer version at every k (the digest given, else
today's trainer: k = 1's runs are Table 1's, whose folder also keeps older versions' runs).
Writes to OUT:

- sweep.csv: per scene and k, the mean optical depth −ln(1 − ᾱ) of the RGB smoke in the test
  views, each method's test PSNR (mean of views), pooled PSNR (of the views' mean squared error),
  SSIM and LPIPS, mean ± std over seeds, and Full's lead paired by seed (Full − RGB-only;
  RGB-only − Full for LPIPS, where lower is better);
- results.md: sweep.csv's test PSNR and LPIPS as markdown tables (eval.density_sweep.results_table, lpips_table);
- crossover.csv: per scene and metric, the optical depth where Full's lead turns positive;
- lead.png: the lead against optical depth, one line per scene, a panel per metric;
- strip.png: one test view per scene across k: smoky input, RGB-only, Full (seed 0), clean;
- claims.csv, claims.md: the sweep's must-holds checked on sweep.csv (eval.density_sweep.sweep_checks).
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import NullLocator  # noqa: E402
import numpy as np  # noqa: E402

from contracts.atomic import write_rows_csv, write_text  # noqa: E402
from contracts.imageio import read_png  # noqa: E402
from contracts.metrics import psnr  # noqa: E402
from contracts.source import code_digest  # noqa: E402
from eval.claims import ClaimCheck, claims_table  # noqa: E402
from eval.density_sweep import (crossover, frames_of_test_views, mean_optical_depth, paired_lead,  # noqa: E402
                                lpips_table, results_table, stems_of_test_views, sweep_checks)
from eval.finished_runs import finished_runs  # noqa: E402
from eval.harness import TRAINER_ENTRY  # noqa: E402
from eval.per_view import pooled_over_views  # noqa: E402
from eval.regions import write_split_files  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
METHODS = ("full", "rgb-only")
METRICS = {"psnr": "test PSNR, mean of views (dB)", "pooled_psnr": "test PSNR pooled over views (dB)",
           "ssim": "test SSIM", "lpips": "test LPIPS, mean of views"}
LOWER_IS_BETTER = frozenset({"lpips"})
"""Metrics whose lead is RGB-only − Full, so that a positive lead is Full's advantage in every metric."""


def lead_label(metric: str) -> str:
    return "RGB-only − Full" if metric in LOWER_IS_BETTER else "Full − RGB-only"


def density_folders(parent: Path, prefix: str = "") -> dict[float, Path]:
    """{k: PARENT/{prefix}kK} for every such folder, in order of k."""
    found = {}
    for p in parent.glob(f"{prefix}k*"):
        m = re.fullmatch(re.escape(prefix) + r"k(\d+(?:\.\d+)?)", p.name)
        if m and p.is_dir():
            found[float(m.group(1))] = p
    return dict(sorted(found.items()))


def _table_folders(tables: Path) -> dict[float, Path]:
    """The tables folders TABLES_kK (one regenerate-tables --out per density)."""
    return density_folders(tables.parent, f"{tables.name}_")


def scene_density(dataset: Path) -> dict[str, Any]:
    """The test views' mean RGB optical depth and the smoky input's PSNR (mean of views)."""
    views = list(frames_of_test_views(dataset))
    alphas = [alpha for _, _, alpha in views]
    psnrs = [psnr(smoky, clean) for smoky, clean, _ in views]
    return {"optical_depth": mean_optical_depth(alphas), "input_psnr": float(np.mean(psnrs)),
            "input_pooled_psnr": pooled_over_views(psnrs)}


Scores = dict[tuple[str, str], dict[int, dict[str, Any]]]
"""{(scene, method): {seed: {metric: value, "run": folder}}} of one density's finished runs."""


def run_scores(tables: Path, digest: str) -> Scores:
    """The scores of one density's finished runs of Full and RGB-only."""
    try:
        _, runs = finished_runs(tables, METHODS, digest)
    except ValueError:  # nothing finished at this density yet
        return {}
    out: Scores = {}
    for run_dir, rec in runs:
        metrics = json.loads((run_dir / "metrics.json").read_text())
        views = [e["psnr"] for e in metrics["per_image"]]
        out.setdefault((rec["scene"], rec["variant"]), {})[int(rec["seed"])] = {
            "psnr": metrics["metrics"]["psnr"], "ssim": metrics["metrics"]["ssim"],
            "lpips": metrics["metrics"].get("lpips"),
            "pooled_psnr": pooled_over_views(views), "run": run_dir}
    return out


def _mean_std(values: list[float]) -> tuple[float, float | None]:
    a = np.asarray(values, dtype=float)
    return float(a.mean()), (float(a.std(ddof=1)) if a.size > 1 else None)


def score_columns(scores: Scores, scene: str) -> dict[str, Any]:
    """Both methods' scores on one dataset, mean ± std over seeds, and Full's lead paired by seed
    (``lead_label``). A metric that some seed's run lacks (LPIPS of a run scored without weights)
    gets no mean and no lead: one over the other seeds would sit beside the PSNR of all of them."""
    def by_seed(method: str, metric: str) -> dict[int, float] | None:
        values = {s: v[metric] for s, v in scores.get((scene, method), {}).items()}
        return None if any(v is None for v in values.values()) else values

    row: dict[str, Any] = {}
    for method in METHODS:
        row[f"{method}_seeds"] = " ".join(str(s) for s in sorted(scores.get((scene, method), {})))
        for metric in METRICS:
            values = by_seed(method, metric)
            mean, std = _mean_std(list(values.values())) if values else (None, None)
            row[f"{method}_{metric}"], row[f"{method}_{metric}_std"] = mean, std
    for metric in METRICS:
        full, rgb_only = by_seed("full", metric), by_seed("rgb-only", metric)
        lead = None if full is None or rgb_only is None else \
            paired_lead(rgb_only, full) if metric in LOWER_IS_BETTER else paired_lead(full, rgb_only)
        row[f"lead_{metric}"] = lead.mean if lead else None
        row[f"lead_{metric}_std"] = lead.std if lead else None
    return row


def sweep_rows(dens: dict[float, Path], scores_by_k: dict[float, Scores]) -> list[dict[str, Any]]:
    """One row per finished dataset: its density and both methods' scores at it."""
    rows = []
    for k, folder in dens.items():
        for dataset in sorted(p for p in folder.iterdir() if (p / "dataset.json").is_file()):
            rows.append({"scene": dataset.name, "k": k, **scene_density(dataset),
                         **score_columns(scores_by_k[k], dataset.name)})
    return rows


def crossover_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for scene in sorted({r["scene"] for r in rows}):
        for metric in METRICS:
            pts = [r for r in rows if r["scene"] == scene and r[f"lead_{metric}"] is not None]
            if not pts:
                continue
            at, how = crossover([r["optical_depth"] for r in pts], [r[f"lead_{metric}"] for r in pts])
            out.append({"scene": scene, "metric": metric, "densities": len(pts), "crossover_optical_depth": at,
                        "finding": how})
    return out


def plot_lead(rows: list[dict[str, Any]], path: Path) -> None:
    fig, axes = plt.subplots(1, len(METRICS), figsize=(5 * len(METRICS), 4.2))
    max_depth = max((r["optical_depth"] for r in rows), default=0.0)
    for ax, (metric, label) in zip(axes, METRICS.items()):
        for scene in sorted({r["scene"] for r in rows}):
            pts = sorted((r for r in rows if r["scene"] == scene and r[f"lead_{metric}"] is not None),
                         key=lambda r: r["optical_depth"])
            if pts:
                ax.errorbar([r["optical_depth"] for r in pts], [r[f"lead_{metric}"] for r in pts],
                            yerr=[r[f"lead_{metric}_std"] or 0.0 for r in pts], marker="o", capsize=3, label=scene)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xscale("symlog", linthresh=0.05)
        ticks = [t for t in (0, 0.1, 0.2, 0.5, 1, 2, 5) if t <= 1.5 * max_depth]
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])  # plain numbers: symlog's own labels put −10⁻² at 0
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xlim(-0.01, max(1.3 * max_depth, 0.1))  # room for the densest point
        ax.set_xlabel("mean optical depth of the RGB smoke, test views")
        ax.set_ylabel(f"{lead_label(metric)}, {label}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Full (RGB + thermal) against RGB-only across smoke density (mean ± std over seeds; "
                 "above 0: Full ahead)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_strip(rows: list[dict[str, Any]], dens: dict[float, Path], scores_by_k: dict[float, Scores],
               path: Path) -> None:
    """Per scene, its first test view at every k: smoky input, RGB-only, Full (seed 0), clean."""
    scenes = sorted({r["scene"] for r in rows})
    ks = list(dens)
    fig, axes = plt.subplots(4 * len(scenes), len(ks), figsize=(2.2 * len(ks), 1.7 * 4 * len(scenes)), squeeze=False)
    for si, scene in enumerate(scenes):
        for ki, k in enumerate(ks):
            dataset, scores = dens[k] / scene, scores_by_k[k]
            images: list[np.ndarray | None] = [None] * 4
            if (dataset / "dataset.json").is_file():
                stem = stems_of_test_views(dataset)[0]
                images[0] = read_png(dataset / "rgb" / "smoky" / f"{stem}.png")
                images[3] = read_png(dataset / "rgb" / "clean" / f"{stem}.png")
                for j, method in ((1, "rgb-only"), (2, "full")):
                    run = scores.get((scene, method), {}).get(0)
                    if run is not None:
                        images[j] = read_png(run["run"] / "renders" / "surface" / f"{stem}.png")
            for j, (img, what) in enumerate(zip(images, ("smoky input", "RGB-only", "Full", "clean"))):
                ax = axes[4 * si + j, ki]
                ax.set_xticks([])
                ax.set_yticks([])
                if img is not None:
                    ax.imshow(img)
                if ki == 0:
                    ax.set_ylabel(f"{scene}\n{what}", fontsize=7)
                if si == 0 and j == 0:
                    ax.set_title(f"k = {k:g}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=Path, default=ROOT / "data" / "density_sweep")
    parser.add_argument("--tables", type=Path, default=ROOT / "data" / "tables_density")
    parser.add_argument("--digest", help="trainer digest prefix of the runs (default: today's trainer)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "density_sweep")
    args = parser.parse_args()
    dens, table_dirs = density_folders(args.datasets), _table_folders(args.tables)
    digest = args.digest or code_digest(TRAINER_ENTRY)
    scores_by_k = {k: run_scores(table_dirs[k], digest) if k in table_dirs else {} for k in dens}
    rows = sweep_rows(dens, scores_by_k)
    if not rows:
        raise SystemExit(f"density_sweep: no dataset under {args.datasets}/k*/ (run "
                         "benchmarks/density_sweep_generate.sh first)")
    args.out.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out / "sweep.csv", rows)
    write_text(args.out / "results.md", "\n".join([
        "# The density sweep's test PSNR, from sweep.csv", "",
        "dB, mean of each dataset's test views; mean ± std over the seeds named (RGB-only / Full where "
        "they differ). Full − RGB-only is paired by seed.", "", *results_table(rows), "",
        "## Test LPIPS", "",
        "LPIPS-AlexNet (lower is better), mean of each dataset's test views, the same seeds; where the runs' "
        "records were scored after training, from their 8-bit surface renders (benchmarks/rescore_lpips.py). "
        "RGB-only − Full is paired by seed: positive where Full is closer to the clean frames.", "",
        *lpips_table(rows)]) + "\n")
    cross = crossover_rows(rows)
    if cross:
        write_rows_csv(args.out / "crossover.csv", cross)
    plot_lead(rows, args.out / "lead.png")
    plot_strip(rows, dens, scores_by_k, args.out / "strip.png")
    checks = sweep_checks(rows)
    summary = "\n".join(["# The density sweep's must-holds, checked on sweep.csv", "",
                         "Test PSNR (dB), each scene's mean over the seeds named (Full / RGB-only).", "",
                         *claims_table(checks)]) + "\n"
    write_split_files(args.out, "claims", ClaimCheck, checks, summary, [])
    for r in rows:
        lead = r["lead_psnr"]
        print(f"{r['scene']:<11} k {r['k']:<5g} optical depth {r['optical_depth']:.3f}  input {r['input_psnr']:.2f} dB  "
              f"Full − RGB-only {'n/a' if lead is None else format(lead, '+.2f')}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
