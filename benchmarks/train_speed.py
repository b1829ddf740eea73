"""Training speed: where a Stage 2 and a Stage 3 iteration spend their time, per rasterizer backend.

``profile``: trains a short run (few iterations per stage) once per backend under cProfile, with
``backend="auto"`` on CPU tensors pointed at that backend inside this process, and reports
seconds per iteration of each stage (from train_log.csv's wall_s; the first logged interval is
dropped as warm-up) plus the top functions by own time and by cumulative time. Writes
``train_speed.csv`` and ``train_speed_profile_<backend>.txt``.

``train``: one full ``train-and-evaluate`` run (quick profile) with the chosen backend, for
before/after comparisons of wall time and PSNR at the same seed.

``curve``: test (or, with ``--metric val_psnr``, validation) PSNR against wall time of finished
runs (their train_log.csv), one line per run, written as ``train_speed_curve.csv`` + ``.png``
(``--name`` changes the stem).

``e2e``: ``train-and-evaluate`` on DATASET at ``--profile`` (quick by default), this checkout
against an earlier commit (exported with ``git archive``), alternated, at ``--threads`` (default:
each CLI's own); ``--current-set KEY=VALUE`` passes settings to this checkout's side only (for
example ``deform.kind=fourier``, which an earlier commit may not know). Each side's kernel is
compiled before the timed runs, so no wall time includes a build. Keeps the best wall time
of each side, prints the ratio and the load, writes ``train_speed_e2e.csv``; the run folders stay
under ``--keep`` for ``curve``.

``parity``: test PSNR of finished ``train`` runs grouped by label (one run per seed), mean and
sample std per label and the same-seed differences against the first label, written as
``train_speed_parity.csv``. Why not one seed: training is chaotic, so two backends that differ
only in float rounding follow different trajectories after a few dozen iterations, and one
seed's difference is a draw from the seed-to-seed spread.

    python benchmarks/train_speed.py profile DATASET [--iterations 60] [--threads 1]
    python benchmarks/train_speed.py train DATASET --backend torch --out RUN [--seed 0]
    python benchmarks/train_speed.py curve torch=RUN_A cpu=RUN_B
    python benchmarks/train_speed.py e2e DATASET --baseline c300de9 [--repeats 2] [--keep DIR]
    python benchmarks/train_speed.py e2e data/standard/food_plate --baseline 2341510 --profile standard \
        --threads 1 --repeats 2 --keep DIR [--current-set deform.kind=fourier]
    python benchmarks/train_speed.py parity cpu=RUN_S0 cpu=RUN_S1 torch=RUN_T0 torch=RUN_T1
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import sys
import sysconfig
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OPENMP_WAIT = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
SHELL_OPENMP_WAIT = {k: os.environ[k] for k in OPENMP_WAIT if k in os.environ}
"""The OpenMP wait settings this script was started with, before importing smokeseer sets its
default: the end-to-end runs get the shell's, so each side sets (or not) its own."""
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from contracts.atomic import write_dataclass_csv  # noqa: E402
from contracts.train_log import read_train_log  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


@dataclass
class CurvePoint:
    run: str
    stage: int
    iteration: int
    wall_s: float
    metric: str
    psnr: float


@dataclass
class EndToEnd:
    side: str
    commit: str
    repeat: int
    wall_s: float
    cpu_s: float
    test_psnr: float
    threads: int
    load_before: float
    load_after: float


@dataclass
class ParityRow:
    label: str
    seed: int
    test_psnr: float
    run: str


@dataclass
class StageSpeed:
    backend: str
    stage: int
    iterations_timed: int
    seconds_per_iteration: float
    iterations_per_second: float
    run_wall_s: float
    run_cpu_s: float
    threads: int
    load_avg_1min: float


def stage_speeds(rows: list[dict[str, str]], backend: str, wall: float, cpu: float) -> list[StageSpeed]:
    """Seconds per iteration of each stage from the logged wall clock, first interval dropped."""
    out = []
    for stage in sorted({int(r["stage"]) for r in rows}):
        pts = [(int(r["iteration"]), float(r["wall_s"])) for r in rows if int(r["stage"]) == stage]
        if len(pts) < 3:
            continue
        (i0, t0), (i1, t1) = pts[1], pts[-1]
        per = (t1 - t0) / (i1 - i0)
        out.append(StageSpeed(backend, stage, i1 - i0, per, 1.0 / per, wall, cpu, torch.get_num_threads(),
                              os.getloadavg()[0]))
    return out


def backend_forced(backend: str):
    """Context manager: ``backend="auto"`` on CPU tensors means ``backend`` inside this process."""
    import contextlib

    from smokeseer.raster import api as raster_api

    @contextlib.contextmanager
    def forced():
        original = raster_api._resolve_backend

        def resolve(name: str, device: torch.device) -> str:
            return backend if name == "auto" and device.type == "cpu" else original(name, device)

        raster_api._resolve_backend = resolve
        try:
            yield
        finally:
            raster_api._resolve_backend = original

    return forced()


def profile_backend(dataset: Path, backend: str, iterations: int, top: int) -> tuple[list[StageSpeed], str]:
    from smokeseer.api import train_and_evaluate

    overrides = {"stage2.iterations": iterations, "stage3.iterations": iterations, "log_every": 5,
                 "stage3.test_every": 10 * iterations, "progress": False}
    with backend_forced(backend), tempfile.TemporaryDirectory() as tmp:
        prof = cProfile.Profile()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        prof.enable()
        train_and_evaluate(dataset, Path(tmp) / "run", profile="quick", seed=0, overrides=overrides)
        prof.disable()
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        rows = read_train_log(Path(tmp) / "run" / "train_log.csv")
    text = io.StringIO()
    stats = pstats.Stats(prof, stream=text)
    text.write(f"# backend={backend}, {iterations} iterations per stage, wall {wall:.1f} s, cpu {cpu:.1f} s, "
               f"threads {torch.get_num_threads()}, load {os.getloadavg()[0]:.1f}\n")
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)
    return stage_speeds(rows, backend, wall, cpu), _portable_paths(text.getvalue())


def _portable_paths(text: str) -> str:
    """cProfile's file names relative to the checkout, the standard library as ``<stdlib>``: the
    profile is committed, and one machine's folders mean nothing elsewhere."""
    return text.replace(f"{ROOT}/", "").replace(f"{sysconfig.get_paths()['stdlib']}/", "<stdlib>/")


def run_train(args: argparse.Namespace) -> None:
    from smokeseer.api import train_and_evaluate

    with backend_forced(args.backend):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        doc = train_and_evaluate(args.dataset, args.out, profile="quick", seed=args.seed,
                                 overrides={"progress": False})
    print(f"backend {args.backend} seed {args.seed}: wall {time.perf_counter() - wall0:.1f} s, "
          f"cpu {time.process_time() - cpu0:.1f} s, test PSNR {doc['metrics']['psnr']:.3f} dB, "
          f"threads {torch.get_num_threads()}, load {os.getloadavg()[0]:.1f}")


def run_profile(args: argparse.Namespace) -> None:
    speeds = []
    for backend in args.backends:
        rows, text = profile_backend(args.dataset, backend, args.iterations, args.top)
        speeds += rows
        (args.out / f"train_speed_profile_{backend}.txt").write_text(text)
        for r in rows:
            print(f"{backend:5s} stage {r.stage}: {r.seconds_per_iteration * 1e3:7.1f} ms/iteration "
                  f"({r.iterations_per_second:.1f} it/s), run wall {r.run_wall_s:.1f} s cpu {r.run_cpu_s:.1f} s, "
                  f"load {r.load_avg_1min:.1f}", flush=True)
    write_dataclass_csv(args.out / "train_speed.csv", speeds)
    print(f"wrote {args.out / 'train_speed.csv'} and train_speed_profile_*.txt")


def run_description(folder: Path) -> str:
    """'SCENE, --profile P' from a finished run's metrics.json (a running one has only its config)."""
    metrics, config = folder / "metrics.json", folder / "config.json"
    if metrics.is_file():
        m = json.loads(metrics.read_text())
        return f"{m['scene']}, --profile {m['profile']}"
    if config.is_file():
        return f"{folder.name}, --profile {json.loads(config.read_text())['profile']}"
    return folder.name


def run_curve(args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = []
    described: set[str] = set()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for spec in args.runs:
        label, _, folder = spec.partition("=")
        described.add(run_description(Path(folder)))
        pts = [CurvePoint(label, int(r["stage"]), int(r["iteration"]), float(r["wall_s"]), args.metric,
                          float(r[args.metric]))
               for r in read_train_log(Path(folder) / "train_log.csv") if r.get(args.metric)]
        if not pts:
            raise SystemExit(f"{folder}/train_log.csv: no {args.metric} entries")
        table += pts
        ax.plot([p.wall_s for p in pts], [p.psnr for p in pts], "o-", label=label)
    split = "validation" if args.metric == "val_psnr" else "test"
    title = args.title or (described.pop() if len(described) == 1 else "; ".join(sorted(described)))
    ax.set(xlabel="wall time [s]", ylabel=f"{split} PSNR [dB]", title=title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / f"{args.name}.png", dpi=120)
    write_dataclass_csv(args.out / f"{args.name}.csv", table)
    print(f"wrote {args.out / args.name}.csv and .png")


def run_e2e(args: argparse.Namespace) -> None:
    import resource
    import subprocess

    from benchmarks.generate_demo_time import export_commit

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    rows: list[EndToEnd] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        export_commit(args.baseline, Path(tmp_name) / "baseline")
        sides = (("baseline", args.baseline, Path(tmp_name) / "baseline"), ("current", head, ROOT))
        for side, commit, root in sides:  # each side's compiled kernel is built before any timed run
            subprocess.run([sys.executable, "-c", "from smokeseer.raster.extension import load_kernel; load_kernel()"],
                           cwd=root, env={**os.environ, "PYTHONPATH": str(root)}, check=True)
        for repeat in range(args.repeats):
            for side, commit, root in sides:
                out = args.keep / f"{side}_{repeat}"
                cmd = [sys.executable, "-m", "smokeseer.cli", str(args.dataset.resolve()), "--out", str(out.resolve()),
                       "--profile", args.profile, "--no-progress"]
                if args.threads:
                    cmd += ["--threads", str(args.threads)]
                if side == "current":
                    cmd += [a for item in args.current_set for a in ("--set", item)]
                if args.iterations:
                    cmd += ["--iterations-stage2", str(args.iterations), "--iterations-stage3", str(args.iterations)]
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                load0, wall0 = os.getloadavg()[0], time.perf_counter()
                env = {k: v for k, v in os.environ.items() if k not in OPENMP_WAIT}
                done = subprocess.run(cmd, cwd=root, env={**env, **SHELL_OPENMP_WAIT, "PYTHONPATH": str(root)},
                                      capture_output=True, text=True)
                wall = time.perf_counter() - wall0
                if done.returncode != 0:
                    raise SystemExit(f"{side} ({commit}) failed: {done.stderr.strip()[-500:]}")
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                psnr = json.loads((out / "metrics.json").read_text())["metrics"]["psnr"]
                rows.append(EndToEnd(side, commit + "".join(f" {item}" for item in args.current_set if side == "current"),
                                     repeat, wall, cpu, psnr, args.threads or torch.get_num_threads(), load0,
                                     os.getloadavg()[0]))
                print(f"{side} {commit} #{repeat}: {wall:.1f} s wall, {cpu:.1f} s CPU, test PSNR {psnr:.3f} dB, "
                      f"load {load0:.2f} -> {os.getloadavg()[0]:.2f}", flush=True)
    best = {side: min((r for r in rows if r.side == side), key=lambda r: r.wall_s) for side, _, _ in sides}
    print(f"best wall: baseline {best['baseline'].wall_s:.1f} s, current {best['current'].wall_s:.1f} s: "
          f"{best['baseline'].wall_s / best['current'].wall_s:.2f}x less wall time "
          f"({best['baseline'].cpu_s / best['current'].cpu_s:.2f}x less CPU)")
    write_dataclass_csv(args.out / "train_speed_e2e.csv", rows)
    print(f"wrote {args.out / 'train_speed_e2e.csv'}; runs kept in {args.keep}")


def run_parity(args: argparse.Namespace) -> None:
    import statistics

    rows = []
    for spec in args.runs:
        label, _, folder = spec.partition("=")
        doc = json.loads((Path(folder) / "metrics.json").read_text())
        rows.append(ParityRow(label, int(doc["seed"]), float(doc["metrics"]["psnr"]), folder))
    labels = list(dict.fromkeys(r.label for r in rows))
    by = {lab: {r.seed: r.test_psnr for r in rows if r.label == lab} for lab in labels}
    for lab in labels:
        vals = list(by[lab].values())
        spread = statistics.stdev(vals) if len(vals) > 1 else float("nan")
        print(f"{lab:>24s}: {len(vals)} seeds, test PSNR {statistics.mean(vals):.3f} +- {spread:.3f} dB "
              f"({', '.join(f'{v:.3f}' for v in vals)})")
    ref = labels[0]
    for lab in labels[1:]:
        seeds = sorted(set(by[ref]) & set(by[lab]))
        diffs = [by[lab][s] - by[ref][s] for s in seeds]
        print(f"{lab} - {ref}, same seed: {', '.join(f'{d:+.3f}' for d in diffs)}; mean {statistics.mean(diffs):+.3f} dB")
    args.out.mkdir(parents=True, exist_ok=True)
    write_dataclass_csv(args.out / "train_speed_parity.csv", rows)
    print(f"wrote {args.out / 'train_speed_parity.csv'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    prof = sub.add_parser("profile", help="cProfile a short run per backend")
    prof.add_argument("dataset", type=Path)
    prof.add_argument("--iterations", type=int, default=60, help="iterations per stage")
    prof.add_argument("--backends", nargs="+", default=["torch", "cpu"])
    prof.add_argument("--top", type=int, default=25)
    prof.add_argument("--threads", type=int, default=0)
    prof.add_argument("--out", type=Path, default=RESULTS)
    train = sub.add_parser("train", help="one full quick-profile run with the chosen backend")
    train.add_argument("dataset", type=Path)
    train.add_argument("--backend", choices=["cpu", "torch"], required=True)
    train.add_argument("--out", type=Path, required=True)
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--threads", type=int, default=0)
    curve = sub.add_parser("curve", help="test (or validation) PSNR against wall time of finished runs")
    curve.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    curve.add_argument("--metric", choices=["test_psnr", "val_psnr"], default="test_psnr",
                       help="train_log.csv column to plot (tune on val_psnr, never on test_psnr)")
    curve.add_argument("--title", help="plot title (default: the runs' dataset folder and profile)")
    curve.add_argument("--name", default="train_speed_curve", help="output file stem")
    curve.add_argument("--out", type=Path, default=RESULTS)
    e2e = sub.add_parser("e2e", help="train-and-evaluate, this checkout against an earlier commit, alternated")
    e2e.add_argument("dataset", type=Path)
    e2e.add_argument("--baseline", required=True, help="git revision to compare against")
    e2e.add_argument("--repeats", type=int, default=2, help="runs of each side (best wall time kept)")
    e2e.add_argument("--keep", type=Path, required=True, help="folder for the run folders (for curve)")
    e2e.add_argument("--iterations", type=int, default=0, help="iterations per stage (default: the profile's)")
    e2e.add_argument("--profile", choices=["quick", "standard"], default="quick")
    e2e.add_argument("--threads", type=int, default=0, help="--threads for both sides' runs (default: their own)")
    e2e.add_argument("--current-set", action="append", default=[], metavar="KEY=VALUE",
                     help="a setting for this checkout's runs only")
    e2e.add_argument("--out", type=Path, default=RESULTS)
    parity = sub.add_parser("parity", help="test PSNR per label over seeds, same-seed differences")
    parity.add_argument("runs", nargs="+", help="LABEL=RUN_DIR (finished train runs, one per seed)")
    parity.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    if getattr(args, "threads", 0):
        torch.set_num_threads(args.threads)
    commands = {"profile": run_profile, "train": run_train, "curve": run_curve, "e2e": run_e2e, "parity": run_parity}
    commands[args.command](args)


if __name__ == "__main__":
    main()
