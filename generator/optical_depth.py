"""The mean RGB optical depth of a scene's smoke over its views, and the calibration that makes
it meet a target (`smoke.optical_depth`, docs/scene-spec.md).

A pixel's smoke optical depth is tau = -ln(1 - alpha), alpha its RGB smoke opacity (the
`smoke_alpha` pass: 1 - transmittance in front of the surfaces, averaged over R, G, B). The
scene's value is the opacity-weighted mean of tau over every pixel of every RGB view,
sum(alpha * tau) / sum(alpha): the mean optical depth of the smoke where there is smoke, with no
threshold (a threshold would make the value jump as faint pixels cross it). Scaling every smoke
coefficient by k scales each ray's tau by k, and this mean then rises strictly and continuously
with k, from 0 to infinity, so every target has exactly one k.

The calibration renders a reduced RGB `smoke_alpha` pass of the baked scene (a pilot) at the
spec's coefficients, finds the k whose mean meets the target, renders a second pilot at that k
and refines it; the dataset is rendered with every smoke coefficient times k. The bake is
deterministic and the pilots are Cycles renders with the scene's seed, so the spec alone gives
the same k again.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from blender.job import WorkerJob
from contracts.dataset_format import PASS_FILES
from contracts.imageio import read_exr_channel
from generator.errors import GeneratorError
from generator.postprocess import read_alpha
from generator.worker_client import render_baked

log = logging.getLogger("generate-scene")

#: Opacity is clipped below 1 by this much before the logarithm (float32 holds 1 - 6e-8).
MAX_ALPHA = 1.0 - 1e-6
SCALE_RANGE = (1e-4, 1e4)
SCALE_DIGITS = 4
"""The calibrated k is rounded to 4 significant digits, so a rerun whose pilot differs in the
last bits of a few pixels renders the same coefficients."""


def pixel_optical_depth(alpha: np.ndarray) -> np.ndarray:
    return -np.log1p(-np.clip(np.asarray(alpha, dtype=np.float64), 0.0, MAX_ALPHA))


def weighted_mean(tau: np.ndarray) -> float:
    """Opacity-weighted mean of optical depths `tau`; 0 when there is no smoke."""
    weight = -np.expm1(-tau)
    total = float(weight.sum())
    return float((weight * tau).sum() / total) if total > 0 else 0.0


def mean_optical_depth(alphas: np.ndarray, scale: float = 1.0) -> float:
    """The scene's mean optical depth from smoke opacities `alphas` (any shape), after every smoke
    coefficient is scaled by `scale`."""
    return weighted_mean(scale * pixel_optical_depth(alphas))


def solve_increasing(fn: Callable[[float], float], target: float, lo: float, hi: float,
                     steps: int = 80) -> float:
    """The x in [lo, hi] where the increasing function `fn` meets `target`, by bisection on log x
    (the nearer end when the target lies outside)."""
    a, b = math.log(lo), math.log(hi)
    for _ in range(steps):
        mid = 0.5 * (a + b)
        if fn(math.exp(mid)) < target:
            a = mid
        else:
            b = mid
    return math.exp(0.5 * (a + b))


def scale_for_target(alphas: np.ndarray, target: float) -> float:
    """The factor k on every smoke coefficient that brings `mean_optical_depth` to `target`."""
    tau = pixel_optical_depth(alphas)
    tau = tau[tau > 0]
    return solve_increasing(lambda k: weighted_mean(k * tau), target, *SCALE_RANGE)


def round_significant(value: float, digits: int = SCALE_DIGITS) -> float:
    return float(f"{value:.{digits - 1}e}")


@dataclass(frozen=True)
class Calibration:
    """What the calibration found: each pilot's scale and mean optical depth, and the final k."""

    target: float
    pilots: tuple[tuple[float, float], ...]
    scale: float

    def describe(self) -> dict[str, Any]:
        return {"target": self.target, "calibration_scale": self.scale,
                "pilots": [{"scale": k, "optical_depth": value} for k, value in self.pilots]}


PILOT_ROUNDS = 2
PILOT_SAMPLES = 4
PILOT_FRAME_STEP = 2
"""Two pilots, each every 2nd RGB frame at the camera's size with 4 samples (at most the
camera's): 1/8 of the work of the dataset's own 16-sample opacity pass. The opacity pass carries
each ray's exact transmittance (blender/materials.py), so even one sample a pixel is smooth, but
a pixel that averages fewer rays shows more optical depth where the smoke varies within it: at
one sample the achieved value fell 1.5-6 % short of the target, at four 1-3 %
(docs/experiments/2026-12-05-random-scene-sampler.md). The first pilot renders at the spec's
coefficients, the second at the k the first gives, because Cycles' optical depth grows a little
less than linearly with the coefficients where it is large; the second's k is then a short step."""


def pilot_job(job: WorkerJob, folder: Path, scale: float) -> WorkerJob:
    """The render stage of `job` reduced to the RGB smoke opacity of every 2nd frame with a few
    samples, with every smoke coefficient times `scale`, written under `folder`."""
    cam = job.cameras["rgb"]
    pilot = replace(cam, samples=min(cam.samples, PILOT_SAMPLES), frames=cam.frames[::PILOT_FRAME_STEP])
    return replace(job, raw_dir=str(folder / "raw"), summary_path=str(folder / "worker_summary.json"),
                   density_scale=scale, passes={"rgb": ("smoke_alpha",)}, cameras={**job.cameras, "rgb": pilot})


def pilot_alphas(folder: Path) -> np.ndarray:
    files = sorted((folder / "raw" / "rgb" / "smoke_alpha").glob("*.exr"))
    return np.stack([read_alpha(f) for f in files]) if files else np.zeros((0, 0, 0))


def next_scale(alphas: np.ndarray, rendered_at: float, target: float, source: str) -> float:
    """The k on the spec's coefficients that meets `target`, from a pilot rendered at `rendered_at`."""
    if mean_optical_depth(alphas) <= 0:
        raise GeneratorError(f"{source}: smoke.optical_depth: no RGB view shows any smoke, so no density meets the "
                             "target; move the sources or the cameras")
    scale = round_significant(rendered_at * scale_for_target(alphas, target))
    if not SCALE_RANGE[0] < scale < SCALE_RANGE[1]:
        raise GeneratorError(f"{source}: smoke.optical_depth: {target:g} needs the smoke {scale:.3g} times as dense "
                             f"as smoke.extinction_per_m gives; set extinction_per_m nearer")
    return scale


def dataset_alphas(dataset: Path) -> np.ndarray:
    """Every RGB smoke-opacity image of a finished dataset, stacked (frames, H, W)."""
    folder = dataset / PASS_FILES[("rgb", "smoke_alpha")][0].folder
    files = sorted(folder.glob("*.exr"))
    if not files:
        return np.zeros((0, 0, 0), dtype=np.float32)
    return np.stack([read_exr_channel(f, "A") for f in files])


@dataclass
class SmokeCalibrator:
    """Run between the bake and the render (`generator.worker_client.run_worker`): renders the
    pilot into WORK/pilot (kept for a resumed run) and returns the job with every smoke
    coefficient times the calibrated k."""

    target: float
    work: Path
    source: str
    show_progress: bool = True
    result: Calibration | None = None
    seconds: float = 0.0

    def __call__(self, job: WorkerJob) -> WorkerJob:
        started = time.perf_counter()
        scale, pilots = 1.0, []
        for i in range(PILOT_ROUNDS):
            folder = self.work / "pilot" / f"round{i + 1}"
            render_baked(pilot_job(job, folder, scale), folder / "job.json", self.work / "logs" / "worker.log",
                         self.show_progress)
            alphas = pilot_alphas(folder)
            pilots.append((scale, mean_optical_depth(alphas)))
            scale = next_scale(alphas, scale, self.target, self.source)
        self.result = Calibration(self.target, tuple(pilots), scale)
        self.seconds = time.perf_counter() - started
        log.info("smoke calibrated in %.1f s: mean RGB optical depth %s at scales %s; x%.4g for the target %.3f",
                 self.seconds, ", ".join(f"{v:.3f}" for _, v in pilots), ", ".join(f"{k:.4g}" for k, _ in pilots),
                 scale, self.target)
        return replace(job, density_scale=job.density_scale * scale)
