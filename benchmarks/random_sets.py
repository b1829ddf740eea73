"""What a drawn set holds: one row per scene with its axes and generation time, a histogram of the axes
that matter for the method (how thick the smoke is, how warm the objects stand out, how much of the
view no training frame sees clear), and a contact sheet of every scene.

    python benchmarks/random_sets.py data/random_dev data/random_test [--out benchmarks/results/random_sets]

Reads each set's `benchmark.json` (written by `generate-benchmark --random`) and its datasets' frames.
Writes, per set NAME (the folder's name): NAME_scenes.csv, NAME_contact_sheet.png; and for all sets
together axes.png (histograms, one colour per set) and summary.md (the spans, the share of scenes at
RGB optical depth >= 1, the median generation time).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import atomic_path, write_rows_csv, write_text  # noqa: E402
from generator.contact_sheet import load_pass, pick_rows, thermal_panel, stretch  # noqa: E402

AXES = (("optical_depth_achieved", "RGB optical depth of the smoke (alpha-weighted, all frames)", True),
        ("contrast_k", "thermal contrast of the warm objects (K)", False),
        ("unrecoverable_share", "share of test-view pixels no training view sees clear", False))
TILE = (160, 120)


def scene_rows(set_dir: Path) -> list[dict[str, Any]]:
    """One flat row per scene of the set's benchmark.json, in seed order."""
    doc = json.loads((set_dir / "benchmark.json").read_text())
    if doc.get("kind") != "random":
        raise ValueError(f"{set_dir / 'benchmark.json'}: kind: not a drawn set (generate-benchmark --random)")
    rows = []
    for r in sorted(doc["scenes"], key=lambda r: r["seed"]):
        stats = r.get("stats") or {}
        views, contrast = stats.get("test_views") or {}, stats.get("thermal_contrast") or {}
        rows.append({
            "scene": r["scene"], "seed": r["seed"], "status": r["status"], "seconds": round(r["seconds"], 1),
            "objects": r["objects"], "sources": r["sources"], "fire": r["fire"], "particles": r["particles"],
            "trajectory": r["trajectory"], "wind": r["wind"], "thermal_size": "x".join(map(str, r["thermal_size"])),
            "optical_depth_target": r["optical_depth_target"],
            "optical_depth_achieved": r["optical_depth_achieved"],
            "test_rgb_optical_depth": views.get("rgb_optical_depth"),
            "test_rgb_optical_depth_in_smoke": views.get("rgb_optical_depth_in_smoke"),
            "test_lwir_optical_depth": views.get("lwir_optical_depth"),
            "smoke_fraction": views.get("smoke_fraction"),
            "unrecoverable_share": views.get("unrecoverable_share"),
            "contrast_k": contrast.get("contrast_k"),
            "psnr_smoky_vs_clean": views.get("psnr_smoky_vs_clean"),
            "psnr_smoky_vs_shadowed": views.get("psnr_smoky_vs_shadowed"),
        })
    return rows


def _values(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([r[key] for r in rows if isinstance(r[key], (int, float))], dtype=np.float64)


def summary(name: str, rows: list[dict[str, Any]]) -> str:
    """The set's spans in words and numbers (markdown)."""
    tau = _values(rows, "optical_depth_achieved")
    seconds = _values(rows, "seconds")
    dense = int((tau >= 1.0).sum())
    lines = [f"## {name}: {len(rows)} scenes (seeds {rows[0]['seed']}-{rows[-1]['seed']})", "",
             f"- RGB optical depth of the smoke: {tau.min():.3f}-{tau.max():.3f}; {dense} of {len(rows)} scenes "
             f"({100 * dense / len(rows):.0f} %) at 1 or more.",
             f"- generation: median {np.median(seconds):.0f} s a scene ({seconds.min():.0f}-{seconds.max():.0f} s), "
             f"{seconds.sum() / 3600:.2f} h of scene time in all (see the README for the set's wall time)."]
    for key, label, _ in AXES[1:]:
        v = _values(rows, key)
        if v.size:
            lines.append(f"- {label}: {v.min():.3g}-{v.max():.3g} (median {np.median(v):.3g}; {len(rows) - v.size} "
                         "scenes without one)")
    fire = sum(1 for r in rows if r["fire"])
    soot = sum(1 for r in rows if r["particles"] == "soot")
    lines.append(f"- {fire} scenes with fire, {soot} with soot, {len(rows) - soot} with organic smoke.")
    return "\n".join(lines) + "\n"


def histograms(sets: dict[str, list[dict[str, Any]]], out_png: Path) -> None:
    fig = Figure(figsize=(12, 3.4))
    for i, (key, label, log) in enumerate(AXES):
        ax = fig.add_subplot(1, len(AXES), i + 1)
        data = {name: _values(rows, key) for name, rows in sets.items()}
        every = np.concatenate(list(data.values()))
        if every.size == 0:
            continue
        lo, hi = float(every.min()), float(every.max())
        bins = (np.geomspace(max(lo, 1e-3), hi * 1.0001, 13) if log
                else np.linspace(lo, hi if hi > lo else lo + 1.0, 13))
        ax.hist(list(data.values()), bins=bins, label=list(data), stacked=False)
        if log:
            ax.set_xscale("log")
        ax.set_xlabel(label, fontsize=8)
        ax.set_ylabel("scenes")
        ax.legend(fontsize=7)
    fig.tight_layout()
    FigureCanvasAgg(fig)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, format="png", dpi=110)


def _tile(dataset: Path) -> np.ndarray:
    """The middle RGB frame with smoke beside the thermal frame nearest to it (TILE each)."""
    row = pick_rows(dataset)[len(pick_rows(dataset)) // 2]
    rgb = load_pass(dataset, "rgb", "smoky", 0, row.rgb_stem)
    left = np.full((TILE[1], TILE[0], 3), 0.5) if rgb is None else _fit(rgb[..., :3].astype(np.float64) / 255.0)
    counts = load_pass(dataset, "thermal", "smoky", 1, row.thermal_stem)
    if counts is None:
        right = np.full_like(left, 0.5)
    else:
        lo, hi = stretch([counts])
        right = thermal_panel(counts, lo, hi, TILE)
    return np.concatenate([left, right], axis=1)


def _fit(image: np.ndarray) -> np.ndarray:
    from PIL import Image

    pil = Image.fromarray((np.clip(image, 0, 1) * 255).astype(np.uint8)).resize(TILE, Image.BILINEAR)
    return np.asarray(pil).astype(np.float64) / 255.0


def contact_sheet(set_dir: Path, rows: list[dict[str, Any]], out_png: Path, columns: int = 5) -> None:
    """Every scene of the set: its middle RGB frame and the thermal frame beside it, titled with its
    seed, optical depth and whether it burns."""
    n = len(rows)
    lines = -(-n // columns)
    fig = Figure(figsize=(columns * 3.2, lines * 1.45))
    for i, r in enumerate(rows):
        ax = fig.add_subplot(lines, columns, i + 1)
        ax.imshow(_tile(set_dir / r["scene"]))
        ax.set_title(f"{r['seed']}: tau {r['optical_depth_achieved']:.2f}, {r['particles'].split('_')[0]}"
                     + (", fire" if r["fire"] else ""), fontsize=7)
        ax.axis("off")
    fig.tight_layout(pad=0.3)
    FigureCanvasAgg(fig)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, format="png", dpi=90)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python benchmarks/random_sets.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sets", type=Path, nargs="+", help="folders written by generate-benchmark --random")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/random_sets"))
    args = p.parse_args(argv)
    sets: dict[str, list[dict[str, Any]]] = {}
    for set_dir in args.sets:
        if not (set_dir / "benchmark.json").is_file():
            print(f"random_sets: error: {set_dir / 'benchmark.json'}: no such file (run generate-benchmark --random "
                  f"... --out {set_dir} first)", file=sys.stderr)
            return 2
        try:
            sets[set_dir.name] = scene_rows(set_dir)
        except (ValueError, KeyError) as exc:
            print(f"random_sets: error: {exc}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for set_dir in args.sets:
        rows = sets[set_dir.name]
        write_rows_csv(args.out / f"{set_dir.name}_scenes.csv", rows)
        contact_sheet(set_dir, rows, args.out / f"{set_dir.name}_contact_sheet.png")
    histograms(sets, args.out / "axes.png")
    write_text(args.out / "summary.md", "\n".join(summary(name, rows) for name, rows in sets.items()))
    print(f"wrote {args.out}: " + ", ".join(f"{name} ({len(rows)} scenes)" for name, rows in sets.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
