"""Dense-smoke diagnosis of a finished run: rebuild its model through the resume path (in a
copy of the run folder), render every RGB frame, and compare with the dataset's truth passes:
composite vs smoky input, surface vs clean, rendered smoke alpha vs the true smoke alpha, and the
smoke colour implied by the smoke-only render. The same on the smoky pixels alone (true alpha over
``SMOKY``): both alphas, the surface's and the input's mean absolute error against clean, and the
smoke colour of the model beside the truth's, (smoky − (1 − a)·clean) / a where a > ``DENSE``.
One line per frame, then the mean per split.

    python benchmarks/dense_diagnosis.py RUN_DIR DATASET ['{"dotted.key": value, ...}']

The overrides must be the ones the run was trained with (its checkpoints are keyed by the config)."""
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from contracts.imageio import read_exr
from contracts.metrics import psnr
from contracts.recorded_paths import recorded_location
from scenes.load import load_scene
from smokeseer.api import prepare
from smokeseer.model.scene import make_view
from smokeseer.train.stage2 import train_stage2
from smokeseer.train.stage3 import build_scene_model, train_stage3
from smokeseer.train.util import RunContext, RunLog

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.smoke_colour_decisions import estimate, haze_lines, implied_smoke_colour  # noqa: E402

SMOKY = 0.05
"""True smoke alpha over which a pixel counts as smoky."""
DENSE = 0.3
"""True smoke alpha over which a pixel's smoke colour is read off the truth (thinner divides noise)."""


def rebuild(run: Path, overrides: dict, tmp: Path):
    """The run's finished model, through the trainer's own resume (which checks the config)."""
    cfg_doc = json.loads((run / "config.json").read_text())
    metrics = json.loads((run / "metrics.json").read_text())
    prep = prepare(recorded_location(metrics["dataset"]), cfg_doc["mode"], cfg_doc["profile"], cfg_doc["seed"], overrides)
    shutil.copytree(run / "checkpoints", tmp / "checkpoints")
    cfg, scene, b = prep.cfg, prep.scene, prep.report.bounds
    ctx = RunContext(cfg, tmp, RunLog(tmp / "log.csv"), torch.as_tensor(b.center, dtype=torch.float32), b.extent)
    saved = torch.load(run / "checkpoints" / "stage3.pt", map_location="cpu", weights_only=False)
    if saved["config_sha256"] != ctx.config_sha or not saved.get("done"):
        raise SystemExit(f"{run}: its stage3.pt is unfinished or from another config; pass the run's overrides")
    geo = scene.thermal if prep.plan.use_thermal else scene.rgb
    s2 = train_stage2(ctx, geo, np.random.default_rng(0).normal(size=(8, 3)), deformable=False, heldout_psnr=lambda *a: None)
    pts = np.random.default_rng(1).normal(size=(cfg.stage3.smoke_points, 3)) if prep.plan.use_smoke else None
    colour, _, trust = estimate(haze_lines(metrics["stages"]))
    if colour is not None and trust > 0.0:  # the smoke colour Stage 3 held, as recorded
        prep.plan.colour, prep.plan.trust = np.asarray(colour, dtype=np.float32), float(trust)
    model = build_scene_model(ctx, s2, prep.plan, pts, scene.smoke_static)
    model = train_stage3(ctx, model, scene.rgb, scene.thermal, prep.plan, None, heldout_psnr=None)
    return prep, model


def main() -> None:
    run, dataset = Path(sys.argv[1]), Path(sys.argv[2])
    overrides = json.loads(sys.argv[3]) if len(sys.argv) > 3 else {}
    with tempfile.TemporaryDirectory() as tmp:
        prep, model = rebuild(run, overrides, Path(tmp))
    rgb = prep.scene.rgb
    truth = load_scene(dataset, prep.cfg.max_width, all_ground_truth=True).rgb.clean  # training frames too
    rows = []
    with torch.no_grad():
        for i, f in enumerate(rgb.frames):
            v = make_view(f.viewmat, f.K, f.width, f.height, f.time, torch.device("cpu"))
            comp = model.render_rgb(v)
            surf = model.render_rgb(v, smoke=False).colors[0].clamp(0, 1).numpy()
            alone = model.render_rgb(v, surface=False)  # the smoke's own colour: its render over its own alpha
            smoke_only, a_alone = alone.colors[0].numpy(), alone.alphas[0, ..., 0].numpy()
            a_model = comp.subset_alphas[0, ..., 0].numpy() if model.smoke is not None else np.zeros(surf.shape[:2])
            a_true = read_exr(dataset / "rgb" / "smoke_alpha" / f"{f.file_stem}.exr")["A"]
            k_model = smoke_only.sum((0, 1)) / max(a_alone.sum(), 1e-6)
            clean = truth[i]
            smoky = a_true > SMOKY
            dense, seen = a_true > DENSE, a_alone > SMOKY
            k_true = implied_smoke_colour(rgb.images[i], clean, a_true, DENSE).mean(0) if dense.any() \
                else np.full(3, np.nan)
            k_seen = (smoke_only[seen] / a_alone[seen][:, None]).mean(0) if seen.any() else np.full(3, np.nan)
            on_smoke = dict(smoky_alpha_true=float(a_true[smoky].mean()),
                            smoky_alpha_model=float(a_model[smoky].mean()),
                            smoky_surf_err=float(np.abs(surf - clean)[smoky].mean()),
                            smoky_input_err=float(np.abs(rgb.images[i] - clean)[smoky].mean()),
                            k_true=k_true.round(3).tolist(), k_seen=k_seen.round(3).tolist()) if smoky.any() else {}
            rows.append(dict(split=f.split, stem=f.file_stem, comp_vs_smoky=psnr(comp.colors[0].clamp(0, 1).numpy(), rgb.images[i]),
                             surf_vs_clean=psnr(surf, clean), input=psnr(rgb.images[i], clean),
                             alpha_true=float(a_true.mean()), alpha_model=float(a_model.mean()),
                             alpha_corr=float(np.corrcoef(a_true.ravel(), a_model.ravel())[0, 1]),
                             bias=(surf - clean).mean((0, 1)).round(3).tolist(), k_model=k_model.round(3).tolist(),
                             **on_smoke))
    for r in rows:
        print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items()))
    for split in ("train", "val", "test"):
        sel = [r for r in rows if r["split"] == split]
        if sel:
            print(f"MEAN {split:5s} n={len(sel)} " + " ".join(
                f"{k}={np.mean([r[k] for r in sel]):.3f}" for k in
                ("comp_vs_smoky", "surf_vs_clean", "input", "alpha_true", "alpha_model", "alpha_corr"))
                  + f" bias={np.mean([r['bias'] for r in sel], 0).round(3).tolist()}")
            sel = [r for r in sel if "smoky_alpha_true" in r]
            if sel:
                print(f"SMOKY {split:5s} n={len(sel)} " + " ".join(
                    f"{k}={np.mean([r[k] for r in sel]):.3f}" for k in
                    ("smoky_alpha_true", "smoky_alpha_model", "smoky_surf_err", "smoky_input_err")) + " " + " ".join(
                    f"{k}={np.nanmean([r[k] for r in sel], 0).round(3).tolist()}" for k in ("k_true", "k_seen")))


main()
