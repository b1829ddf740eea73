"""Where a standard-profile Stage-2 and Stage-3 iteration spends its time, part by part, at the
Gaussian counts of a finished standard run.

    python benchmarks/iteration_profile.py [--scenes house,room] [--modes full,rgb-only] [--threads 1]
    python benchmarks/iteration_profile.py --scenes house --modes full --checkpoints RUN/checkpoints
    python benchmarks/iteration_profile.py --scenes room --modes full --counts-from RUN \
        --checkpoints RUN/checkpoints --set deform.kind=fourier

``--set`` profiles a variant of the standard settings (its column is named mode + overrides); a
Fourier variant started from a network-trained state gets zero coefficients with fresh moments,
a network of another shape, or the plane field (``deform.kind=planes``), starts fresh.
``--counts-from`` takes the Gaussian counts from any finished run instead of the committed one.

A standard run takes 20-40 min of one thread, so each scene and mode is profiled in three steps:

1. A trained state: a finished standard run's checkpoints (``--checkpoints``), or by default a
   pretraining run of the standard profile at a tenth of its length (300 + 300 iterations) with
   every schedule scaled with it (densification windows, deformation warm-up, SH degree steps).
2. The standard profile's stages built exactly as ``train_and_evaluate`` builds them (Stage 1, the
   haze-line smoke colour, the mask floor), loaded with that state's Gaussians, deformation
   network and optimiser state, and the Gaussian sets grown (3DGS splits of randomly chosen
   Gaussians) or trimmed (the most transparent first) to the counts the committed standard run
   of that scene and mode (seed 0, the current standard settings; ``data/tables_standard/runs``)
   logged at iteration 2400, the last densification step.
3. Each stage trains through the trainer's own loop for 35 iterations numbered so the window
   ends at iteration 2400 (full SH degree, deformation active, the last densification step in
   the window): 3 warm-up, 10 timed without the profiler (thread CPU time), 1 profiler warm-up and
   20 under ``torch.profiler`` (CPU activities), and one more that closes the window.

What a pretrained start gets right and wrong: the counts are the real run's, so every part whose
cost follows the counts (projection, SH colours, the deformation network, Adam, densification,
the snapshot) is measured at the real size. The Gaussians themselves are a short run's, fainter
and larger than a real run's at 2400, so a pixel blends more of them and the compositing parts
come out heavier than the real run's. Compare the total with the committed run's logged time per
iteration (in the table): that run used an older kernel, 2.0-2.5x slower on its own, so a total
above it says the compositing here is too heavy. ``--checkpoints`` removes the difference.

``part:`` labels (``torch.profiler.record_function``) are put around the trainer's methods from
here, for this process only (nothing in the trainer changes); ``benchmarks/iteration_attribution.py``
splits the capture by them and by the rasterizer's autograd Functions. The densification step runs
once in the window (at 2400); its time is reported spread over the run (22 steps in 3000
iterations), an upper bound, since earlier steps see fewer Gaussians. Times are wall time under
the profiler; ``cpu_share`` (thread CPU time over wall time of the window) says how much of it
the process ran on a core, and the shares do not depend on it.

Writes ``iteration_profile.csv`` (one row per part), ``iteration_profile_ops.csv`` (each stage's
largest single ops), both keeping the rows of scene/mode pairs not measured this time, and
``iteration_profile.md`` from them.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Iterator
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile, record_function, schedule  # noqa: E402

from benchmarks.iteration_attribution import (DENSIFY_STEP, LABEL, PART_ORDER, attribute,  # noqa: E402
                                              spans_from_profiler)
from contracts.atomic import write_dataclass_csv, write_text  # noqa: E402
from contracts.train_log import read_train_log  # noqa: E402
from smokeseer import api  # noqa: E402
from contracts.set_items import parse_set_items  # noqa: E402
from smokeseer.config import DensifyConfig, DensifyWindow, TrainConfig, make_config  # noqa: E402
from smokeseer.model.deform import MOTION_KEYS, motion_tensors  # noqa: E402
from smokeseer.model.gaussians import GaussianSet, edit_rows, quat_to_rotmat  # noqa: E402
from smokeseer.model.optim import Adam  # noqa: E402
from smokeseer.raster import api as raster_api  # noqa: E402
from smokeseer.train import losses, stage2  # noqa: E402
from smokeseer.train import loop as trainloop  # noqa: E402
from smokeseer.train.loop import IterationOutput, StageProblem, StageSchedule, run_stage  # noqa: E402
from smokeseer.train.stage2 import Stage2Problem  # noqa: E402
from smokeseer.train.stage3 import Stage3Problem  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
RUNS = ROOT / "data" / "tables_standard" / "runs"
DATASETS = ROOT / "data" / "standard"
PRETRAIN_FRACTION = 0.1
WINDOW_END = 2400
WARM, TIMED, ACTIVE = 3, 10, 20
TOP_OPS = 15


@dataclass
class PartRow:
    scene: str
    mode: str
    stage: int
    part: str
    ms_per_iteration: float
    share: float
    surface_gaussians: int
    smoke_gaussians: int
    loaded_surface: int
    loaded_smoke: int
    start_state: str
    iterations_profiled: int
    threads: int
    load_1min: float
    cpu_share: float
    unprofiled_cpu_ms_per_iteration: float
    commit: str


@dataclass
class OpRow:
    scene: str
    mode: str
    stage: int
    part: str
    op: str
    ms_per_iteration: float
    share: float


@dataclass
class Counts:
    """Gaussian counts of a committed standard run at ``WINDOW_END``, and its logged wall time per
    iteration of each stage over the 100 iterations before (older code, its own machine load)."""

    stage2: int
    surface: int
    smoke: int
    run: Path
    ms_per_iteration: dict[int, float]


def labelled(fn: Callable[..., Any], label: str) -> Callable[..., Any]:
    """``fn`` inside ``record_function("part:LABEL")``: no change to what it computes."""
    def call(*args: Any, **kwargs: Any) -> Any:
        with record_function(LABEL + label):
            return fn(*args, **kwargs)
    return call


def run_counts(run: Path) -> Counts:
    """The Gaussian counts a finished run (``run``/train_log.csv) logged at ``WINDOW_END``."""
    rows = {(int(r["stage"]), int(r["iteration"])): r for r in read_train_log(run / "train_log.csv")}
    ends = {s: (rows.get((s, WINDOW_END - 100)), rows.get((s, WINDOW_END))) for s in (2, 3)}
    if any(r is None for pair in ends.values() for r in pair):
        raise SystemExit(f"{run / 'train_log.csv'}: no stage 2 and 3 rows at iterations "
                         f"{WINDOW_END - 100} and {WINDOW_END}")
    per_it = {s: (float(b["wall_s"]) - float(a["wall_s"])) / 100 * 1e3 for s, (a, b) in ends.items()}
    s2, s3 = ends[2][1], ends[3][1]
    return Counts(int(s2["n_gaussians"]), int(s3["n_gaussians"]), int(s3["n_smoke"] or 0), run, per_it)


def committed_counts(scene: str, mode: str, runs: Path, overrides: dict[str, Any] | None = None) -> Counts:
    """The Gaussian counts of the committed seed-0 run of today's standard settings (with ``overrides``)."""
    want = make_config(mode, "standard", 0, overrides).sha256()
    for metrics in sorted((runs / scene / mode).glob("seed0-*/metrics.json")):
        doc = json.loads(metrics.read_text())
        if doc.get("status") == "ok" and doc.get("config_sha256") == want:
            return run_counts(metrics.parent)
    raise SystemExit(f"{runs / scene / mode}: no finished seed-0 run of the current standard settings "
                     f"(config_sha256 {want[:12]}...); --counts-from RUN takes the counts from another run")


def scaled_overrides(cfg: TrainConfig, fraction: float) -> dict[str, Any]:
    """Overrides that shorten both stages to ``fraction`` of their iterations and scale with them
    the schedules counted in iterations (the windows and warm-ups are fractions of the stage, so
    they follow by themselves); no held-out evaluation, no intermediate checkpoint."""
    def scale(v: int) -> int:
        return max(1, round(v * fraction))

    out: dict[str, Any] = {"stage2.iterations": scale(cfg.stage2.iterations),
                           "stage3.iterations": scale(cfg.stage3.iterations),
                           "sh_increase_every": scale(cfg.sh_increase_every),
                           "stage3.test_every": 0, "checkpoint_every": 0, "progress": False}
    for name, d in (("stage2.densify", cfg.stage2.densify), ("stage3.smoke_densify", cfg.stage3.smoke_densify),
                    ("stage3.surface_densify", cfg.stage3.surface_densify)):
        if d.every > 0:
            out[f"{name}.every"] = scale(d.every)
    return out


def match_count(g: GaussianSet, opt: Adam, target: int, generator: torch.Generator) -> None:
    """Grow ``g`` to ``target`` Gaussians by 3DGS splits of randomly chosen ones (two samples of
    the Gaussian, scales / 1.6, the parent's other values and Adam moments), or trim it by dropping
    the most transparent ones (by the largest of their opacities)."""
    while g.n < target:
        idx = torch.randperm(g.n, generator=generator)[:target - g.n]
        means = g["means"].detach()[idx]
        scales = g["log_scales"].detach()[idx].exp()
        rot = quat_to_rotmat(g.quats.detach()[idx])
        a, b = (means + torch.einsum("nij,nj->ni", rot, torch.randn(len(idx), 3, generator=generator) * scales)
                for _ in range(2))

        def grow(name: str, t: torch.Tensor, moment: bool = False) -> torch.Tensor:
            t = t.clone()
            if moment:
                return torch.cat([t, t[idx]])
            if name == "means":
                t[idx] = a
                return torch.cat([t, b])
            if name == "log_scales":
                t[idx] -= math.log(1.6)
            return torch.cat([t, t[idx]])
        edit_rows(g, opt, grow)
    if g.n > target:
        opacity = torch.stack([g[k].detach().reshape(g.n) for k in g.params if k.startswith("opacity")]).max(0).values
        keep = opacity.argsort(descending=True)[:target].sort().values
        edit_rows(g, opt, lambda name, t, moment=False: t[keep])


class ProfiledProblem(StageProblem):
    """A stage seen through the trainer's loop with its methods labelled, its iterations numbered
    ``offset`` later, the profiler stepped and the unprofiled iterations timed."""

    def __init__(self, inner: StageProblem, offset: int, prof: profile) -> None:
        self.inner, self.offset, self.prof = inner, offset, prof
        self.stage, self.name, self.streams = inner.stage, inner.name, inner.streams
        self.checkpoint = f"{inner.checkpoint}_profiled"  # never the real stage's: nothing to resume
        self.clock: dict[int, tuple[float, float]] = {}

    def forward(self, it: int) -> IterationOutput:
        self.clock[it] = (time.thread_time(), time.perf_counter())  # before the profiler's own work
        if it > 1:
            self.prof.step()
        with record_function(LABEL + "forward"):
            return self.inner.forward(it + self.offset)

    def named_gradients(self) -> list[tuple[str, torch.Tensor | None]]:
        with record_function(LABEL + "nan guard"):
            return self.inner.named_gradients()

    def named_parameters(self) -> list[tuple[str, torch.Tensor]]:
        with record_function(LABEL + "nan guard"):
            return self.inner.named_parameters()

    def optimizer_step(self, it: int) -> None:
        with record_function(LABEL + "adam"):
            self.inner.optimizer_step(it + self.offset)

    def after_step(self, it: int, out: IterationOutput) -> None:
        with record_function(LABEL + "densify"):
            self.inner.after_step(it + self.offset, out)

    def state(self) -> dict[str, Any]:
        with record_function(LABEL + "snapshot"):
            return self.inner.state()

    def load_state(self, payload: dict[str, Any]) -> None:
        self.inner.load_state(payload)

    def log_row(self, it: int, out: IterationOutput, heldout: dict[str, float | None] | None) -> dict[str, Any]:
        with record_function(LABEL + "log"):
            return self.inner.log_row(it + self.offset, out, heldout)


@contextmanager
def loop_labels() -> Iterator[None]:
    """Labels on the loop's NaN guard and snapshot, on SSIM and on the SH colours, restored on exit."""
    with ExitStack() as stack:
        for module, name, label in ((trainloop, "guard", "nan guard"), (trainloop, "detached_copy", "snapshot"),
                                    (losses, "ssim", "ssim"), (raster_api, "view_colors", "sh colours")):
            stack.enter_context(mock.patch.object(module, name, labelled(getattr(module, name), label)))
        yield


@dataclass
class Window:
    """One stage's profiled window: parts and (part, op) in ms per iteration, and how it ran."""

    parts: dict[str, float]
    ops: dict[tuple[str, str], float]
    cpu_share: float
    unprofiled_cpu_ms: float
    load: float
    sizes: tuple[int, int, int, int] = (0, 0, 0, 0)
    """Surface and smoke Gaussians in the window, and as loaded (before the counts were matched)."""


def densify_steps(d: DensifyWindow, first: int, last: int) -> int:
    """Iterations in [first, last] on which a densification step runs (``DensifyStrategy.step``)."""
    if d.every <= 0:
        return 0
    return sum(1 for it in range(max(first, d.start), min(last, d.stop) + 1) if it % d.every == 0)


def run_window(ctx: Any, problem: StageProblem, densify: DensifyConfig, stage_iterations: int) -> Window:
    """Train ``problem`` for the window through ``run_stage`` under the profiler."""
    wait = WARM + TIMED
    total = wait + 1 + ACTIVE + 1
    offset = WINDOW_END - (wait + 1 + ACTIVE)
    prof = profile(activities=[ProfilerActivity.CPU], schedule=schedule(wait=wait, warmup=1, active=ACTIVE, repeat=1))
    wrapped = ProfiledProblem(problem, offset, prof)
    load = os.getloadavg()[0]
    with loop_labels():
        prof.start()
        run_stage(ctx, wrapped, StageSchedule(total, ctx.cfg.log_every, 0, 0, "profile window"))
        prof.stop()
    att = attribute(spans_from_profiler(prof.events()))
    if att.steps != ACTIVE:
        raise RuntimeError(f"profiled {att.steps} steps, expected {ACTIVE}")
    window = densify.window(stage_iterations)
    in_window = densify_steps(window, wait + 2 + offset, wait + 1 + ACTIVE + offset)
    spread = att.steps / in_window * densify_steps(window, 1, stage_iterations) / stage_iterations if in_window else 0

    def per_iteration(part: str, us: float) -> float:
        return us / 1e3 / att.steps * (spread if part == DENSIFY_STEP else 1.0)
    c = wrapped.clock
    (cpu0, wall0), (cpu1, wall1) = c[wait + 2], c[total]
    timed_cpu = (c[wait + 1][0] - c[WARM + 1][0]) / TIMED * 1e3
    return Window({k: per_iteration(k, v) for k, v in att.parts.items()},
                  {k: per_iteration(k[0], v) for k, v in att.ops.items()},
                  (cpu1 - cpu0) / (wall1 - wall0), timed_cpu, load)


class WindowsDone(Exception):
    """Raised after the Stage-3 window: the run stops there (no evaluation)."""


def profile_case(dataset: Path, mode: str, counts: Counts, tmp: Path, fraction: float,
                 checkpoints: Path | None, overrides: dict[str, Any]) -> dict[int, Window]:
    """Pretrain (unless ``checkpoints`` holds a finished run's), then profile one Stage-2 and one
    Stage-3 window (module docstring)."""
    if checkpoints is None:
        t = time.perf_counter()
        api.train_and_evaluate(dataset, tmp / "pretrain", mode, "standard", 0,
                               {**overrides, **scaled_overrides(make_config(mode, "standard", 0, overrides), fraction)})
        print(f"  pretrained in {time.perf_counter() - t:.0f} s", flush=True)
        checkpoints = tmp / "pretrain" / "checkpoints"
    payload = {s: torch.load(checkpoints / f"stage{s}.pt", map_location="cpu", weights_only=False) for s in (2, 3)}
    split_rng = torch.Generator().manual_seed(0)
    windows: dict[int, Window] = {}

    def stage2_window(ctx: Any, mod: Any, init_points: Any, deformable: bool, heldout_psnr: Any = None,
                      sha: Any = None) -> Any:
        problem = Stage2Problem(ctx, mod, init_points, deformable, heldout_psnr)
        problem.load_state(payload[2])
        loaded = problem.g.n
        match_count(problem.g, problem.optimizer, counts.stage2, split_rng)
        problem.strategy.step = labelled(problem.strategy.step, "densify step")
        n = problem.g.n
        with mock.patch.object(stage2, "render", labelled(stage2.render, f"{problem.color} pass")):
            windows[2] = run_window(ctx, problem, ctx.cfg.stage2.densify, ctx.cfg.stage2.iterations)
        windows[2].sizes = (n, 0, loaded, 0)
        return problem.result()

    def stage3_window(ctx: Any, model: Any, rgb: Any, thermal: Any, switches: Any, prior: Any,
                      heldout_psnr: Any = None) -> Any:
        problem = Stage3Problem(ctx, model, rgb, thermal, switches, prior, heldout_psnr)
        state = payload[3]
        if model.deform is not None and state.get("deform") is not None:
            own = model.deform.state_dict()
            if own.keys() != state["deform"].keys() or any(own[k].shape != v.shape for k, v in state["deform"].items()):
                # A network of another shape (``--set deform.width=...``): this one starts fresh.
                state = {**state, "deform": None, "deform_optimizer": None}
        smoke = state.get("smoke")
        if smoke is not None and ctx.cfg.deform.kind == "fourier" and MOTION_KEYS[0] not in smoke:
            # A state trained with the network: zero Fourier coefficients and a fresh smoke optimiser,
            # so the window pays for the motion as such a run does.
            n = smoke["means"].shape[0]
            state = {**state, "smoke": {**smoke, **motion_tensors(n, ctx.cfg.deform, torch.device("cpu"))},
                     "smoke_optimizer": None}
        problem.load_state(state)
        loaded = (model.surface.n, model.smoke.n if model.smoke is not None else 0)
        match_count(model.surface, problem.surface_optimizer, counts.surface, split_rng)
        if model.smoke is not None:
            match_count(model.smoke, problem.smoke_optimizer, counts.smoke, split_rng)
        sizes = (model.surface.n, model.smoke.n if model.smoke is not None else 0, *loaded)
        model.render_rgb = labelled(model.render_rgb, "rgb pass")
        model.render_thermal = labelled(model.render_thermal, "thermal pass")
        if model.deform is not None:  # encode once and decode per time with deform.shared_position
            for name in ("forward", "encode", "decode"):
                setattr(model.deform, name, labelled(getattr(model.deform, name), "deformation"))
        for strategy in (problem.strategy, problem.surface_strategy):
            if strategy is not None:
                strategy.step = labelled(strategy.step, "densify step")
        windows[3] = run_window(ctx, problem, ctx.cfg.stage3.smoke_densify, ctx.cfg.stage3.iterations)
        windows[3].sizes = sizes
        raise WindowsDone

    with mock.patch.object(api, "train_stage2", stage2_window), mock.patch.object(api, "train_stage3", stage3_window):
        try:
            api.train_and_evaluate(dataset, tmp / "profiled", mode, "standard", 0, {**overrides, "progress": False})
        except WindowsDone:
            pass
    return windows


def git_commit() -> str:
    done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else "unknown"


def rows_for(scene: str, mode: str, windows: dict[int, Window], start: str,
             commit: str) -> tuple[list[PartRow], list[OpRow]]:
    """The parts of each stage (and their total), and the stage's ``TOP_OPS`` largest ops."""
    parts, ops = [], []
    for stage, w in sorted(windows.items()):
        total = sum(w.parts.values())
        for part in [*PART_ORDER, *(p for p in w.parts if p not in PART_ORDER), "total"]:
            ms = total if part == "total" else w.parts.get(part, 0.0)
            parts.append(PartRow(scene, mode, stage, part, round(ms, 3), round(ms / total, 4), *w.sizes, start, ACTIVE,
                                 torch.get_num_threads(), round(w.load, 2), round(w.cpu_share, 3),
                                 round(w.unprofiled_cpu_ms, 2), commit))
        for (part, op), ms in sorted(w.ops.items(), key=lambda kv: -kv[1])[:TOP_OPS]:
            ops.append(OpRow(scene, mode, stage, part, op, round(ms, 3), round(ms / total, 4)))
    return parts, ops


def merged(path: Path, new: list[Any]) -> list[Any]:
    """``new`` after the rows of an earlier run of this script for scene/mode pairs ``new`` lacks."""
    if not path.is_file():
        return new
    cls = type(new[0])
    types = {f.name: f.type for f in fields(cls)}
    with path.open(newline="") as fh:
        old = [cls(**{k: {"int": int, "float": float}.get(types[k], str)(v) for k, v in r.items()})
               for r in csv.DictReader(fh)]
    done = {(r.scene, r.mode) for r in new}
    return [r for r in old if (r.scene, r.mode) not in done] + new


def earlier_counts(scene: str, label: str, runs: Path) -> Counts | None:
    """The committed run behind the rows an earlier call wrote for ``label`` (a mode, or a mode and
    its overrides), or None where there is none to find (rows profiled at another run's counts)."""
    mode, *sets = label.split(" ")
    try:
        return committed_counts(scene, mode, runs, parse_set_items(sets))
    except SystemExit:
        return None


def markdown(rows: list[PartRow], ops: list[OpRow], counts: dict[tuple[str, str], Counts | None]) -> str:
    """Per stage, one column per scene/mode: ms per iteration (share); then each case's largest ops."""
    cases = list(dict.fromkeys((r.scene, r.mode) for r in rows))
    lines = ["# Where a standard iteration spends its time", "",
             "Written by `python benchmarks/iteration_profile.py`; its docstring says how (a trained state grown or",
             "trimmed to a committed standard run's Gaussian counts, 20 profiled iterations ending at iteration 2400).",
             "Milliseconds per iteration, wall time under `torch.profiler`, share of the iteration in brackets;",
             "-: under 0.05 ms (the stage has no such pass); parts under 0.05 ms everywhere are left out",
             "(all are in `iteration_profile.csv`, the largest single ops in `iteration_profile_ops.csv`).", ""]
    for stage in (2, 3):
        here = [r for r in rows if r.stage == stage]
        if not here:
            continue
        cols = [c for c in cases if any((r.scene, r.mode) == c for r in here)]
        get = {(r.scene, r.mode, r.part): r for r in here}
        lines += [f"## Stage {stage}", "", "| part | " + " | ".join(f"{s} {m}" for s, m in cols) + " |",
                  "|---|" + "---:|" * len(cols)]
        for part in dict.fromkeys(r.part for r in here):
            found = [get.get((s, m, part)) for s, m in cols]
            if part == "total":
                lines.append("| **total** | " + " | ".join(f"**{r.ms_per_iteration:.1f}**" if r else "" for r in found)
                             + " |")
            elif any(r is not None and r.ms_per_iteration >= 0.05 for r in found):
                lines.append(f"| {part} | " + " | ".join(
                    f"{r.ms_per_iteration:.1f} ({100 * r.share:.0f} %)" if r and r.ms_per_iteration >= 0.05 else "-"
                    for r in found) + " |")
        info = [get[(s, m, "total")] for s, m in cols]
        lines.append("| Gaussians (surface + smoke) | " + " | ".join(
            f"{r.surface_gaussians} + {r.smoke_gaussians}" if r.smoke_gaussians else f"{r.surface_gaussians}"
            for r in info) + " |")
        lines.append("| start: state loaded, its Gaussians | " + " | ".join(
            f"{r.start_state}: {r.loaded_surface}" + (f" + {r.loaded_smoke}" if r.smoke_gaussians else "")
            for r in info) + " |")
        lines.append("| without the profiler: thread CPU ms per iteration | " + " | ".join(
            f"{r.unprofiled_cpu_ms_per_iteration:.1f}" for r in info) + " |")
        lines.append("| CPU share of the window; load (1 min) | " + " | ".join(
            f"{r.cpu_share:.2f}; {r.load_1min:.1f}" for r in info) + " |")
        lines.append("| threads; commit | " + " | ".join(f"{r.threads}; {r.commit}" for r in info) + " |")
        lines.append("| the counts' run: its logged ms per iteration, 2300-2400 | " + " | ".join(
            f"{counts[c].ms_per_iteration[stage]:.0f}" if counts.get(c) else "-" for c in cols) + " |")
        lines.append("")
    lines += ["The densification step ran once in each window; its row is that step spread over the run's 22 steps",
              "in 3000 iterations (an upper bound: earlier steps see fewer Gaussians).", "",
              "A `pretrained` start has the real run's Gaussian counts but a short run's Gaussians, fainter and",
              "larger than the real run's at iteration 2400: the parts that follow the counts (projection, SH",
              "colours, deformation network, Adam, densification, snapshot) are at the real size, the compositing",
              "parts heavier than the real run's. The committed run's logged time is the check: it ran an older",
              "kernel, 2.0-2.5x slower on its own, at its own machine load, so a total above it means compositing",
              "too heavy here. A `checkpoints` start is a finished run's own state.", "", "## Largest ops", "",
              "Own time of single op names within a part, ms per iteration (the backward nodes' names are",
              "torch's `evaluate_function` entries).", ""]
    for stage in (2, 3):
        for s, m in cases:
            top = [o for o in ops if (o.scene, o.mode, o.stage) == (s, m, stage)]
            if top:
                lines.append(f"- {s} {m}, Stage {stage}: " + "; ".join(
                    f"`{o.op}` ({o.part}) {o.ms_per_iteration:.1f}" for o in top[:8]))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="house", help="comma-separated standard scenes (data/standard/SCENE)")
    ap.add_argument("--modes", default="full,rgb-only", help="comma-separated methods")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--pretrain-fraction", type=float, default=PRETRAIN_FRACTION,
                    help="pretraining length as a fraction of the standard profile's")
    ap.add_argument("--checkpoints", type=Path,
                    help="a finished standard run's checkpoints/ (stage2.pt, stage3.pt) to start from instead of "
                         "pretraining: that run's trained state (one scene and mode)")
    ap.add_argument("--runs", type=Path, default=RUNS, help="committed standard runs (for the Gaussian counts)")
    ap.add_argument("--counts-from", type=Path,
                    help="a finished run folder whose logged Gaussian counts to profile at, instead of the "
                         "committed seed-0 run (one scene and mode)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config overrides for every case (as train-and-evaluate's); the column names them")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    overrides = parse_set_items(args.set)
    variant = " ".join(args.set)
    torch.set_num_threads(args.threads)
    cases = [(s, m) for s in args.scenes.split(",") for m in args.modes.split(",")]
    for scene, _ in cases:
        if not (DATASETS / scene / "dataset.json").is_file():
            raise SystemExit(f"{DATASETS / scene}: no standard dataset (dataset.json missing)")
    if (args.checkpoints is not None or args.counts_from is not None) and len(cases) != 1:
        raise SystemExit("--checkpoints, --counts-from: give one scene and one mode (the run they are of)")
    if args.checkpoints is not None:
        for s in (2, 3):
            if not (args.checkpoints / f"stage{s}.pt").is_file():
                raise SystemExit(f"{args.checkpoints / f'stage{s}.pt'}: no such checkpoint (--checkpoints)")
    start = (f"checkpoints {args.checkpoints.resolve().parent.name}" if args.checkpoints is not None
             else f"pretrained {args.pretrain_fraction:g}")
    counts = {(s_, f"{m} {variant}".strip()): run_counts(args.counts_from) if args.counts_from is not None
              else committed_counts(s_, m, args.runs, overrides) for s_, m in cases}
    commit = git_commit()
    parts: list[PartRow] = []
    ops: list[OpRow] = []
    for scene, mode in cases:
        label = f"{mode} {variant}".strip()
        c = counts[(scene, label)]
        print(f"{scene} {label}: stage 2 {c.stage2}, stage 3 {c.surface} + {c.smoke} Gaussians "
              f"(from {c.run.relative_to(ROOT) if c.run.is_relative_to(ROOT) else c.run})", flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            windows = profile_case(DATASETS / scene, mode, c, Path(tmp), args.pretrain_fraction, args.checkpoints,
                                   overrides)
        new_parts, new_ops = rows_for(scene, label, windows, start, commit)
        parts += new_parts
        ops += new_ops
        for stage, w in sorted(windows.items()):
            print(f"  stage {stage}: {sum(w.parts.values()):.1f} ms/it profiled, {w.unprofiled_cpu_ms:.1f} ms CPU "
                  f"unprofiled, cpu share {w.cpu_share:.2f}, load {w.load:.1f}", flush=True)
    parts = merged(args.out / "iteration_profile.csv", parts)
    ops = merged(args.out / "iteration_profile_ops.csv", ops)
    text = markdown(parts, ops, {**{c: earlier_counts(*c, args.runs) for c in {(r.scene, r.mode) for r in parts}},
                                 **counts})
    write_dataclass_csv(args.out / "iteration_profile.csv", parts)
    write_dataclass_csv(args.out / "iteration_profile_ops.csv", ops)
    write_text(args.out / "iteration_profile.md", text)
    print(f"wrote iteration_profile.csv, iteration_profile_ops.csv and iteration_profile.md in {args.out}")


if __name__ == "__main__":
    main()
