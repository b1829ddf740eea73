"""The haze-line smoke-colour decision of every finished run of a table, beside its score.

    python benchmarks/smoke_colour_decisions.py [--tables data/tables_standard] [--digest PREFIX]
        [--variants full,rgb-only] [--min-meeting F --full-meeting F --max-brightness F --full-brightness F
         --surface-full-brightness F]
        [--datasets data/standard]

For each finished run of ``--variants`` (default Full and RGB-only; Table 2's ablations decide
the same way) of one trainer version (``--digest``, default: the version with the most runs)
this reads ``metrics.json`` → ``stages.smoke_colour``: the haze-line estimate, how many
observation lines it had, the fraction of lines that meet, and the trust the run gave it (runs
of trainer f13fe3c1 and older held it, trust 1, or refused it, 0, naming the colour the lines
came nearest to) and, where the run recorded it, the surface start's trust; beside the run's
final validation and test PSNR and its test LPIPS (empty where the run has none). Writes
``benchmarks/results/standard/smoke_colour_decisions.csv``. Why: the estimate's colour can be
stable across seeds while its trust moves, and which runs gain from holding it is a question of
the colour as much as of the trust. The ramp options add the trusts
``smokeseer.stage1.haze_lines.trust`` gives each run's estimate under those settings
(``rule_trust`` for the colour, ``rule_surface_trust`` for the start), so a rule can be read
against every run before any run retrains with it.
``--datasets`` adds each scene's true smoke colour, read off the generator's passes (scoring only):
(smoky − (1 − α)·clean) / α over the pixels of every third RGB frame where α > 0.3, its median
and the mean 10th-90th percentile spread over channels (how far one colour is from every pixel's).
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from contracts.dataset_format import file_path, load_transforms, pass_file, read_pass_image
from contracts.imageio import image01, read_png
from eval.finished_runs import runs_of_variants
from eval.runs import VARIANTS as TABLE_VARIANTS
from smokeseer.stage1.haze_lines import HazeLineSettings, trust

REFUSED_COLOUR = re.compile(r"(?:nearest point|smoke colour|at) \[([-\d.]+), ([-\d.]+), ([-\d.]+)\]")


def haze_lines(stages: dict) -> dict:
    """metrics.json ``stages.smoke_colour.haze_lines``, or {} for a run without an estimate."""
    return (stages.get("smoke_colour") or {}).get("haze_lines") or {}


def estimate(lines: dict) -> tuple[list[float] | None, float | None, float]:
    """From a run's haze-line record (``haze_lines``): the estimate's colour (for older runs also a
    refused one), the meeting fraction and the trust the run gave it (older runs: 1 held, 0 refused)."""
    colour = lines.get("colour")
    if "trust" in lines:
        return colour, lines.get("meeting_fraction"), lines["trust"]
    held = colour is not None
    if colour is None:
        found = REFUSED_COLOUR.search(lines.get("refused") or "")
        colour = [float(v) for v in found.groups()] if found else None
    return colour, lines.get("meeting_fraction"), 1.0 if held else 0.0


def decision(stages: dict) -> dict[str, object]:
    """``estimate`` as table columns, with the colour's mean over channels."""
    lines = haze_lines(stages)
    colour, met, given = estimate(lines)
    surface = lines.get("surface_trust")
    return {"held": given == 1.0, "trust": round(given, 4),
            "surface_trust": None if surface is None else round(surface, 4), "lines": lines.get("lines"),
            "meeting_fraction": met,
            "colour": "" if colour is None else " ".join(f"{c:.3f}" for c in colour),
            "colour_mean": None if colour is None else round(sum(colour) / 3, 3)}


def fraction(met: float | None) -> str:
    """A meeting fraction for the printout; none where too few lines were found to try."""
    return "none" if met is None else f"{met:.2f}"


def implied_smoke_colour(smoky: np.ndarray, clean: np.ndarray, alpha: np.ndarray, min_alpha: float = 0.3) -> np.ndarray:
    """(n, 3): the smoke colour the image formation smoky = alpha·k + (1 − alpha)·clean implies at
    each pixel whose true smoke alpha (H, W) is over ``min_alpha`` (thinner smoke says little of k)."""
    inside = alpha > min_alpha
    return (smoky[inside] - (1.0 - alpha[inside, None]) * clean[inside]) / alpha[inside, None]


def true_smoke_colour(root: Path, min_alpha: float = 0.3, every: int = 3) -> tuple[list[float], float]:
    """The median of the per-pixel smoke colour the passes imply, and its 10th-90th percentile spread."""
    data = load_transforms(root, "rgb")
    spec = pass_file("rgb", "smoke_alpha", "exr")
    colours = []
    for frame in data["frames"][::every]:
        name = frame["file_stem"]
        smoky, clean = (image01(read_png(root / "rgb" / kind / f"{name}.png")[..., :3]) for kind in ("smoky", "clean"))
        alpha = read_pass_image(file_path(root, spec, name), spec, (data["h"], data["w"]))
        colours.append(implied_smoke_colour(smoky, clean, alpha, min_alpha))
    c = np.concatenate(colours)
    if not len(c):
        return [], 0.0
    spread = np.percentile(c, 90, axis=0) - np.percentile(c, 10, axis=0)
    return [round(float(v), 3) for v in np.median(c, axis=0)], round(float(spread.mean()), 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tables", type=Path, default=Path("data/tables_standard"))
    ap.add_argument("--digest", default=None, help="trainer code digest prefix (default: the one with the most runs)")
    ap.add_argument("--variants", default="full,rgb-only", help="comma-separated table variants")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/standard/smoke_colour_decisions.csv"))
    ramps = {"min_meeting_fraction": "--min-meeting", "full_meeting_fraction": "--full-meeting",
             "max_brightness": "--max-brightness", "full_brightness": "--full-brightness",
             "surface_full_brightness": "--surface-full-brightness"}
    for field, flag in ramps.items():
        column = "rule_surface_trust" if field == "surface_full_brightness" else "rule_trust, rule_surface_trust"
        ap.add_argument(flag, dest=field, type=float, default=None,
                        help=f"a trust ramp end ({column}; haze_lines.HazeLineSettings)")
    ap.add_argument("--datasets", type=Path, default=None, help="the scenes' datasets, for the true smoke colour")
    args = ap.parse_args()
    given = {k: getattr(args, k) for k in ramps if getattr(args, k) is not None}
    rule = HazeLineSettings(**given) if given else None
    runs = runs_of_variants(args.tables, args.variants, TABLE_VARIANTS, args.digest)
    truth: dict[str, tuple[list[float], float]] = {}
    rows = []
    for folder, rec in runs:
        doc = json.loads((folder / "metrics.json").read_text())
        rows.append({"scene": rec["scene"], "variant": rec["variant"], "seed": rec["seed"],
                     "code_digest": rec["code_digest"][:8], **decision(doc["stages"]),
                     "val_psnr": round(doc["validation"]["psnr"], 3), "test_psnr": round(doc["metrics"]["psnr"], 3),
                     "test_lpips": None if doc["metrics"].get("lpips") is None else round(doc["metrics"]["lpips"], 4)})
        if rule is not None:
            colour, met, _ = estimate(haze_lines(doc["stages"]))
            rows[-1].update(rule=f"meeting {rule.min_meeting_fraction}-{rule.full_meeting_fraction}, brightness "
                                 f"{rule.max_brightness}-{rule.full_brightness} (start "
                                 f"{rule.max_brightness}-{rule.surface_full_brightness})",
                            **{column: 0.0 if colour is None or met is None
                               else round(trust(np.array(colour), rows[-1]["lines"], met, rule, full)[0], 4)
                               for column, full in (("rule_trust", rule.full_brightness),
                                                    ("rule_surface_trust", rule.surface_full_brightness))})
        if args.datasets is not None:
            if rec["scene"] not in truth:
                truth[rec["scene"]] = true_smoke_colour(args.datasets / rec["scene"])
            colour, spread = truth[rec["scene"]]
            rows[-1].update(true_colour=" ".join(f"{c:.3f}" for c in colour), true_colour_spread=spread)
    write_rows_csv(args.out, rows)
    for r in rows:
        print(f"{r['scene']:11s} {r['variant']:14s} {r['seed']}  lines {r['lines']}  meet {fraction(r['meeting_fraction'])}  colour "
              f"[{r['colour']}] (mean {r['colour_mean']})  trust {r['trust']:.3f}  "
              f"val {r['val_psnr']:.2f}  test {r['test_psnr']:.2f}"
              + ("" if rule is None else f"  -> rule: trust {r['rule_trust']:.3f}, start {r['rule_surface_trust']:.3f}"))
    print(f"{len(rows)} runs, trainer {rows[0]['code_digest']}; wrote {args.out}")


if __name__ == "__main__":
    main()
