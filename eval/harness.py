"""Run or collect every (scene, variant, seed), cached by config hash, on a process
pool or a Dask cluster, then write the tables, figures and report.

Each dataset generation, dehazing pass and training run is one task. The callables
that do the work are parameters (defaults: the generator and trainer APIs), so the
same scheduling, caching and failure bookkeeping runs for real work and in tests.
"""

from __future__ import annotations

import concurrent.futures as cf
import fcntl
import json
import logging
import multiprocessing
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
from PIL import Image
from tqdm import tqdm

from contracts.atomic import write_json
from contracts.metrics import load_lpips
from eval.dehaze import dehaze_dataset, get_dehazer
from eval.runs import ABLATIONS, METHODS, VARIANTS, RunResult, RunSpec, config_hash, source_digest

log = logging.getLogger("regenerate-tables")

TrainFn = Callable[..., dict[str, Any]]
GenerateFn = Callable[..., Path]


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


def default_workers() -> int:
    """Half the cores: each training run uses two torch threads."""
    return max(1, (os.cpu_count() or 1) // 2)


@dataclass
class HarnessConfig:
    """Every setting of one `regenerate-tables` invocation (all of it goes in report.md)."""

    out: Path
    scenes: list[str]
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    ablations: list[str] = field(default_factory=lambda: list(ABLATIONS))
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    profile: str = "quick"
    train_overrides: dict[str, Any] = field(default_factory=dict)
    gen_overrides: dict[str, Any] = field(default_factory=dict)
    datasets: dict[str, Path] = field(default_factory=dict)
    dataset_seed: int = 0
    dehazer: str = "dcp"
    workers: int = field(default_factory=default_workers)
    scheduler: str | None = None
    lpips_weights: str | None = None
    lpips_heads: str | None = None

    def validate(self) -> None:
        if not self.scenes:
            raise ValueError("scenes: at least one scene is needed")
        if len(set(self.scenes)) != len(self.scenes):
            raise ValueError(f"scenes: duplicates in {self.scenes}")
        for m in self.methods:
            if m not in METHODS:
                raise ValueError(f"methods: unknown {m!r}, choose from {', '.join(METHODS)}")
        for a in self.ablations:
            if a not in ABLATIONS:
                raise ValueError(f"ablations: unknown {a!r}, choose from {', '.join(ABLATIONS)}")
        if not self.methods and not self.ablations:
            raise ValueError("methods: nothing to run (no methods and no ablations)")
        if not self.seeds or any(s < 0 for s in self.seeds) or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: need distinct non-negative seeds, got {self.seeds}")
        if self.profile not in ("quick", "paper"):
            raise ValueError(f"profile: must be quick or paper, got {self.profile!r}")
        if self.workers < 1:
            raise ValueError(f"workers: must be >= 1, got {self.workers}")
        for scene, path in self.datasets.items():
            if not (Path(path) / "dataset.json").is_file():
                raise ValueError(f"datasets: {scene}={path} has no dataset.json")

    def variants(self) -> list[str]:
        """Methods, plus Full once more as the reference row of the ablation table."""
        keys = list(self.methods) + list(self.ablations)
        if self.ablations and "full" not in keys:
            keys.append("full")
        return keys


@dataclass
class DatasetOutcome:
    scene: str
    kind: str  # "generated", "provided" or "dehazed:<name>"
    path: str
    hash: str
    status: str = "ok"
    error: str = ""
    wall_time_s: float = 0.0
    cached: bool = False


# ---------------------------------------------------------------- tasks (run in workers)


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"


def dataset_task(o: DatasetOutcome, make: Callable[[Path], Any]) -> tuple[str, str, float]:
    """Produce one dataset folder under its lock and mark it done before the lock is released,
    so an overlapping invocation reuses it; returns (status, error, seconds)."""
    path = Path(o.path)
    with _folder_lock(path):
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
    """The cached record of a run that finished with exactly this config, else None."""
    rec = _read_json(run_dir / "harness.json")
    if rec and rec.get("status") == "ok" and rec.get("config_hash") == spec.hash() \
            and (run_dir / "metrics.json").is_file():
        r = RunResult.from_json(rec)
        r.cached = True
        return r
    return None


@contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """Invocations that share an --out folder may plan the same dataset or run: the second waits
    for the first instead of deleting the folder it works in (POSIX flock, released if it dies)."""
    lock = folder.with_name(f".{folder.name}.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def run_task(spec: RunSpec, run_dir: str, train_fn: TrainFn, threads: int, prep_time_s: float = 0.0) -> RunResult:
    """Train and evaluate one run under its lock, and record it in harness.json before the lock
    is released; a run another invocation finished meanwhile is returned as cached."""
    with _folder_lock(Path(run_dir)):
        done = finished_run(spec, Path(run_dir))
        if done is not None:
            return done
        res = _train_run(spec, run_dir, train_fn, threads)
        res.prep_time_s = prep_time_s
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        write_json(Path(run_dir) / "harness.json", res.to_json())
        return res


def _train_run(spec: RunSpec, run_dir: str, train_fn: TrainFn, threads: int) -> RunResult:
    """Train and evaluate one run from scratch; any exception becomes a failed record with its error."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)
    res = RunResult(scene=spec.scene, variant=spec.variant, seed=spec.seed, status="failed",
                    run_dir=run_dir, config_hash=spec.hash(), dataset=spec.dataset)
    t0 = time.perf_counter()
    try:
        if Path(run_dir).exists():
            shutil.rmtree(run_dir)
        Path(run_dir).parent.mkdir(parents=True, exist_ok=True)
        out = train_fn(Path(spec.dataset), Path(run_dir), spec.mode, profile=spec.profile, seed=spec.seed,
                       overrides=dict(spec.overrides))
        res.wall_time_s = time.perf_counter() - t0
        if out.get("status", "ok") != "ok":
            res.error = str(out.get("error") or "trainer reported status failed without an error")
            return res
        metrics = out.get("metrics") or {}
        psnr = metrics.get("psnr")
        if not isinstance(psnr, (int, float)) or not np.isfinite(psnr):
            res.error = f"trainer returned no finite metrics.psnr (got {psnr!r})"
            return res
        res.metrics = dict(metrics)
        total = (out.get("wall_time_s") or {}).get("total")
        if isinstance(total, (int, float)):
            res.wall_time_s = float(total)
        res.status = "ok"
    except Exception as exc:
        res.wall_time_s = time.perf_counter() - t0
        res.error = _error_text(exc)
    return res


# ---------------------------------------------------------------- execution back-ends


@dataclass
class _Executor:
    submit: Callable[..., Any]
    as_completed: Callable[[list[Any]], Iterator[Any]]
    description: str


@contextmanager
def open_executor(workers: int, scheduler: str | None) -> Iterator[_Executor]:
    """A spawn-context process pool by default; "local" starts a Dask LocalCluster with
    one single-threaded worker per slot; any other value is a Dask scheduler address."""
    if scheduler is None:
        ctx = multiprocessing.get_context("spawn")  # bpy/torch state must not be forked
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            yield _Executor(pool.submit, cf.as_completed, f"process pool, {workers} worker(s)")
        return
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="30s")
    try:
        yield _Executor(lambda fn, *a: client.submit(fn, *a, pure=False), as_completed,
                        f"dask scheduler {client.scheduler.address}")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _drain(ex: _Executor, jobs: list[tuple[Any, tuple[Any, ...], Callable[[Any], None],
                                           Callable[[BaseException], None]]], bar: tqdm) -> None:
    """Submit every job, then route each result (or a worker crash) to its callback."""
    futures = {ex.submit(fn, *args): (ok, fail) for fn, args, ok, fail in jobs}
    for fut in ex.as_completed(list(futures)):
        ok, fail = futures[fut]
        try:
            value = fut.result()
        except Exception as exc:  # a worker died (e.g. a native abort): the task failed
            fail(exc)
        else:
            ok(value)
        bar.update(1)


# ---------------------------------------------------------------- orchestration


def _done_marker(path: Path) -> Path:
    return path.with_name(path.name + ".done.json")


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def prepare_datasets(cfg: HarnessConfig, ex: _Executor, generate_fn: GenerateFn) -> dict[str, DatasetOutcome]:
    """Provided datasets are used as they are; the rest are generated once per config hash."""
    outcomes: dict[str, DatasetOutcome] = {}
    jobs = []
    for scene in cfg.scenes:
        if scene in cfg.datasets:
            p = Path(cfg.datasets[scene]).resolve()
            outcomes[scene] = DatasetOutcome(scene, "provided", str(p),
                                             config_hash((p / "dataset.json").read_text()), cached=True)
            continue
        h = config_hash({"scene": scene, "overrides": cfg.gen_overrides, "seed": cfg.dataset_seed,
                         "code": source_digest("generator", "blender")})
        path = (Path(cfg.out) / "datasets" / f"{scene}-{h[:12]}").resolve()
        o = DatasetOutcome(scene, "generated", str(path), h)
        outcomes[scene] = o
        seconds = finished_dataset(path, h)
        if seconds is not None:
            o.cached, o.wall_time_s = True, seconds
            continue

        def ok(v: tuple[str, str, float], o: DatasetOutcome = o) -> None:
            o.status, o.error, o.wall_time_s = v
            log.info("dataset %-12s %s %.1f s%s", o.scene, o.status, o.wall_time_s,
                     "" if o.status == "ok" else "\n" + o.error)

        def fail(exc: BaseException, o: DatasetOutcome = o) -> None:
            o.status, o.error = "failed", f"worker crashed: {type(exc).__name__}: {exc}"
            log.info("dataset %-12s failed: %s", o.scene, o.error)

        path.parent.mkdir(parents=True, exist_ok=True)
        make = partial(generate_fn, scene, seed=cfg.dataset_seed, **cfg.gen_overrides)
        jobs.append((dataset_task, (o, make), ok, fail))
    if jobs:
        with tqdm(total=len(jobs), desc="datasets", unit="scene", file=sys.stderr) as bar:
            _drain(ex, jobs, bar)
    return outcomes


def prepare_dehazed(cfg: HarnessConfig, ex: _Executor, sources: dict[str, DatasetOutcome]) -> dict[str, DatasetOutcome]:
    """One dehazed copy per scene for the ImgDehaze baseline, cached like a dataset."""
    outcomes: dict[str, DatasetOutcome] = {}
    if not any(VARIANTS[v].dehazer for v in cfg.variants()):
        return outcomes
    jobs = []
    settings = asdict(get_dehazer(cfg.dehazer)) if cfg.dehazer == "dcp" else {"name": cfg.dehazer}
    for scene, src in sources.items():
        h = config_hash({"source": src.hash, "dehazer": cfg.dehazer, "settings": settings,
                         "code": source_digest("eval.dehaze")})
        path = (Path(cfg.out) / "datasets" / f"{scene}-{src.hash[:12]}-dehazed-{cfg.dehazer}-{h[:8]}").resolve()
        o = DatasetOutcome(scene, f"dehazed:{cfg.dehazer}", str(path), h)
        outcomes[scene] = o
        if src.status != "ok":
            o.status, o.error = "failed", "source dataset unavailable"
            continue
        seconds = finished_dataset(path, h)
        if seconds is not None:
            o.cached, o.wall_time_s = True, seconds
            continue

        def ok(v: tuple[str, str, float], o: DatasetOutcome = o) -> None:
            o.status, o.error, o.wall_time_s = v

        def fail(exc: BaseException, o: DatasetOutcome = o) -> None:
            o.status, o.error = "failed", f"worker crashed: {type(exc).__name__}: {exc}"

        path.parent.mkdir(parents=True, exist_ok=True)
        jobs.append((dataset_task, (o, partial(dehaze_into, src.path, cfg.dehazer)), ok, fail))
    if jobs:
        with tqdm(total=len(jobs), desc="dehaze", unit="scene", file=sys.stderr) as bar:
            _drain(ex, jobs, bar)
    return outcomes


def plan_runs(cfg: HarnessConfig, datasets: dict[str, DatasetOutcome],
              dehazed: dict[str, DatasetOutcome]) -> list[RunSpec]:
    specs = []
    code = source_digest("smokeseer")
    for scene in cfg.scenes:
        for key in cfg.variants():
            v = VARIANTS[key]
            ds = dehazed[scene] if v.dehazer else datasets[scene]
            for seed in cfg.seeds:
                specs.append(RunSpec(scene, key, v.mode, seed, cfg.profile, dict(cfg.train_overrides),
                                     ds.path, ds.hash, code))
    return specs


def _line(r: RunResult) -> str:
    head = f"{r.scene}/{r.variant} seed {r.seed}"
    if r.status == "ok":
        tag = "cached" if r.cached else "ok"
        return f"[{tag:>6}] {head}: PSNR {r.metrics.get('psnr', float('nan')):.2f} dB, {r.wall_time_s:.1f} s"
    return f"[FAILED] {head}: {r.error.splitlines()[0] if r.error else 'unknown error'}"


def execute_runs(cfg: HarnessConfig, ex: _Executor, specs: list[RunSpec], train_fn: TrainFn,
                 datasets: dict[str, DatasetOutcome], dehazed: dict[str, DatasetOutcome]) -> list[RunResult]:
    """Collect cached runs, run the rest; a run whose dataset failed is failed, not skipped."""
    results: list[RunResult] = []
    jobs = []
    threads = max(1, (os.cpu_count() or 1) // cfg.workers)
    bar = tqdm(total=len(specs), desc="runs", unit="run", file=sys.stderr)
    for spec in specs:
        run_dir = spec.run_dir(Path(cfg.out)).resolve()
        ds = dehazed[spec.scene] if VARIANTS[spec.variant].dehazer else datasets[spec.scene]
        prep = ds.wall_time_s if VARIANTS[spec.variant].dehazer else 0.0
        if ds.status != "ok":
            r = RunResult(spec.scene, spec.variant, spec.seed, "failed", str(run_dir), spec.hash(), ds.path,
                          error=f"dataset ({ds.kind}) failed: {ds.error.splitlines()[0] if ds.error else ''}")
            results.append(r)
            bar.write(_line(r))
            bar.update(1)
            continue
        cached = finished_run(spec, run_dir)
        if cached is not None:
            results.append(cached)
            bar.write(_line(cached))
            bar.update(1)
            continue

        def ok(r: RunResult) -> None:
            results.append(r)
            bar.write(_line(r))

        def fail(exc: BaseException, spec: RunSpec = spec, run_dir: Path = run_dir) -> None:
            r = RunResult(spec.scene, spec.variant, spec.seed, "failed", str(run_dir), spec.hash(), spec.dataset,
                          error=f"worker crashed: {type(exc).__name__}: {exc}")
            results.append(r)
            bar.write(_line(r))

        jobs.append((run_task, (spec, str(run_dir), train_fn, threads, prep), ok, fail))
    if jobs:
        _drain(ex, jobs, bar)
    bar.close()
    order = {(s.scene, s.variant, s.seed): i for i, s in enumerate(specs)}
    return sorted(results, key=lambda r: order[(r.scene, r.variant, r.seed)])


def add_lpips(results: list[RunResult], scorer: Callable[[Any, Any], float] | None, status: str) -> None:
    """Fill LPIPS the trainer left empty, from the saved surface renders against rgb/clean."""
    for r in results:
        if r.status != "ok" or r.metrics.get("lpips") is not None:
            continue
        if scorer is None:
            r.metrics["lpips_status"] = r.metrics.get("lpips_status") or status
            continue
        frames = json.loads((Path(r.dataset) / "transforms_rgb.json").read_text())["frames"]
        vals = []
        for f in frames:
            if f.get("split") != "test":
                continue
            pred = Path(r.run_dir) / "renders" / "surface" / f"{f['file_stem']}.png"
            gt = Path(r.dataset) / "rgb" / "clean" / f"{f['file_stem']}.png"
            if pred.is_file() and gt.is_file():
                vals.append(scorer(np.asarray(Image.open(pred).convert("RGB"), np.float64) / 255.0,
                                   np.asarray(Image.open(gt).convert("RGB"), np.float64) / 255.0))
        if vals:
            r.metrics["lpips"] = float(np.mean(vals))
            r.metrics["lpips_status"] = f"{status} (harness, {len(vals)} test views)"


def regenerate(cfg: HarnessConfig, train_fn: TrainFn = default_train,
               generate_fn: GenerateFn = default_generate) -> tuple[list[RunResult], dict[str, Path]]:
    """The whole pipeline: datasets, dehazing, runs, LPIPS, tables, figures, report."""
    from eval.figures import write_psnr_vs_time, write_qualitative_grid
    from eval.report import write_report
    from eval.tables import write_tables

    cfg.validate()
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open_executor(cfg.workers, cfg.scheduler) as ex:
        log.info("executing on %s", ex.description)
        datasets = prepare_datasets(cfg, ex, generate_fn)
        dehazed = prepare_dehazed(cfg, ex, datasets)
        results = execute_runs(cfg, ex, plan_runs(cfg, datasets, dehazed), train_fn, datasets, dehazed)
        backend = ex.description
    scorer, lpips_status = load_lpips(cfg.lpips_weights, heads_path=cfg.lpips_heads)
    if scorer is None:
        log.info("LPIPS %s. How to enable it: docs/metrics.md, 'Enabling LPIPS offline'.", lpips_status)
    add_lpips(results, scorer, lpips_status)
    (out / "results.json").write_text(json.dumps({
        "runs": [r.to_json() for r in results],
        "datasets": [asdict(d) for d in [*datasets.values(), *dehazed.values()]],
    }, indent=2))
    paths = write_tables(results, out)
    paths["psnr_vs_time.csv"], paths["psnr_vs_time.png"] = write_psnr_vs_time(results, out)
    ok_sets = {s: Path(d.path) for s, d in datasets.items() if d.status == "ok"}
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
