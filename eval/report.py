"""report.md: every setting a table depends on, every run with its status, every failure
with its error, and the tables themselves, so one file answers "where did this digit come from"."""

from __future__ import annotations

import platform
from collections import Counter
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Any

from contracts.atomic import write_text
from contracts.source import code_digest
from eval.dehaze import DarkChannelPrior
from eval.runs import VARIANTS, RunResult
from eval.settings import DatasetOutcome, HarnessConfig


def _version(pkg: str) -> str:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return "not installed"


def _shown(path: str | Path) -> str:
    """A path as the report prints it: relative to the working folder when it lies below it, else
    with the home folder written as ``~``. Why: report.md is committed beside the tables, and one
    machine's absolute paths tell a reader of another clone nothing."""
    if not str(path):
        return ""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return home_as_tilde(str(p))


def home_as_tilde(text: str) -> str:
    """The text with the home folder written ~/, so that committed reports and tables do not name
    the account that made them."""
    home = str(Path.home()).rstrip("/") + "/"
    return text.replace(home, "~/") if home != "/" else text


def _variant(key: str, label: bool) -> str:
    v = VARIANTS[key]
    return (f"{key} ({v.label + ', ' if label else ''}trainer mode `{v.mode}`"
            + "".join(f", `{o}={val}`" for o, val in v.overrides.items()) + ")")


def _settings(cfg: HarnessConfig, backend: str) -> list[tuple[str, Any]]:
    return [
        ("scenes", ", ".join(cfg.scenes)),
        ("methods", ", ".join(_variant(k, label=True) for k in cfg.methods) or "none"),
        ("ablations", ", ".join(_variant(k, label=False) for k in cfg.ablations) or "none"),
        ("rule candidates", ", ".join(_variant(k, label=False) for k in cfg.candidates) or "none"),
        ("seeds", ", ".join(map(str, cfg.seeds))),
        ("training profile", cfg.profile),
        ("training overrides", cfg.train_overrides or "none"),
        ("generator overrides", cfg.gen_overrides or "none"),
        ("dataset seed", cfg.dataset_seed),
        ("dehazer", f"{cfg.dehazer} {asdict(DarkChannelPrior()) if cfg.dehazer == 'dcp' else ''}"),
        ("execution", f"{backend}, training on {cfg.device}"),
        ("LPIPS", f"{cfg.lpips_net}, weights {cfg.lpips_weights or 'from the default search ($TORCH_HOME, ~/.cache/torch)'}"),
        ("output folder", _shown(cfg.out)),
        ("versions", ", ".join(f"{p} {_version(p)}" for p in ("smokeseer-synth", "torch", "numpy", "bpy"))
         + f", python {platform.python_version()}"),
        ("code digests (part of every cache key: each entry point and the project modules it imports)",
         ", ".join(f"{n} {_digest_shown(cfg, n)}" for n in ("generator.api+blender.worker", "smokeseer.api", "eval.dehaze"))),
    ]


def _digest_shown(cfg: HarnessConfig, entry: str) -> str:
    """An entry point's code digest; for the trainer tabled with --digest, the runs' and today's."""
    today = code_digest(*entry.split("+"))[:12]
    if entry == "smokeseer.api" and cfg.trainer_digest:
        return f"{cfg.trainer_digest[:12]} (the runs tabled, --digest; today's trainer {today})"
    return today


def write_report(cfg: HarnessConfig, results: list[RunResult], datasets: list[DatasetOutcome],
                 lpips_status: str, backend: str, wall_s: float, paths: dict[str, Path], out: Path) -> Path:
    failed = [r for r in results if r.status == "failed"]
    pending = sum(r.status == "pending" for r in results)
    lines = ["# regenerate-tables report", "",
             f"{len(results)} runs: {len(results) - len(failed) - pending} ok "
             f"({sum(r.cached for r in results)} from cache), {len(failed)} failed"
             + (f", {pending} pending (not trained yet: --finished-only)" if pending else "")
             + f"; {wall_s:.1f} s wall.", "",
             "## Settings", ""]
    lines += [f"- **{k}**: {v}" for k, v in _settings(cfg, backend)]
    lines += [f"- **LPIPS**: {home_as_tilde(lpips_status)}", ""]
    lines += ["## Datasets", "", "| scene | kind | status | cached | seconds | path |", "|---|---|---|---|---|---|"]
    lines += [f"| {d.scene} | {d.kind} | {d.status} | {d.cached} | {d.wall_time_s:.1f} | `{_shown(d.path)}` |"
              for d in datasets]
    lines += ["", "## Runs", "",
              "| scene | variant | seed | status | cached | device | seconds | PSNR | LPIPS | config hash | run dir |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        p, lp = r.metrics.get("psnr"), r.metrics.get("lpips")
        device = "—" if r.status == "pending" else r.device  # a pending run has not trained anywhere yet
        lines.append(f"| {r.scene} | {r.variant} | {r.seed} | {r.status} | {r.cached} | {device} | {r.wall_time_s:.1f} | "
                     f"{'' if p is None else f'{p:.2f}'} | {'' if lp is None else f'{lp:.3f}'} | {r.config_hash[:12]} "
                     f"| `{_shown(r.run_dir)}` |")
    taken = [r for r in results if r.stage2_from]
    if taken:
        lines += ["", f"{len(taken)} run(s) took the finished Stage 2 of a run with the same Stage-2 settings "
                  "instead of training it again (eval/shared_stage2.py; harness.json `stage2_from`); their "
                  "seconds include that Stage 2's logged time: "
                  + ", ".join(f"{r.scene}/{r.variant}/seed {r.seed}" for r in taken) + "."]
    twins = [r for r in results if r.same_as]
    if twins:
        lines += ["", f"{len(twins)} run(s) not trained because the finished run of another variant stands for "
                  "them (eval/twins.py; their row above shows that run's folder and scores): "
                  + "; ".join(f"{r.scene}/{r.variant}/seed {r.seed} = {r.same_as} ({r.same_as_reason})" for r in twins)
                  + "."]
    setups = Counter(r.float_setup or "not recorded" for r in results if r.status == "ok" and not r.same_as)
    if len(setups) > 1:
        lines += ["", "The runs trained under more than one float setup (harness.json `float_setup`, "
                  "contracts/float_setup.py), so equal settings need not give equal bytes between them: "
                  + "; ".join(f"{n} under {s}" for s, n in sorted(setups.items())) + "."]
    adopted = [r for r in results if r.adopted_from]
    if adopted:
        lines += ["", f"{len(adopted)} run(s) were trained under another key and adopted (eval/adopt.py; "
                  "harness.json `adopted_from` says from where and what was checked): "
                  + "; ".join(f"{r.scene}/{r.variant}/seed {r.seed} on {r.device}" for r in adopted) + "."]
    lines += ["", "## Failures", ""]
    if not failed:
        lines.append("None.")
    for r in failed:
        lines += [f"### {r.scene} / {r.variant} / seed {r.seed}", "", "```", r.error.strip() or "(no message)", "```", ""]
    for d in datasets:
        if d.status == "failed":
            lines += [f"### dataset {d.scene} ({d.kind})", "", "```", d.error.strip() or "(no message)", "```", ""]
    lines += ["", "## Tables", ""]
    for name in ("table1.md", "table2.md", "claims.md", "convergence.md", "per_scene_regions.md", "per_view.md"):
        if name in paths:
            lines += [Path(paths[name]).read_text(), ""]
    lines += ["## Files", ""] + [f"- `{k}`" for k in sorted(paths)]
    write_text(out, "\n".join(lines) + "\n")
    return out
