"""How the standard tables move when their ground truth is re-rendered converged: every committed
run's saved test renders scored against the clean frames it was scored against and against the
re-rendered ones (issue 49, item 5).

    python benchmarks/rescore_clean.py --before REV [--digest 6663d970]

REV is the commit whose `data/standard/*/rgb/clean/` frames the runs were scored against (the
last one before the clean passes were re-rendered); the re-rendered frames are read from the
working tree. A run is re-scored from its `renders/surface/*.png` (8-bit), so the "before"
column is also taken from the PNGs: its gap to the recorded float score is the PNG rounding,
reported, and the move is PNG against PNG. Depth and mask scores do not read the clean frames and
do not move. Validation scores cannot be redone (no validation renders are kept).

Writes benchmarks/results/standard/rescore_clean.{csv,md}.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contracts.atomic import write_rows_csv, write_text
from contracts.imageio import image01, read_png
from contracts.metrics import psnr, ssim_3dgs
from eval.finished_runs import finished_runs
from eval.runs import ABLATIONS, METHODS, variant_label
from eval.tables import seed_stat
from scenes.load import load_scene

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "benchmarks" / "results" / "standard"
TABLES = {"Table 1 (seeds 0-2)": ("data/tables_standard", tuple(METHODS)),
          "Table 2 (seed 0)": ("data/tables_standard", ("full", *ABLATIONS)),
          "twice the Stage-3 budget (seed 0)": ("data/tables_standard_2x", ("full", "rgb-only"))}


def _old_dataset(scene: str, rev: str, work: Path) -> Path:
    """A copy of the scene's dataset with the clean frames of commit `rev`."""
    src, dst = ROOT / "data" / "standard" / scene, work / scene
    if not dst.exists():
        shutil.copytree(src, dst)
        for png in sorted((dst / "rgb" / "clean").glob("*.png")):
            rel = png.relative_to(work).as_posix()
            png.write_bytes(subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:data/standard/{rel}"],
                                           check=True, capture_output=True).stdout)
    return dst


@dataclass
class GroundTruth:
    """One side's dataset, loaded once at one width; the smoky input's score is the same for
    every run on the same test views, so it is taken once per set of views."""

    data: Any
    inputs: dict[tuple[str, ...], float] = field(default_factory=dict)
    index: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        self.index = {f.file_stem: i for i, f in enumerate(self.data.rgb.frames)}

    def clean(self, stems: list[str]) -> list[np.ndarray]:
        return [self.data.rgb.clean[self.index[s]].astype(np.float64) for s in stems]

    def input_psnr(self, stems: list[str]) -> float:
        if tuple(stems) not in self.inputs:
            self.inputs[tuple(stems)] = float(np.mean([psnr(self.data.rgb.images[self.index[s]], g)
                                                       for s, g in zip(stems, self.clean(stems))]))
        return self.inputs[tuple(stems)]


def _scores(pred: list[np.ndarray], truth: GroundTruth, stems: list[str]) -> dict[str, float]:
    gt = truth.clean(stems)
    return {"psnr": float(np.mean([psnr(p, g) for p, g in zip(pred, gt)])),
            "ssim": float(np.mean([ssim_3dgs(p, g) for p, g in zip(pred, gt)])),
            "psnr_input": truth.input_psnr(stems)}


def rescore(rev: str, digest: str) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    loaded: dict[tuple[str, str, int], GroundTruth] = {}
    seen: set[Path] = set()
    with tempfile.TemporaryDirectory() as tmp:
        for tables, variants in dict.fromkeys(TABLES.values()):
            _, runs = finished_runs(ROOT / tables, variants, digest)
            for run_dir, rec in runs:
                if run_dir in seen:
                    continue
                seen.add(run_dir)
                metrics = json.loads((run_dir / "metrics.json").read_text())
                stems = [e["file_stem"] for e in metrics["per_image"]]
                pred = [image01(read_png(run_dir / "renders" / "surface" / f"{s}.png")) for s in stems]
                width = pred[0].shape[1]
                scene = rec["scene"]
                row = {"tables": tables, "scene": scene, "variant": rec["variant"], "seed": rec["seed"],
                       "run": run_dir.relative_to(ROOT).as_posix(),
                       "psnr_recorded": metrics["metrics"]["psnr"], "ssim_recorded": metrics["metrics"]["ssim"]}
                for side, path in (("before", lambda: _old_dataset(scene, rev, Path(tmp))),
                                   ("after", lambda: ROOT / "data" / "standard" / scene)):
                    key = (scene, side, width)
                    if key not in loaded:
                        loaded[key] = GroundTruth(load_scene(path(), max_width=width, all_ground_truth=True))
                    for name, value in _scores(pred, loaded[key], stems).items():
                        row[f"{name}_{side}"] = value
                rows.append(row)
                print(f"{row['run']}: PSNR {row['psnr_before']:.2f} -> {row['psnr_after']:.2f} "
                      f"(recorded {row['psnr_recorded']:.2f})", flush=True)
    return rows


def stat_text(rows: list[dict[str, Any]], key: str, digits: int = 2) -> str:
    by_seed: dict[int, list[float]] = {}
    for r in rows:
        by_seed.setdefault(int(r["seed"]), []).append(float(r[key]))
    s = seed_stat(by_seed)
    return f"{s.mean:.{digits}f}" + (f" ± {s.std:.{digits}f}" if s.std is not None else "")


def report(rows: list[dict[str, Any]], rev: str, digest: str) -> str:
    rounding = max(abs(r["psnr_before"] - r["psnr_recorded"]) for r in rows)
    lines = [f"# The standard tables re-scored against converged clean frames\n",
             f"Runs: trainer digest {digest[:8]}, {len(rows)} finished runs; clean frames before: commit "
             f"{rev[:7]} (rendered at the smoky pass's 32 samples); after: the re-rendered frames (256 "
             "samples, `room` 512). Both sides scored from the runs' 8-bit surface renders; the largest gap "
             f"between the recorded float PSNR and the PNG score against the same frames is {rounding:.3f} dB. "
             "Mean over scenes per seed, then mean ± std over seeds, as in the tables. Command: "
             f"`python benchmarks/rescore_clean.py --before {rev[:7]}`.\n"]
    for title, (tables, variants) in TABLES.items():
        mine = [r for r in rows if r["tables"] == tables and r["variant"] in variants
                and (title.startswith("Table 1") or int(r["seed"]) == 0)]
        if not mine:
            continue
        lines += [f"## {title}\n", "| variant | runs | PSNR before | PSNR after | move | SSIM before | SSIM after "
                  "| smoky input PSNR before | after |", "|---|---|---|---|---|---|---|---|---|"]
        for v in variants:
            rs = [r for r in mine if r["variant"] == v]
            if not rs:
                continue
            move = np.mean([r["psnr_after"] - r["psnr_before"] for r in rs])
            lines.append(f"| {variant_label(v)} | {len(rs)} | {stat_text(rs, 'psnr_before')} | {stat_text(rs, 'psnr_after')} "
                         f"| {move:+.2f} | {stat_text(rs, 'ssim_before', 3)} | {stat_text(rs, 'ssim_after', 3)} "
                         f"| {stat_text(rs, 'psnr_input_before')} | {stat_text(rs, 'psnr_input_after')} |")
        lines.append("")
    t1 = [r for r in rows if r["tables"] == "data/tables_standard" and r["variant"] in METHODS]
    scenes = sorted({r["scene"] for r in t1})
    methods = [v for v in METHODS if any(r["variant"] == v for r in t1)]
    lines += ["## Per scene, Table 1 (mean over seeds 0-2): PSNR before → after\n",
              "| scene | " + " | ".join(variant_label(v) for v in methods) + " | smoky input |",
              "|---|" + "---|" * (len(methods) + 1)]
    for s in scenes:
        cells = []
        for v in methods:
            rs = [r for r in t1 if r["scene"] == s and r["variant"] == v]
            cells.append(f"{np.mean([r['psnr_before'] for r in rs]):.2f} → {np.mean([r['psnr_after'] for r in rs]):.2f}"
                         if rs else "—")
        rs = [r for r in t1 if r["scene"] == s]
        cells.append(f"{rs[0]['psnr_input_before']:.2f} → {rs[0]['psnr_input_after']:.2f}")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="commit with the clean frames the runs were scored against")
    parser.add_argument("--digest", default="6663d970", help="trainer digest of the tables' runs (default 6663d970)")
    args = parser.parse_args()
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", args.before], check=True, capture_output=True,
                         text=True).stdout.strip()
    rows = rescore(rev, args.digest)
    write_rows_csv(OUT / "rescore_clean.csv", [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}
                                               for r in rows])
    write_text(OUT / "rescore_clean.md", report(rows, rev, args.digest))
    print(f"wrote {OUT / 'rescore_clean.csv'} and {OUT / 'rescore_clean.md'}")


if __name__ == "__main__":
    main()
