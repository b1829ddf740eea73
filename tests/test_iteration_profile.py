"""benchmarks/iteration_attribution.py and the pieces of benchmarks/iteration_profile.py that decide
what the profile measures: the split of a capture into parts (a hand-built capture with its sums
worked out by hand, and a real torch.profiler capture against the profiler's own per-op totals),
the pretraining schedule and the Gaussian count matching."""
from __future__ import annotations

import math

import pytest
import torch
from torch.profiler import ProfilerActivity, profile, schedule

from benchmarks.iteration_attribution import (ADAM, DEFORM_BWD, DEFORM_FWD, LOSSES, REST, SSIM_BWD, SSIM_FWD, Span,
                                              attribute, pass_parts, spans_from_profiler)
from benchmarks.iteration_profile import densify_steps, labelled, match_count, scaled_overrides
from smokeseer.config import DensifyWindow, at_iteration, make_config
from smokeseer.model.gaussians import GaussianSet, make_optimizer
from smokeseer.raster import rasterize
from smokeseer.train.losses import ssim

BWD = "autograd::engine::evaluate_function: "


def build(tree: list[tuple]) -> list[Span]:
    """Spans from nested (name, start, end, seq, children) tuples."""
    spans: list[Span] = []

    def add(node: tuple, parent: int | None) -> None:
        name, start, end, seq, kids = node
        spans.append(Span(name, start, end, parent, seq))
        me = len(spans) - 1
        for kid in kids:
            add(kid, me)
    for node in tree:
        add(node, None)
    return spans


def test_hand_built_capture_splits_as_worked_out() -> None:
    rgb = pass_parts("rgb")
    spans = build([
        ("ProfilerStep*", 0, 1000, -1, [
            ("part:forward", 10, 600, -1, [
                ("part:rgb pass", 20, 400, -1, [
                    ("aten::cat", 25, 35, 5, []),
                    ("part:deformation", 40, 140, -1, [("aten::addmm", 50, 130, 7, [])]),
                    ("_Projection", 150, 200, 8, []),
                    ("aten::detach", 202, 205, 9, []),  # creates no node: reports the composite's number
                    ("_TileComposite", 210, 380, 9, [("aten::empty", 220, 230, -1, [])]),
                ]),
                ("part:ssim", 410, 500, -1, [("aten::conv2d", 420, 480, 10, [])]),
                ("aten::abs", 510, 520, 11, []),
                ("aten::isfinite", 530, 540, 12, []),
            ]),
            (BWD + "_TileCompositeBackward", 610, 760, -1, [("_TileCompositeBackward", 611, 759, 9, [])]),
            (BWD + "AddmmBackward0", 770, 800, 7, [("AddmmBackward0", 771, 799, 7, [])]),
            (BWD + "torch::autograd::AccumulateGrad", 800, 805, -1, []),
            ("part:adam", 810, 900, -1, []),
        ]),
        ("aten::mm", 2000, 2100, -1, []),  # outside any step: not counted
    ])
    att = attribute(spans)
    expected = {REST: 135 + 5, LOSSES: 100 + 10 + 10, rgb["other"]: 47 + 10 + 3, DEFORM_FWD: 20 + 80,
                rgb["projection fwd"]: 50, rgb["composite fwd"]: 160 + 10, SSIM_FWD: 30 + 60,
                rgb["composite bwd"]: 150, DEFORM_BWD: 30, ADAM: 90}
    assert {k: v for k, v in att.parts.items() if v} == pytest.approx(expected)
    assert att.steps == 1 and att.step_us == 1000
    assert sum(att.parts.values()) == pytest.approx(att.step_us)
    assert att.ops[(rgb["composite fwd"], "aten::empty")] == 10


def test_capture_without_steps_or_with_unknown_label_is_refused() -> None:
    with pytest.raises(ValueError, match="no profiler step"):
        attribute(build([("aten::mm", 0, 10, -1, [])]))
    with pytest.raises(ValueError, match="part:renderr"):
        attribute(build([("ProfilerStep*", 0, 10, -1, [("part:renderr", 1, 2, -1, [])])]))


def test_real_capture_matches_the_profilers_own_totals() -> None:
    """A small iteration (deformation MLP, one compiled-rasterizer pass, SSIM, backward) profiled
    for real: the parts add up to the steps, and the rasterizer's and the labelled MLP's parts equal
    the profiler's totals of those ops."""
    torch.manual_seed(0)
    n = 400
    mlp = torch.nn.Sequential(torch.nn.Linear(8, 32), torch.nn.ReLU(), torch.nn.Linear(32, 3))
    mlp.forward = labelled(mlp.forward, "deformation")
    base = (torch.randn(n, 3) * 0.4 + torch.tensor([0.0, 0.0, 3.0])).requires_grad_()
    quats = torch.randn(n, 4).requires_grad_()
    scales = torch.full((n, 3), -2.5).requires_grad_()
    opac = torch.full((n,), 0.4).requires_grad_()
    cols = torch.rand(n, 3).requires_grad_()
    target = torch.rand(40, 48, 3)
    viewmat = torch.eye(4)[None]
    k = torch.tensor([[40.0, 0, 24], [0, 40.0, 20], [0, 0, 1]])[None]
    pass_label, ssim_label = labelled(rasterize, "rgb pass"), labelled(ssim, "ssim")

    def iteration() -> None:
        means = base + 0.01 * mlp(torch.randn(n, 8))
        out = pass_label(means, quats, scales, opac, cols, viewmat, k, 48, 40, log_scales=True, backend="cpu")
        loss = 1.0 - ssim_label(out.colors[0], target)
        loss.backward()

    prof = profile(activities=[ProfilerActivity.CPU], schedule=schedule(wait=1, warmup=1, active=3, repeat=1))
    prof.start()
    for i in range(6):
        if i:
            prof.step()
        iteration()
    prof.stop()
    events = list(prof.events())
    att = attribute(spans_from_profiler(events))
    rgb = pass_parts("rgb")

    def total(*names: str) -> float:
        return sum(e.cpu_time_total for e in events if e.name in names)
    assert att.steps == 3
    assert sum(att.parts.values()) == pytest.approx(att.step_us, rel=1e-9)
    assert att.parts[rgb["composite fwd"]] == pytest.approx(total("_TileComposite"), rel=1e-6)
    assert att.parts[rgb["composite bwd"]] == pytest.approx(total(BWD + "_TileCompositeBackward"), rel=1e-6)
    assert att.parts[rgb["projection fwd"]] == pytest.approx(total("_Projection"), rel=1e-6)
    assert att.parts[rgb["projection bwd"]] == pytest.approx(total(BWD + "_ProjectionBackward"), rel=1e-6)
    assert att.parts[DEFORM_FWD] == pytest.approx(total("part:deformation"), rel=1e-6)
    mlp_nodes = [BWD + f"{op}Backward0" for op in ("Addmm", "T", "Relu")]
    assert att.parts[DEFORM_BWD] == pytest.approx(total(*mlp_nodes), rel=1e-6)
    assert att.parts[SSIM_BWD] >= total(BWD + "ConvolutionBackward0") > 0
    assert att.parts[SSIM_FWD] == pytest.approx(total("part:ssim"), rel=1e-6)


def test_pretraining_schedule_is_the_standard_one_scaled() -> None:
    standard = make_config("full", "standard", 0)
    short = make_config("full", "standard", 0, scaled_overrides(standard, 0.1))
    assert (short.stage2.iterations, short.stage3.iterations) == (300, 300)
    assert short.stage3.smoke_densify.window(300) == DensifyWindow(30, 240, 10, 0)
    assert (at_iteration(short.stage3.deform_warmup, 300), short.sh_increase_every) == (50, 80)
    # the standard run densifies at 300, 400, ..., 2400; the short one as often
    assert densify_steps(standard.stage3.smoke_densify.window(3000), 1, 3000) == 22
    assert densify_steps(short.stage3.smoke_densify.window(300), 1, 300) == 22
    assert densify_steps(standard.stage2.densify.window(3000), 2381, 2400) == 1


def test_match_count_grows_by_splits_and_trims_the_most_transparent() -> None:
    torch.manual_seed(1)
    g = GaussianSet({"means": torch.randn(10, 3), "quats": torch.randn(10, 4), "log_scales": torch.full((10, 3), -2.0),
                     "opacity": torch.linspace(-3, 3, 10)})
    opt = make_optimizer(g, {"means": 1e-3, "quats": 1e-3, "log_scales": 1e-3, "opacity": 1e-2})
    for p in g.params.values():
        p.grad = torch.ones_like(p)
    opt.step()
    match_count(g, opt, 27, torch.Generator().manual_seed(0))
    assert g.n == 27
    for group in opt.param_groups:
        param = group["params"][0]
        assert param is g.params[group["name"]]
        assert opt.state[param]["exp_avg"].shape == param.shape
    # every one of the 10 split (20), then 7 of those 20 again (27): both halves of a split have
    # their parent's scale / 1.6
    levels = torch.round((-2.0 - g["log_scales"].detach()[:, 0]) / math.log(1.6))
    assert sorted(levels.tolist()) == [1.0] * 13 + [2.0] * 14
    kept = torch.sort(g["opacity"].detach(), descending=True).values[:5]
    match_count(g, opt, 5, torch.Generator())
    assert g.n == 5
    assert torch.equal(torch.sort(g["opacity"].detach(), descending=True).values, kept)


def test_deformation_tradeoff_averages_seeds_and_keeps_one_commit_per_scene() -> None:
    """Per scene and trainer: the seeds' mean and std of the final validation PSNR beside the
    profiled Stage-3 cost times the trainer's iterations; a scene whose trainers were profiled by
    different commits is left out (their costs do not compare), as are unprofiled trainers."""
    from benchmarks.deformation_tradeoff import tradeoff_rows
    final = [{"scene": "a", "seed": s, "trainer": t, "val_psnr": v} for s, t, v in
             ((0, "estimated-floor", 12.0), (1, "estimated-floor", 14.0), (0, "fourier", 11.0), (1, "fourier", 12.0),
              (1, "fourier, 6000", 13.5), (0, "rgb-only (6663d970, true-alpha floor)", 9.0),
              (0, "estimated-floor", 20.0))]
    final[-1]["scene"] = "b"
    final.append({"scene": "b", "seed": 0, "trainer": "fourier", "val_psnr": 19.0})
    costs = {("a", "full"): (300.0, "c1"), ("a", "full deform.kind=fourier"): (150.0, "c1"),
             ("b", "full"): (300.0, "c1"), ("b", "full deform.kind=fourier"): (150.0, "c2")}
    listed = tradeoff_rows(final, costs)
    assert {(r["scene"], r["trainer"]) for r in listed} == {("a", "estimated-floor"), ("a", "fourier"),
                                                            ("a", "fourier, 6000")}  # b left out, RGB-only unprofiled
    rows = {r["trainer"]: r for r in listed}
    assert rows["estimated-floor"]["val_psnr_mean"] == 13.0 and rows["estimated-floor"]["val_psnr_std"] == pytest.approx(1.414, abs=1e-3)
    assert rows["estimated-floor"]["stage3_min"] == 15.0 and rows["fourier"]["stage3_min"] == 7.5
    assert rows["fourier, 6000"]["stage3_min"] == 15.0 and rows["fourier, 6000"]["val_psnr_std"] == ""


def test_deformation_tradeoff_reads_trainers_named_by_their_settings() -> None:
    """A trainer labelled by its --set words finds the iteration_profile column of those words
    (the iteration count left out of the column, used for the minutes); the summary gives each
    trainer's mean and worst validation difference from the network and its share of the time."""
    from benchmarks.deformation_tradeoff import profiled, summary_rows, tradeoff_rows
    planes = "deform.kind=planes deform.planes_levels=1"
    assert profiled(planes) == ("full deform.kind=planes deform.planes_levels=1", 3000)
    assert profiled(planes + " stage3.iterations=6000") == ("full deform.kind=planes deform.planes_levels=1", 6000)
    assert profiled("fourier") == ("full deform.kind=fourier", 3000) and profiled("width 48") is None
    final = [{"scene": s, "seed": 0, "trainer": t, "val_psnr": v} for s, t, v in
             (("a", "estimated-floor", 20.0), ("a", planes, 19.9), ("b", "estimated-floor", 15.0), ("b", planes, 15.3))]
    costs = {(s, c): (ms, "c1") for s in "ab" for c, ms in (("full", 300.0), ("full " + planes, 120.0))}
    rows = tradeoff_rows(final, costs)
    assert {r["stage3_min"] for r in rows if r["trainer"] == planes} == {6.0}
    (summary,) = summary_rows(rows)
    assert summary["trainer"] == planes and summary["scenes"] == 2
    assert summary["mean_val_psnr_minus_baseline"] == pytest.approx(0.1, abs=1e-9)
    assert (summary["worst_scene"], summary["worst_val_psnr_minus_baseline"]) == ("a", pytest.approx(-0.1, abs=1e-9))
    assert summary["stage3_time_over_baseline"] == 0.4
