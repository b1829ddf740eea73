"""Harness: caching by config hash, failures recorded, process pool and Dask back-ends,
the CLI's input errors, and (once generator and trainer are installed) the real path.

The task callables here are small real functions, not stand-ins for the trainer: an
"identity" method whose surface render is the smoky input, scored with contracts.metrics and
written as a run folder in the results format (the harness reads only run folders).
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from eval import harness, harness_cli, settings
from eval.harness import HarnessConfig, regenerate
from contracts.metrics import psnr, ssim_3dgs
from contracts.provenance import provenance
from eval.regions import MASK
from eval.runs import VARIANTS, RunSpec
from generator.profiles import get_profile
from tests.results_builder import write_metrics


def write_tiny_dataset(root: Path, scene: str, seed: int = 0, frames: int = 4) -> Path:
    """A valid-layout dataset: clean images, smoke composited over them, thermal frames."""
    rng = np.random.default_rng(seed)
    h, w = 24, 32
    rgb_frames, th_frames = [], []
    for i in range(frames):
        stem = f"{i:04d}"
        clean = np.clip(rng.random((h, w, 3)) * 0.6 + 0.2, 0, 1)
        alpha = np.clip(rng.random((h, w, 1)) * 0.6, 0, 1)
        smoky = alpha * 0.85 + (1 - alpha) * clean
        for sub, img in (("rgb/clean", clean), ("rgb/smoky", smoky)):
            (root / sub).mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.round(img * 255).astype(np.uint8)).save(root / sub / f"{stem}.png")
        (root / "thermal/smoky").mkdir(parents=True, exist_ok=True)
        Image.fromarray((rng.random((12, 16)) * 4000 + 1000).astype(np.uint16)).save(root / "thermal/smoky" / f"{stem}.png")
        t = i / max(1, frames - 1)
        rgb_frames.append({"index": i, "file_stem": stem, "time": t, "timestamp_s": t,
                           "split": "test" if i % 2 else "train", "transform_matrix": np.eye(4).tolist()})
        th_frames.append({"index": i, "file_stem": stem, "time": t, "timestamp_s": t, "split": "train",
                          "transform_matrix": np.eye(4).tolist()})
    (root / "transforms_rgb.json").write_text(json.dumps({"modality": "rgb", "w": w, "h": h, "frames": rgb_frames}))
    (root / "transforms_thermal.json").write_text(json.dumps({"modality": "thermal", "w": 16, "h": 12,
                                                              "frames": th_frames}))
    (root / "dataset.json").write_text(json.dumps({"format": "smokeseer-synth-dataset", "format_version": 1,
                                                   "scene": scene, "seed": seed}))
    return root


def tiny_generate(preset: str, out: Path, **overrides: Any) -> Path:
    if preset == "broken":
        raise RuntimeError("preset broken cannot be built")
    return write_tiny_dataset(Path(out), preset, int(overrides.get("seed", 0)))


def identity_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                   overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Reconstruction = the smoky input itself; metrics computed for real on the test split."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out.parent / "calls.log", "a") as f:
        f.write(f"{mode} {seed}\n")
    if mode == "no-mask":
        raise RuntimeError("no-mask diverged (injected)")
    frames = json.loads((dataset / "transforms_rgb.json").read_text())["frames"]
    (out / "renders/surface").mkdir(parents=True)
    ps, ss = [], []
    for f in frames:
        if f["split"] != "test":
            continue
        pred = np.asarray(Image.open(dataset / "rgb/smoky" / f"{f['file_stem']}.png"), np.float64) / 255
        gt = np.asarray(Image.open(dataset / "rgb/clean" / f"{f['file_stem']}.png"), np.float64) / 255
        Image.open(dataset / "rgb/smoky" / f"{f['file_stem']}.png").save(out / "renders/surface" / f"{f['file_stem']}.png")
        ps.append(psnr(pred, gt))
        ss.append(ssim_3dgs(pred, gt))
    with open(out / "train_log.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["iteration", "stage", "wall_s", "loss", "test_psnr"])
        w.writerow([0, 3, 0.5, 1.0, ""])
        w.writerow([10, 3, 1.0, 0.5, f"{np.mean(ps) - 1:.4f}"])
    write_metrics(out, scene=dataset.name, method=mode, profile=profile, seed=seed, dataset=str(dataset),
                  provenance=provenance("eval.runs", 1), config_sha256="identity", wall_time_s={"total": 1.5},
                  metrics={"psnr": float(np.mean(ps)) + seed, "ssim": float(np.mean(ss)),
                           "lpips_status": "skipped: no weights", "psnr_input": float(np.mean(ps)),
                           "depth_absrel": 0.1, "depth_rmse": 0.2})
    return {"status": "ignored: the harness reads the run folder"}


def _cfg(tmp_path: Path, **kw: Any) -> HarnessConfig:
    base = dict(out=tmp_path / "out", scenes=["alpha", "beta"], methods=["full", "imgdehaze-dcp"],
                ablations=["no-mask"], seeds=[0, 1], workers=2)
    base.update(kw)
    return HarnessConfig(**base)


def _calls(out: Path) -> int:
    return sum(len(p.read_text().splitlines()) for p in out.rglob("calls.log"))


def test_pipeline_cache_and_failures(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path)
    results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    assert len(results) == 2 * 3 * 2  # scenes × (full, imgdehaze, no-mask) × seeds
    failed = [r for r in results if r.status == "failed"]
    assert {r.variant for r in failed} == {"no-mask"} and len(failed) == 4
    assert all("diverged (injected)" in r.error for r in failed)
    report = paths["report.md"].read_text()
    assert report.count("/ no-mask / seed") == 4 and "no-mask diverged (injected)" in report
    t2 = paths["table2.md"].read_text()
    assert "| w/o mask | — |" in t2 and "0/4 †" in t2
    # the claims check leaves the failed ablation's seeds out and says so, in its file and the report
    claims = {row["claim"]: row for row in csv.DictReader(open(paths["claims.csv"]))}
    no_mask = claims["w/o mask ≤ Ours (Full) + 0.10 dB on the mean over scenes"]
    assert no_mask["holds"] == "not yet" and no_mask["left_out"] == "seed 0: 2 of 4 runs; seed 1: 2 of 4 runs"
    assert "# The claims, checked on the finished runs" in report
    assert "# Would more budget close the gap? (validation PSNR)" in report

    # numbers in the table are the runs' numbers: Full PSNR = mean over seeds of scene means
    full = [r for r in results if r.variant == "full"]
    per_seed = [np.mean([r.metrics["psnr"] for r in full if r.seed == s]) for s in (0, 1)]
    rows = {row["metric"]: row for row in csv.DictReader(open(paths["table1.csv"])) if row["variant"] == "full"}
    assert float(rows["psnr"]["mean"]) == pytest.approx(np.mean(per_seed))
    assert float(rows["psnr"]["std"]) == pytest.approx(np.std(per_seed, ddof=1))
    assert float(rows["psnr"]["paper"]) == 19.92
    # the dehazer really ran: its input PSNR (dehazed frames) differs from the smoky floor
    deh = [r for r in results if r.variant == "imgdehaze-dcp"]
    assert deh[0].metrics["psnr_input"] != full[0].metrics["psnr_input"] and deh[0].prep_time_s > 0
    for name in ("psnr_vs_time.png", "figure3_qualitative.png", "figure5_ablations.png", "table1.tex"):
        assert paths[name].stat().st_size > 0
    n_calls = _calls(cfg.out)
    assert n_calls == 12

    # second invocation: finished runs come from cache, failed ones are retried
    results2, _ = regenerate(_cfg(tmp_path), train_fn=identity_train, generate_fn=tiny_generate)
    assert _calls(cfg.out) - n_calls == 4
    assert sum(r.cached for r in results2) == 8
    assert [r.metrics.get("psnr") for r in results2] == [r.metrics.get("psnr") for r in results]

    # a changed override changes the config hash: those runs are redone
    cfg3 = _cfg(tmp_path, ablations=[], methods=["full"], seeds=[0], train_overrides={"stage3.iterations": 5})
    results3, _ = regenerate(cfg3, train_fn=identity_train, generate_fn=tiny_generate)
    assert not any(r.cached for r in results3)


def test_finished_only_tables_the_finished_runs_and_trains_nothing(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Beside an invocation still training, --finished-only writes the tables from what has finished:
    the rest are pending (no calls, no new dataset), counted apart from failures in the notes."""
    regenerate(_cfg(tmp_path, scenes=["alpha"], methods=["full"], ablations=[], seeds=[0], workers=1),
               train_fn=identity_train, generate_fn=tiny_generate)
    n = _calls(tmp_path / "out")
    cfg = _cfg(tmp_path, methods=["full", "rgb-only"], ablations=[], seeds=[0], workers=1, finished_only=True)
    results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    assert _calls(tmp_path / "out") == n
    assert not list((tmp_path / "out" / "datasets").glob("beta-*"))
    status = {(r.scene, r.variant): r.status for r in results}
    assert status == {("alpha", "full"): "ok", ("alpha", "rgb-only"): "pending",
                      ("beta", "full"): "pending", ("beta", "rgb-only"): "pending"}
    assert all(r.cached for r in results if r.status == "ok")
    rows = {row["variant"]: row for row in csv.DictReader(open(paths["table1.csv"])) if row["metric"] == "psnr"}
    assert rows["full"]["runs_ok"] == "1" and rows["full"]["runs_failed"] == "0" and rows["full"]["runs_expected"] == "2"
    t1 = paths["table1.md"].read_text()
    assert "1/2 †" in t1 and "0 failed, 1 not trained yet, 1 of 2 runs averaged" in t1
    assert "Mean over the finished runs of 1 of 2 scene(s) per seed" in t1
    report = paths["report.md"].read_text()
    assert "0 failed, 3 pending" in report and "None." in report  # pending runs are not failures
    assert "| alpha | rgb-only | 0 | pending | False | — |" in report  # not trained, so on no device
    assert "| alpha | full | 0 | ok | True | cpu |" in report

    argv = ["--out", str(tmp_path / "out"), "--scenes", "alpha", "--dataset", f"alpha={tmp_path / 'ds'}",
            "--methods", "full", "--no-ablations", "--seeds", "0,", "--finished-only"]
    write_tiny_dataset(tmp_path / "ds", "alpha")
    assert harness_cli.main(argv) == 0
    assert "0 runs ok, 0 failed, 1 pending" in capsys.readouterr().out


def train_recording_device(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                           overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """identity_train that also logs the device it was handed (workers are separate processes)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / "devices.log", "a") as f:
        f.write(f"{(overrides or {}).get('device', 'missing')}\n")
    return identity_train(dataset, out, mode, profile, seed, overrides)


def test_device_reaches_the_trainer_and_is_recorded_but_not_keyed(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """--device goes to the trainer as its `device` override and into harness.json and the report;
    the cache key is the CPU one, so a finished run is found whichever device made it."""
    base = dict(scenes=["alpha"], methods=["full"], ablations=[], seeds=[0], workers=1)
    monkeypatch.setattr("torch.cuda.is_available", lambda: True)  # the fake trainer needs no GPU
    results, paths = regenerate(_cfg(tmp_path, device="cuda:1", **base), train_fn=train_recording_device,
                                generate_fn=tiny_generate)
    devices = tmp_path / "out" / "runs" / "alpha" / "full" / "devices.log"
    assert devices.read_text().split() == ["cuda:1"]
    (run,) = results
    assert run.status == "ok" and run.device == "cuda:1"
    assert json.loads((Path(run.run_dir) / "harness.json").read_text())["device"] == "cuda:1"
    assert "| cuda:1 |" in paths["report.md"].read_text()
    again, _ = regenerate(_cfg(tmp_path, **base), train_fn=train_recording_device, generate_fn=tiny_generate)
    assert devices.read_text().split() == ["cuda:1"] and again[0].cached and again[0].device == "cuda:1"
    with pytest.raises(ValueError, match="device"):
        _cfg(tmp_path, device="gpu", **base).validate()
    with pytest.raises(ValueError, match="set with --device"):
        _cfg(tmp_path, train_overrides={"device": "cuda"}, **base).validate()
    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    with pytest.raises(ValueError, match="sees no CUDA device"):
        _cfg(tmp_path, device="cuda", **base).validate()


def test_changed_trainer_code_reruns(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = _cfg(tmp_path, methods=["full"], ablations=[], seeds=[0], workers=1)
    regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    n = _calls(cfg.out)
    real = harness.code_digest
    monkeypatch.setattr(harness, "code_digest",
                        lambda *names: real(*names) + ("x" if names == (harness.TRAINER_ENTRY,) else ""))
    results, _ = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    assert _calls(cfg.out) - n == 2 and not any(r.cached for r in results)


def test_dataset_failure_fails_its_runs(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, scenes=["alpha", "broken"], methods=["full"], ablations=[], seeds=[0], workers=1)
    results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    by_scene = {r.scene: r for r in results}
    assert by_scene["alpha"].status == "ok"
    assert by_scene["broken"].status == "failed" and "cannot be built" in by_scene["broken"].error
    assert "preset broken cannot be built" in paths["report.md"].read_text()


def test_dask_scheduler_address(tmp_path: Path) -> None:
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        cfg = _cfg(tmp_path, scenes=["alpha"], methods=["full"], ablations=[], seeds=[0, 1],
                   scheduler=cluster.scheduler_address, workers=1)
        results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    assert [r.status for r in results] == ["ok", "ok"]
    assert "dask scheduler" in paths["report.md"].read_text()


def test_provided_dataset_and_cli_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds = write_tiny_dataset(tmp_path / "ds", "given")
    assert harness_cli.main(["--scenes", "given", "--dataset", f"given={ds}", "--seeds", "0,",
                             "--methods", "full", "--no-ablations", "--out", str(tmp_path / "o"),
                             "--workers", "0"]) == 2
    assert "workers" in capsys.readouterr().err
    assert harness_cli.main(["--scenes", "given", "--dataset", f"given={tmp_path}/nope", "--out", str(tmp_path)]) == 2
    assert "datasets" in capsys.readouterr().err
    assert harness_cli.main(["--scenes", "given", "--dataset", f"given={ds}", "--methods", "convir"]) == 2
    assert "methods" in capsys.readouterr().err
    assert harness_cli.main(["--scenes", "given", "--dataset", f"given={ds}", "--seeds", "x"]) == 2
    assert "seeds" in capsys.readouterr().err
    args = harness_cli.build_parser().parse_args(
        ["--scenes", "given", "--dataset", f"given={ds}", "--seeds", "2", "--iterations", "40",
         "--no-ablations", "--set", "loss.depth=1.5"])
    cfg = harness_cli.config_from_args(args)
    assert cfg.seeds == [0, 1] and cfg.ablations == []
    assert cfg.train_overrides == {"loss.depth": 1.5, "stage2.iterations": 40, "stage3.iterations": 40,
                                   "stage3.test_every": 10}
    # Datasets follow the training profile's size unless told otherwise; flags refine the profile.
    assert cfg.gen_overrides == get_profile("bench").kwargs()
    args = harness_cli.build_parser().parse_args(["--scenes", "chair", "--profile", "paper", "--frames", "30"])
    assert harness_cli.config_from_args(args).gen_overrides == {**get_profile("paper").kwargs(), "frames": 30}
    args = harness_cli.build_parser().parse_args(["--scenes", "chair", "--gen-profile", "native", "--samples", "8"])
    assert harness_cli.config_from_args(args).gen_overrides == {"samples": 8}


@pytest.mark.slow
def test_end_to_end_demo_tiny_budget(tmp_path: Path) -> None:
    """The real generator and trainer on the demo preset: 1 seed, 2 methods, tiny budget."""
    out = tmp_path / "tables"
    rc = harness_cli.main(["--scenes", "demo", "--methods", "full,rgb-only", "--no-ablations", "--seeds", "1",
                           "--iterations", "20", "--gen-profile", "native", "--frames", "6",
                           "--resolution", "48x36", "--samples", "4",
                           "--workers", "1", "--out", str(out)])
    assert rc == 0, (out / "report.md").read_text()
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert {r["variant"] for r in runs} == {"full", "rgb-only"} and all(r["status"] == "ok" for r in runs)
    for r in runs:
        assert np.isfinite(r["metrics"]["psnr"])
    assert (out / "table1.md").is_file() and (out / "figure3_qualitative.png").is_file()


def slow_identity_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                        overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """identity_train that takes long enough for a second invocation to arrive mid-run."""
    time.sleep(0.5)
    return identity_train(dataset, out, mode, profile, seed, overrides)


def test_overlapping_invocations_share_a_run(tmp_path: Path) -> None:
    """Two invocations on one --out that plan the same run: one trains, the other waits and takes
    its result (without the lock the second deleted the folder the first was training in)."""
    ds = write_tiny_dataset(tmp_path / "ds", "alpha")
    spec = RunSpec("alpha", "full", "full", 0, "quick", {}, str(ds), "h", "code")
    run_dir = str(spec.run_dir(tmp_path / "out"))
    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda _: harness.run_task(spec, run_dir, slow_identity_train, 1), range(2)))
    assert [r.status for r in results] == ["ok", "ok"]
    assert sorted(r.cached for r in results) == [False, True]
    assert _calls(tmp_path / "out") == 1
    assert results[0].metrics["psnr"] == results[1].metrics["psnr"]
    assert json.loads((Path(run_dir) / "harness.json").read_text())["status"] == "ok"


def checkpointing_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                        overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Like the trainer: resumes from out/checkpoints, and its first attempt stops half-way."""
    checkpoint = out / "checkpoints" / "stage3.pt"
    if not checkpoint.is_file():
        checkpoint.parent.mkdir(parents=True)
        checkpoint.write_text("iteration 1500")
        raise RuntimeError("interrupted half-way (injected)")
    (out / "resumed_at.txt").write_text(checkpoint.read_text())
    return identity_train(dataset, out, mode, profile, seed, overrides)


def test_a_stopped_run_resumes_from_its_checkpoints(tmp_path: Path) -> None:
    """The folder of a run that stopped before finishing is kept for the next invocation, so
    the trainer resumes from its checkpoints (the harness used to delete it and start over)."""
    ds = write_tiny_dataset(tmp_path / "ds", "alpha")
    spec = RunSpec("alpha", "full", "full", 0, "quick", {}, str(ds), "h", "code")
    run_dir = spec.run_dir(tmp_path / "out")
    first = harness.run_task(spec, str(run_dir), checkpointing_train, 1)
    assert first.status == "failed" and "half-way" in first.error
    second = harness.run_task(spec, str(run_dir), checkpointing_train, 1)
    assert second.status == "ok" and not second.cached
    assert (run_dir / "resumed_at.txt").read_text() == "iteration 1500"
    assert json.loads((run_dir / "harness.json").read_text())["status"] == "ok"


def slow_generate(preset: str, out: Path, **overrides: Any) -> Path:
    with open(out.parent / "generate_calls.log", "a") as f:
        f.write(f"{preset}\n")
    time.sleep(0.5)
    return tiny_generate(preset, out, **overrides)


def test_overlapping_invocations_share_a_dataset(tmp_path: Path) -> None:
    """The same holds for datasets: generated once, marked done before the lock is released."""
    o = harness.DatasetOutcome("alpha", "generated", str(tmp_path / "datasets" / "alpha-h"), "h")
    make = partial(slow_generate, "alpha", seed=0)
    with ThreadPoolExecutor(2) as pool:
        outcomes = list(pool.map(lambda _: harness.dataset_task(o, make), range(2)))
    assert [v[0] for v in outcomes] == ["ok", "ok"], outcomes
    assert (tmp_path / "datasets" / "generate_calls.log").read_text().splitlines() == ["alpha"]
    assert json.loads((tmp_path / "datasets" / "alpha-h.done.json").read_text())["hash"] == "h"


def test_plan_is_printed_before_anything_runs(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level("INFO", logger="regenerate-tables")
    cfg = _cfg(tmp_path)
    results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate, dry_run=True)
    assert results == [] and paths == {} and not cfg.out.exists()
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("plan:"))
    assert "2 scene(s) x 3 variant(s) x 2 seed(s) = 12 runs (0 cached, 12 to train)" in line
    assert "2 dataset(s) to generate, 2 to dehaze" in line and "estimated" in line
    caplog.clear()
    regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate, dry_run=True)
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("plan:") and "cached" in r.getMessage()
                and "8 cached" in r.getMessage())
    assert "0 dataset(s) to generate" in line and "earlier run(s) in this folder" in line


def test_rule_candidates_run_beside_full_and_share_its_stage2(tmp_path: Path) -> None:
    """--candidates adds each rule candidate, with Full as its reference when Full is not a method;
    a candidate that changes only Stage 3's start shares Full's Stage-2 key (so it takes Full's
    finished Stage 2); an unknown one is refused."""
    from eval.harness import plan_runs
    from eval.shared_stage2 import stage2_sha

    cfg = _cfg(tmp_path, methods=["rgb-only"], ablations=[], candidates=["start-thermal", "carve-where-smoky"])
    assert cfg.variants() == ["rgb-only", "start-thermal", "carve-where-smoky", "full"]
    ds = {s: harness.DatasetOutcome(s, "generated", str(tmp_path / s), "h") for s in cfg.scenes}
    specs = {(r.scene, r.variant, r.seed): r for r in plan_runs(cfg, ds, ds)}
    full, carve = specs[("alpha", "full", 0)], specs[("alpha", "carve-where-smoky", 0)]
    assert carve.overrides["stage3.carve_by"] == "depth-and-smoke"
    assert specs[("alpha", "start-thermal", 0)].overrides["stage3.surface_init"] == "thermal"
    assert stage2_sha(carve) == stage2_sha(full) == stage2_sha(specs[("alpha", "start-thermal", 0)])
    planes = _cfg(tmp_path, methods=["full"], ablations=[], candidates=["motion-planes", "densify-by-gradient"])
    specs = {(r.variant, r.seed): r for r in plan_runs(planes, ds, ds) if r.scene == "alpha"}
    assert stage2_sha(specs[("motion-planes", 0)]) == stage2_sha(specs[("full", 0)])  # the motion is Stage 3's
    assert stage2_sha(specs[("densify-by-gradient", 0)]) != stage2_sha(specs[("full", 0)])
    from eval.runs import CANDIDATES
    from smokeseer.config import make_config

    for key, v in CANDIDATES.items():  # every candidate is a Full run the standard profile accepts
        assert v.mode == "full" and v.table == "candidates" and v.overrides, key
        make_config("full", "standard", overrides=v.overrides)
    with pytest.raises(ValueError, match="candidates: unknown 'start-magic'"):
        _cfg(tmp_path, candidates=["start-magic"]).validate()
    # the tables and the report are written with candidates among the runs
    cfg = _cfg(tmp_path, methods=["full"], ablations=[], candidates=["start-thermal"], seeds=[0])
    results, paths = regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    assert sorted({r.variant for r in results}) == ["full", "start-thermal"] and all(r.status == "ok" for r in results)
    report = paths["report.md"].read_text()
    assert "rule candidates" in report and "start-thermal" in report


def test_results_json_names_the_commit_threads_and_machine(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, scenes=["alpha"], methods=["full"], ablations=[], seeds=[0], workers=1)
    regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    prov = json.loads((cfg.out / "results.json").read_text())["provenance"]
    assert {"commit", "version", "source_digest", "threads", "machine"} <= set(prov)


def test_lpips_settings_reach_the_trainer_and_its_cache_key(tmp_path: Path) -> None:
    a = _cfg(tmp_path, scenes=["alpha"], methods=["full"], ablations=[], seeds=[0])
    b = _cfg(tmp_path, scenes=["alpha"], methods=["full"], ablations=[], seeds=[0], lpips_net="vgg",
             lpips_weights="/w/vgg16.pth")
    assert b.run_overrides() == {"lpips_net": "vgg", "lpips_weights": "/w/vgg16.pth"} and a.run_overrides() == {}


def test_trainer_and_harness_read_set_values_alike() -> None:
    from smokeseer import cli as trainer_cli

    items = ["loss.depth=1.5", "stage3.iterations=40", "smoke_ply_times=[0.0, 1.0]", "progress=false"]
    trainer = trainer_cli.overrides_from_args(trainer_cli.build_parser().parse_args(
        ["ds", "--out", "o"] + [x for i in items for x in ("--set", i)]))
    harness_args = harness_cli.build_parser().parse_args(["--scenes", "chair"] + [x for i in items for x in ("--set", i)])
    assert harness_cli.config_from_args(harness_args).train_overrides == {k: trainer[k] for k in
                                                                         ("loss.depth", "stage3.iterations",
                                                                          "smoke_ply_times", "progress")}
    assert trainer["smoke_ply_times"] == [0.0, 1.0] and trainer["progress"] is False


def test_estimated_stage1_variant_trains_full_with_stage1_estimate_and_its_own_cache_key(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, scenes=["alpha"], methods=["full", "full-estimated"], ablations=[], seeds=[0],
               train_overrides={"stage3.iterations": 5})
    ds = {"alpha": harness.DatasetOutcome("alpha", "generated", str(tmp_path / "ds"), "d" * 64)}
    specs = {s.variant: s for s in harness.plan_runs(cfg, ds, {})}
    assert specs["full-estimated"].mode == specs["full"].mode == "full"
    assert specs["full-estimated"].overrides == {"stage3.iterations": 5, "stage1": "estimate"}
    assert specs["full"].overrides == {"stage3.iterations": 5}
    assert specs["full"].hash() != specs["full-estimated"].hash()
    assert specs["full-estimated"].run_dir(tmp_path) != specs["full"].run_dir(tmp_path)


def test_table2_depth_row_differs_from_full() -> None:
    """Table 2's depth row is the one that differs from the profile's Full: "w/o depth" where Full
    has the depth term (quick), "with depth (Stage-2 prior)" where it has none (standard), and that
    row's run does have the term; the user's overrides decide as well."""
    from eval.runs import VARIANTS
    from smokeseer.config import make_config
    from smokeseer.train.plan import depth_term_on

    quick, standard = settings.default_ablations("quick", {}), settings.default_ablations("standard", {})
    assert "no-depth" in quick and "stage2-depth" not in quick
    assert "stage2-depth" in standard and "no-depth" not in standard
    assert set(quick) - {"no-depth"} == set(standard) - {"stage2-depth"}
    assert depth_term_on(make_config("full", "standard", overrides=VARIANTS["stage2-depth"].overrides))
    assert "no-depth" in settings.default_ablations("standard", {"depth_prior": "thermal-render"})
    cfg = HarnessConfig(out=Path("unused"), scenes=["demo"], profile="standard")
    assert cfg.ablations == standard


def test_ablations_take_fulls_finished_stage2_and_end_as_if_they_trained_it(tmp_path: Path) -> None:
    """The real trainer at a tiny budget: no-mask differs from Full in Stage 3 only, so it takes
    Full's finished Stage 2 (one worker: Full first), and its model and scores are those of a
    no-mask run that trained its own Stage 2; its wall time counts the Stage 2 it took. Stage 3
    starts from two surfaces here (the haze lines give no estimate), so the RGB Stage 2 comes too."""
    from tests.test_smokeseer_data import write_splat_dataset

    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    tiny = {"stage2.iterations": 12, "stage3.iterations": 12, "stage2.init_points": 300,
            "stage3.smoke_points": 120, "log_every": 3, "stage3.test_every": 6, "checkpoint_every": 6,
            "stage2.deform_warmup": 0.25, "stage3.deform_warmup": 0.25, "progress": False,
            "stage3.smoke_color": "haze-lines", "stage3.surface_init": "by-smoke-colour"}

    def run(out: Path, methods: list[str], ablations: list[str]) -> dict[str, RunResult]:
        cfg = HarnessConfig(out=out, scenes=["splat"], methods=methods, ablations=ablations, seeds=[0], workers=1,
                            datasets={"splat": ds}, train_overrides=tiny)
        results, paths = regenerate(cfg)
        assert all(r.status == "ok" for r in results), [r.error for r in results]
        taker = "no-mask" if "full" in methods else "full"  # Full, Table 2's reference, comes last when only added
        assert f"instead of training it again (eval/shared_stage2.py; harness.json `stage2_from`); their seconds " \
               f"include that Stage 2's logged time: splat/{taker}/seed 0." in paths["report.md"].read_text()
        return {r.variant: r for r in results}

    shared = run(tmp_path / "shared", ["full"], ["no-mask"])
    alone = run(tmp_path / "alone", [], ["no-mask"])["no-mask"]
    full, taker = shared["full"], shared["no-mask"]
    assert taker.stage2_from == full.run_dir and full.stage2_from == "" and alone.stage2_from == ""
    assert taker.logged_before_s > 0 and taker.wall_time_s > taker.logged_before_s
    ply = Path("ply") / "surface.ply"
    assert (Path(taker.run_dir) / ply).read_bytes() == (Path(alone.run_dir) / ply).read_bytes()
    assert (Path(taker.run_dir) / ply).read_bytes() != (Path(full.run_dir) / ply).read_bytes()
    assert taker.metrics["psnr"] == alone.metrics["psnr"]
    rgb_stage2 = lambda r: (Path(r.run_dir) / "checkpoints" / "stage2_rgb.pt").read_bytes()
    assert rgb_stage2(taker) == rgb_stage2(full) == rgb_stage2(alone)
    stage2_rows = lambda r: [(x["iteration"], x["loss"]) for x in csv.DictReader(open(Path(r.run_dir) / "train_log.csv"))
                             if x["stage"] == "2"]
    assert stage2_rows(taker) == stage2_rows(full) == stage2_rows(alone)


def test_a_taker_gets_the_donors_rgb_stage2_only_when_finished_with_its_key(tmp_path: Path) -> None:
    """take_finished_stage2 copies stage2_rgb.pt beside stage2.pt when the donor's is finished
    under the RGB key asked for, and leaves it for the run to train otherwise."""
    import torch

    from eval.shared_stage2 import take_finished_stage2

    donor = tmp_path / "donor"
    (donor / "checkpoints").mkdir(parents=True)
    (donor / "train_log.csv").write_text("stage,iteration,loss\n2,3,0.5\n")
    torch.save({"done": True, "config_sha256": "thermal"}, donor / "checkpoints" / "stage2.pt")
    for rgb_done, rgb_key, expected in ((True, "rgb", True), (False, "rgb", False), (True, "other", False)):
        torch.save({"done": rgb_done, "config_sha256": "rgb"}, donor / "checkpoints" / "stage2_rgb.pt")
        taker = tmp_path / f"taker-{rgb_done}-{rgb_key}"
        assert take_finished_stage2(taker, [str(donor)], "thermal", rgb_key) == str(donor)
        assert (taker / "checkpoints" / "stage2.pt").is_file()
        assert (taker / "checkpoints" / "stage2_rgb.pt").is_file() == expected


def test_two_workers_train_one_stage2_for_full_and_its_ablations(tmp_path: Path) -> None:
    """Two workers start Full and two Stage-3 ablations of it together. Full's group trains Stage 2
    once: the ablations wait for Full's (they start with it or behind it), take it, and end with
    Full's Stage-2 log rows; without the wait, each would train its own."""
    from tests.test_smokeseer_data import write_splat_dataset

    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    tiny = {"stage2.iterations": 30, "stage3.iterations": 6, "stage2.init_points": 300,
            "stage3.smoke_points": 120, "log_every": 3, "stage3.test_every": 6, "checkpoint_every": 6,
            "stage2.deform_warmup": 0.25, "stage3.deform_warmup": 0.25, "progress": False}
    cfg = HarnessConfig(out=tmp_path / "out", scenes=["splat"], methods=["full", "full-estimated"],
                        ablations=["no-mask", "no-mono"], seeds=[0], workers=2, datasets={"splat": ds},
                        train_overrides=tiny)
    results, _ = regenerate(cfg)
    assert all(r.status == "ok" for r in results), [r.error for r in results]
    runs = {r.variant: r for r in results}
    assert runs["full"].stage2_from == ""
    takers = ("no-mask", "no-mono", "full-estimated")
    assert {runs[v].stage2_from for v in takers} == {runs["full"].run_dir}
    rows = lambda r: [(x["iteration"], x["loss"]) for x in csv.DictReader(open(Path(r.run_dir) / "train_log.csv"))
                      if x["stage"] == "2"]
    assert all(rows(runs[v]) == rows(runs["full"]) for v in takers)


def test_stage1_from_images_trains_the_same_stage2(tmp_path: Path) -> None:
    """Why "Full, estimated Stage 1" may take Full's Stage 2: Stage 2 reads no mask, so a run
    that estimates Stage 1 trains, on its own, the Stage 2 of one that reads the dataset's."""
    from smokeseer.cli import main
    from smokeseer.config import make_config
    from tests.test_smokeseer_data import write_splat_dataset

    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    tiny = ["--iterations-stage2", "20", "--iterations-stage3", "2", "--no-progress", "--set", "stage2.init_points=300",
            "--set", "stage3.smoke_points=120", "--set", "log_every=2"]
    for stage1 in ("ground-truth", "estimate"):
        assert main([str(ds), "--out", str(tmp_path / stage1), "--set", f"stage1={stage1}"] + tiny) == 0
    rows = {s: [(x["iteration"], x["loss"], x["n_gaussians"])
                for x in csv.DictReader(open(tmp_path / s / "train_log.csv")) if x["stage"] == "2"]
            for s in ("ground-truth", "estimate")}
    assert len(rows["estimate"]) == 10 and rows["estimate"] == rows["ground-truth"]
    assert make_config("full", "standard", overrides={"stage1": "estimate"}).stage2_sha256() == \
        make_config("full", "standard").stage2_sha256()


def test_leaders_first_puts_every_stage2_taker_behind_every_group_leader(tmp_path: Path) -> None:
    """Plan order interleaves scenes' Full runs and ablations; the start order has each group's
    first run ahead of every run that can take a Stage 2, and keeps plan order within each part."""
    from eval.shared_stage2 import leaders_first, stage2_groups, stage2_leaders

    specs = [RunSpec(scene, variant, VARIANTS[variant].mode, 0, "quick", dict(VARIANTS[variant].overrides),
                     f"/data/{scene}", "d" * 8, "c" * 8)
             for scene in ("a", "b") for variant in ("full", "no-mask", "rgb-only", "no-mono")]
    groups = stage2_groups(specs, tmp_path)
    order = [(s.scene, s.variant) for s in leaders_first(specs, tmp_path, groups)]
    assert order == [("a", "full"), ("a", "rgb-only"), ("b", "full"), ("b", "rgb-only"),
                     ("a", "no-mask"), ("a", "no-mono"), ("b", "no-mask"), ("b", "no-mono")]
    leaders = stage2_leaders(groups)
    assert sorted(Path(d).parts[-3] + "/" + Path(d).parts[-2] for d in leaders) == \
        ["a/no-mask", "a/no-mono", "b/no-mask", "b/no-mono"]


def test_a_taker_that_shares_an_earlier_takers_rgb_stage2_starts_behind_it(tmp_path: Path) -> None:
    """Two candidates with one RGB Stage 2 (they differ in Stage 3 only) both take Full's thermal
    Stage 2; the second of them starts behind every other taker, so that it finds the first one's
    RGB Stage 2 finished instead of training it again. Full's ablations share Full's RGB Stage 2
    and keep their places."""
    from eval.shared_stage2 import leaders_first, stage2_groups

    clear_env = {"background_from": "clear-pixels"}  # an RGB Stage 2 of its own
    variants = {"full": ("full", {}), "background-clear": ("full", clear_env),
                "background-clear-carve": ("full", {**clear_env, "stage3.carve_by": "depth-and-smoke"}),
                "no-mask": (VARIANTS["no-mask"].mode, dict(VARIANTS["no-mask"].overrides))}
    specs = [RunSpec(scene, variant, mode, 0, "standard", dict(overrides), f"/data/{scene}", "d" * 8, "c" * 8)
             for scene in ("a", "b") for variant, (mode, overrides) in variants.items()]
    order = [(s.scene, s.variant) for s in leaders_first(specs, tmp_path, stage2_groups(specs, tmp_path))]
    assert order == [("a", "full"), ("b", "full"),
                     ("a", "background-clear"), ("a", "no-mask"), ("b", "background-clear"), ("b", "no-mask"),
                     ("a", "background-clear-carve"), ("b", "background-clear-carve")]


def test_a_taker_prefers_the_donor_that_has_its_rgb_stage2(tmp_path: Path) -> None:
    """Of two donors with the thermal Stage 2 a taker needs, the one that also has its finished RGB
    Stage 2 is taken, though it comes second; with neither, the first."""
    import torch

    from eval.shared_stage2 import take_finished_stage2

    donors = []
    for name, rgb_key in (("full", "rgb-all-pixels"), ("candidate", "rgb-clear-pixels")):
        donor = tmp_path / name
        (donor / "checkpoints").mkdir(parents=True)
        (donor / "train_log.csv").write_text("stage,iteration,loss\n2,3,0.5\n")
        torch.save({"done": True, "config_sha256": "thermal"}, donor / "checkpoints" / "stage2.pt")
        torch.save({"done": True, "config_sha256": rgb_key}, donor / "checkpoints" / "stage2_rgb.pt")
        donors.append(str(donor))
    assert take_finished_stage2(tmp_path / "taker", donors, "thermal", "rgb-clear-pixels") == donors[1]
    assert torch.load(tmp_path / "taker" / "checkpoints" / "stage2_rgb.pt", weights_only=False)["config_sha256"] \
        == "rgb-clear-pixels"
    assert take_finished_stage2(tmp_path / "other", donors, "thermal", "rgb-elsewhere") == donors[0]
    assert not (tmp_path / "other" / "checkpoints" / "stage2_rgb.pt").exists()


def heavy_identity_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                         overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """identity_train that also leaves what the real trainer leaves and no table reads."""
    status = identity_train(dataset, out, mode, profile, seed, overrides)
    for heavy in ("checkpoints/stage3.pt", "ply/surface.ply", "renders/composite/0001.png", "renders/smoke/0001.png"):
        (out / heavy).parent.mkdir(parents=True, exist_ok=True)
        (out / heavy).write_bytes(b"\0" * 64)
    return status


def test_a_committed_out_folder_serves_its_finished_runs_on_a_fresh_clone(tmp_path: Path) -> None:
    """data/README.md: the project's .gitignore keeps each run's record, metrics, log and surface
    renders and drops checkpoints, PLYs and the dehazed copies; a fresh clone of that commit, with
    the original folder gone, tables every run without training one, from the clone's own files."""
    git = ["git", "-c", "user.name=test", "-c", "user.email=test@example.com"]
    repo, clone = tmp_path / "repo", tmp_path / "clone"
    repo.mkdir()
    shutil.copyfile(Path(__file__).parents[1] / ".gitignore", repo / ".gitignore")
    ds = write_tiny_dataset(repo / "data/standard/alpha", "alpha")
    for png in sorted((ds / "rgb/clean").glob("*.png")):
        (ds / MASK.folder).mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.full((24, 32), 255, np.uint8)).save(ds / MASK.folder / png.name)

    def cfg(root: Path) -> HarnessConfig:
        return HarnessConfig(out=root / "data/tables_standard", scenes=["alpha"], methods=["full", "imgdehaze-dcp"],
                             ablations=[], seeds=[0], workers=1, datasets={"alpha": root / "data/standard/alpha"})

    first, _ = regenerate(cfg(repo), train_fn=heavy_identity_train)
    assert [r.status for r in first] == ["ok", "ok"]
    subprocess.run([*git, "init", "-q", str(repo)], check=True)
    subprocess.run([*git, "-C", str(repo), "add", "-A"], check=True)
    subprocess.run([*git, "-C", str(repo), "commit", "-q", "-m", "runs"], check=True)
    subprocess.run([*git, "clone", "-q", str(repo), str(clone)], check=True)
    shutil.rmtree(repo)

    out = clone / "data/tables_standard"
    kept = {p.relative_to(out).as_posix().split("/", 4)[-1] for p in (out / "runs").rglob("*") if p.is_file()}
    assert {"harness.json", "metrics.json", "train_log.csv", "renders/surface/0001.png"} <= kept
    assert not {k for k in kept if k.startswith(("checkpoints", "ply", "renders/composite", "renders/smoke"))}
    assert not (out / "datasets").exists() and not (out / "table1.md").exists()
    calls = _calls(out)
    results, paths = regenerate(cfg(clone), train_fn=heavy_identity_train)
    assert _calls(out) == calls
    assert [(r.status, r.cached) for r in results] == [("ok", True), ("ok", True)]
    assert [r.metrics["psnr"] for r in results] == [r.metrics["psnr"] for r in first]
    assert all(Path(r.run_dir).is_relative_to(out) and Path(r.run_dir).is_dir() for r in results)
    regions = list(csv.DictReader(open(paths["per_scene_regions.csv"])))
    assert {row["variant"] for row in regions} == {"full", "imgdehaze-dcp"}
    assert "skipped" not in paths["per_scene_regions.md"].read_text().lower()

    # --finished-only rebuilds nothing, the dehazed copy included, and still tables the baseline's run
    shutil.rmtree(out / "datasets")
    again, _ = regenerate(replace(cfg(clone), finished_only=True), train_fn=heavy_identity_train)
    assert [(r.variant, r.status, r.cached) for r in again] == [("full", "ok", True), ("imgdehaze-dcp", "ok", True)]
    assert [r.metrics["psnr"] for r in again] == [r.metrics["psnr"] for r in first]
    assert _calls(out) == calls and not (out / "datasets").exists()


def test_adopt_from_takes_only_runs_that_differ_by_the_python_digest(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Runs trained where the trainer's digest differs, as under another Python, are adopted when
    their key with that digest is this plan's and their trainer sources equal this checkout's;
    a run whose sources differ, or a plan with other settings, adopts nothing."""
    from eval.adopt import adopt_runs

    write_tiny_dataset(tmp_path / "ds", "alpha")
    elsewhere, here = tmp_path / "elsewhere", tmp_path / "here"
    real_digest = harness.code_digest
    monkeypatch.setattr(harness, "code_digest",
                        lambda *entries: "other-python" if entries == (harness.TRAINER_ENTRY,) else real_digest(*entries))
    made = regenerate(_cfg(tmp_path, out=elsewhere, scenes=["alpha"], datasets={"alpha": tmp_path / "ds"},
                           methods=["full", "rgb-only"], ablations=[], seeds=[0], workers=1),
                      train_fn=identity_train, generate_fn=tiny_generate)[0]
    monkeypatch.undo()
    assert {r.status for r in made} == {"ok"}
    tampered = next((elsewhere / "runs/alpha/rgb-only").glob("seed0-*/harness.json"))
    rec = json.loads(tampered.read_text())
    assert rec["code_digest"] == "other-python" and len(rec["sources_sha256"]) == 64
    tampered.write_text(json.dumps({**rec, "sources_sha256": "f" * 64}))

    other = _cfg(tmp_path, out=here, scenes=["alpha"], datasets={"alpha": tmp_path / "ds"}, methods=["full"],
                 ablations=[], seeds=[0], workers=1, lpips_net="vgg")
    (refused,) = adopt_runs(other, elsewhere)
    assert not refused.adopted and "settings or dataset differ" in refused.reason and not here.exists()

    argv = ["--out", str(here), "--scenes", "alpha", "--dataset", f"alpha={tmp_path / 'ds'}", "--methods",
            "full,rgb-only", "--no-ablations", "--seeds", "0,", "--adopt-from", str(elsewhere), "--finished-only"]
    assert harness_cli.main(argv) == 0
    err = capsys.readouterr().err
    assert "[adopted] alpha/full/seed 0 from" in err
    assert "[not adopted] alpha/rgb-only/seed 0:" in err and "field 'sources_sha256' differs" in err
    runs = {r["variant"]: r for r in json.loads((here / "results.json").read_text())["runs"]}
    assert runs["full"]["status"] == "ok" and runs["full"]["cached"] and runs["rgb-only"]["status"] == "pending"
    assert "trainer digest other-py" in runs["full"]["adopted_from"] and runs["full"]["code_digest"] != "other-python"
    source_full = next((elsewhere / "runs/alpha/full").glob("seed0-*"))
    assert (Path(runs["full"]["run_dir"]) / "metrics.json").read_bytes() == (source_full / "metrics.json").read_bytes()
    assert "1 run(s) were trained under another key and adopted" in (here / "report.md").read_text()
    assert not list(here.rglob(".*.adopting")) and _calls(here) == 0


def test_each_run_records_its_float_setup_and_the_report_names_a_mix(tmp_path: Path) -> None:
    """harness.json says what set the run's rounding here (the CPU's vector flags, torch's CPU
    capability, the compiler); a cached run keeps what it recorded, and a report over runs of two setups says so."""
    import torch

    from contracts.float_setup import cpu_facts, float_setup

    base = dict(scenes=["alpha", "beta"], methods=["full"], ablations=[], seeds=[0], workers=1)
    results, paths = regenerate(_cfg(tmp_path, **base), train_fn=identity_train, generate_fn=tiny_generate)
    here = float_setup()
    assert f"torch {torch.__version__} {torch.backends.cpu.get_cpu_capability()}" in here
    model, flags = cpu_facts()
    assert here.startswith(f"cpu {model} (") and all(f in here for f in flags)
    assert ("avx2" in flags) == ("avx2" in here.split(";")[0])
    for r in results:
        assert json.loads((Path(r.run_dir) / "harness.json").read_text())["float_setup"] == here
    assert "more than one float setup" not in paths["report.md"].read_text()
    record = Path(results[0].run_dir) / "harness.json"
    rec = json.loads(record.read_text())
    record.write_text(json.dumps({**rec, "float_setup": "cpu Other; torch 2.13.0+cpu AVX2; kernel g++ -O3"}))
    again, paths = regenerate(_cfg(tmp_path, **base), train_fn=identity_train, generate_fn=tiny_generate)
    assert all(r.cached for r in again)
    assert {r.float_setup for r in again} == {here, "cpu Other; torch 2.13.0+cpu AVX2; kernel g++ -O3"}
    report = paths["report.md"].read_text()
    assert "more than one float setup" in report and "1 under cpu Other; torch 2.13.0+cpu AVX2" in report


def test_finished_only_with_digest_tables_an_earlier_trainers_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """After a trainer change every run is keyed anew, so --finished-only finds none; with --digest
    it tables the earlier trainer's finished runs kept in --out, under their own keys, trains
    nothing, and the report names both digests. Without --finished-only, or with a digest no run
    has, it is one line."""
    ds = write_tiny_dataset(tmp_path / "ds", "alpha")
    out = tmp_path / "out"
    argv = ["--out", str(out), "--scenes", "alpha", "--dataset", f"alpha={ds}", "--methods", "full",
            "--no-ablations", "--seeds", "0,", "--workers", "1"]
    cfg = harness_cli.config_from_args(harness_cli.build_parser().parse_args(argv))
    regenerate(cfg, train_fn=identity_train, generate_fn=tiny_generate)
    earlier = json.loads(next(out.glob("runs/alpha/full/*/harness.json")).read_text())["code_digest"]
    real = harness.code_digest
    monkeypatch.setattr(harness, "code_digest",
                        lambda *names: ("f" * 64) if names == (harness.TRAINER_ENTRY,) else real(*names))
    monkeypatch.setattr("eval.report.code_digest",
                        lambda *names: ("f" * 64) if names == (harness.TRAINER_ENTRY,) else real(*names))
    n = _calls(out)
    assert harness_cli.main([*argv, "--finished-only"]) == 0
    assert "0 runs ok, 0 failed, 1 pending" in capsys.readouterr().out
    assert harness_cli.main([*argv, "--finished-only", "--digest", earlier[:8]]) == 0
    assert "1 runs ok, 0 failed" in capsys.readouterr().out and _calls(out) == n
    report = (out / "report.md").read_text()
    assert f"smokeseer.api {earlier[:12]} (the runs tabled, --digest; today's trainer ffffffffffff)" in report
    assert "| alpha | full | 0 | ok | True | cpu |" in report
    assert harness_cli.main([*argv, "--digest", earlier[:8]]) == 2
    assert "digest: only with --finished-only" in capsys.readouterr().err
    assert harness_cli.main([*argv, "--finished-only", "--digest", "00000000"]) == 2
    assert f"--digest 00000000: no run in {out}/runs has a code_digest starting so (found {earlier[:8]})" \
        in capsys.readouterr().err
    assert _calls(out) == n


def test_report_lists_each_runs_psnr_and_lpips(tmp_path: Path) -> None:
    from eval.report import write_report
    from eval.runs import RunResult

    cfg = _cfg(tmp_path, scenes=["alpha"], methods=["full", "rgb-only"], ablations=[], seeds=[0])
    scored = RunResult("alpha", "full", 0, "ok", str(tmp_path / "a"), "abcdef1234567890",
                       metrics={"psnr": 21.234, "lpips": 0.1236})
    unscored = RunResult("alpha", "rgb-only", 0, "ok", str(tmp_path / "b"), "0123456789abcdef",
                         metrics={"psnr": 20.0})
    text = write_report(cfg, [scored, unscored], [], "x", "local", 1.0, {}, tmp_path / "report.md").read_text()
    assert "| seconds | PSNR | LPIPS | config hash | run dir |" in text
    assert "| 21.23 | 0.124 | abcdef123456 |" in text and "| 20.00 |  | 0123456789ab |" in text
