"""Split a torch.profiler capture of training iterations into the parts of an iteration.

Every recorded op's own time (its duration less its children's) goes to exactly one part, so the
parts of a step add up to the step. An op belongs to the part of the innermost ``part:`` label
(``torch.profiler.record_function``) around it, except the compiled rasterizer's autograd
Functions (``_Projection``, ``_TileComposite``), which are parts of their own, named after the
render pass around them. A backward node (``autograd::engine::evaluate_function: ...``) belongs
to the backward part of the forward op that created it: the profiler gives both the autograd
sequence number (on the evaluate_function span, or for custom Functions on the node's span
inside it), and the creator is the last forward op recorded with that number (ops that create no
node report the counter's next value, so they come before the creator). Nodes with no creator
in the capture (gradient accumulation into leaves) go to ``rest``, with the steps' own time
between labelled ops: the loop and Python overhead.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

LABEL = "part:"
STEP = "ProfilerStep"
BACKWARD = "autograd::engine::evaluate_function: "
PROJECTION, COMPOSITE = "_Projection", "_TileComposite"
PASSES = ("rgb", "thermal")
UNLABELLED = "unlabelled pass"
REST = "rest: loop, logging, Python overhead"


def pass_parts(name: str) -> dict[str, str]:
    """The parts of one render pass, by role."""
    return {"projection fwd": f"{name}: projection fwd", "projection bwd": f"{name}: projection bwd",
            "composite fwd": f"{name}: compositing fwd (binning, sort, blend)",
            "composite bwd": f"{name}: compositing bwd", "sh": f"{name}: SH colours, fwd+bwd",
            "other": f"{name}: other render ops (placement, concatenation, background), fwd+bwd"}


DEFORM_FWD, DEFORM_BWD = "deformation MLP fwd", "deformation MLP bwd"
SSIM_FWD, SSIM_BWD = "SSIM fwd", "SSIM bwd"
LOSSES = "other loss terms (L1, priors, mask) and forward glue, fwd+bwd"
DENSIFY = "densification bookkeeping (every iteration)"
DENSIFY_STEP = "densification step (clone, split, prune)"
ADAM = "Adam step, learning rates, zero_grad"
GUARD = "NaN guard and state snapshot"

LABEL_PARTS: dict[str, str] = {
    **{f"{p} pass": pass_parts(p)["other"] for p in PASSES},
    "deformation": DEFORM_FWD, "ssim": SSIM_FWD, "forward": LOSSES, "densify": DENSIFY,
    "densify step": DENSIFY_STEP, "adam": ADAM, "nan guard": GUARD, "snapshot": GUARD, "log": REST,
}
"""What each label the profiling harness puts around trainer code (``part:NAME``) stands for."""

PASS_LABELS: dict[str, str] = {"sh colours": "sh"}
"""Labels whose part is a role inside the render pass around them."""

BACKWARD_PART: dict[str, str] = {
    DEFORM_FWD: DEFORM_BWD, SSIM_FWD: SSIM_BWD,
    **{pass_parts(p)[f"{r} fwd"]: pass_parts(p)[f"{r} bwd"] for p in (*PASSES, UNLABELLED)
       for r in ("projection", "composite")},
    **{pass_parts(p)[r]: pass_parts(p)[r] for p in (*PASSES, UNLABELLED) for r in ("sh", "other")}, LOSSES: LOSSES,
}
"""The part a backward node joins, by the part of the forward op that created it."""

PART_ORDER: tuple[str, ...] = (
    *(pass_parts(p)[r] for p in PASSES for r in ("projection fwd", "projection bwd", "composite fwd",
                                                   "composite bwd", "sh", "other")),
    DEFORM_FWD, DEFORM_BWD, SSIM_FWD, SSIM_BWD, LOSSES, DENSIFY, DENSIFY_STEP, ADAM, GUARD, REST,
)
"""Every part, in the order the tables list them."""


@dataclass(frozen=True)
class Span:
    """One recorded op or label: name, start and end (µs), parent's index, autograd sequence number."""

    name: str
    start: float
    end: float
    parent: int | None
    seq: int


@dataclass
class Attribution:
    """Own time (µs) per part over ``steps`` profiler steps of ``step_us`` in all."""

    parts: dict[str, float]
    steps: int
    step_us: float
    ops: dict[tuple[str, str], float]
    """Own time (µs) by part and op name: what a part is made of."""


def spans_from_profiler(events: Iterable[Any]) -> list[Span]:
    """``torch.profiler.profile(...).events()`` as spans (CPU ops of the profiled thread)."""
    events = list(events)
    index = {id(e): i for i, e in enumerate(events)}
    return [Span(e.name, float(e.time_range.start), float(e.time_range.end),
                 index.get(id(e.cpu_parent)) if e.cpu_parent is not None else None, int(e.sequence_nr))
            for e in events]


def attribute(spans: list[Span]) -> Attribution:
    """Each span's own time to one part (see the module docstring); spans outside profiler steps
    are left out. Raises ValueError when the capture has no step or an unknown ``part:`` label."""
    children: list[list[int]] = [[] for _ in spans]
    roots = []
    for i, s in enumerate(spans):
        (roots if s.parent is None else children[s.parent]).append(i)
    totals = {p: 0.0 for p in PART_ORDER}
    creator_part: dict[int, str] = {}
    ops: dict[tuple[str, str], float] = {}
    steps, step_us = 0, 0.0

    def node_seq(i: int) -> int:
        """A backward node's sequence number: on the evaluate_function span, or (custom Functions)
        only on its child named after the node."""
        if spans[i].seq >= 0:
            return spans[i].seq
        node = spans[i].name[len(BACKWARD):]
        return next((spans[k].seq for k in children[i] if spans[k].name == node), -1)

    def visit(i: int, part: str, render_pass: str | None, backward: bool) -> None:
        s = spans[i]
        if s.name.startswith(LABEL):
            label = s.name[len(LABEL):]
            if label in PASS_LABELS:
                part = pass_parts(render_pass or UNLABELLED)[PASS_LABELS[label]]
            elif label in LABEL_PARTS:
                part = LABEL_PARTS[label]
            else:
                raise ValueError(f"unknown part label {s.name!r}")
            if label.endswith(" pass"):
                render_pass = label[:-len(" pass")]
        elif s.name in (PROJECTION, COMPOSITE) and not backward:
            part = pass_parts(render_pass or UNLABELLED)["projection fwd" if s.name == PROJECTION
                                                          else "composite fwd"]
        elif s.name.startswith(BACKWARD):
            backward = True
            part = BACKWARD_PART.get(creator_part.get(node_seq(i), REST), REST)
        if not backward and s.seq >= 0:
            creator_part[s.seq] = part  # a later op with the same number is the node's creator
        kids = sorted(children[i], key=lambda k: spans[k].start)
        own = (s.end - s.start) - sum(spans[k].end - spans[k].start for k in kids)
        totals[part] = totals.get(part, 0.0) + own
        ops[(part, s.name)] = ops.get((part, s.name), 0.0) + own
        for k in kids:
            visit(k, part, render_pass, backward)

    for i in sorted(roots, key=lambda k: spans[k].start):
        if spans[i].name.startswith(STEP):
            steps += 1
            step_us += spans[i].end - spans[i].start
            visit(i, REST, None, False)
    if steps == 0:
        raise ValueError("the capture holds no profiler step (ProfilerStep): profile with a schedule")
    return Attribution(totals, steps, step_us, ops)
