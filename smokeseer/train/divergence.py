"""When a stage's loss has run away: the smoothed loss against its best so far.

Each iteration's loss is one view's, and views differ several-fold, so the watch smooths: an
exponential moving average over ``loss.divergence_span`` iterations, bias-corrected as Adam's
moments are (its first values are the plain mean of the losses so far, the very first one the
first loss). Its best is taken from the first iteration on, so a loss that explodes in a stage's
first steps is caught too, and a stage diverges when the average exceeds
``loss.divergence_factor`` × that best. An opacity reset raises the loss on purpose, so the watch
starts over after one. Calibration (docs/method.md, "Input and optimisation checks"): over the
1503 stages of the committed run logs the same average (over ten logged rows, every 10th
iteration) rose at most 5.4× over its best (p99 3.2), early in a Stage 3 whose priors grow with
the smoke; the default factor 20 leaves that a margin of 3.7, and the blow-ups seen rose
thousands of times.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from contracts.results_format import RunWarning


class StageDiverged(RuntimeError):
    """A stage's smoothed loss rose past the divergence factor over its best; carries where."""

    def __init__(self, stage: int, checkpoint: str, iteration: int, loss: float, best: float, best_iteration: int,
                 factor: float, span: int) -> None:
        rise = loss / best if best > 0 else float("inf")
        which = f"stage {stage}" + (f" ({checkpoint})" if checkpoint != f"stage{stage}" else "")
        super().__init__(f"{which} loss (smoothed over {span} iterations) rose to {loss:.4g} at iteration "
                         f"{iteration}, {rise:.3g}× its best {best:.4g} (iteration {best_iteration}; "
                         f"loss.divergence_factor={factor:g})")
        self.stage, self.checkpoint, self.iteration, self.loss, self.best = stage, checkpoint, iteration, loss, best
        self.best_iteration, self.factor, self.rise = best_iteration, factor, rise

    def warning(self) -> RunWarning:
        return RunWarning("loss-diverged", f"{self}: the stage stopped and the run has no scores", "rise", self.rise,
                          self.factor)

    def record(self) -> dict[str, Any]:
        """metrics.json ``diverged``."""
        return {"stage": self.stage, "checkpoint": self.checkpoint, "iteration": self.iteration, "loss": self.loss,
                "best": self.best, "best_iteration": self.best_iteration, "rise": self.rise, "factor": self.factor}


@dataclass
class LossWatch:
    """The smoothed loss of one stage, its best, and the largest rise seen (kept in checkpoints so a
    resumed stage watches as an uninterrupted one does)."""

    factor: float
    span: int
    mean: float = 0.0
    """The running average before bias correction."""
    seen: int = 0
    """Losses averaged since the start or the last restart."""
    best: float | None = None
    best_iteration: int = 0
    max_rise: float = 1.0

    def restart(self) -> None:
        """Forget the average and its best (after an opacity reset); the largest rise stays."""
        self.mean, self.seen, self.best, self.best_iteration = 0.0, 0, None, 0

    def update(self, stage: int, checkpoint: str, iteration: int, loss: float) -> None:
        """Add iteration ``iteration``'s loss; raise StageDiverged when the average has run away."""
        beta = 1.0 - 2.0 / (self.span + 1)
        self.mean = beta * self.mean + (1.0 - beta) * loss
        self.seen += 1
        average = self.mean / (1.0 - beta ** self.seen)
        if self.best is None or average < self.best:
            self.best, self.best_iteration = average, iteration
        rise = average / self.best if self.best > 0 else 1.0
        self.max_rise = max(self.max_rise, rise)
        if rise > self.factor:
            raise StageDiverged(stage, checkpoint, iteration, average, self.best, self.best_iteration, self.factor,
                                self.span)

    def state(self) -> dict[str, Any]:
        return asdict(self)

    def load_state(self, state: dict[str, Any]) -> None:
        for key in ("mean", "seen", "best", "best_iteration", "max_rise"):
            setattr(self, key, state[key])
