"""The colour cast a de-smoked surface keeps, for finished runs that were scored before the trainer
measured it (the surface issue's first diagnostic): the mean signed error per channel of the
surface render against the clean frame, on the test pixels the smoke mask marks; and, where the
dataset has them, against the shadowed frames (`rgb.shadowed`), which the shadow does not tint;
and on the recoverable part of those pixels alone (some training view sees their surface with
smoke alpha under 0.1, ``eval.regions``' reach split), where a de-smoking method can know the
colour at all.

    python benchmarks/colour_bias.py [--tables data/tables_standard] [--digest d65d2bcb]
        [--variants full,rgb-only] [--out benchmarks/results/standard/colour_bias]

A run's bias is read from its saved 8-bit surface renders (`renders/surface/*.png`, what run
folders keep) against the clean frames and smoke masks of the dataset its harness record names,
loaded at the renders' width as the trainer loads them: the trainer's own function
(`smokeseer.evaluation.scoring.masked_colour_bias`), which newer runs record from their float renders (the
two agree to the 8-bit rounding, under 0.002; tests/test_colour_bias.py). Writes OUT.csv (one row
per run) and OUT.md: per variant, the per-channel bias on the ten-scene mean (mean ± std over
seeds) and the largest |bias| of any scene (mean over its seeds), the two numbers the surface
issue bounds (0.02 and 0.05), and the same against shadowed and on the recoverable pixels, over
the scenes that have the frames, passes and pixels (the row's scene count); then per scene.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from contracts.atomic import write_rows_csv, write_text  # noqa: E402
from contracts.imageio import image01, read_png  # noqa: E402
from contracts.recorded_paths import recorded_location  # noqa: E402
from eval.finished_runs import finished_runs  # noqa: E402
from eval.regions import reach_masks  # noqa: E402
from eval.runs import variant_label  # noqa: E402
from scenes.load import load_scene  # noqa: E402
from smokeseer.evaluation.scoring import masked_colour_bias  # noqa: E402

CHANNELS = ("r", "g", "b")
MEAN_LIMIT, SCENE_LIMIT = 0.02, 0.05
"""The surface issue's bounds: |bias| per channel on the mean of the scenes, and on each scene."""


def run_bias(run: Path, scene_cache: dict[tuple[str, Any], Any]) -> dict[str, Any]:
    """The run's per-channel signed error on its test views' masked pixels, and their count."""
    rec = json.loads((run / "harness.json").read_text())
    stems = [e["file_stem"] for e in json.loads((run / "metrics.json").read_text())["per_image"]]
    renders = [image01(read_png(run / "renders" / "surface" / f"{s}.png")) for s in stems]
    width = renders[0].shape[1]
    dataset = str(recorded_location(rec["dataset"]))
    key = (dataset, width)
    if key not in scene_cache:
        scene_cache[key] = load_scene(Path(dataset), max_width=width)
    rgb = scene_cache[key].rgb
    if rgb.masks is None or rgb.clean is None:
        raise ValueError(f"{dataset}: no smoke masks or clean frames to measure a colour cast against")
    index = {f.file_stem: i for i, f in enumerate(rgb.frames)}
    found, pixels = masked_colour_bias((img, rgb.clean[index[stem]], rgb.masks[index[stem]])
                                       for stem, img in zip(stems, renders))
    bias = np.asarray(found if found is not None else [np.nan] * 3)
    shadowed: list[float | str] = [""] * 3  # no shadowed frames in the dataset
    if rgb.shadowed is not None:
        under, _ = masked_colour_bias((img, rgb.shadowed[index[stem]], rgb.masks[index[stem]])
                                      for stem, img in zip(stems, renders))
        shadowed = [round(float(b), 5) for b in (under if under is not None else [np.nan] * 3)]
    recoverable, share, against = recoverable_bias(run, dataset, stems, renders, rgb, index, scene_cache)
    return {"scene": rec["scene"], "variant": rec["variant"], "seed": rec["seed"], "run": rec["run_dir"],
            **{f"bias_{c}": round(float(b), 5) for c, b in zip(CHANNELS, bias)},
            "max_abs_bias": round(float(np.abs(bias).max()), 5), "smoky_pixels": pixels,
            **{f"bias_shadowed_{c}": b for c, b in zip(CHANNELS, shadowed)},
            **{f"bias_recoverable_{c}": b for c, b in zip(CHANNELS, recoverable)},
            "recoverable_share": share, "recoverable_against": against}


def recoverable_bias(run: Path, dataset: str, stems: list[str], renders: list[np.ndarray], rgb: Any,
                     index: dict[str, int],
                     cache: dict[tuple[str, Any], Any]) -> tuple[list[float | str], float | str, str]:
    """The cast on the masked pixels some training view sees with thin smoke (``eval.regions``'
    reach split), against the shadowed frames where the dataset has them, else the clean ones; the
    share of the masked pixels that are recoverable; and which truth. Under smoke that no training
    view sees through no method reading the RGB frames can know the colour, so the cast there is
    the input's, not the method's. Empty where no masked pixel is recoverable (share 0), the
    dataset lacks the depth and smoke-opacity passes, or the renders are not at its resolution
    (said on stderr)."""
    key = ("reach", dataset)
    if key not in cache:
        cache[key] = reach_masks(Path(dataset))
    reach = cache[key]
    if not reach:
        return [""] * 3, "", ""
    if any(reach[s].shape != r.shape[:2] for s, r in zip(stems, renders)):
        print(f"colour_bias: {run}: renders at {renders[0].shape[1]} px wide, the reach masks at the dataset's "
              f"{next(iter(reach.values())).shape[1]}: no recoverable split", file=sys.stderr)
        return [""] * 3, "", ""
    truth, against = (rgb.shadowed, "shadowed") if rgb.shadowed is not None else (rgb.clean, "clean")
    masks = [np.where(reach[s], 0.0, rgb.masks[index[s]]) for s in stems]
    found, pixels = masked_colour_bias((img, truth[index[s]], m) for s, img, m in zip(stems, renders, masks))
    total = sum(int((rgb.masks[index[s]] > 0.5).sum()) for s in stems)
    bias: list[float | str] = [round(float(b), 5) for b in found] if found is not None else [""] * 3
    return bias, (round(pixels / total, 4) if total else ""), against


def summary(rows: list[dict[str, Any]], variants: list[str], digest: str) -> str:
    lines = [f"# The colour cast of the de-smoked surface (trainer {digest[:8]})", "",
             "Mean signed error per channel (render − clean, in [0, 1]) on the test pixels the smoke mask "
             "marks, from each run's saved 8-bit surface renders (`python benchmarks/colour_bias.py`). "
             f"The surface issue bounds it at {MEAN_LIMIT} per channel on the mean of the scenes and "
             f"{SCENE_LIMIT} on each scene.", "",
             "| variant | seeds | scenes | R | G | B | largest scene |bias| (scene) |",
             "|---|---|---|---|---|---|---|"]
    per_scene: dict[str, dict[str, np.ndarray]] = {}

    def scene_means(mine: list[dict[str, Any]], prefix: str) -> dict[str, np.ndarray]:
        """Each scene's cast, the mean over its seeds."""
        return {s: np.mean([[r[f"{prefix}{c}"] for c in CHANNELS] for r in mine if r["scene"] == s], axis=0)
                for s in sorted({r["scene"] for r in mine})}

    def summary_row(label: str, mine: list[dict[str, Any]], prefix: str) -> dict[str, np.ndarray]:
        """The variant's line (mean over seeds of the scene mean, ± over seeds) and its per-scene casts."""
        seeds = sorted({r["seed"] for r in mine})
        by_seed = [np.mean([[r[f"{prefix}{c}"] for c in CHANNELS] for r in mine if r["seed"] == s], axis=0)
                   for s in seeds]
        table = scene_means(mine, prefix)
        worst = max(table, key=lambda s: np.abs(table[s]).max())
        cells = [f"{m:+.4f}" for m in np.mean(by_seed, axis=0)]
        if len(seeds) > 1:
            cells = [f"{c} ± {d:.4f}" for c, d in zip(cells, np.std(by_seed, axis=0, ddof=1))]
        lines.append(f"| {label} | {', '.join(map(str, seeds))} | {len(table)} | {' | '.join(cells)} | "
                     f"{np.abs(table[worst]).max():.4f} ({worst}) |")
        return table

    for v in variants:
        mine = [r for r in rows if r["variant"] == v]
        if mine:
            per_scene[v] = summary_row(variant_label(v), mine, "bias_")
    extra: list[tuple[str, dict[str, np.ndarray]]] = []  # the scenes whose dataset has the frames or passes
    for suffix, prefix in (("against shadowed", "bias_shadowed_"), ("recoverable pixels", "bias_recoverable_")):
        for v in per_scene:
            mine = [r for r in rows if r["variant"] == v]
            found = [r for r in mine if r.get(f"{prefix}r", "") != ""]
            label = f"{variant_label(v)}, {suffix}"
            if found:  # the row's scene count says how many have the frames, passes or pixels
                extra.append((label, summary_row(label, found, prefix)))
    columns = [variant_label(v) for v in per_scene] + [label for label, _ in extra]
    lines += ["", "Per scene, mean over its seeds (R, G, B); against shadowed: the same pixels against the frames "
              "under the smoke's shadow with no smoke in view (`rgb.shadowed`, where the dataset has it), so "
              "the shadow is no part of the cast; recoverable pixels: the masked pixels some training view "
              "sees with smoke alpha under 0.1 (`eval/regions.py`), against shadowed where the dataset has it, "
              "so the surface no RGB view reaches is no part of it (the CSV's `recoverable_share`):", "",
              "| scene | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]

    def cell(table: dict[str, np.ndarray], scene: str) -> str:
        return ", ".join(f"{b:+.3f}" for b in table[scene]) if scene in table else ""

    for s in sorted({s for d in per_scene.values() for s in d}):
        cells = [cell(per_scene[v], s) for v in per_scene] + [cell(table, s) for _, table in extra]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python benchmarks/colour_bias.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    p.add_argument("--digest", help="the trainer version whose runs to read (a prefix; else the one with the most)")
    p.add_argument("--variants", default="full,rgb-only")
    p.add_argument("--out", type=Path, default=Path("benchmarks/results/standard/colour_bias"))
    args = p.parse_args(argv)
    variants = [v for v in args.variants.split(",") if v]
    try:
        digest, runs = finished_runs(args.tables, variants, args.digest)
        cache: dict[tuple[str, Any], Any] = {}
        rows = [run_bias(run, cache) for run, _ in sorted(runs, key=lambda x: str(x[0]))]
    except (ValueError, FileNotFoundError, KeyError) as exc:
        print(f"colour_bias: error: {exc}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_rows_csv(args.out.with_suffix(".csv"), rows)
    write_text(args.out.with_suffix(".md"), summary(rows, variants, digest))
    print(summary(rows, variants, digest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
