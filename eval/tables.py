"""Table 1 (methods) and Table 2 (ablations) as Markdown, LaTeX and CSV.

Aggregation: each run's metric is already a mean over the test split; per seed we
average over scenes, then report mean ± sample std (ddof=1) over seeds. With one
seed there is no std and none is printed. Failed runs are counted and flagged in
the row, never silently left out.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from contracts.train_log import stage2_rows
from eval.runs import ABLATIONS, METHODS, VARIANTS, RunResult, variant_label


@dataclass(frozen=True)
class Stat:
    mean: float | None
    std: float | None
    n_seeds: int


@dataclass(frozen=True)
class Column:
    metric: str
    header: str
    digits: int


TABLE1_COLUMNS = (
    Column("psnr", "PSNR ↑", 2), Column("ssim", "SSIM ↑", 3), Column("lpips", "LPIPS ↓", 3),
)
TABLE1_EXTRA = (
    Column("psnr_input", "Input PSNR", 2), Column("depth_absrel", "Depth AbsRel ↓", 3),
    Column("depth_rmse", "Depth RMSE (m) ↓", 3), Column("mask_iou", "Mask IoU ↑", 3),
)
SHADOWED_EXTRA = (Column("psnr_shadowed", "PSNR vs shadowed ↑", 2),
                  Column("psnr_input_shadowed", "Input PSNR vs shadowed", 2))
"""Table 1's scores against the shadowed ground truth (rgb.shadowed), shown when a run has them."""
TABLE2_COLUMNS = TABLE1_COLUMNS


def table1_extra(results: list[RunResult]) -> tuple[Column, ...]:
    """Table 1's extra columns: the scores against shadowed only when some finished run has them."""
    shadowed = any(r.status == "ok" and r.metrics.get("psnr_shadowed") is not None for r in results)
    return TABLE1_EXTRA + (SHADOWED_EXTRA if shadowed else ())


@dataclass(frozen=True)
class Row:
    variant: str
    label: str
    stats: dict[str, Stat]
    paper: dict[str, float]
    runs_ok: int
    runs_failed: int
    runs_expected: int
    lpips_status: str
    runs_same_as: int = 0
    """Runs that a finished run of another variant stands for (eval/twins.py), and why."""
    same_as_reason: str = ""
    scenes_by_seed: dict[int, int] = field(default_factory=dict)
    """Finished runs (scenes) each seed's mean is taken over."""
    stage2_apart_by_seed: dict[int, tuple[int, int]] = field(default_factory=dict)
    """An ablation's trained runs whose Stage 2 ended apart from Full's of the same scene and seed,
    and how many were compared, per seed (``stage2_apart``)."""
    lpips_runs: int = 0
    """Finished runs with an LPIPS score (``lpips_coverage``)."""
    lpips_rescored: int = 0
    """Finished runs whose LPIPS was scored after training from their saved renders (``RESCORED_LPIPS``)."""
    lpips_rescored_status: str = ""


def seed_stat(values_by_seed: dict[int, list[float]]) -> Stat:
    """Mean over scenes within a seed, then mean and sample std over seeds."""
    per_seed = [sum(v) / len(v) for _, v in sorted(values_by_seed.items()) if v]
    if not per_seed:
        return Stat(None, None, 0)
    n = len(per_seed)
    mean = sum(per_seed) / n
    std = math.sqrt(sum((x - mean) ** 2 for x in per_seed) / (n - 1)) if n > 1 else None
    return Stat(mean, std, n)


def _metric_values(results: Iterable[RunResult], metric: str) -> dict[int, list[float]]:
    out: dict[int, list[float]] = {}
    for r in results:
        if r.status != "ok":
            continue
        v = r.metrics.get(metric)
        out.setdefault(r.seed, [])
        if v is not None:
            out[r.seed].append(float(v))
    return out


RESCORED_LPIPS = "rescored from the run's 8-bit surface renders"
"""How a record's ``lpips_status`` starts when benchmarks/rescore_lpips.py wrote its LPIPS after
training (docs/results-format.md); the trainer scores its float renders."""


def rescored_lpips_note(how: Iterable[str], rescored: int, ok: int) -> str:
    """The note beneath a table some of whose ``ok`` finished runs (``rescored`` of them) had their
    LPIPS scored after training; ``how``: their ``lpips_status`` lines (the weights, the renders)."""
    return (f"LPIPS: {'; '.join(sorted(set(how)))}" + (f", in {rescored} of the {ok} runs" if rescored < ok else "")
            + "; scored after training, where the trainer scores its float renders (docs/results-format.md).")


def lpips_coverage(results: Iterable[RunResult]) -> tuple[int, int]:
    """(finished runs with an LPIPS score, finished runs). Runs trained before the weights were
    installed, or on views too small for the network, have none; a mean over the scored ones alone
    would be over other scenes than the other columns', so a partly scored group gets no LPIPS mean."""
    ok = [r for r in results if r.status == "ok"]
    return sum(r.metrics.get("lpips") is not None for r in ok), len(ok)


def _stat_of(results: list[RunResult], metric: str) -> Stat:
    if metric == "lpips":
        scored, ok = lpips_coverage(results)
        if 0 < scored < ok:
            return Stat(None, None, 0)
    return seed_stat(_metric_values(results, metric))


def stage2_apart(results: list[RunResult]) -> dict[str, dict[int, tuple[int, int]]]:
    """Per ablation and seed: of its trained runs that have a finished Full of the same scene and
    seed, how many logged a Stage 2 other than Full's, and how many were compared. Table 2's
    ablations share Full's Stage-2 settings (``TrainConfig.stage2_sha256``), so with the same data,
    code and seed the two differ only in float rounding, which differs between machines and builds;
    where they differ, the ablation's difference to Full holds Stage 2's spread besides the ablated
    term. Each Full log is read once, however many ablations compare with it."""
    full = {(r.scene, r.seed): stage2_rows(Path(r.run_dir))
            for r in results if r.variant == "full" and r.status == "ok"}
    out: dict[str, dict[int, tuple[int, int]]] = {}
    for r in results:
        if r.variant not in ABLATIONS or r.status != "ok" or r.same_as or full.get((r.scene, r.seed)) is None:
            continue
        mine = stage2_rows(Path(r.run_dir))
        if mine is None:
            continue
        per_seed = out.setdefault(r.variant, {})
        apart, compared = per_seed.get(r.seed, (0, 0))
        per_seed[r.seed] = (apart + (mine != full[(r.scene, r.seed)]), compared + 1)
    return {v: dict(sorted(per_seed.items())) for v, per_seed in out.items()}


def build_rows(results: list[RunResult], variants: list[str], metrics: Iterable[str]) -> list[Row]:
    """One row per variant that appears in `variants`, in that order."""
    metrics = list(metrics)
    scenes = {r.scene for r in results}
    seeds = {r.seed for r in results}
    apart = stage2_apart(results) if any(k in ABLATIONS for k in variants) else {}
    rows = []
    for key in variants:
        mine = [r for r in results if r.variant == key]
        if not mine:
            continue
        ok_statuses = [str(r.metrics.get("lpips_status", "")) for r in mine if r.status == "ok"]
        statuses = sorted(set(ok_statuses) - {""})
        rows.append(Row(
            variant=key, label=variant_label(key),
            stats={m: _stat_of(mine, m) for m in metrics},
            paper=VARIANTS[key].paper if key in VARIANTS else {},
            runs_ok=sum(r.status == "ok" for r in mine),
            runs_failed=sum(r.status == "failed" for r in mine),
            runs_expected=len(scenes) * len(seeds),
            lpips_status="; ".join(statuses),
            lpips_runs=lpips_coverage(mine)[0],
            lpips_rescored=sum(s.startswith(RESCORED_LPIPS) for s in ok_statuses),
            lpips_rescored_status="; ".join(sorted({s for s in ok_statuses if s.startswith(RESCORED_LPIPS)})),
            runs_same_as=sum(bool(r.same_as) for r in mine if r.status == "ok"),
            same_as_reason="; ".join(sorted({r.same_as_reason for r in mine if r.same_as})),
            scenes_by_seed=dict(sorted(Counter(r.seed for r in mine if r.status == "ok").items())),
            stage2_apart_by_seed=apart.get(key, {}),
        ))
    return rows


def format_stat(stat: Stat, digits: int, latex: bool = False) -> str:
    if stat.mean is None:
        return "—"
    if stat.std is None:
        return f"{stat.mean:.{digits}f}"
    pm = r" $\pm$ " if latex else " ± "
    return f"{stat.mean:.{digits}f}{pm}{stat.std:.{digits}f}"


def _cell(row: Row, col: Column, latex: bool) -> str:
    stat = row.stats[col.metric]
    if col.metric == "lpips" and stat.mean is None:
        if 0 < row.lpips_runs < row.runs_ok:
            return f"partial: {row.lpips_runs}/{row.runs_ok} runs"
        if row.lpips_status.startswith("skipped"):
            return "skipped: no weights"
    return format_stat(stat, col.digits, latex)


def _paper_cell(row: Row, col: Column) -> str:
    v = row.paper.get(col.metric)
    return "—" if v is None else f"{v:.{col.digits}f}"


def _runs_cell(row: Row) -> str:
    flag = " †" if row.runs_failed or row.runs_ok + row.runs_failed < row.runs_expected else ""
    return f"{row.runs_ok}/{row.runs_expected}{flag}"


def _grid(rows: list[Row], cols: tuple[Column, ...], extra: tuple[Column, ...], latex: bool,
          first: str) -> tuple[list[str], list[list[str]]]:
    header = [first] + [c.header for c in cols] + [f"Paper {c.header.split()[0]}" for c in cols]
    header += [c.header for c in extra] + ["Runs ok"]
    body = []
    for r in rows:
        body.append([r.label] + [_cell(r, c, latex) for c in cols] + [_paper_cell(r, c) for c in cols]
                    + [_cell(r, c, latex) for c in extra] + [_runs_cell(r)])
    return header, body


def _footnotes(rows: list[Row], n_scenes: int, n_finished: int, devices: dict[str, int]) -> list[str]:
    seeds = max((s.n_seeds for r in rows for s in r.stats.values()), default=0)
    over = f"{n_scenes}" if n_finished == n_scenes else f"the finished runs of {n_finished} of {n_scenes}"
    notes = [f"Mean over {over} scene(s) per seed, then mean ± sample std over {seeds} seed(s) "
             "(no ± with one seed). SSIM in the 3DGS convention (full zero-padded map). "
             "Paper columns: SmokeSeer paper, synthetic benchmark (its scenes, not ours)."]
    if len(devices) > 1:
        counts = ", ".join(f"{n} on {d}" for d, n in sorted(devices.items()))
        notes.append(f"The runs were trained on more than one device ({counts}); the settings are the same, "
                     "the float rounding differs. report.md gives each run's.")
    rescored = sum(r.lpips_rescored for r in rows)
    if rescored:
        notes.append(rescored_lpips_note({r.lpips_rescored_status for r in rows if r.lpips_rescored}, rescored,
                                         sum(r.runs_ok for r in rows)))
    for r in rows:
        v = VARIANTS.get(r.variant)
        if v is not None and v.note:
            dehazed = "; its Input PSNR is that of the dehazed frames" if v.dehazer else ""
            notes.append(f"{r.label}: {v.note}{dehazed}.")
        if len(set(r.scenes_by_seed.values())) > 1:
            per_seed = ", ".join(f"seed {k}: {n}" for k, n in r.scenes_by_seed.items())
            notes.append(f"{r.label}: its seeds are means over different numbers of scenes ({per_seed}), so its ± "
                         "mixes the spread between scenes with the spread between seeds; per_scene.csv has each scene.")
        if 0 < r.lpips_runs < r.runs_ok:
            notes.append(f"{r.label}: LPIPS was scored in {r.lpips_runs} of its {r.runs_ok} runs (the others were "
                         "trained before the weights were installed, or their views are too small); a mean over the "
                         "scored ones alone would be over other scenes, so none is shown. "
                         "benchmarks/rescore_lpips.py scores the others from their saved renders.")
        if r.runs_same_as:
            notes.append(f"{r.label}: {r.runs_same_as} of its {r.runs_ok} runs are Full's of the same scene and "
                         f"seed, not trained: {r.same_as_reason}.")
        apart = sum(a for a, _ in r.stage2_apart_by_seed.values())
        if apart:
            compared = sum(n for _, n in r.stage2_apart_by_seed.values())
            per_seed = ", ".join(f"seed {k}: {a} of {n}" for k, (a, n) in r.stage2_apart_by_seed.items())
            notes.append(f"{r.label}: its Stage 2 ended apart from Full's on {apart} of the {compared} runs compared "
                         f"({per_seed}). Both had the same settings, data, code and seed, so they differ only in "
                         "float rounding, which differs between machines and builds; on those runs its difference "
                         "to Full holds Stage 2's spread besides the ablated term.")
        if r.runs_failed or r.runs_ok < r.runs_expected:
            pending = r.runs_expected - r.runs_ok - r.runs_failed
            notes.append(f"† {r.label}: {r.runs_failed} failed, " + (f"{pending} not trained yet, " if pending else "")
                         + f"{r.runs_ok} of {r.runs_expected} runs averaged; see report.md.")
    return notes


def _markdown(header: list[str], body: list[list[str]], title: str, notes: list[str]) -> str:
    lines = [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    return "\n".join(lines + [""] + [f"- {n}" for n in notes]) + "\n"


def _tex_escape(s: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("_", r"\_"), ("%", r"\%"), ("&", r"\&"), ("#", r"\#"),
                 ("↑", r"$\uparrow$"), ("↓", r"$\downarrow$"), ("†", r"$^\dagger$"), ("—", "--")):
        s = s.replace(a, b)
    return s


def _latex(header: list[str], body: list[list[str]], title: str, notes: list[str]) -> str:
    esc = [[c if "$\\pm$" in c else _tex_escape(c) for c in row] for row in body]
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             r"\begin{tabular}{l" + "c" * (len(header) - 1) + "}", r"\toprule",
             " & ".join(_tex_escape(h) for h in header) + r" \\", r"\midrule"]
    lines += [" & ".join(row) + r" \\" for row in esc]
    lines += [r"\bottomrule", r"\end{tabular}",
              r"\caption{" + _tex_escape(title + ". " + " ".join(notes)) + "}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def _csv_rows(table: str, rows: list[Row], cols: tuple[Column, ...]) -> list[list[object]]:
    out: list[list[object]] = []
    for r in rows:
        for c in cols:
            s = r.stats[c.metric]
            out.append([table, r.variant, r.label, c.metric, "" if s.mean is None else s.mean,
                        "" if s.std is None else s.std, s.n_seeds, r.runs_ok, r.runs_failed,
                        r.runs_expected, r.paper.get(c.metric, "")])
    return out


CSV_HEADER = ["table", "variant", "label", "metric", "mean", "std", "n_seeds", "runs_ok",
              "runs_failed", "runs_expected", "paper"]


def write_tables(results: list[RunResult], out_dir: Path) -> dict[str, Path]:
    """Write table1.{md,tex,csv}, table2.{md,tex,csv} and per_scene.csv; return their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n_scenes = len({r.scene for r in results})
    n_finished = len({r.scene for r in results if r.status == "ok"})
    paths: dict[str, Path] = {}
    specs = (
        ("table1", "Table 1: methods", [k for k in METHODS], TABLE1_COLUMNS, table1_extra(results), "Method"),
        ("table2", "Table 2: ablations", ["full", *ABLATIONS], TABLE2_COLUMNS, (), "Variant"),
    )
    for name, title, order, cols, extra, first in specs:
        variants = [k for k in order if any(r.variant == k for r in results)]
        if name == "table2" and not any(r.variant in ABLATIONS for r in results):
            continue
        rows = build_rows(results, variants, [c.metric for c in cols + extra])
        devices = Counter(r.device for r in results if r.variant in variants and r.status == "ok")
        notes = _footnotes(rows, n_scenes, n_finished, dict(devices))
        header, body = _grid(rows, cols, extra, False, first)
        (out_dir / f"{name}.md").write_text(_markdown(header, body, title, notes))
        header_tex, body_tex = _grid(rows, cols, extra, True, first)
        (out_dir / f"{name}.tex").write_text(_latex(header_tex, body_tex, title, notes))
        with open(out_dir / f"{name}.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(CSV_HEADER)
            w.writerows(_csv_rows(name, rows, cols + extra))
        paths.update({f"{name}.md": out_dir / f"{name}.md", f"{name}.tex": out_dir / f"{name}.tex",
                      f"{name}.csv": out_dir / f"{name}.csv"})
    paths["per_scene.csv"] = _write_per_scene(results, out_dir / "per_scene.csv")
    return paths


def _write_per_scene(results: list[RunResult], path: Path) -> Path:
    metrics = [c.metric for c in TABLE1_COLUMNS + table1_extra(results)]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "variant", "metric", "mean", "std", "n_seeds", "runs_failed"])
        for scene in sorted({r.scene for r in results}):
            for key in sorted({r.variant for r in results if r.scene == scene}):
                mine = [r for r in results if r.scene == scene and r.variant == key]
                for m in metrics:
                    s = _stat_of(mine, m)
                    w.writerow([scene, key, m, "" if s.mean is None else s.mean,
                                "" if s.std is None else s.std, s.n_seeds,
                                sum(r.status == "failed" for r in mine)])
    return path
