"""``python -m benchmarks.gpu_check.run --wheels DIR --out DIR``: the GPU check (scripts/gpu_check.sh).

On a Linux node with an NVIDIA GPU, torch with CUDA, nvcc and ninja, and no internet: install
the project from the wheel folder (make_wheels), build gsplat's CUDA code, run the gsplat parity
tests against the compiled CPU rasterizer, train one standard dataset with gsplat (the standard
profile, then part of the paper profile) and Stage 3 with the torch backend for comparison, and
write gpu_check.json and gpu_check.md. Every step has a timeout inside one budget (600 s); a
step that cannot run is skipped and the report says why.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from packaging.tags import sys_tags

from benchmarks.gpu_check.reference import cpu_reference, last_iterations, psnr_verdict, stage_rates
from benchmarks.gpu_check.report import write_report
from benchmarks.gpu_check.prebuilt import mismatches, read_record
from benchmarks.gpu_check.steps import (FAILED, OK, SKIPPED, Budget, Running, StepResult, blocked, run_command,
                                        start_command)
from benchmarks.gpu_check.wheels import check_folder

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
CAPS = {"probe": 60, "install": 150, "build": 360, "parity": 150, "stage3-torch": 75, "paper-gsplat": 75}
"""Longest each step may take, in seconds; the standard run gets what the budget leaves after
reserving the two short runs that follow it."""
REPORT_RESERVE_S = 10.0


def _env(*paths: Path, **extra: str) -> dict[str, str]:
    """This environment with PYTHONPATH set to ``paths`` (the installed folders) and their ``bin``
    folders (ninja's, for one) first on PATH."""
    bins = [str(p / "bin") for p in paths if (p / "bin").is_dir()]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(str(p) for p in paths),
            "PATH": os.pathsep.join([*bins, os.environ.get("PATH", "")]), **extra}


def _commit() -> str | None:
    res = subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=7"], cwd=ROOT, capture_output=True,
                         text=True)
    return res.stdout.strip() or None if res.returncode == 0 else None


def parity_detail(junit: Path) -> dict[str, Any]:
    """Per-test outcome and the figures the tests printed, from pytest's JUnit XML."""
    tests = {}
    for case in ET.parse(junit).getroot().iter("testcase"):
        outcome = "passed"
        for tag in ("failure", "error", "skipped"):
            node = case.find(tag)
            if node is not None:
                outcome = f"{tag}: {(node.get('message') or '')[:200]}"
        out = case.find("system-out")
        lines = (out.text or "").splitlines() if out is not None else []
        printed = [ln for ln in lines if not (ln.startswith("-") and "Captured" in ln)]  # pytest's section header
        tests[case.get("name")] = {"outcome": outcome, "printed": "\n".join(printed).strip()}
    return tests


def run_figures(run: Path, memory: Path) -> dict[str, Any]:
    """What a training run folder shows: it/s per stage, iterations done, test PSNR, peak memory."""
    fig: dict[str, Any] = {}
    log = run / "train_log.csv"
    if log.is_file():
        fig["iterations_per_s"] = stage_rates(log)
        fig["iterations_done"] = last_iterations(log)
    if (run / "metrics.json").is_file():
        doc = json.loads((run / "metrics.json").read_text())
        if doc.get("status") == "ok":
            fig["psnr"] = doc["metrics"]["psnr"]
            fig["ssim"] = doc["metrics"]["ssim"]
            fig["wall_time_s"] = doc["wall_time_s"]
            fig["source_digest"] = doc["provenance"]["source_digest"]
    if memory.is_file():
        fig.update(json.loads(memory.read_text()))
    return fig


class Check:
    """The steps in order, sharing one budget and one work folder."""

    def __init__(self, wheels: Path, out: Path, budget_s: float, dataset: Path, paper_iterations: int,
                 torch_iterations: int) -> None:
        self.wheels, self.out, self.dataset = wheels.resolve(), out.resolve(), dataset.resolve()
        self.paper_iterations, self.torch_iterations = paper_iterations, torch_iterations
        self.budget = Budget(budget_s)
        self.work = self.out / "install"
        self.site, self.gsplat_site = self.work / "site", self.work / "gsplat-site"
        self.logs, self.runs = self.out / "logs", self.out / "runs"
        self.done: dict[str, StepResult] = {}
        self.background: dict[str, Running | StepResult] = {}
        self.node: dict[str, Any] = {}

    def record(self, result: StepResult) -> StepResult:
        self.done[result.name] = result
        print(f"[{result.status:>7}] {result.name} {result.seconds:.1f} s {result.reason}".rstrip(), flush=True)
        return result

    def command(self, name: str, argv: list[str], cap_s: float, needs: list[str], reserve_s: float = 0.0,
                **kw: Any) -> StepResult:
        return self.record(blocked(name, needs, self.done)
                           or run_command(name, argv, self.log(name),
                                          self.budget.timeout_for(cap_s, reserve_s + REPORT_RESERVE_S), **kw))

    def probe(self) -> None:
        res = self.command("probe", [PY, "-m", "benchmarks.gpu_check.target"], CAPS["probe"], [], cwd=ROOT)
        if res.status == OK:
            self.node = json.loads([ln for ln in Path(res.log).read_text().splitlines() if ln.startswith("{")][-1])
        n = self.node
        print(f"Python {n.get('python')}, torch {n.get('torch')} (CUDA {n.get('torch_cuda')}), nvcc {n.get('nvcc')}, "
              f"GPU {', '.join(n.get('gpus') or []) or 'none'} (arch {n.get('arch_list')})", flush=True)
        missing = [] if n.get("cuda_available") else ["torch sees no CUDA device"]
        # A source build needs nvcc, CUDA's headers and ninja; a matching prebuilt wheel does not.
        compile_gaps = [what for what, ok in (("no nvcc on PATH", n.get("nvcc")), ("no ninja on PATH", n.get("ninja")),
                                              (f"CUDA_HOME {n.get('cuda_home')} has no include/cuda_runtime.h",
                                               n.get("cuda_headers"))) if not ok]
        self.record(StepResult("gpu", SKIPPED if missing else OK, reason="; ".join(missing + compile_gaps)))

    def wheel_folder(self) -> None:
        python = ".".join((self.node.get("python") or "").split(".")[:2])
        if not python:
            self.record(StepResult("wheels", SKIPPED, reason="needs step 'probe'"))
            return
        check = check_folder(self.wheels, ROOT / "pyproject.toml", python, list(sys_tags()))
        self.record(StepResult("wheels", OK if check.ok else FAILED, reason="; ".join(check.problems[:5]),
                               detail={"size_bytes": check.size_bytes, "files": check.files}))

    def install(self) -> None:
        wheels = [p for p in sorted(self.wheels.glob("*.whl")) if not p.name.startswith("gsplat-")]
        pip = self._pip_install(self.site)
        marker = self.work / "site-wheels.json"
        listing = {p.name: p.stat().st_size for p in wheels}
        if marker.is_file() and json.loads(marker.read_text()) == listing and not blocked("install", ["wheels"], self.done):
            self.record(StepResult("install", OK, reason=f"the same wheels are installed in {self.site} already"))
        elif self.command("install", [*pip, *map(str, wheels)], CAPS["install"], ["wheels"]).status == OK:
            marker.write_text(json.dumps(listing) + "\n")
        # Built with the setuptools just installed (a build-isolated one would need the image's
        # packages too); the project declares Python 3.11, and its trainer runs on later ones.
        self.command("install-project", [*pip, "--no-build-isolation", "--ignore-requires-python", str(ROOT)],
                     CAPS["install"], ["install"], env=_env(self.site), cwd=self.work)
        # The installed copy, not the checkout, and without Blender: what training needs. It prints
        # the installed trainer's source fingerprint, which finds the CPU runs of the same code.
        res = self.command("imports", [PY, "-c", "import sys, smokeseer.api, smokeseer.cli, smokeseer.raster, "
                                                 "eval.shared_stage2; from eval.harness import TRAINER_ENTRY; "
                                                 "from eval.sources import sources_sha256; "
                                                 "assert not {'bpy', 'pycolmap'} & set(sys.modules), "
                                                 "'bpy or pycolmap imported'; "
                                                 "print('sources_sha256', sources_sha256(TRAINER_ENTRY))"],
                           30, ["install-project"], env=_env(self.site), cwd=self.work)
        if res.status == OK:
            for line in Path(res.log).read_text().splitlines():
                if line.startswith("sources_sha256 "):
                    self.node["trainer_sources_sha256"] = line.split()[1]

    def build(self) -> None:
        """gsplat's CUDA extension: the folder's prebuilt wheel where it was built for this node
        (benchmarks.gpu_check.prebuilt), else compiled here from the source archive. With a
        prebuilt wheel the archive is compiled as well, beside the steps that follow at the lowest
        CPU priority, so the report still has this node's compile time."""
        n = self.node
        jobs = int(n.get("compile_jobs", 4))
        archive = next(iter(sorted(self.wheels.glob("gsplat-*.tar.gz"))), None)
        try:
            record = read_record(self.wheels)
            why = "the folder has no prebuilt wheel" if record is None else "; ".join(mismatches(record, n))
        except ValueError as exc:
            record, why = None, str(exc)
        needs = ["gpu", "install-project"]
        marker = self.work / "gsplat-build.json"
        if any(self.gsplat_site.glob("gsplat/csrc*.so")) and marker.is_file():
            earlier = json.loads(marker.read_text())
            self.record(StepResult("build", OK, reason=f"installed by an earlier check ({earlier['how']}), kept in "
                                                       f"{self.gsplat_site}", detail=earlier))
        elif record is not None and not why:
            res = blocked("build", needs, self.done) or run_command(
                "build", [*self._pip_install(self.gsplat_site), str(self.wheels / record.wheel)], self.log("build"),
                self.budget.timeout_for(60, REPORT_RESERVE_S), env=_env(self.site))
            res.detail.update({"how": "prebuilt wheel", "prebuilt": record.to_dict()})
            if res.status == OK:
                res.reason = (f"prebuilt {record.wheel}: compiled in {record.seconds:.0f} s with {record.jobs} jobs on "
                              f"{record.cpus} CPUs for arch {record.arch_list}, nvcc {record.nvcc}")
                marker.write_text(json.dumps(res.detail) + "\n")
            self.record(res)
            if res.status == OK and archive is not None:
                shutil.rmtree(self.work / "gsplat-from-source", ignore_errors=True)
                self.background["build-from-source"] = start_command(
                    "build-from-source", self._source_build(archive, self.work / "gsplat-from-source"),
                    self.log("build-from-source"), self.budget.left() - REPORT_RESERVE_S,
                    env=self._build_env(max(jobs - 2, 1)), nice=19)
        else:
            res = blocked("build", needs, self.done) or run_command(
                "build", self._source_build(archive, self.gsplat_site), self.log("build"),
                self.budget.timeout_for(CAPS["build"], 300 + REPORT_RESERVE_S), env=self._build_env(jobs))
            res.detail.update({"how": f"compiled from {archive.name if archive else 'no archive'}",
                               "prebuilt_not_used": why, "max_jobs": jobs})
            if res.status == OK:
                res.reason = f"compiled here with {jobs} jobs ({why})"
                marker.write_text(json.dumps(res.detail) + "\n")
            self.record(res)
        self.command("gsplat-import", [PY, "-c", "from gsplat.cuda._backend import _C; assert _C is not None, "
                                                 "'gsplat has no CUDA extension'"],
                     60, ["build"], env=_env(self.gsplat_site, self.site), cwd=self.work)

    def log(self, name: str) -> Path:
        return self.logs / f"{name}.log"

    def _pip_install(self, target: Path) -> list[str]:
        return [PY, "-m", "pip", "install", "--quiet", "--no-compile", "--no-index", "--no-deps", "--upgrade",
                "--target", str(target)]

    def _source_build(self, archive: Path | None, target: Path) -> list[str]:
        # Built with the setuptools just installed (a build-isolated one would need the image's
        # packages too), for the node's architecture alone.
        return [*self._pip_install(target), "--no-build-isolation", str(archive)]

    def _build_env(self, jobs: int) -> dict[str, str]:
        return _env(self.site, MAX_JOBS=str(jobs), TORCH_CUDA_ARCH_LIST=str(self.node.get("arch_list")))

    def start_parity(self) -> None:
        """The parity tests, started beside the standard run (their CPU reference compiles the
        CPU rasterizer first, on its own core)."""
        argv = [PY, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider", "tests/test_raster_gsplat.py",
                f"--junitxml={self.out / 'parity.xml'}", "-o", "junit_logging=system-out"]
        self.background["parity"] = blocked("parity", ["gsplat-import"], self.done) or start_command(
            "parity", argv, self.log("parity"), self.budget.timeout_for(CAPS["parity"], REPORT_RESERVE_S),
            env=_env(ROOT, self.gsplat_site, self.site), cwd=ROOT)

    def finish(self, name: str, stop_at_s: float | None = None) -> StepResult | None:
        """Wait for a background step and record it (None when it was never started)."""
        started = self.background.pop(name, None)
        if started is None:
            return None
        res = started if isinstance(started, StepResult) else started.wait(stop_at_s)
        if name == "parity":
            junit = self.out / "parity.xml"
            if junit.is_file():
                res.detail["tests"] = parity_detail(junit)
                skipped = [k for k, v in res.detail["tests"].items() if v["outcome"].startswith("skipped")]
                if res.status == OK and skipped:
                    res.status, res.reason = FAILED, f"skipped on this node: {', '.join(skipped)}"
            if isinstance(started, Running):
                res.reason = (res.reason + "; " if res.reason else "") + "ran beside the start of standard-gsplat"
        return self.record(res)

    def train(self, name: str, args: list[str], cap_s: float, needs: list[str], with_gsplat: bool,
              reserve_s: float = 0.0) -> StepResult:
        run = self.runs / name
        self.runs.mkdir(parents=True, exist_ok=True)
        # The installed trainer first; the checkout after it only for benchmarks/, which is not installed.
        paths = (self.gsplat_site, self.site, ROOT) if with_gsplat else (self.site, ROOT)
        argv = [PY, "-m", "benchmarks.gpu_check.train_run", str(self.runs / f"{name}.memory.json"), "--",
                str(self.dataset), "--out", str(run), "--device", "cuda", "--no-progress", *args]
        return self.command(name, argv, cap_s, needs, reserve_s=reserve_s, env=_env(*paths), cwd=self.work)

    def trainings(self) -> None:
        short = CAPS["stage3-torch"] + CAPS["paper-gsplat"]
        self.start_parity()
        self.train("standard-gsplat", ["--profile", "standard"], self.budget.left(), ["gsplat-import"], True,
                   reserve_s=short)
        self.finish("parity")
        donor = self.runs / "standard-gsplat"
        torch_run = self.runs / "stage3-torch"
        if (donor / "checkpoints" / "stage2.pt").is_file():
            self.command("take-stage2", [PY, "-m", "benchmarks.gpu_check.take_stage2", str(torch_run), str(donor),
                                         "full", "standard", "0", "device=cuda",
                                         f"stage3.iterations={self.torch_iterations}"],
                         30, [], env=_env(self.site, ROOT), cwd=self.work)
        else:
            self.record(StepResult("take-stage2", SKIPPED, reason="the gsplat run did not finish Stage 2"))
        self.train("stage3-torch", ["--profile", "standard", "--iterations-stage3", str(self.torch_iterations)],
                   CAPS["stage3-torch"], ["take-stage2"], False)
        self.train("paper-gsplat", ["--profile", "paper", "--iterations-stage2", str(self.paper_iterations),
                                    "--iterations-stage3", str(self.paper_iterations)],
                   CAPS["paper-gsplat"], ["gsplat-import"], True)

    def results(self) -> dict[str, Any]:
        runs = {name: run_figures(self.runs / name, self.runs / f"{name}.memory.json")
                for name in ("standard-gsplat", "stage3-torch", "paper-gsplat") if (self.runs / name).is_dir()}
        if "stage3-torch" in runs:  # its Stage-2 rows are the gsplat run's, taken with the checkpoint
            runs["stage3-torch"].get("iterations_per_s", {}).pop("2", None)
            runs["stage3-torch"]["stage2_from"] = "standard-gsplat"
        out: dict[str, Any] = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                               "commit": _commit(), "budget_s": self.budget.total_s,
                               "elapsed_s": self.budget.total_s - self.budget.left(), "node": self.node,
                               "wheels": str(self.wheels), "dataset": str(self.dataset),
                               "steps": [s.to_dict() for s in self.done.values()], "runs": runs, "notes": []}
        beside = [f"{name} ({self.done[name].seconds:.0f} s{', lowest CPU priority' if name == 'build-from-source' else ''})"
                  for name in ("parity", "build-from-source") if name in self.done and self.done[name].seconds > 0]
        if beside:
            out["notes"].append("standard-gsplat started together with " + " and ".join(beside)
                                + ", so its first iterations shared the node's CPUs with them.")
        scene = self.dataset.name
        try:
            ref = cpu_reference(ROOT / "data" / "tables_standard" / "runs" / scene / "full", "standard",
                                prefer=(runs.get("standard-gsplat", {}).get("source_digest", ""),
                                        self.node.get("trainer_sources_sha256", "")))
        except (ValueError, OSError) as exc:
            out["notes"].append(f"No CPU reference: {exc}")
            return out
        out["reference"] = ref.to_dict()
        gsplat_run = runs.get("standard-gsplat", {})
        if "psnr" in gsplat_run:
            out["psnr_verdict"] = psnr_verdict(gsplat_run["psnr"], ref)
        n = self.torch_iterations
        cpu_log = Path(ref.runs_folder) / ref.seed0_run / "train_log.csv"
        compare = {"stage3_iterations": n, "note": "Stage-3 iterations/s over its first iterations, from the "
                                                   "same finished Stage 2 on the GPU"}
        for label, log in (("gsplat", self.runs / "standard-gsplat" / "train_log.csv"),
                           ("torch", self.runs / "stage3-torch" / "train_log.csv"), ("cpu_1_thread", cpu_log)):
            if log.is_file():
                compare[label] = stage_rates(log, last_iteration=n).get("3")
        out["stage3_speed"] = compare
        out["notes"].append("Stage 3, first {} iterations, iterations/s: gsplat {}, torch backend {}, one CPU "
                            "thread (committed seed-0 run) {}.".format(
                                n, *(f"{compare[k]:.2f}" if compare.get(k) else "—"
                                     for k in ("gsplat", "torch", "cpu_1_thread"))))
        return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="gpu_check", description=__doc__.splitlines()[0])
    p.add_argument("--wheels", type=Path, required=True, help="folder made by benchmarks.gpu_check.make_wheels")
    p.add_argument("--out", type=Path, required=True, help="folder for the report, logs, runs and build")
    p.add_argument("--budget", type=float, default=600.0, help="seconds for the whole check (default 600)")
    p.add_argument("--dataset", type=Path, default=ROOT / "data" / "standard" / "house")
    p.add_argument("--paper-iterations", type=int, default=300, help="paper-profile iterations per stage (300)")
    p.add_argument("--torch-iterations", type=int, default=200,
                   help="Stage-3 iterations of the torch-backend comparison (200)")
    args = p.parse_args(argv)
    for flag, path in (("--wheels", args.wheels), ("--dataset", args.dataset)):
        if not path.is_dir():
            print(f"gpu_check: error: {flag}: {path} is not a directory", file=sys.stderr)
            return 2
    check = Check(args.wheels, args.out, args.budget, args.dataset, args.paper_iterations, args.torch_iterations)
    # Training starts afresh (clean timings); the installed packages and gsplat's build are kept.
    for old in (check.runs, check.logs):
        shutil.rmtree(old, ignore_errors=True)
    (check.out / "parity.xml").unlink(missing_ok=True)
    check.probe()
    check.wheel_folder()
    check.install()
    check.build()
    check.trainings()
    check.finish("build-from-source", stop_at_s=check.budget.left() - REPORT_RESERVE_S)
    json_path, md_path = write_report(check.out, check.results(), ROOT)
    print(f"report: {json_path} and {md_path}")
    return 0 if all(s.status == OK for s in check.done.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
