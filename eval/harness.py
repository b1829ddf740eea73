"""Run or collect every (scene, variant, seed), cached by config hash, on a process
pool or a Dask cluster, then write the tables, figures and report.

Each dataset generation, dehazing pass and training run is one task. The callables
that do the work are parameters (defaults: the generator and trainer APIs), so the
same scheduling, caching and failure bookkeeping runs for real work and in tests.
Results are read back from the run folders (contracts.results_format), never from the
trainer's return value, so cached and fresh runs go through the same reader.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
import time
import traceback
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
from tqdm import tqdm

from contracts.atomic import write_json
from contracts.executors import Executor, Job, drain, open_executor
from contracts.folder_lock import folder_lock, lock_held
from contracts.provenance import provenance
from contracts.results_format import ResultsFormatError, read_metrics
from contracts.source import code_digest
from contracts.train_log import read_train_log
from eval.dehaze import dehaze_dataset, get_dehazer
from contracts.float_setup import float_setup
from eval.runs import VARIANTS, RunResult, RunSpec, config_hash
from eval.settings import DatasetOutcome, HarnessConfig
from eval.shared_stage2 import (leaders_first, rgb_stage2_sha, stage2_done, stage2_donors, stage2_groups,
                                stage2_leaders, stage2_sha, take_finished_stage2)
from eval.sources import sources_sha256
from eval.twins import full_twins, twin_source

log = logging.getLogger("regenerate-tables")

TrainFn = Callable[..., Any]
GenerateFn = Callable[..., Path]
TRAINER_ENTRY = "smokeseer.api"
GENERATOR_ENTRIES = ("generator.api", "blender.worker")
DEHAZE_ENTRY = "eval.dehaze"
DEFAULT_OUT = Path("runs/tables")


def default_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                  overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The real trainer (imported lazily so the harness loads without torch work)."""
    from smokeseer.api import train_and_evaluate

    quiet = {"progress": False, **(overrides or {})}  # per-run lines come from the harness
    return train_and_evaluate(dataset, out, mode, profile=profile, seed=seed, overrides=quiet)


def default_generate(preset: str, out: Path, **overrides: Any) -> Path:
    """The real generator (Blender runs in its own worker subprocess)."""
    from generator.api import generate

    return generate(preset, out, show_progress=False, **overrides)


# ---------------------------------------------------------------- tasks (run in workers)


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"


def dataset_task(o: DatasetOutcome, make: Callable[[Path], Any]) -> tuple[str, str, float]:
    """Produce one dataset folder under its lock and mark it done before the lock is released,
    so an overlapping invocation reuses it; returns (status, error, seconds)."""
    path = Path(o.path)
    with folder_lock(path):
        seconds = finished_dataset(path, o.hash)
        if seconds is not None:
            return "ok", "", seconds
        t0 = time.perf_counter()
        try:
            if path.exists():
                shutil.rmtree(path)
            make(path)
            if not (path / "dataset.json").is_file():
                raise RuntimeError(f"{o.kind} dataset task returned without writing {path}/dataset.json")
        except Exception as exc:  # recorded against every run of the scene, never dropped
            return "failed", _error_text(exc), time.perf_counter() - t0
        done = replace(o, status="ok", error="", wall_time_s=time.perf_counter() - t0)
        write_json(_done_marker(path), asdict(done))
        return "ok", "", done.wall_time_s


def dehaze_into(src: str, dehazer: str, dst: Path) -> None:
    dehaze_dataset(Path(src), dst, get_dehazer(dehazer))


def finished_dataset(path: Path, h: str) -> float | None:
    """Seconds it took, if the dataset at path was finished with this config hash, else None."""
    marker = _read_json(_done_marker(path))
    if marker and marker.get("hash") == h and (path / "dataset.json").is_file():
        return float(marker.get("wall_time_s", 0.0))
    return None


def finished_run(spec: RunSpec, run_dir: Path) -> RunResult | None:
    """The cached record of a run that finished with exactly this config, else None. Its paths
    are where the run lies now: a committed --out folder (data/README.md) or a moved one was
    recorded on another machine or in another checkout."""
    rec = _read_json(run_dir / "harness.json")
    if rec and rec.get("status") == "ok" and rec.get("config_hash") == spec.hash() \
            and (run_dir / "metrics.json").is_file():
        r = RunResult.from_json(rec)
        r.cached, r.run_dir, r.dataset = True, str(run_dir), spec.dataset
        return r
    return None


def wait_for_stage2(leader: Path, stage2_sha: str, poll_s: float = 2.0, start_grace_s: float = 60.0) -> float:
    """Wait while the run folder ``leader`` is training and has no finished Stage 2 of these
    settings; returns the seconds waited. The leader was handed to a worker first
    (``leaders_first``) but may not have taken its lock yet, so it gets ``start_grace_s`` to
    start; one that is not running after that (finished or dead) is not waited for."""
    t0 = time.perf_counter()
    while not lock_held(leader) and not (leader / "train_log.csv").exists() \
            and time.perf_counter() - t0 < start_grace_s:
        time.sleep(min(poll_s, 0.5))
    checkpoint, seen = leader / "checkpoints" / "stage2.pt", None
    while lock_held(leader):
        stamp = checkpoint.stat().st_mtime_ns if checkpoint.is_file() else None
        if stamp is not None and stamp != seen and stage2_done(leader, stage2_sha):
            break
        seen = stamp
        time.sleep(poll_s)
    return time.perf_counter() - t0


def run_task(spec: RunSpec, run_dir: str, train_fn: TrainFn, threads: int, prep_time_s: float = 0.0,
             stage2_donors: tuple[str, ...] = (), device: str = "cpu", stage2_leader: str = "") -> RunResult:
    """Train and evaluate one run under its lock, and record it in harness.json before the lock
    is released; a run another invocation finished meanwhile is returned as cached. A run that
    has not started takes a finished Stage 2 from one of ``stage2_donors`` when one has it,
    after waiting for ``stage2_leader`` (its group's first run) if that one is in Stage 2 now."""
    with folder_lock(Path(run_dir)):
        done = finished_run(spec, Path(run_dir))
        if done is not None:
            return done
        if stage2_leader and not (Path(run_dir) / "train_log.csv").exists():
            waited = wait_for_stage2(Path(stage2_leader), stage2_sha(spec))
            if waited > 1.0:
                log.info("%s/%s/seed %d waited %.0f s for the Stage 2 of %s", spec.scene, spec.variant, spec.seed,
                         waited, stage2_leader)
        donor = (take_finished_stage2(Path(run_dir), list(stage2_donors), stage2_sha(spec), rgb_stage2_sha(spec))
                 if stage2_donors else "")
        res = _train_run(spec, run_dir, train_fn, threads, device)
        res.prep_time_s = prep_time_s
        res.stage2_from = donor
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        write_json(Path(run_dir) / "harness.json", res.to_json())
        return res


def logged_wall_s(run_dir: Path) -> float:
    """The wall time train_log.csv already holds (its last row's wall_s), 0 for a fresh folder:
    the trainer's own total covers only the attempt that finishes."""
    log_path = run_dir / "train_log.csv"
    rows = read_train_log(log_path) if log_path.is_file() else []
    return float(rows[-1]["wall_s"]) if rows and rows[-1].get("wall_s") else 0.0


def _train_run(spec: RunSpec, run_dir: str, train_fn: TrainFn, threads: int, device: str) -> RunResult:
    """Train and evaluate one run; any exception becomes a failed record with its error. A folder
    left by an interrupted or failed attempt is kept: its name holds the config hash, so its
    checkpoints were written with these settings and the trainer resumes from them."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
    res = RunResult(scene=spec.scene, variant=spec.variant, seed=spec.seed, status="failed",
                    run_dir=run_dir, config_hash=spec.hash(), dataset=spec.dataset, device=device,
                    code_digest=spec.code, sources_sha256=sources_sha256(TRAINER_ENTRY),
                    float_setup=float_setup())
    t0 = time.perf_counter()
    res.logged_before_s = logged_wall_s(Path(run_dir))
    try:
        Path(run_dir).parent.mkdir(parents=True, exist_ok=True)
        train_fn(Path(spec.dataset), Path(run_dir), spec.mode, profile=spec.profile, seed=spec.seed,
                 overrides={**spec.overrides, "device": device})
        res.wall_time_s = time.perf_counter() - t0
        try:
            out = read_metrics(Path(run_dir))
        except ResultsFormatError as exc:
            res.error = f"run folder unreadable: {exc}"
            return res
        if out["status"] != "ok":
            res.error = str(out.get("error") or "trainer reported status failed without an error")
            return res
        metrics = out["metrics"]
        psnr = metrics.get("psnr")
        if not isinstance(psnr, (int, float)) or not np.isfinite(psnr):
            res.error = f"trainer returned no finite metrics.psnr (got {psnr!r})"
            return res
        res.metrics = dict(metrics)
        total = (out.get("wall_time_s") or {}).get("total")
        if isinstance(total, (int, float)):
            res.wall_time_s = float(total) + res.logged_before_s
        res.status = "ok"
    except Exception as exc:
        res.wall_time_s = time.perf_counter() - t0
        res.error = _error_text(exc)
    return res


# ---------------------------------------------------------------- orchestration


def _done_marker(path: Path) -> Path:
    return path.with_name(path.name + ".done.json")


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


@dataclass
class DatasetJob:
    """A dataset to produce (or reuse): its outcome record and how to make it."""

    outcome: DatasetOutcome
    make: Callable[[Path], Any] | None
    source: DatasetOutcome | None = None


def _job(o: DatasetOutcome, make: Callable[[Path], Any] | None, source: DatasetOutcome | None = None) -> DatasetJob:
    if make is not None:
        seconds = finished_dataset(Path(o.path), o.hash)
        if seconds is not None:
            o.cached, o.wall_time_s, make = True, seconds, None
    return DatasetJob(o, make, source)


def plan_datasets(cfg: HarnessConfig, generate_fn: GenerateFn) -> list[DatasetJob]:
    """Provided datasets are used as they are; the rest are generated once per config hash."""
    jobs = []
    code = code_digest(*GENERATOR_ENTRIES)
    for scene in cfg.scenes:
        if scene in cfg.datasets:
            p = Path(cfg.datasets[scene]).resolve()
            jobs.append(DatasetJob(DatasetOutcome(scene, "provided", str(p), config_hash((p / "dataset.json").read_text()),
                                                  cached=True), None))
            continue
        h = config_hash({"scene": scene, "overrides": cfg.gen_overrides, "seed": cfg.dataset_seed, "code": code})
        path = (Path(cfg.out) / "datasets" / f"{scene}-{h[:12]}").resolve()
        make = partial(generate_fn, scene, seed=cfg.dataset_seed, **cfg.gen_overrides)
        jobs.append(_job(DatasetOutcome(scene, "generated", str(path), h), make))
    return jobs


def plan_dehazed(cfg: HarnessConfig, sources: list[DatasetJob]) -> list[DatasetJob]:
    """One dehazed copy per scene for the ImgDehaze baseline, cached like a dataset."""
    if not any(VARIANTS[v].dehazer for v in cfg.variants()):
        return []
    settings = asdict(get_dehazer(cfg.dehazer)) if cfg.dehazer == "dcp" else {"name": cfg.dehazer}
    code = code_digest(DEHAZE_ENTRY)
    jobs = []
    for src in (j.outcome for j in sources):
        h = config_hash({"source": src.hash, "dehazer": cfg.dehazer, "settings": settings, "code": code})
        path = (Path(cfg.out) / "datasets" / f"{src.scene}-{src.hash[:12]}-dehazed-{cfg.dehazer}-{h[:8]}").resolve()
        jobs.append(_job(DatasetOutcome(src.scene, f"dehazed:{cfg.dehazer}", str(path), h),
                         partial(dehaze_into, src.path, cfg.dehazer), src))
    return jobs


def produce_datasets(ex: Executor, jobs: list[DatasetJob], desc: str, finished_only: bool = False) -> None:
    """Run every job that is not cached; a job whose source failed fails without running; with
    ``finished_only`` a job not yet done stays pending."""
    pending = []
    for job in jobs:
        o = job.outcome
        if job.source is not None and job.source.status != "ok":
            o.status, o.error = ("pending", "source dataset pending") if job.source.status == "pending" \
                else ("failed", "source dataset unavailable")
            continue
        if job.make is None:
            continue
        if finished_only:
            o.status, o.error = "pending", "not produced yet (--finished-only)"
            continue
        Path(o.path).parent.mkdir(parents=True, exist_ok=True)

        def ok(v: tuple[str, str, float], o: DatasetOutcome = o) -> None:
            o.status, o.error, o.wall_time_s = v
            log.info("%s %-12s %s %.1f s%s", desc, o.scene, o.status, o.wall_time_s,
                     "" if o.status == "ok" else "\n" + o.error)

        def fail(exc: BaseException, o: DatasetOutcome = o) -> None:
            o.status, o.error = "failed", f"worker crashed: {type(exc).__name__}: {exc}"
            log.info("%s %-12s failed: %s", desc, o.scene, o.error)

        pending.append((dataset_task, (o, job.make), ok, fail))
    if pending:
        with tqdm(total=len(pending), desc=desc, unit="scene", file=sys.stderr) as bar:
            drain(ex, pending, bar)


def plan_runs(cfg: HarnessConfig, datasets: dict[str, DatasetOutcome],
              dehazed: dict[str, DatasetOutcome]) -> list[RunSpec]:
    """Every run; its key holds the digest of the trainer's code (the modules it imports)."""
    specs = []
    code = cfg.trainer_digest or code_digest(TRAINER_ENTRY)
    for scene in cfg.scenes:
        for key in cfg.variants():
            v = VARIANTS[key]
            ds = dehazed[scene] if v.dehazer else datasets[scene]
            for seed in cfg.seeds:
                specs.append(RunSpec(scene, key, v.mode, seed, cfg.profile, {**cfg.run_overrides(), **v.overrides},
                                     ds.path, ds.hash, code))
    return specs


SECONDS_PER_RUN = {"quick": 240.0, "standard": 1150.0, "paper": 2700.0}
"""Rough wall time of one run when the output folder has no finished run to learn from: the
quick profile's demo run on 2 CPU cores (README), the standard profile's measured 19 min on one
core of two busy ones (house, docs/method.md), and the paper's 10 + 30 minutes on an RTX 4090."""


@dataclass
class Plan:
    """What an invocation will do, printed before it starts."""

    datasets: list[DatasetJob]
    dehazed: list[DatasetJob]
    runs: list[RunSpec]
    cached_runs: int
    seconds_per_run: float
    per_run_source: str
    twins: dict[str, RunResult] = field(default_factory=dict)
    """Runs a finished Full run stands for (eval/twins.py), by run folder; not counted in cached_runs."""

    def estimated_seconds(self, workers: int) -> float:
        todo = len(self.runs) - self.cached_runs - len(self.twins)
        return todo * self.seconds_per_run / max(workers, 1)

    def describe(self, cfg: HarnessConfig) -> str:
        todo_ds = sum(j.make is not None for j in self.datasets)
        todo_dh = sum(j.make is not None for j in self.dehazed)
        todo = len(self.runs) - self.cached_runs - len(self.twins)
        est = self.estimated_seconds(cfg.workers)
        twins = f", {len(self.twins)} taken from Full's runs" if self.twins else ""
        if cfg.finished_only:
            return (f"plan: {len(cfg.scenes)} scene(s) x {len(cfg.variants())} variant(s) x {len(cfg.seeds)} seed(s) "
                    f"= {len(self.runs)} runs; --finished-only: tabling the {self.cached_runs} finished{twins}, "
                    f"{todo} pending (nothing is generated, dehazed or trained); output {Path(cfg.out).resolve()}")
        return (f"plan: {len(cfg.scenes)} scene(s) x {len(cfg.variants())} variant(s) x {len(cfg.seeds)} seed(s) "
                f"= {len(self.runs)} runs ({self.cached_runs} cached{twins}, {todo} to train); "
                f"{todo_ds} dataset(s) to generate, {todo_dh} to dehaze; profile {cfg.profile}, "
                f"{cfg.workers} worker(s); estimated {est / 3600:.1f} h of training "
                f"({self.seconds_per_run:.0f} s per run, {self.per_run_source}); output {Path(cfg.out).resolve()}")


def make_plan(cfg: HarnessConfig, generate_fn: GenerateFn) -> Plan:
    datasets = plan_datasets(cfg, generate_fn)
    dehazed = plan_dehazed(cfg, datasets)
    specs = plan_runs(cfg, {j.outcome.scene: j.outcome for j in datasets},
                      {j.outcome.scene: j.outcome for j in dehazed})
    dirs = [s.run_dir(Path(cfg.out)).resolve() for s in specs]
    finished = {str(d) for s, d in zip(specs, dirs) if finished_run(s, d) is not None}
    past = [json.loads(p.read_text()).get("wall_time_s", 0.0)
            for p in (Path(cfg.out) / "runs").rglob("harness.json")] if (Path(cfg.out) / "runs").is_dir() else []
    past = [t for t in past if isinstance(t, (int, float)) and t > 0]
    if past:
        per_run, source = float(np.mean(past)), f"mean of {len(past)} earlier run(s) in this folder"
    else:
        per_run, source = SECONDS_PER_RUN[cfg.profile], f"typical {cfg.profile}-profile run"
    twins = {d: r for d, r in full_twins(specs, Path(cfg.out), finished_run).items() if d not in finished}
    return Plan(datasets, dehazed, specs, len(finished), per_run, source, twins)


def _line(r: RunResult) -> str:
    head = f"{r.scene}/{r.variant} seed {r.seed}"
    if r.status == "ok":
        tag = "twin" if r.same_as else "cached" if r.cached else "ok"
        how = f" (the {r.same_as} run: {r.same_as_reason})" if r.same_as else \
            f" (Stage 2 from {Path(r.stage2_from).parent.name}/{Path(r.stage2_from).name})" if r.stage2_from else ""
        return f"[{tag:>6}] {head}: PSNR {r.metrics.get('psnr', float('nan')):.2f} dB, {r.wall_time_s:.1f} s{how}"
    if r.status == "pending":
        return f"[pending] {head}: {r.error}"
    return f"[FAILED] {head}: {r.error.splitlines()[0] if r.error else 'unknown error'}"


def _keep(results: list[RunResult], bar: Any, r: RunResult, advance: bool) -> None:
    """Keep a run's result and print its line; ``advance`` the bar where no executor does (the
    executor advances it for the runs it trains)."""
    results.append(r)
    bar.write(_line(r))
    if advance:
        bar.update(1)


def after_full(jobs: list[Job], specs: list[RunSpec], out: Path, training: set[str], results: list[RunResult],
               bar: Any) -> list[Job]:
    """The jobs to submit now: a run that Full's run may stand for (eval/twins.py) waits for the
    Full run this invocation trains, then takes it where its rule says so and trains otherwise."""
    now: list[Job] = []
    waiting: dict[str, list[tuple[Job, RunSpec]]] = {}
    for job in jobs:
        full = twin_source(job[1][0], specs)
        full_dir = str(full.run_dir(out).resolve()) if full is not None else ""
        if full is not None and full_dir in training:
            waiting.setdefault(full_dir, []).append((job, full))
        else:
            now.append(job)

    def release(full_dir: str) -> list[Job]:
        """The waiting jobs that Full's run, now ended, does not stand for."""
        train = []
        for job, full in waiting.pop(full_dir, []):
            spec, run_dir = job[1][0], job[1][1]
            twin = full_twins([full, spec], out, finished_run).get(run_dir)
            if twin is None:
                train.append(job)
            else:
                _keep(results, bar, twin, advance=True)
        return train

    def then(callback: Callable[[Any], Any], full_dir: str) -> Callable[[Any], list[Job]]:
        def call(value: Any) -> list[Job]:
            callback(value)
            return release(full_dir)
        return call

    return [(fn, args, then(ok, args[1]), then(fail, args[1])) if args[1] in waiting else (fn, args, ok, fail)
            for fn, args, ok, fail in now]


def execute_runs(cfg: HarnessConfig, ex: Executor, plan: Plan, train_fn: TrainFn,
                 datasets: dict[str, DatasetOutcome], dehazed: dict[str, DatasetOutcome]) -> list[RunResult]:
    """Collect cached runs and those a finished Full run stands for (eval/twins.py), run the rest
    (or, with ``finished_only``, list them as pending); a run whose dataset failed is failed, not
    skipped."""
    results: list[RunResult] = []
    pending = []
    threads = max(1, (os.cpu_count() or 1) // cfg.workers)
    specs = plan.runs
    groups = stage2_groups(specs, Path(cfg.out))
    donors, leaders = stage2_donors(groups), stage2_leaders(groups)
    bar = tqdm(total=len(specs), desc="runs", unit="run", file=sys.stderr)
    for spec in leaders_first(specs, Path(cfg.out), groups):
        run_dir = spec.run_dir(Path(cfg.out)).resolve()
        ds = dehazed[spec.scene] if VARIANTS[spec.variant].dehazer else datasets[spec.scene]
        prep = ds.wall_time_s if VARIANTS[spec.variant].dehazer else 0.0
        cached = finished_run(spec, run_dir) or plan.twins.get(str(run_dir))
        # A finished run is tabled without its dataset: --finished-only does not rebuild the dehazed
        # copies a fresh clone lacks, and the run's key holds the copy's settings, not its bytes.
        if ds.status != "ok" and not (ds.status == "pending" and cached is not None):
            r = RunResult(spec.scene, spec.variant, spec.seed, "pending" if ds.status == "pending" else "failed",
                          str(run_dir), spec.hash(), ds.path,
                          error=f"dataset ({ds.kind}) {ds.status}: {ds.error.splitlines()[0] if ds.error else ''}")
            _keep(results, bar, r, advance=True)
            continue
        if cached is not None or cfg.finished_only:
            r = cached or RunResult(spec.scene, spec.variant, spec.seed, "pending", str(run_dir), spec.hash(),
                                    spec.dataset, error="not trained yet (--finished-only)")
            _keep(results, bar, r, advance=True)
            continue

        def ok(r: RunResult) -> None:
            _keep(results, bar, r, advance=False)

        def fail(exc: BaseException, spec: RunSpec = spec, run_dir: Path = run_dir) -> None:
            r = RunResult(spec.scene, spec.variant, spec.seed, "failed", str(run_dir), spec.hash(), spec.dataset,
                          error=f"worker crashed: {type(exc).__name__}: {exc}")
            _keep(results, bar, r, advance=False)

        pending.append((spec, run_dir, prep, ok, fail))
    training = {str(run_dir) for _, run_dir, _, _, _ in pending}
    jobs = [(run_task, (spec, str(run_dir), train_fn, threads, prep, tuple(donors[str(run_dir)]), cfg.device,
                        leaders.get(str(run_dir), "") if leaders.get(str(run_dir)) in training else ""), ok, fail)
            for spec, run_dir, prep, ok, fail in pending]
    if jobs:
        drain(ex, after_full(jobs, specs, Path(cfg.out), training, results, bar), bar)
    bar.close()
    order = {(s.scene, s.variant, s.seed): i for i, s in enumerate(specs)}
    return sorted(results, key=lambda r: order[(r.scene, r.variant, r.seed)])


def regenerate(cfg: HarnessConfig, train_fn: TrainFn = default_train,
               generate_fn: GenerateFn = default_generate, dry_run: bool = False
               ) -> tuple[list[RunResult], dict[str, Path]]:
    """The whole pipeline: plan (printed first), datasets, dehazing, runs, tables, figures,
    report. With ``dry_run`` only the plan is printed."""
    from eval.claims import targets_for, write_claims
    from eval.convergence import write_convergence
    from eval.figures import write_psnr_vs_time, write_qualitative_grid
    from eval.per_view import write_per_view
    from eval.regions import write_region_split
    from eval.report import write_report
    from eval.tables import write_tables

    cfg.validate()
    plan = make_plan(cfg, generate_fn)
    log.info("%s", plan.describe(cfg))
    if dry_run:
        return [], {}
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    datasets = {j.outcome.scene: j.outcome for j in plan.datasets}
    dehazed = {j.outcome.scene: j.outcome for j in plan.dehazed}
    with open_executor(cfg.workers, cfg.scheduler) as ex:
        log.info("executing on %s", ex.description)
        produce_datasets(ex, plan.datasets, "datasets", cfg.finished_only)
        produce_datasets(ex, plan.dehazed, "dehaze", cfg.finished_only)
        results = execute_runs(cfg, ex, plan, train_fn, datasets, dehazed)
        backend = ex.description
    statuses = sorted({str(r.metrics.get("lpips_status", "")) for r in results if r.status == "ok"} - {""})
    lpips_status = "; ".join(statuses) or "no finished run"
    if any(s.startswith("skipped") for s in statuses):
        log.info("LPIPS %s. How to enable it: docs/metrics.md, 'Enabling LPIPS offline'.", lpips_status)
    write_json(out / "results.json", {
        "runs": [r.to_json() for r in results],
        "datasets": [asdict(d) for d in [*datasets.values(), *dehazed.values()]],
        "provenance": provenance("eval.harness", max(1, (os.cpu_count() or 1) // cfg.workers)),
    })
    paths = write_tables(results, out)
    paths["psnr_vs_time.csv"], paths["psnr_vs_time.png"] = write_psnr_vs_time(results, out)
    ok_sets = {s: Path(d.path) for s, d in datasets.items() if d.status == "ok"}
    paths.update(write_region_split(results, ok_sets, out))
    paths.update(write_per_view(results, out))
    paths.update(write_claims(results, out, targets_for(cfg.profile)))
    paths.update(write_convergence(results, out))
    if ok_sets:
        cols = ["thermal", "rgb", "gt"] + [k for k in ("full", "imgdehaze-dcp", "rgb-only") if k in cfg.methods]
        paths["figure3_qualitative.png"] = write_qualitative_grid(
            results, ok_sets, cols, out / "figure3_qualitative.png", "Qualitative comparison (cf. paper Fig. 3)")
        if cfg.ablations:
            paths["figure5_ablations.png"] = write_qualitative_grid(
                results, ok_sets, ["gt", "full", *cfg.ablations], out / "figure5_ablations.png",
                "Ablations (cf. paper Fig. 5)")
    paths["report.md"] = write_report(cfg, results, [*datasets.values(), *dehazed.values()], lpips_status,
                                      backend, time.perf_counter() - t0, paths, out / "report.md")
    return results, paths
