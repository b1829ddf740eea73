"""Shared training plumbing: the run log, checkpoints, NaN detection, LR schedules and the run context."""
from __future__ import annotations

import csv
import math
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import torch
from tqdm import tqdm

from contracts.atomic import atomic_path
from smokeseer.config import TrainConfig
from smokeseer.config.streams import stream_seed
from smokeseer.model.optim import Adam


class NaNDetected(RuntimeError):
    """A loss, gradient or parameter went non-finite; carries where, for the report."""

    def __init__(self, stage: int, iteration: int, tensor: str) -> None:
        super().__init__(f"non-finite value in {tensor} at stage {stage}, iteration {iteration}")
        self.stage = stage
        self.iteration = iteration
        self.tensor = tensor
        self.last_good: Path | None = None
        """The checkpoint holding the state before the step, set by the stage loop once it is written."""


def exp_lr(step: int, total: int, lr_init: float, lr_final: float) -> float:
    """3DGS's log-linear decay from lr_init to lr_final over ``total`` steps."""
    if total <= 0:
        return lr_init
    frac = min(max(step / total, 0.0), 1.0)
    return math.exp((1 - frac) * math.log(lr_init) + frac * math.log(lr_final))


def step_optimizers(it: int, total: int, cfg: TrainConfig, extent: float,
                    gaussian_optimizers: Sequence[Adam | None],
                    other_optimizers: Sequence[Adam | None],
                    deform_optimizer: Adam | None, deform_warmup: int) -> None:
    """One optimiser step of a stage of ``total`` iterations: the Gaussian sets' ``means`` learning
    rate decays over the stage as in 3DGS (a group frozen at lr 0 stays frozen), and so does the
    Fourier position offsets' (``deform.fourier_lr_scale`` of it), every optimiser
    steps and clears its gradients, and the deformation network follows its own decay over the
    stage (each group at its ``lr_scale`` times it, where it has one: the plane field's planes)
    and only steps after its warm-up (an iteration of the stage)."""
    decayed = exp_lr(it, total, cfg.lr.means_init * extent, cfg.lr.means_final * extent)
    scale = {"means": 1.0, "motion_means": cfg.deform.fourier_lr_scale}
    for opt in gaussian_optimizers:
        for group in opt.param_groups if opt is not None else ():
            if group["name"] in scale and group["lr"] > 0:
                group["lr"] = decayed * scale[group["name"]]
    for opt in (*gaussian_optimizers, *other_optimizers):
        if opt is not None:
            opt.step()
            opt.zero_grad(set_to_none=True)
    if deform_optimizer is not None:
        for group in deform_optimizer.param_groups:
            group["lr"] = exp_lr(it, total, cfg.deform.lr_init, cfg.deform.lr_final) * group.get("lr_scale", 1.0)
        if it > deform_warmup:
            deform_optimizer.step()
        deform_optimizer.zero_grad(set_to_none=True)


def check_finite(stage: int, it: int, named: Iterable[tuple[str, torch.Tensor | None]]) -> None:
    """Raise NaNDetected naming the first non-finite tensor."""
    for name, t in named:
        if t is not None and not bool(torch.isfinite(t).all()):
            raise NaNDetected(stage, it, name)


def state_or_none(part: Any) -> dict[str, Any] | None:
    """``part.state_dict()`` of a module, optimiser or Gaussian set a checkpoint holds, or None
    where the run has no such part."""
    return part.state_dict() if part is not None else None


def grads_of(prefix: str, params: dict[str, torch.nn.Parameter]) -> list[tuple[str, torch.Tensor | None]]:
    return [(f"{prefix}.{k}.grad", p.grad) for k, p in params.items()]


class RunLog:
    """train_log.csv: iteration, stage, wall_s, loss terms, val_psnr, test_psnr; appends across resumes.

    Columns are fixed up front (every loss term any stage may log) so the file stays one table.
    """

    COLUMNS = ["stage", "iteration", "wall_s", "n_gaussians", "n_smoke", "loss", "render_rgb",
               "render_thermal", "smoke_alpha", "smoke_color", "mono", "depth", "mask",
               "thermal_smoke_opacity", "val_psnr", "test_psnr"]

    def __init__(self, path: Path, wall_offset: float = 0.0) -> None:
        self.path = path
        self.t0 = time.perf_counter() - wall_offset
        if not path.exists():
            with path.open("w", newline="") as fh:
                csv.writer(fh).writerow(self.COLUMNS)

    def wall(self) -> float:
        return time.perf_counter() - self.t0

    def write(self, row: dict[str, Any]) -> None:
        row = dict(row)
        row.setdefault("wall_s", round(self.wall(), 3))
        with self.path.open("a", newline="") as fh:
            csv.writer(fh).writerow([_fmt(row.get(c)) for c in self.COLUMNS])

    def last_wall(self) -> float:
        """Wall time already spent by earlier (resumed) runs, from the log's last row."""
        with self.path.open() as fh:
            rows = list(csv.DictReader(fh))
        return float(rows[-1]["wall_s"]) if rows and rows[-1].get("wall_s") else 0.0


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


class CheckpointError(ValueError):
    """A checkpoint that exists but cannot be resumed from; the message names the file."""


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Atomic write, so an interrupted save never leaves a truncated checkpoint to resume from."""
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: Path, config_sha: str, log_line: Callable[[str], None]) -> dict[str, Any] | None:
    """The checkpoint at ``path`` if it was written with these settings; None when there is none
    or it holds other settings (said in the log). An unreadable file is an error: restarting a
    stage silently would hide lost work."""
    if not path.exists():
        return None
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a damaged file
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(exc).__name__}); delete it to "
                              "restart this stage") from None
    if not isinstance(payload, dict) or "iteration" not in payload:
        raise CheckpointError(f"{path}: not a train-and-evaluate checkpoint (no field 'iteration')")
    if payload.get("config_sha256") != config_sha:
        log_line(f"{path.name}: written with other settings; this stage starts afresh and overwrites it")
        return None
    return payload


class RunContext:
    """What every stage needs: config, device, output folders, the log and the random streams.
    Streams live on the CPU so a seed draws the same views and splits on every device; their
    draws are moved to the parameters' device where they meet them."""

    def __init__(self, cfg: Any, out: Path, log: RunLog, scene_center: torch.Tensor, extent: float) -> None:
        self.cfg = cfg
        self.out = out
        self.log = log
        self.device = torch.device(cfg.device)
        self.center = scene_center.to(self.device)
        self.extent = extent
        self.config_sha = cfg.sha256()
        self.stage2_sha = cfg.stage2_sha256()
        self.loss_rise: dict[str, float] = {}
        """Each stage's largest smoothed-loss rise over its best (``LossWatch.max_rise``), for metrics.json."""

    def stream(self, name: str) -> torch.Generator:
        """A fresh CPU generator on the run seed's stream ``name`` (``smokeseer.config.streams``)."""
        return torch.Generator(device="cpu").manual_seed(stream_seed(self.cfg.seed, name))

    @contextmanager
    def seeded_torch(self, name: str) -> Iterator[None]:
        """Torch's global generators seeded on stream ``name`` inside the block, for draws made by code
        that takes no generator (a module's default weight initialisation); the CPU one is put back
        after it (nothing else draws from a GPU's)."""
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(stream_seed(self.cfg.seed, name))
            yield

    def log_line(self, msg: str) -> None:
        """One human-readable line per stage event, kept clear of the progress bars."""
        tqdm.write(f"[train-and-evaluate] {msg}", file=sys.stderr)

    def checkpoint_path(self, name: str) -> Path:
        return self.out / "checkpoints" / f"{name}.pt"
