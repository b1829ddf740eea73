"""What the smoke's motion costs per Stage-3 iteration: the deformation MLP of the standard
profile against the plane field (``deform.kind=planes``), forward + backward, in one process.

    python benchmarks/deformation_cost.py [--sizes 4000,10000,20000] [--repeats 7] [--set deform.planes_levels=1]

One Stage-3 iteration's work on N smoke Gaussians: the offsets at the RGB frame's time and at the
thermal frame's (two evaluations; with ``deform.shared_position`` one ``encode`` and two
``decode``), a loss on all offsets (position, rotation, log-scale), its backward. The sides:

- ``mlp``: the standard profile's MLP evaluated twice (the reference of every ratio);
- ``mlp shared``: the same with the time-independent part shared (``deform.shared_position``);
- ``planes``: the plane field with the standard profile plus ``--set`` (shared, compiled lookups);
- ``planes grid_sample``: the same field with torch's ``grid_sample`` in place of the kernel.

The sides run alternately, ``--inner`` iterations per timing, best of ``--repeats``, after a
warm-up, on ``--threads`` threads (1: one standard run per core), with the 1-minute load average
recorded before and after each size. Also timed, apart: one Adam step over each side's parameters
(the planes hold more numbers than the network). Prints per-Gaussian costs and ratios against
``mlp``; writes ``benchmarks/results/deformation_cost.csv``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from contracts.atomic import write_dataclass_csv  # noqa: E402
from contracts.provenance import code_version  # noqa: E402
from contracts.set_items import parse_set_items  # noqa: E402
from smokeseer.config import DeformConfig, make_config  # noqa: E402
from smokeseer.model import planes as planes_module  # noqa: E402
from smokeseer.model.deform import DeformNetwork  # noqa: E402
from smokeseer.model.optim import Adam  # noqa: E402
from smokeseer.model.planes import PlaneField, plane_product_reference  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
TIMES = (0.31, 0.33)
"""The RGB and the thermal frame's times of the iteration (any two differ alike)."""
HALF = 1.0
"""Smoke positions uniform in [-HALF, HALF]³; the MLP's scene extent and the planes' domain follow."""


@dataclass
class Row:
    n: int
    side: str
    ms_fwd_bwd: float
    ns_per_gaussian: float
    ratio_vs_mlp: float
    ms_adam: float
    parameters: int
    settings: str
    threads: int
    load_1min_before: float
    load_1min_after: float
    seed: int
    torch: str
    commit: str


@dataclass
class Side:
    name: str
    field: torch.nn.Module
    shared: bool
    lookups: Callable[..., Any] | None = None
    """Stands in for the plane field's lookups while this side runs (``grid_sample``)."""


def make_sides(overrides: dict[str, Any], device: torch.device) -> list[Side]:
    """The four sides, each field with a non-zero head (as after training) and seeded weights."""
    standard = make_config("full", "standard", 0).deform
    planes_cfg: DeformConfig = make_config("full", "standard", 0, {"deform.kind": "planes", **overrides}).deform
    torch.manual_seed(0)
    mlp = DeformNetwork(standard, 2 * HALF, device)
    lo, hi = torch.full((3,), -1.1 * HALF), torch.full((3,), 1.1 * HALF)
    field = PlaneField(planes_cfg, lo, hi, 2 * HALF, device)
    for f in (mlp, field):
        torch.nn.init.normal_(f.head.weight, std=1e-2)
    settings = " ".join(f"{k}={v}" for k, v in overrides.items())
    return [Side("mlp", mlp, False), Side("mlp shared", mlp, True),
            Side(f"planes {settings}".strip(), field, planes_cfg.shared_position),
            Side(f"planes grid_sample {settings}".strip(), field, planes_cfg.shared_position,
                 plane_product_reference)]


def iteration(side: Side, means: torch.Tensor, weights: torch.Tensor) -> None:
    """One iteration's deformation work: both times, the loss on every offset, backward."""
    field, center = side.field, torch.zeros(3)
    enc = field.encode(means, center) if side.shared else None
    loss = 0.0
    for t in TIMES:
        out = field.decode(enc, t) if side.shared else field(means, t, center)
        loss = loss + (torch.cat([o for o in out if o is not None], dim=1) * weights).sum()
    loss.backward()
    field.zero_grad(set_to_none=True)


def time_sides(sides: list[Side], n: int, repeats: int, inner: int) -> dict[str, float]:
    """Best seconds per iteration of each side, the sides alternating within every repeat."""
    g = torch.Generator().manual_seed(n)
    means = (torch.rand(n, 3, generator=g) * 2 - 1) * HALF
    weights = torch.randn(n, 10, generator=g)
    best = {s.name: float("inf") for s in sides}
    for rep in range(repeats + 1):  # the first round warms up (allocations, kernel load)
        for side in sides:
            patch = mock.patch.object(planes_module, "plane_product", side.lookups) if side.lookups else nullcontext()
            with patch:
                start = time.perf_counter()
                for _ in range(inner):
                    iteration(side, means, weights)
                elapsed = (time.perf_counter() - start) / inner
            if rep > 0:
                best[side.name] = min(best[side.name], elapsed)
    return best


def adam_seconds(field: torch.nn.Module, repeats: int) -> float:
    """Best seconds of one Adam step over the field's parameters (every one with a gradient)."""
    groups = field.parameter_groups(1e-4) if isinstance(field, PlaneField) else field.parameters()
    opt = Adam(groups, lr=1e-4)
    saved = [p.detach().clone() for p in field.parameters()]
    for p in field.parameters():
        p.grad = torch.randn_like(p) * 1e-3
    best = float("inf")
    for _ in range(repeats + 1):
        start = time.perf_counter()
        opt.step()
        best = min(best, time.perf_counter() - start)
    with torch.no_grad():
        for p, s in zip(field.parameters(), saved):
            p.copy_(s)
            p.grad = None
    return best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="4000,10000,20000", help="smoke Gaussian counts, comma-separated")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--inner", type=int, default=3, help="iterations per timing")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="a deform.* setting of the plane field (standard profile otherwise)")
    p.add_argument("--out", type=Path, default=RESULTS / "deformation_cost.csv")
    args = p.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",")]
        overrides = parse_set_items(args.sets)
        if any(not k.startswith("deform.") for k in overrides):
            raise ValueError("--set: only deform.* settings")
        if not (all(0 < n <= 1_000_000 for n in sizes) and 1 <= args.repeats <= 100 and 1 <= args.inner <= 100):
            raise ValueError("--sizes 1..1e6 each, --repeats and --inner 1..100")
        sides = make_sides(overrides, torch.device("cpu"))
    except ValueError as exc:
        print(f"deformation_cost: error: {exc}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    commit = str(code_version()["commit"] or code_version()["version"])[:12]
    adam = {s.name: adam_seconds(s.field, args.repeats) for s in sides}
    rows: list[Row] = []
    print(f"threads {args.threads}, best of {args.repeats} × {args.inner} iterations, sides alternating; "
          f"commit {commit}, torch {torch.__version__}")
    for n in sizes:
        before = os.getloadavg()[0]
        best = time_sides(sides, n, args.repeats, args.inner)
        after = os.getloadavg()[0]
        for s in sides:
            rows.append(Row(n, s.name, round(best[s.name] * 1e3, 3), round(best[s.name] * 1e9 / n, 1),
                            round(best["mlp"] / best[s.name], 2), round(adam[s.name] * 1e3, 3),
                            sum(q.numel() for q in s.field.parameters()), " ".join(args.sets), args.threads,
                            round(before, 2), round(after, 2), 0, torch.__version__, commit))
            r = rows[-1]
            print(f"{n:>7} {s.name:<40} {r.ms_fwd_bwd:8.2f} ms  {r.ns_per_gaussian:8.1f} ns/Gaussian  "
                  f"×{r.ratio_vs_mlp:<6} (Adam {r.ms_adam:.2f} ms, {r.parameters} numbers)  "
                  f"load {before:.2f} → {after:.2f}")
    write_dataclass_csv(args.out, rows)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
