"""The same runs under two float setups on one machine: this machine's default, and torch, oneDNN and
MKL held to AVX2 (``contracts.float_setup.HELD_TO``), so that a result which hangs on the CPU's
arithmetic shows up here, not only when a run moves to another machine.

    python -m benchmarks.float_setup --out data/float_setup [--scenes house,room] [--datasets data/standard]
        [--profile standard] [--seed 0] [--workers 2] [--default-from data/tables_standard]
        [--method full | --method CANDIDATE] [--csv benchmarks/results/float_setup/per_scene.csv]

Each setup is one ``regenerate-tables`` call (Full at one seed, no ablations) in a process started
with that setup's environment, into OUT/<setup> (the default side may reuse a tables folder that
already holds those runs: ``--default-from``); both are resumable. ``--method`` compares a rule
candidate of ``eval/runs.py`` in place of Full (trained beside Full; where the harness took Full's
run for it, ``eval/twins.py``, Full's run is its run on that side, and the row says so). The CSV
has one row per scene: ``scene, default_psnr, avx2_psnr``, the difference, both validation PSNRs,
the trainer version and the float-setup line each side recorded, the method, and the sides on
which Full's run stood for it (a scene trained under two trainer versions on both sides has a row
for each). It refuses to compare when the two sides report the same torch capability (an
AVX2 machine has nothing to compare) or trained different trainer versions.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from benchmarks import full_seed_runs
from contracts.float_setup import HELD_TO, ISA_VARIABLES
from eval.finished_runs import runs_by_version
from eval.runs import CANDIDATES
from eval.twins import stood_for

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CSV = Path("benchmarks/results/float_setup/per_scene.csv")


def setup_environment(setup: str, base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (this process's environment) with every ISA variable removed, then ``setup``'s set."""
    env = {k: v for k, v in (os.environ if base is None else base).items() if k not in ISA_VARIABLES}
    env.update(HELD_TO[setup])
    return env


def tables_command(scenes: list[str], datasets: Path, profile: str, seed: int, workers: int,
                   out: Path, method: str = "full") -> list[str]:
    """The ``regenerate-tables`` call that trains Full (and ``method`` where it is a candidate) on
    ``scenes`` at ``seed`` into ``out``."""
    return full_seed_runs.tables_command({s: datasets / s for s in scenes}, profile, seed, workers, out,
                                         () if method == "full" else (method,))


Side = dict[str, dict[str, tuple[Path, dict[str, Any], bool]]]
"""{scene: {trainer digest: (run folder, harness record, whether it is Full's run standing in)}}."""


def side(tables: Path, seed: int, scenes: list[str], method: str = "full") -> Side:
    """The finished runs of ``method`` at ``seed`` on one side: its own, else Full's run where the
    harness's rule lets Full's run stand for it (``eval.twins.stood_for``)."""
    runs: Side = {}
    for (scene, digest), variants in runs_by_version(tables, {"full", method}, seed).items():
        if scene not in scenes:
            continue
        if method in variants:
            runs.setdefault(scene, {})[digest] = (*variants[method], False)
        elif stood_for([method], variants):
            runs.setdefault(scene, {})[digest] = (*variants["full"], True)
    return runs


def compare(default_tables: Path, avx2_tables: Path, seed: int, scenes: list[str],
            method: str = "full") -> list[dict[str, Any]]:
    """One row per scene and trainer version that finished on both sides (a scene's two runs are
    compared only under one trainer); raises ValueError when the sides are not comparable."""
    default, avx2 = side(default_tables, seed, scenes, method), side(avx2_tables, seed, scenes, method)
    rows = []
    for scene in scenes:
        if scene not in default or scene not in avx2:
            continue
        common = sorted(set(default[scene]) & set(avx2[scene]))
        if not common:
            raise ValueError(f"{scene}: {default_tables} holds trainer {', '.join(d[:8] for d in default[scene])} and "
                             f"{avx2_tables} trainer {', '.join(d[:8] for d in avx2[scene])}: train both sides with "
                             "the same code")
        rows += [_row(scene, method, default[scene][digest], avx2[scene][digest]) for digest in common]
    return rows


def _row(scene: str, method: str, default: tuple[Path, dict[str, Any], bool],
         avx2: tuple[Path, dict[str, Any], bool]) -> dict[str, Any]:
    """The CSV row of one scene's two runs under one trainer."""
    (d_run, d_rec, d_full), (a_run, a_rec, a_full) = default, avx2
    if _capability(d_rec["float_setup"]) == _capability(a_rec["float_setup"]):
        raise ValueError(f"{scene}: both sides trained with torch's {_capability(d_rec['float_setup'])} kernels "
                         "(on an AVX2 machine the default is AVX2: there is nothing to compare)")
    dp, ap = float(d_rec["metrics"]["psnr"]), float(a_rec["metrics"]["psnr"])
    return {"scene": scene, "default_psnr": round(dp, 4), "avx2_psnr": round(ap, 4),
            "avx2_minus_default": round(ap - dp, 4), "default_val_psnr": full_seed_runs.validation_psnr(d_run),
            "avx2_val_psnr": full_seed_runs.validation_psnr(a_run), "trainer": d_rec["code_digest"][:8],
            "default_float_setup": d_rec["float_setup"], "avx2_float_setup": a_rec["float_setup"],
            "method": method, "full_run_on": ",".join(n for n, f in (("default", d_full), ("avx2", a_full)) if f)}


def _capability(line: str) -> str:
    """torch's CPU capability from a float-setup line ("... torch 2.13.0+cpu AVX512; ...")."""
    part = next((p.strip() for p in line.split(";") if p.strip().startswith("torch ")), "")
    return part.split()[-1] if part else "unknown"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.float_setup", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="OUT/default and OUT/avx2 hold the runs")
    full_seed_runs.add_arguments(p, "house,forest,food_plate,excavator,rover,chair,plant,brick_toy,machine,room",
                                 None)
    p.add_argument("--default-from", type=Path, help="a tables folder that holds (or will hold) the default side")
    p.add_argument("--method", default="full", choices=["full", *CANDIDATES],
                   help="Full, or a rule candidate trained beside it (its CSV: per_scene-METHOD.csv unless --csv names one)")
    args = p.parse_args(argv)
    if args.csv is None:  # Full's CSV stays Full's
        args.csv = DEFAULT_CSV if args.method == "full" else DEFAULT_CSV.with_name(f"per_scene-{args.method}.csv")
    scenes = full_seed_runs.scenes_of(args, "float_setup")
    if scenes is None:
        return 2
    folders = {"default": args.default_from or args.out / "default", "avx2": args.out / "avx2"}
    if not args.compare_only:
        for setup, tables in folders.items():
            cmd = tables_command(scenes, args.datasets, args.profile, args.seed, args.workers, tables, args.method)
            print(f"== float setup {setup}: {' '.join(f'{k}={v}' for k, v in HELD_TO[setup].items())} "
                  f"{' '.join(cmd[1:])}", flush=True)
            done = subprocess.run(cmd, cwd=ROOT, env=setup_environment(setup))
            if done.returncode not in (0, 1):  # 1: tables written, some runs failed
                return done.returncode
    try:
        rows = compare(folders["default"], folders["avx2"], args.seed, scenes, args.method)
    except ValueError as exc:
        print(f"float_setup: error: {exc}", file=sys.stderr)
        return 2
    if not full_seed_runs.write_pairs("float_setup", args.csv, rows, ("default", "avx2"), "avx2_minus_default",
                                      f"no scene of {', '.join(scenes)} has finished on both sides"):
        return 2
    print(f"wrote {args.csv} ({len(rows)} of {len(scenes)} scenes finished on both sides)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
