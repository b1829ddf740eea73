"""The GPU check's CPU-side parts (benchmarks/gpu_check): the wheel folder's completeness check
against the real requirement list of pyproject.toml, the make_wheels tag sets against this
interpreter's own, the node probe's parsing, the step runner's timeouts and budget, the report
writer, the figures read from run folders, and the JUnit reading of the parity tests. The parts
that need CUDA (gsplat's build, tests/test_raster_gsplat.py, the training runs) are skipped here."""
from __future__ import annotations

import importlib.metadata as md
import json
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest
import torch
from packaging.requirements import Requirement
from packaging.tags import sys_tags
from packaging.utils import canonicalize_name

from benchmarks.gpu_check.make_wheels import interpreter_tags
from benchmarks.gpu_check.prebuilt import RECORD as PREBUILT_RECORD
from benchmarks.gpu_check.prebuilt import PrebuiltRecord, mismatches, read_record
from benchmarks.gpu_check.reference import cpu_reference, last_iterations, psnr_verdict, stage_rates
from benchmarks.gpu_check.report import markdown, write_report
from benchmarks.gpu_check.run import parity_detail
from benchmarks.gpu_check.steps import (FAILED, OK, SKIPPED, TIMEOUT, Budget, Running, StepResult, blocked, run_command,
                                        start_command)
from benchmarks.gpu_check.target import arch_list, cpu_jobs, nvcc_version
from benchmarks.gpu_check.wheels import (FOLDER_LIMIT_BYTES, IMAGE_PACKAGES, IMAGE_PROVIDES, check_folder, excluded,
                                         folder_requirements, project_requirements)

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = ROOT / "pyproject.toml"
PY311 = [t for t in sys_tags()] if sys.version_info[:2] == (3, 11) else []


def _lowest(req: Requirement) -> str:
    """A version the requirement accepts: its lower bound, or 1.0."""
    for spec in req.specifier:
        if spec.operator in (">=", "==", "~="):
            return spec.version
    return "1.0"


def _wheel(folder: Path, name: str, version: str, tag: str = "py3-none-any", requires: tuple[str, ...] = ()) -> Path:
    """A real (tiny) wheel file: its name, and a METADATA with ``requires`` as Requires-Dist."""
    dist = canonicalize_name(name).replace("-", "_")
    path = folder / f"{dist}-{version}-{tag}.whl"
    meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n" + "".join(
        f"Requires-Dist: {r}\n" for r in requires)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(f"{dist}-{version}.dist-info/METADATA", meta)
    return path


def complete_folder(folder: Path) -> Path:
    """One wheel per requirement of the real list (dask with its distributed extra), and gsplat's archive."""
    folder.mkdir()
    for req in folder_requirements(PYPROJECT):
        needs = ('distributed; extra == "distributed"',) if req.name == "dask" else ()
        _wheel(folder, req.name, _lowest(req), requires=needs)
    _wheel(folder, "distributed", "2024.1")
    (folder / "gsplat-1.5.3.tar.gz").write_bytes(b"")
    return folder


def test_the_folder_requirements_are_pyprojects_less_the_image_and_blender() -> None:
    names = {canonicalize_name(r.name) for r in folder_requirements(PYPROJECT)}
    declared = {canonicalize_name(r.name) for r in project_requirements(PYPROJECT)}
    assert {"bpy", "torch", "numpy", "scipy", "matplotlib", "miepython", "pycolmap"} <= declared
    assert not names & excluded()
    assert declared - excluded() <= names
    assert {"jaxtyping", "rich", "setuptools", "pytest", "scikit-image", "openexr"} <= names


def test_a_complete_folder_passes_and_each_gap_is_named(tmp_path: Path) -> None:
    folder = complete_folder(tmp_path / "w")
    assert check_folder(folder, PYPROJECT, "3.12").problems == []

    (folder / "trimesh-4.0-py3-none-any.whl").unlink()
    (folder / "gsplat-1.5.3.tar.gz").unlink()
    _wheel(folder, "numpy", "1.26.4", "cp312-cp312-manylinux_2_17_x86_64")
    (folder / "notes.txt").write_text("x")
    problems = check_folder(folder, PYPROJECT, "3.12").problems
    assert any("no wheel for trimesh>=4.0" in p for p in problems), problems
    assert any("no source archive of gsplat==1.5.3" in p for p in problems), problems
    assert any("numpy" in p and "left out" in p for p in problems), problems
    assert any(p.endswith("notes.txt: not a wheel or source archive") for p in problems), problems


def test_versions_tags_and_size_are_checked(tmp_path: Path) -> None:
    folder = complete_folder(tmp_path / "w")
    (folder / "colour_science-0.4.4-py3-none-any.whl").unlink()
    _wheel(folder, "colour-science", "0.4.7")
    (folder / "pyyaml-6.0-py3-none-any.whl").unlink()
    _wheel(folder, "pyyaml", "6.0.2", "cp310-cp310-manylinux_2_17_x86_64")
    problems = check_folder(folder, PYPROJECT, "3.12", interpreter_tags("3.12", 28)).problems
    assert any("colour-science<0.4.7,>=0.4.4 wanted, found colour_science-0.4.7" in p for p in problems), problems
    assert any("no wheel of pyyaml>=6.0 for this Python and platform" in p for p in problems), problems
    big = tmp_path / "big"
    complete_folder(big)
    with open(big / "trimesh-4.0-py3-none-any.whl", "r+b") as f:  # sparse: its size counts, no disk is used
        f.truncate(FOLDER_LIMIT_BYTES)
    assert any("over the 60 MB limit" in p for p in check_folder(big, PYPROJECT, "3.12").problems)


def test_the_closure_follows_requirements_markers_and_extras(tmp_path: Path) -> None:
    folder = complete_folder(tmp_path / "w")
    (folder / "rich-12-py3-none-any.whl").unlink()
    _wheel(folder, "rich", "12", requires=("markdown-it-py>=2.2", 'tomli>=2; python_version < "3.11"', "numpy"))
    problems = check_folder(folder, PYPROJECT, "3.12").problems
    assert problems == ["markdown-it-py>=2.2 (wanted by rich 12): not in the folder"], problems
    problems = check_folder(folder, PYPROJECT, "3.10").problems
    assert any(p.startswith('tomli>=2; python_version < "3.11" (wanted by rich 12)') for p in problems), problems
    (folder / "distributed-2024.1-py3-none-any.whl").unlink()
    problems = check_folder(folder, PYPROJECT, "3.12").problems
    assert any(p.startswith('distributed; extra == "distributed" (wanted by dask') for p in problems), problems
    (folder / "tqdm-4.66-py3-none-any.whl").write_bytes(b"not a zip")
    problems = check_folder(folder, PYPROJECT, "3.12").problems
    assert any("tqdm-4.66-py3-none-any.whl: unreadable wheel" in p for p in problems), problems


def test_what_the_image_provides_is_required_by_what_it_has() -> None:
    """IMAGE_PROVIDES is left out because torch, numpy, scipy or matplotlib require it: check that
    against their installed metadata."""
    closure, todo = set(), list(IMAGE_PACKAGES)
    while todo:
        name = canonicalize_name(todo.pop())
        if name in closure:
            continue
        closure.add(name)
        for line in md.distribution(name).requires or []:
            req = Requirement(line)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(req.name)
    assert {canonicalize_name(n) for n in IMAGE_PROVIDES} <= closure


@pytest.mark.skipif(not PY311 or sys.platform != "linux", reason="compares with a Linux CPython 3.11's own tags")
def test_make_wheels_tags_are_this_interpreters_own() -> None:
    """pip's tags for this very interpreter, restricted to glibc 2.28, are the ones make_wheels
    asks for when told Python 3.11."""
    ours = set(interpreter_tags("3.11", 28))
    theirs = {t for t in PY311 if not t.platform.startswith("manylinux_2_") or int(t.platform.split("_")[2]) <= 28}
    theirs = {t for t in theirs if t.platform != "linux_x86_64"}  # only local builds carry it
    assert theirs <= ours, sorted(map(str, theirs - ours))[:5]
    assert not any(t.interpreter == "cp312" for t in ours)


def test_nvcc_arch_and_job_parsing() -> None:
    text = ("nvcc: NVIDIA (R) Cuda compiler driver\nCopyright (c) 2005-2025 NVIDIA Corporation\n"
            "Cuda compilation tools, release 13.0, V13.0.88\nBuild cuda_13.0.r13.0/compiler.36424714_0\n")
    assert nvcc_version(text) == "13.0"
    assert nvcc_version("command not found") is None
    assert arch_list([(9, 0)]) == "9.0"
    assert arch_list([(8, 6), (9, 0), (8, 6)]) == "8.6;9.0"
    with pytest.raises(ValueError, match="no CUDA device"):
        arch_list([])
    assert cpu_jobs(16, 128.0) == 16
    assert cpu_jobs(16, 20.0) == 8
    assert cpu_jobs(0, None) == 1


def test_a_step_that_overruns_is_stopped_with_its_children(tmp_path: Path) -> None:
    pid_file = tmp_path / "child.pid"
    start = time.monotonic()
    res = run_command("sleeper", ["sh", "-c", f"sleep 60 & echo $! > {pid_file}; wait"], tmp_path / "s.log", 1.0,
                      min_s=0.5)
    assert res.status == TIMEOUT and time.monotonic() - start < 8, res
    assert "its 1 s timeout" in res.reason
    child = int(pid_file.read_text())
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        pytest.fail("the step's child process outlived the timeout")


def test_failures_budget_and_dependencies(tmp_path: Path) -> None:
    res = run_command("fails", [sys.executable, "-c", "import sys; print('first'); sys.exit('bad input: x')"],
                      tmp_path / "f.log", 30)
    assert res.status == FAILED and res.reason == "exit status 1: bad input: x", res
    ok = run_command("ok", [sys.executable, "-c", "print('hi')"], tmp_path / "o.log", 30)
    assert ok.status == OK and "hi" in Path(ok.log).read_text()
    budget = Budget(100.0)
    assert budget.timeout_for(30.0) == 30.0
    assert 89.0 < budget.timeout_for(500.0, reserve_s=10.0) <= 90.0
    late = run_command("late", [sys.executable, "-c", "pass"], tmp_path / "l.log", Budget(3.0).timeout_for(60.0))
    assert late.status == SKIPPED and late.reason.startswith("time budget: 3 s left")
    done = {"a": StepResult("a", OK), "b": StepResult("b", TIMEOUT)}
    assert blocked("c", ["a"], done) is None
    assert blocked("c", ["a", "b"], done).reason == "needs step 'b', which ended timeout"
    assert blocked("c", ["z"], done).reason == "needs step 'z', which was not run"


def _results() -> dict:
    return {"date": "2026-11-28T12:00:00+00:00", "commit": "abc1234", "budget_s": 600.0, "elapsed_s": 512.3,
            "node": {"python": "3.12.3", "torch": "2.11.0+cu130", "torch_cuda": "13.0", "nvcc": "13.0", "cpus": 16,
                     "gpus": ["NVIDIA H100 80GB HBM3"], "capabilities": ["9.0"]},
            "steps": [StepResult("build", OK, 201.5).to_dict(),
                      StepResult("paper-gsplat", SKIPPED, reason="time budget: 0 s left for it").to_dict()],
            "runs": {"standard-gsplat": {"backend": "gsplat", "iterations_per_s": {"2": 41.234, "3": 17.5},
                                         "iterations_done": {"2": 3000, "3": 3000}, "peak_memory_bytes": 3 * 2**30,
                                         "psnr": 29.41}},
            "reference": {"runs_folder": "data/tables_standard/runs/house/full", "source_digest": "6663d970aaaa",
                          "seeds": [0, 1, 2], "seed0_psnr": 29.53, "spread_db": 0.54},
            "psnr_verdict": "GPU test PSNR 29.41 dB, -0.12 dB from the CPU seed-0 run: within the CPU seeds' span.",
            "notes": ["Stage 3, first 200 iterations, iterations/s: gsplat 17.50."]}


def test_the_report_is_written_as_json_and_markdown(tmp_path: Path) -> None:
    json_path, md_path = write_report(tmp_path / "report", _results())
    assert json.loads(json_path.read_text()) == _results()
    page = md_path.read_text()
    assert page == markdown(_results())
    assert "- GPU: NVIDIA H100 80GB HBM3 (compute capability 9.0)" in page
    assert "- Python 3.12.3, torch 2.11.0+cu130 (CUDA 13.0), nvcc 13.0, 16 CPUs" in page
    assert "| build | ok | 201.5 |  |" in page
    assert "| paper-gsplat | skipped | 0.0 | time budget: 0 s left for it |" in page
    assert "| standard-gsplat | gsplat | 41.23 | 17.50 | 3000 + 3000 | 3.00 | 29.41 |" in page
    assert "trainer 6663d970): seed 0 29.53 dB, seeds [0, 1, 2] span 0.54 dB." in page
    assert sorted(p.name for p in (tmp_path / "report").iterdir()) == ["gpu_check.json", "gpu_check.md"]
    results = {**_results(), "dataset": "/node/checkout/data/standard/house", "wheels": "/elsewhere/wheels"}
    written = json.loads(write_report(tmp_path / "rel", results, Path("/node/checkout"))[0].read_text())
    assert (written["dataset"], written["wheels"]) == ("data/standard/house", "/elsewhere/wheels")


def test_stage_rates_from_a_train_log(tmp_path: Path) -> None:
    log = tmp_path / "train_log.csv"
    rows = ["stage,iteration,wall_s,n_gaussians,n_smoke,loss,render_rgb,render_thermal,smoke_alpha,smoke_color,mono,"
            "depth,mask,thermal_smoke_opacity,val_psnr,test_psnr"]
    rows += [f"2,{i},{0.5 + (i - 10) / 40:.4f},5000,,0.1,,0.1,,,,,,,," for i in range(10, 101, 10)]
    rows += [f"3,{i},{10 + (i - 10) / 8:.4f},5000,100,0.1,0.1,0.1,,,,,,,," for i in range(10, 301, 10)]
    log.write_text("\n".join(rows) + "\n")
    rates = stage_rates(log)
    assert rates["2"] == pytest.approx(40.0) and rates["3"] == pytest.approx(8.0)
    assert stage_rates(log, last_iteration=100)["3"] == pytest.approx(8.0)
    assert last_iterations(log) == {"2": 100, "3": 300}


def test_the_committed_cpu_reference_of_house() -> None:
    ref = cpu_reference(ROOT / "data" / "tables_standard" / "runs" / "house" / "full", "standard")
    assert ref.seeds == [0, 1, 2] and ref.source_digest.startswith("6663d970")
    assert ref.seed0_run == "seed0-acb1b770748b"
    assert ref.seed0_psnr == pytest.approx(29.5336, abs=1e-3)
    assert ref.spread_db == pytest.approx(30.0235 - 29.4853, abs=1e-3)
    assert "within" in psnr_verdict(29.2, ref) and "outside" in psnr_verdict(28.9, ref)
    with pytest.raises(ValueError, match="no finished CPU run of seed 0 at profile paper"):
        cpu_reference(ROOT / "data" / "tables_standard" / "runs" / "house" / "full", "paper")
    # the GPU run's own trainer version is preferred where it has a seed-0 run
    house = ROOT / "data" / "tables_standard" / "runs" / "house" / "full"
    own = json.loads((house / "seed0-6cae0a53465b" / "metrics.json").read_text())["provenance"]["source_digest"]
    mine = cpu_reference(house, "standard", prefer=(own,))
    assert mine.source_digest == own and mine.seed0_run == "seed0-6cae0a53465b"
    assert mine.seed0_psnr == pytest.approx(32.2057, abs=1e-3)
    assert cpu_reference(house, "standard", prefer=("no such version",)).source_digest.startswith("6663d970")


def test_a_node_under_another_python_finds_its_own_trainer_version_by_the_source_fingerprint() -> None:
    """Under Python 3.12 the GPU run's source digest is not the CPU runs' (ast.dump differs), so
    the reference is found by the trainer's source fingerprint that harness.json records."""
    house = ROOT / "data" / "tables_standard" / "runs" / "house" / "full"
    harness = json.loads((house / "seed0-bf5f6efcd9d1" / "harness.json").read_text())
    ref = cpu_reference(house, "standard", prefer=("a 3.12 digest", harness["sources_sha256"]))
    assert ref.source_digest.startswith("d65d2bcb") and ref.seeds == [0, 1, 2]
    assert ref.seed0_run == "seed0-bf5f6efcd9d1" and ref.seed0_psnr == pytest.approx(32.2057, abs=1e-3)


def test_the_torch_backend_comparison_takes_both_stage2s_of_the_gsplat_run(tmp_path: Path) -> None:
    """take_stage2 gives the torch-backend run the donor's thermal and RGB Stage 2, so it trains
    neither (an RGB Stage 2 on the torch backend outlasts the step's timeout)."""
    from eval.shared_stage2 import rgb_stage2_sha_of, stage2_sha_of

    donor_settings = {"device": "cuda"}
    thermal = stage2_sha_of("full", "standard", 0, donor_settings)
    rgb = rgb_stage2_sha_of("standard", 0, donor_settings)
    donor, run = tmp_path / "donor", tmp_path / "run"
    (donor / "checkpoints").mkdir(parents=True)
    torch.save({"done": True, "config_sha256": thermal}, donor / "checkpoints" / "stage2.pt")
    torch.save({"done": True, "config_sha256": rgb}, donor / "checkpoints" / "stage2_rgb.pt")
    (donor / "train_log.csv").write_text("stage,iteration,wall_s\n2,10,1.0\n")  # one Stage-2 row to hand over
    res = subprocess.run([sys.executable, "-m", "benchmarks.gpu_check.take_stage2", str(run), str(donor), "full",
                          "standard", "0", "device=cuda", "stage3.iterations=200"], cwd=ROOT, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr
    for name in ("stage2.pt", "stage2_rgb.pt"):
        assert (run / "checkpoints" / name).read_bytes() == (donor / "checkpoints" / name).read_bytes()


def test_parity_outcomes_and_printed_errors_come_from_junit(tmp_path: Path) -> None:
    (tmp_path / "test_x.py").write_text(
        "import pytest\n"
        "def test_prints():\n    print('alpha: max |difference| 1e-06')\n"
        "def test_fails():\n    assert 1 == 2, 'means'\n"
        "@pytest.mark.skipif(True, reason='needs CUDA and gsplat')\ndef test_skips():\n    pass\n")
    junit = tmp_path / "out.xml"
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path / "test_x.py"),
                    f"--junitxml={junit}", "-o", "junit_logging=system-out"], cwd=tmp_path, capture_output=True)
    tests = parity_detail(junit)
    assert tests["test_prints"] == {"outcome": "passed", "printed": "alpha: max |difference| 1e-06"}
    assert tests["test_fails"]["outcome"].startswith("failure: AssertionError: means")
    assert tests["test_skips"]["outcome"] == "skipped: needs CUDA and gsplat"


def test_train_run_records_its_backend_even_when_training_refuses(tmp_path: Path) -> None:
    memory = tmp_path / "m.json"
    res = subprocess.run([sys.executable, "-m", "benchmarks.gpu_check.train_run", str(memory), "--",
                          str(tmp_path / "missing"), "--out", str(tmp_path / "run")],
                         cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 2 and "train-and-evaluate: error:" in res.stderr
    record = json.loads(memory.read_text())
    assert record["completed"] is False
    if not torch.cuda.is_available():
        assert record["backend"] == "torch" and record["peak_memory_bytes"] is None


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU: the probe's GPU fields")
def test_the_probe_sees_the_gpu() -> None:
    res = subprocess.run([sys.executable, "-m", "benchmarks.gpu_check.target"], cwd=ROOT, capture_output=True,
                         text=True, check=True)
    node = json.loads(res.stdout)
    assert node["cuda_available"] and node["gpus"] and node["arch_list"]


def _prebuilt(folder: Path, **fields: object) -> PrebuiltRecord:
    record = PrebuiltRecord(**{"wheel": "gsplat-1.5.3-cp312-cp312-linux_x86_64.whl", "python": "3.12",
                               "torch": "2.11.0+cu130", "torch_cuda": "13.0", "arch_list": "9.0", "nvcc": "13.0",
                               "seconds": 900.0, "jobs": 2, "cpus": 2, **fields})
    (folder / record.wheel).write_bytes(b"")
    (folder / PREBUILT_RECORD).write_text(json.dumps(record.to_dict()))
    return record


def test_a_prebuilt_gsplat_is_used_only_on_the_node_it_was_built_for(tmp_path: Path) -> None:
    folder = complete_folder(tmp_path / "w")
    assert read_record(folder) is None
    record = _prebuilt(folder)
    assert check_folder(folder, PYPROJECT, "3.12").problems == [], "the wheel and its record belong in the folder"
    assert read_record(folder) == record
    node = {"python": "3.12.3", "torch": "2.11.0+cu130", "torch_cuda": "13.0", "arch_list": "9.0"}
    assert mismatches(record, node) == []
    assert mismatches(record, {**node, "arch_list": "8.0;9.0", "torch": "2.11.0+cu128"}) == [
        "torch: built for 2.11.0+cu130, the node has 2.11.0+cu128",
        "arch_list: built for 9.0, the node has 8.0;9.0"]
    assert mismatches(record, {**node, "python": "3.11.9"}) == ["python: built for 3.12, the node has 3.11"]
    (folder / record.wheel).unlink()
    with pytest.raises(ValueError, match=r"gsplat-prebuilt.json: wheel: gsplat-1.5.3-cp312.*is not in"):
        read_record(folder)
    (folder / PREBUILT_RECORD).write_text(json.dumps({"wheel": record.wheel}))
    with pytest.raises(ValueError, match=r"gsplat-prebuilt.json: field 'python' is missing"):
        read_record(folder)


def test_a_background_step_runs_beside_others_and_stops_with_the_budget(tmp_path: Path) -> None:
    quick = start_command("quick", [sys.executable, "-c", "print('done')"], tmp_path / "q.log", 30)
    slow = start_command("slow", ["sleep", "30"], tmp_path / "s.log", 30, nice=19)
    assert isinstance(quick, Running) and isinstance(slow, Running)
    time.sleep(1.0)
    done = quick.wait()
    assert done.status == OK and done.seconds < 0.9, "the time it ran, not the time until it was waited for"
    start = time.monotonic()
    res = slow.wait(stop_at_s=0.5)
    assert res.status == TIMEOUT and "end of the check's time budget" in res.reason, res
    assert time.monotonic() - start < 8
    assert start_command("late", ["true"], tmp_path / "l.log", 1.0).status == SKIPPED


def test_prebuild_refuses_in_one_line_without_an_archive_or_cuda(tmp_path: Path) -> None:
    def prebuild(folder: Path) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "benchmarks.gpu_check.prebuild_gsplat", "--wheels", str(folder),
                               "--arch", "9.0"], capture_output=True, text=True, cwd=ROOT)

    res = prebuild(tmp_path / "none")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "holds no source archive of gsplat==1.5.3" in res.stderr
    folder = complete_folder(tmp_path / "w")
    res = prebuild(folder)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    if torch.version.cuda is None:
        assert f"torch {torch.__version__} is a CPU build" in res.stderr
    assert not (folder / PREBUILT_RECORD).exists()


def test_a_folder_named_gsplat_is_not_gsplat(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The check once ran the torch-backend comparison from a folder holding ``gsplat/`` (the
    install target): Python imported it as an empty namespace package and the trainer took it
    for gsplat."""
    from smokeseer.raster import gsplat_available

    (tmp_path / "gsplat").mkdir()
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in sys.modules if m == "gsplat" or m.startswith("gsplat.")]:
        monkeypatch.delitem(sys.modules, name)
    assert not gsplat_available()
