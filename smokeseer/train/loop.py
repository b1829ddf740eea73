"""The one training-stage loop Stages 2 and 3 share: resume, iterate, NaN guard, divergence
watch, optimiser steps, densification, logging, progress bar and checkpoints.

A stage describes itself as a ``StageProblem`` (what one iteration computes, which tensors to
guard, what a checkpoint holds); the loop owns everything else, so a fix to checkpointing or
divergence handling lands in both stages at once.
"""
from __future__ import annotations

import gc
from abc import ABC, abstractmethod
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator

import torch
from tqdm import tqdm

from smokeseer.raster.finite import first_non_finite
from smokeseer.train.divergence import LossWatch
from smokeseer.train.util import NaNDetected, RunContext, load_checkpoint, save_checkpoint


@dataclass
class IterationOutput:
    """What one iteration's forward pass produced: the total loss and its named terms."""

    loss: torch.Tensor
    terms: dict[str, torch.Tensor]
    extra: dict[str, Any] = field(default_factory=dict)


class StageProblem(ABC):
    """One stage's model, optimisers and loss, as the loop needs them."""

    stage: int
    name: str
    checkpoint: str
    """The checkpoint's file stem under ``checkpoints/`` (``stage2``, ``stage3``, ...)."""
    streams: dict[str, torch.Generator]
    """The random streams the stage draws from while it trains, by name (``smokeseer.config.streams``):
    their states go into every checkpoint and come back at a resume."""

    @abstractmethod
    def forward(self, it: int) -> IterationOutput:
        """Render and compute the loss of iteration ``it`` (1-based)."""

    @abstractmethod
    def named_gradients(self) -> list[tuple[str, torch.Tensor | None]]:
        """Every gradient the NaN guard checks after backward."""

    @abstractmethod
    def named_parameters(self) -> list[tuple[str, torch.Tensor]]:
        """Every parameter the NaN guard checks after the optimiser step."""

    @abstractmethod
    def optimizer_step(self, it: int) -> None:
        """Learning-rate schedules, optimiser steps and zeroing the gradients."""

    @abstractmethod
    def after_step(self, it: int, out: IterationOutput) -> None:
        """Densification and other edits between iterations."""

    @abstractmethod
    def state(self) -> dict[str, Any]:
        """Model and optimiser state for a checkpoint (tensors may alias the live ones)."""

    @abstractmethod
    def load_state(self, payload: dict[str, Any]) -> None:
        """Restore what ``state`` returned."""

    @abstractmethod
    def log_row(self, it: int, out: IterationOutput, heldout: dict[str, float | None] | None) -> dict[str, Any] | None:
        """The train_log.csv row of iteration ``it``; None writes none."""

    def heldout_psnr(self, it: int) -> dict[str, float | None] | None:
        """Held-out PSNRs for the log (``val_psnr``, ``test_psnr``), or None where the stage has none."""
        return None

    def raised_loss(self, it: int) -> bool:
        """Whether ``after_step`` of iteration ``it`` raised the loss on purpose (an opacity reset), so
        that the divergence watch starts over."""
        return False


_ATOMS = frozenset({int, float, bool, str, bytes, type(None)})


def detached_copy(obj: Any) -> Any:
    """A deep copy whose tensors are detached clones on their own device (a state snapshot).

    Why this shape: it runs every iteration on the model and optimiser state (hundreds of
    entries, mostly scalars in the optimisers' param groups); cloning under no_grad and not
    recursing into immutable scalars takes a third off the snapshot."""
    with torch.no_grad():
        return _copy(obj)


def _copy(obj: Any) -> Any:
    if isinstance(obj, torch.Tensor):
        return obj.clone()
    if isinstance(obj, dict):
        return {k: v if type(v) in _ATOMS else _copy(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)([v if type(v) in _ATOMS else _copy(v) for v in obj])
    return obj


def guard(stage: int, it: int, named: list[tuple[str, torch.Tensor | None]]) -> None:
    """Raise NaNDetected naming the first non-finite tensor of ``named`` (one fused check,
    ``smokeseer.raster.finite``)."""
    name = first_non_finite(named)
    if name is not None:
        raise NaNDetected(stage, it, name)


@dataclass
class StageSchedule:
    """How long a stage runs and how often it logs, evaluates and checkpoints."""

    iterations: int
    log_every: int
    test_every: int
    checkpoint_every: int
    checkpoint_sha: str


GC_EVERY = 100
"""Iterations between the explicit garbage collections of ``collect_every``."""


@contextmanager
def collect_every(iterations: int) -> Iterator[Any]:
    """Python's cyclic garbage collector off inside the loop, with an explicit young-generation
    collection every ``iterations`` calls of the yielded function.

    Why: an iteration allocates thousands of short-lived tensor wrappers, so the automatic
    collector runs many times per iteration and walks every tracked object; perf put it at about
    5 % of a demo Stage 3 CPU profile. Tensors are freed by reference counting either way; the
    periodic collection keeps any reference cycle from piling up."""
    count = 0

    def tick() -> None:
        nonlocal count
        count += 1
        if count % iterations == 0:
            gc.collect(1)

    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield tick
    finally:
        if was_enabled:
            gc.enable()


def resume(ctx: RunContext, problem: StageProblem, sched: StageSchedule, watch: LossWatch) -> tuple[int, bool]:
    """Load the stage's checkpoint if there is one for these settings: (start iteration, done). It
    also puts the stage's random streams and its divergence watch back where they stood, so a
    resumed run draws the views and splits an uninterrupted one would and watches its loss alike."""
    path = ctx.checkpoint_path(problem.checkpoint)
    payload = load_checkpoint(path, sched.checkpoint_sha, ctx.log_line)
    if payload is None:
        return 0, False
    problem.load_state(payload)
    start, done = int(payload["iteration"]), bool(payload.get("done"))
    ctx.log_line(f"{problem.name}: resumed from {path} at iteration {start}{' (finished)' if done else ''}")
    states = payload.get("rng_state")
    if isinstance(states, dict) and set(problem.streams) <= set(states):
        for name, generator in problem.streams.items():
            generator.set_state(states[name])
    else:
        ctx.log_line(f"{path.name}: holds no state of the streams {', '.join(problem.streams)} (written by an older "
                     "version), so the view draws and splits from here on differ from an uninterrupted run's")
    if payload.get("loss_watch") is not None:
        watch.load_state(payload["loss_watch"])
    return start, done


def run_stage(ctx: RunContext, problem: StageProblem, sched: StageSchedule) -> None:
    """Train ``problem`` to ``sched.iterations``, resuming from its checkpoint. On a non-finite
    loss, gradient or parameter (after the optimiser step and densification) it writes
    ``<checkpoint>_nan.pt`` holding the state that passed the previous iteration's check, and raises
    NaNDetected. That state is a snapshot taken before the step, so a step or a densification
    that produces non-finite values never reaches the checkpoint. Loss terms are checked with
    the gradients after backward (a non-finite loss still names itself first). A loss that runs
    away without going non-finite raises StageDiverged (``smokeseer.train.divergence``)."""
    loss = ctx.cfg.loss
    watch = LossWatch(loss.divergence_factor, loss.divergence_span)
    start, done = resume(ctx, problem, sched, watch)
    ctx.loss_rise[problem.checkpoint] = watch.max_rise
    if done:
        return
    nan_path = ctx.checkpoint_path(f"{problem.checkpoint}_nan")

    def payload(it: int, finished: bool, state: dict[str, Any]) -> dict[str, Any]:
        return {"stage": problem.stage, "iteration": it, "done": finished, "config_sha256": sched.checkpoint_sha,
                "rng_state": {name: g.get_state() for name, g in problem.streams.items()},
                "loss_watch": watch.state(), **state}

    total = sched.iterations
    bar = tqdm(range(start + 1, total + 1), desc=problem.name, disable=not ctx.cfg.progress, leave=False)
    with collect_every(GC_EVERY) as collect:
        for it in bar:
            out = problem.forward(it)
            try:
                out.loss.backward()
                guard(problem.stage, it, [(f"loss.{n}", v) for n, v in out.terms.items()] + problem.named_gradients())
            except NaNDetected as exc:
                save_checkpoint(nan_path, payload(it - 1, False, problem.state()))
                exc.last_good = nan_path
                raise
            watch.update(problem.stage, problem.checkpoint, it, float(out.loss.detach()))
            ctx.loss_rise[problem.checkpoint] = watch.max_rise
            last_good = detached_copy(problem.state())
            problem.optimizer_step(it)
            problem.after_step(it, out)
            if problem.raised_loss(it):
                watch.restart()
            try:
                guard(problem.stage, it, problem.named_parameters())
            except NaNDetected as exc:
                save_checkpoint(nan_path, payload(it - 1, False, last_good))
                exc.last_good = nan_path
                raise
            del last_good
            if it % sched.log_every == 0 or it == total:
                due = sched.test_every > 0 and (it % sched.test_every == 0 or it == total)
                row = problem.log_row(it, out, problem.heldout_psnr(it) if due else None)
                if row is not None:
                    ctx.log.write(row)
                bar.set_postfix(loss=f"{float(out.loss.detach()):.4f}")
            if sched.checkpoint_every and it % sched.checkpoint_every == 0 and it < total:
                save_checkpoint(ctx.checkpoint_path(problem.checkpoint), payload(it, False, problem.state()))
            collect()
    save_checkpoint(ctx.checkpoint_path(problem.checkpoint), payload(total, True, problem.state()))
