"""Runs that would train exactly like Full take Full's finished run (eval/twins.py).

The claims they rest on are checked with the real trainer: with the smoke colour held fixed,
"w/o smoke_color" and "w/o mono" end with Full's bytes, and "w/o mask" (a control) does not; the
meeting candidate ends with Full's bytes where its rule says it would.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from eval.harness import HarnessConfig, regenerate
from eval.twins import COLOUR_FIXED_REASON, twin_reason
from smokeseer.train.plan import COLOUR_FIXED
from tests.test_harness import _calls, identity_train, write_tiny_dataset
from tests.test_smokeseer_data import write_splat_dataset

TINY = {"stage2.iterations": 12, "stage3.iterations": 12, "stage2.init_points": 300, "stage3.smoke_points": 120,
        "log_every": 3, "stage3.test_every": 6, "checkpoint_every": 6, "stage2.deform_warmup": 0.25, "stage3.deform_warmup": 0.25,
        "progress": False, "stage3.smoke_color": "haze-lines"}


def test_colour_prior_ablations_train_like_full_when_the_colour_is_fixed(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    import smokeseer.api as api
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    # The estimate itself is not under test here (tests/test_haze_lines.py): a fully trusted one is given.
    monkeypatch.setattr(api, "haze_line_smoke_colour",
                        lambda cfg, depth, rgb: SmokeColourEstimate(np.array([0.8, 0.8, 0.82]), 500, 900, 0.9,
                                                                                trust=1.0))
    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    plys, psnr, docs = {}, {}, {}
    for mode in ("full", "no-smoke-color", "no-mono", "no-mask"):
        doc = docs[mode] = api.train_and_evaluate(ds, tmp_path / mode, mode, profile="quick", seed=0, overrides=TINY)
        assert doc["stages"]["smoke_colour"]["source"] == "haze-lines"
        plys[mode] = (tmp_path / mode / "ply" / "surface.ply").read_bytes()
        psnr[mode] = doc["metrics"]["psnr"]
    assert plys["no-smoke-color"] == plys["full"] and plys["no-mono"] == plys["full"]
    assert psnr["no-smoke-color"] == psnr["full"] == psnr["no-mono"]
    assert plys["no-mask"] != plys["full"]
    # The plan each run recorded: Full's dropped both colour priors, which is what the harness reads.
    assert docs["full"]["stages"]["stage3_plan"]["dropped"] == {"smoke_color": COLOUR_FIXED, "mono": COLOUR_FIXED}
    assert docs["no-mono"]["stages"]["stage3_plan"]["dropped"] == {"smoke_color": COLOUR_FIXED}
    assert docs["full"]["stages"]["stage3_plan"]["loss_weights"]["mono"] == 0.0
    assert "haze-line estimate" in twin_reason("no-mono", docs["full"])


def _plan(smoke_colour: str, dropped: dict[str, str]) -> dict[str, Any]:
    weights = {"render": 1.0, "smoke_alpha": 0.1, "smoke_color": 0.05, "mono": 0.1, "depth": 0.0, "mask": 0.5,
               "thermal_smoke_opacity": 0.01}
    return {"smoke_colour": smoke_colour, "mask_floor": "all", "depth_prior": None, "depth_camera": None,
            "loss_weights": {k: 0.0 if k in dropped else v for k, v in weights.items()}, "dropped": dropped}


def test_twin_reason_reads_fulls_plan_and_falls_back_for_older_runs() -> None:
    """The plan Full recorded decides (a colour prior it dropped, for whatever reason it names);
    runs written before plans were recorded are read by their smoke colour's source."""
    fixed = {"stages": {"stage3_plan": _plan("haze-lines", {"smoke_color": COLOUR_FIXED, "mono": COLOUR_FIXED})}}
    assert "(the smoke colour is held fixed at the haze-line estimate)" in twin_reason("no-mono", fixed)
    assert twin_reason("no-smoke-alpha", fixed) is None and twin_reason("no-mask", fixed) is None
    no_smoke = {"stages": {"stage3_plan": _plan("none", {"smoke_color": "no smoke Gaussians"})}}
    assert "no smoke Gaussians" in twin_reason("no-smoke-color", no_smoke)
    learned = {"stages": {"stage3_plan": _plan("learned", {}), "smoke_colour": {"source": "haze-lines"}}}
    assert twin_reason("no-mono", learned) is None
    assert twin_reason("no-smoke-color", {"stages": {"smoke_colour": {"source": "haze-lines"}}}) == COLOUR_FIXED_REASON
    assert twin_reason("no-smoke-color", {"stages": {"smoke_colour": {"source": "learned"}}}) is None
    assert twin_reason("no-mono", {"stages": {}}) is None


def colour_fixed_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
                       overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """identity_train whose metrics.json says where the smoke colour came from: fixed on scene alpha."""
    identity_train(dataset, out, mode, profile, seed, overrides)
    doc = json.loads((out / "metrics.json").read_text())
    source = "haze-lines" if json.loads((dataset / "dataset.json").read_text())["scene"] == "alpha" else "learned"
    doc["stages"] = {"smoke_colour": {"source": source, "haze_lines": None}}
    (out / "metrics.json").write_text(json.dumps(doc))
    return doc


def test_harness_takes_fulls_run_for_colour_prior_ablations_where_the_colour_was_fixed(tmp_path: Path) -> None:
    datasets = {s: write_tiny_dataset(tmp_path / s, s) for s in ("alpha", "beta")}
    base = dict(out=tmp_path / "out", scenes=["alpha", "beta"], seeds=[0], workers=1, datasets=datasets)
    regenerate(HarnessConfig(methods=["full"], ablations=[], **base), train_fn=colour_fixed_train)
    n = _calls(tmp_path / "out")
    ablations = ["no-smoke-color", "no-mono", "no-smoke-alpha"]
    results, paths = regenerate(HarnessConfig(methods=["full"], ablations=ablations, **base),
                                train_fn=colour_fixed_train)
    # alpha's two colour-prior rows are Full's; the other four ablation runs train
    assert _calls(tmp_path / "out") - n == 4
    by = {(r.scene, r.variant): r for r in results}
    for v in ("no-smoke-color", "no-mono"):
        twin = by[("alpha", v)]
        assert twin.status == "ok" and twin.same_as == "full" and twin.run_dir == by[("alpha", "full")].run_dir
        assert twin.metrics == by[("alpha", "full")].metrics and "haze-line estimate" in twin.same_as_reason
        assert not by[("beta", v)].same_as
    assert not by[("alpha", "no-smoke-alpha")].same_as
    t2 = paths["table2.md"].read_text()
    assert "w/o smoke_color: 1 of its 2 runs are Full's of the same scene and seed, not trained" in t2
    assert "w/o smoke_alpha: 1 of" not in t2
    rows = {r["variant"]: r for r in csv.DictReader(open(paths["table2.csv"])) if r["metric"] == "psnr"}
    assert rows["no-mono"]["runs_ok"] == "2"
    assert "alpha/no-mono/seed 0 = full" in paths["report.md"].read_text()


def write_full_record(run: Path, colour: list[float] | None, lines: int, met: float | None,
                      mask_floor: str = "estimated-meeting", surface_trust: float = 0.5) -> None:
    """A finished Full run's metrics.json and config.json as the meeting rule reads them: the plan's
    floor and the haze lines' record (its validation kept where the folder had one)."""
    from smokeseer.config import make_config
    from tests.results_builder import write_metrics

    old = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").is_file() else {}
    plan = {**_plan("haze-lines" if colour else "learned", {}), "mask_floor": mask_floor}
    write_metrics(run, scene=run.parents[1].name, method="full", profile="standard", seed=0,
                  metrics=old.get("metrics"), validation=old.get("validation"),
                  stages={"stage3_plan": plan, "smoke_colour": {"source": "haze-lines", "haze_lines": {
                      "colour": colour, "lines": lines, "meeting_fraction": met if colour else None,
                      "surface_trust": surface_trust if colour else 0.0}}})
    (run / "config.json").write_text(json.dumps(make_config("full", "standard", 0).to_dict()))


@pytest.mark.parametrize("colour, lines, met, floor, surface_trust, twin", [
    (None, 86, None, "estimated-meeting", 0.0, True),              # no point: both floors read none
    ([0.3, 0.3, 0.3], 500, 0.8, "estimated-meeting", 1.0, True),   # weight 1 (surface trust 1): the floors agree
    ([0.6, 0.6, 0.6], 500, 0.8, "estimated-meeting", 0.0, False),  # weight 1 under a bright colour: not read
    ([0.3, 0.3, 0.3], 500, 0.1, "estimated-meeting", 0.0, True),   # weight 0, and Full did not
    ([0.3, 0.3, 0.3], 106, 0.58, "estimated-meeting", 0.02, False),  # weight 0.02: food_plate's case
    ([0.3, 0.3, 0.3], 500, 0.25, "estimated-bound", 0.5, False),   # used, at weight 0.5
    ([0.3, 0.3, 0.3], 100, 0.5, "estimated-meeting", 0.0, False),  # used, at weight 0 (the ramp's foot)
    ([0.3, 0.3, 0.3], 106, 0.58, "never-clear", 0.02, True),       # a floor that reads no haze line
])
def test_the_meeting_candidate_stands_on_fulls_run_where_the_floors_agree(tmp_path: Path, colour, lines, met,
                                                                         floor, surface_trust, twin) -> None:
    from eval.twins import run_twin_reason

    run = tmp_path / "runs" / "scene" / "full" / "seed0-x"
    run.mkdir(parents=True)
    write_full_record(run, colour, lines, met, floor, surface_trust)
    reason = run_twin_reason("floor-by-meeting-trust", run)
    assert (reason is not None) == twin
    assert run_twin_reason("thermal-box-filtered", run) is None


def test_the_meeting_candidate_trains_like_full_where_its_rule_says_so(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The claim the meeting rule rests on, with the real trainer and the standard floor: with no
    meeting point, or a fully trusted one, loss.mask_floor_meeting=trusted (a float floor map and
    the mask term's weighted form) ends with Full's bytes. (This scene's geometry leaves every
    masked pixel floored under both rules, so a point at weight 0.5 floors alike here too: the
    blend itself is tests/test_mask_floor.py's.)"""
    import smokeseer.api as api
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    floor = {**TINY, "loss.mask_floor_where": "estimated-meeting"}
    point = np.array([0.8, 0.8, 0.82])
    estimates = {"none": SmokeColourEstimate(None, 86, 191, reason="fewer than 100 observation lines"),
                 "full weight": SmokeColourEstimate(point, 500, 900, 0.9, meeting=point, trust=1.0, meeting_weight=1.0)}
    for name, estimate in estimates.items():
        monkeypatch.setattr(api, "haze_line_smoke_colour", lambda cfg, depth, rgb, e=estimate: e)
        plys = {}
        for meeting in ("present", "trusted"):
            out = tmp_path / f"{name}-{meeting}"
            api.train_and_evaluate(ds, out, "full", profile="quick", seed=0,
                                   overrides={**floor, "loss.mask_floor_meeting": meeting})
            plys[meeting] = (out / "ply" / "surface.ply").read_bytes()
        assert plys["present"] == plys["trusted"], name


def test_the_carve_candidate_stands_on_fulls_run_where_no_start_was_joined() -> None:
    from eval.twins import twin_reason

    assert "one surface" in twin_reason("carve-where-smoky", {"stages": {"surface_union": None}})
    assert twin_reason("carve-where-smoky", {"stages": {"surface_union": {"rgb_kept": 10}}}) is None
    assert twin_reason("carve-where-smoky", {"stages": {}}) is None  # a record that does not say


def test_the_carve_candidate_trains_like_full_without_a_joined_start(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The claim the carve rule rests on, with the real trainer: under a fully trusted dark smoke
    colour Stage 3 starts from the thermal Stage 2 alone and stage3.carve_by changes no byte; under
    an untrusted one the start is joined and carved by the setting, as the record says (this tiny
    scene has nothing in front of its thermal surface, so both carvings keep every RGB Gaussian)."""
    import smokeseer.api as api
    from smokeseer.stage1.haze_lines import SmokeColourEstimate

    ds = write_splat_dataset(tmp_path / "splat", n_rgb=8, n_thermal=6)
    point = np.array([0.2, 0.2, 0.22])
    estimates = {"thermal start": SmokeColourEstimate(point, 500, 900, 0.9, meeting=point, trust=1.0,
                                                      surface_trust=1.0, meeting_weight=1.0),
                 "joined start": SmokeColourEstimate(None, 86, 191, reason="fewer than 100 observation lines")}
    for name, estimate in estimates.items():
        monkeypatch.setattr(api, "haze_line_smoke_colour", lambda cfg, depth, rgb, e=estimate: e)
        plys, joined = {}, {}
        for carve in ("depth", "depth-and-smoke"):
            out = tmp_path / f"{name}-{carve}"
            api.train_and_evaluate(ds, out, "full", profile="quick", seed=0,
                                   overrides={**TINY, "stage3.surface_init": "by-smoke-colour",
                                              "stage3.carve_by": carve})
            plys[carve] = (out / "ply" / "surface.ply").read_bytes()
            joined[carve] = json.loads((out / "metrics.json").read_text())["stages"]["surface_union"]
        if name == "thermal start":
            assert joined == {"depth": None, "depth-and-smoke": None}
            assert plys["depth"] == plys["depth-and-smoke"]
        else:
            assert joined["depth"]["carve_by"] == "depth" and joined["depth-and-smoke"]["carve_by"] == "depth-and-smoke"


def haze_train(dataset: Path, out: Path, mode: str, profile: str = "quick", seed: int = 0,
               overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """identity_train whose record has no meeting point on scene alpha, one at weight 0.5 on beta."""
    identity_train(dataset, out, mode, profile, seed, overrides)
    alpha = json.loads((dataset / "dataset.json").read_text())["scene"] == "alpha"
    write_full_record(out, None if alpha else [0.3, 0.3, 0.3], 250, 0.5)
    return {}


def test_harness_takes_fulls_run_for_the_meeting_candidate_where_the_floors_agree(tmp_path: Path) -> None:
    datasets = {s: write_tiny_dataset(tmp_path / s, s) for s in ("alpha", "beta")}
    base = dict(out=tmp_path / "out", scenes=["alpha", "beta"], seeds=[0], workers=1, datasets=datasets,
                ablations=[])
    regenerate(HarnessConfig(methods=["full"], **base), train_fn=haze_train)
    n = _calls(tmp_path / "out")
    results, _ = regenerate(HarnessConfig(methods=["full"], candidates=["floor-by-meeting-trust"], **base),
                            train_fn=haze_train)
    assert _calls(tmp_path / "out") - n == 1   # beta's candidate trains; alpha's is Full's run
    by = {(r.scene, r.variant): r for r in results}
    twin = by[("alpha", "floor-by-meeting-trust")]
    assert twin.same_as == "full" and twin.run_dir == by[("alpha", "full")].run_dir
    assert "no meeting point" in twin.same_as_reason
    assert not by[("beta", "floor-by-meeting-trust")].same_as


def test_the_meeting_candidate_waits_for_the_full_run_trained_beside_it(tmp_path: Path) -> None:
    """In one invocation that trains Full too, the candidate is decided once Full's run has ended:
    the run Full's record stands for is not trained, the other is."""
    datasets = {s: write_tiny_dataset(tmp_path / s, s) for s in ("alpha", "beta")}
    results, _ = regenerate(HarnessConfig(methods=["full"], candidates=["floor-by-meeting-trust"], ablations=[],
                                          out=tmp_path / "out", scenes=["alpha", "beta"], seeds=[0], workers=2,
                                          datasets=datasets), train_fn=haze_train)
    assert _calls(tmp_path / "out") == 3   # both Full runs and beta's candidate
    by = {(r.scene, r.variant): r for r in results}
    twin = by[("alpha", "floor-by-meeting-trust")]
    assert twin.status == "ok" and twin.same_as == "full" and twin.run_dir == by[("alpha", "full")].run_dir
    assert by[("beta", "floor-by-meeting-trust")].status == "ok" and not by[("beta", "floor-by-meeting-trust")].same_as
    assert [(r.scene, r.variant) for r in results] == [(s, v) for s in ("alpha", "beta")
                                                       for v in ("full", "floor-by-meeting-trust")]
