"""Camera poses from the images alone against the truth of generated datasets.

For each dataset: SfM (``scenes.sfm``) on the smoky RGB frames at full size with the known
intrinsics held fixed, the features masked where the true smoke opacity exceeds a threshold
(or not at all), then the thermal poses from the rig (``scenes.rig``) with the extrinsic given
(the generator's baseline, scaled to SfM units by the alignment), with it estimated (the rotation
from SfM on the smoky thermal frames, ``scenes.rig.estimate_rig_rotation``, zero lever) and with
it assumed (identity, zero lever). The SfM poses are brought onto the truth by a Sim(3): its rotation is the chordal mean
of the per-frame rotations between the two frames (camera orientations), its scale and shift the
least-squares fit of the camera centres. Umeyama on the centres alone cannot score rotations: on
the flyovers (straight paths) the rotation about the path is undetermined by the centres (it
returned 127-152 degree errors), and on orbits it tilts with the centre noise. The trajectory
error is given both ways: ``centre_rmse_*`` after the alignment above, and ``ate_rmse_*``, the
absolute trajectory error of the TUM RGB-D benchmark (Umeyama Sim(3) on the centres, the
least-squares optimum, so never above the first; a rotation left free about a straight path
moves no centre).

    python benchmarks/sfm_poses.py DATASET... [--mask-alpha none 0.5] [--set FIELD=VALUE ...] [--no-thermal]
        [--out benchmarks/results/sfm_poses]

Writes ``OUT/NAME.csv`` (``--name``, default sfm_poses; one row per dataset and mask setting) and
``OUT/NAME_frames.csv`` (one row per registered frame: its errors beside the true smoke over it); each SfM run is timed on its
own (no cache) and the load average is recorded. ``--set`` overrides ``SfmSettings`` fields (recorded in the
``settings`` column, with the mapper's filter values in effect), so settings can be compared on scenes held out
from the ones they are reported on; ``--no-thermal`` skips the thermal SfM (and the rig estimate) when only RGB poses matter.
"""
from __future__ import annotations

import argparse
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from contracts.atomic import write_rows_csv
from contracts.dataset_format import file_path, load_transforms, pass_file, read_pass_image, transforms_name
from contracts.imageio import read_png
from scenes.cameras import c2w_gl_to_viewmat, camera_center, intrinsics, scene_bounds
from scenes.generated import spec_rig
from scenes.rig import RigExtrinsic, estimate_rig_rotation, thermal_from_rig
from scenes.sfm import SfmError, SfmResult, SfmSettings, run_sfm, stretched
from scenes.similarity import umeyama


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0))))


def truth(root: Path, modality: str) -> tuple[dict, np.ndarray, np.ndarray]:
    """The transforms, world-to-camera matrices (OpenCV) and timestamps of one camera."""
    data = load_transforms(root, modality)
    views = np.stack([c2w_gl_to_viewmat(np.array(f["transform_matrix"])) for f in data["frames"]])
    return data, views, np.array([float(f["timestamp_s"]) for f in data["frames"]])


def baseline_cv(root: Path) -> np.ndarray:
    """The generator's thermal baseline in OpenCV axes (the rig's lever arm, metres)."""
    return spec_rig(root).lever_arm_m


@dataclass(frozen=True)
class Alignment:
    """x_ref = scale · rotation · x_est + translation."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def viewmat(self, v: np.ndarray) -> np.ndarray:
        """An estimated world-to-camera matrix moved into the reference world."""
        out = np.eye(4)
        out[:3, :3] = v[:3, :3] @ self.rotation.T
        out[:3, 3] = -out[:3, :3] @ (self.scale * self.rotation @ camera_center(v) + self.translation)
        return out


def align(est: np.ndarray, ref: np.ndarray) -> Alignment:
    """The Sim(3) taking estimated poses onto the true ones: rotation from the orientations
    (``R_ref ≈ R_est · Aᵀ`` per frame, chordal mean of ``R_refᵀ R_est``), then scale and shift
    from the centres by least squares."""
    per_frame = np.einsum("nji,njk->nik", ref[:, :3, :3], est[:, :3, :3])
    u, _, vt = np.linalg.svd(per_frame.sum(0))
    rotation = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    c_est = np.stack([camera_center(v) for v in est]) @ rotation.T
    c_ref = np.stack([camera_center(v) for v in ref])
    d_est, d_ref = c_est - c_est.mean(0), c_ref - c_ref.mean(0)
    scale = float((d_est * d_ref).sum() / max((d_est ** 2).sum(), 1e-18))
    return Alignment(scale, rotation, c_ref.mean(0) - scale * c_est.mean(0))


def frame_errors(est: np.ndarray, ref: np.ndarray, sim: Alignment) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's rotation error (deg) and centre distance (m) after ``sim``."""
    moved = np.stack([sim.viewmat(v) for v in est])
    rot = np.array([rotation_error_deg(m[:3, :3], r[:3, :3]) for m, r in zip(moved, ref)])
    dist = np.linalg.norm(np.stack([camera_center(m) - camera_center(r) for m, r in zip(moved, ref)]), axis=1)
    return rot, dist


def pose_errors(est: np.ndarray, ref: np.ndarray, sim: Alignment, extent: float) -> dict[str, float]:
    """Median and max rotation error (deg) and centre RMSE (fraction of ``extent``) after ``sim``."""
    return summarise(*frame_errors(est, ref, sim), extent)


def summarise(rot: np.ndarray, dist: np.ndarray, extent: float) -> dict[str, float]:
    """``pose_errors`` from the per-frame errors."""
    return {"rot_median_deg": float(np.median(rot)), "rot_max_deg": float(rot.max()),
            "centre_rmse_m": float(np.sqrt(np.mean(dist ** 2))),
            "centre_rmse_frac": float(np.sqrt(np.mean(dist ** 2)) / extent)}


def ate_rmse_m(est: np.ndarray, ref: np.ndarray) -> float:
    """Absolute trajectory error: RMSE of the camera centres after the least-squares Sim(3) of
    the centres alone (Umeyama), as the TUM RGB-D benchmark defines it."""
    c_est = np.stack([camera_center(v) for v in est])
    c_ref = np.stack([camera_center(v) for v in ref])
    moved = umeyama(c_est, c_ref).apply(c_est)
    return float(np.sqrt(np.mean(np.sum((moved - c_ref) ** 2, axis=1))))


def evaluate(root: Path, mask_alpha: float | None, settings: SfmSettings,
             thermal: tuple[SfmResult | None, str]) -> tuple[dict[str, object], list[dict[str, object]]]:
    """The scene's row, and one row per registered frame: its errors beside the true smoke over it
    (scoring only; SfM never reads it unless ``mask_alpha`` masks features)."""
    rgb, views, times = truth(root, "rgb")
    _, th_views, th_times = truth(root, "thermal")
    names = [f["file_stem"] for f in rgb["frames"]]
    images = [read_png(root / "rgb" / "smoky" / f"{n}.png") for n in names]
    pf = pass_file("rgb", "smoke_alpha", "exr")
    alpha = [read_pass_image(file_path(root, pf, n), pf, (rgb["h"], rgb["w"])) for n in names]
    masks = None if mask_alpha is None else [a > mask_alpha for a in alpha]
    K = intrinsics(rgb["fl_x"], rgb["fl_y"], rgb["cx"], rgb["cy"])
    bounds = scene_bounds(views, np.repeat(K[None], len(views), 0), np.full(len(views), rgb["w"]))
    row: dict[str, object] = {"scene": root.name, "mask_alpha": "none" if mask_alpha is None else mask_alpha,
                              "frames": len(names), "size": f"{rgb['w']}x{rgb['h']}",
                              "smoke_covered_px": round(float(np.mean(masks)), 4) if masks is not None else ""}
    t0 = time.perf_counter()
    try:
        res = run_sfm(names, images, masks, K, settings, cache=None)
    except SfmError as exc:
        row.update(wall_s=round(time.perf_counter() - t0, 2), registered=0, status=str(exc))
        return row, []
    wall = time.perf_counter() - t0
    reg = res.registered
    sim = align(res.viewmats[reg], views[reg])
    rot, dist = frame_errors(res.viewmats[reg], views[reg], sim)
    errs = summarise(rot, dist, bounds.extent)
    ate = ate_rmse_m(res.viewmats[reg], views[reg])
    errs.update(ate_rmse_m=ate, ate_rmse_frac=ate / bounds.extent)
    frames = [{"scene": root.name, "mask_alpha": row["mask_alpha"], "frame": names[i], "timestamp_s": times[i],
               "true_alpha_mean": round(float(alpha[i].mean()), 4),
               "true_alpha_over_half": round(float(np.mean(alpha[i] > 0.5)), 4),
               "rot_deg": round(float(r), 4), "centre_err_frac": round(float(d) / bounds.extent, 5)}
              for i, r, d in zip(np.flatnonzero(reg), rot, dist)]
    row.update(wall_s=round(wall, 2), extract_s=res.stats["extract_s"], match_s=res.stats["match_s"],
               map_s=res.stats["map_s"], registered=int(reg.sum()), registered_frac=round(float(reg.mean()), 4),
               keypoints_median=res.stats["keypoints_median"], points=len(res.points),
               reproj_px=res.stats["mean_reprojection_error_px"], extent_m=round(bounds.extent, 4),
               **{k: round(v, 5) for k, v in errs.items()})
    rig = RigExtrinsic(np.eye(3), baseline_cv(root), metres_per_unit=sim.scale)
    extrinsics = {"given": rig, "assumed": None}
    th_res, row["rig_estimate"] = thermal
    if th_res is not None:
        try:
            est = estimate_rig_rotation(res.viewmats[reg], times[reg], th_res.viewmats[th_res.registered],
                                        th_times[th_res.registered])
            extrinsics["estimated"] = RigExtrinsic(est.rotation, np.zeros(3))
            row["rig_estimate"] += f", residual {est.residual_deg:.3f} deg"
        except ValueError as exc:
            row["rig_estimate"] += f", not estimated: {exc}"
    for label, extrinsic in extrinsics.items():
        th_est, _ = thermal_from_rig(res.viewmats[reg], times[reg], th_times, extrinsic)
        th = pose_errors(th_est, th_views, sim, bounds.extent)
        row.update({f"thermal_{label}_rot_median_deg": round(th["rot_median_deg"], 5),
                    f"thermal_{label}_rot_max_deg": round(th["rot_max_deg"], 5),
                    f"thermal_{label}_centre_rmse_m": round(th["centre_rmse_m"], 5)})
    row["status"] = "ok"
    return row, frames


def thermal_sfm(root: Path, settings: SfmSettings) -> tuple[SfmResult | None, str]:
    """SfM on the smoky thermal frames (percentile-stretched), for the rig estimate; None and why
    when too few register."""
    th, _, _ = truth(root, "thermal")
    names = [f["file_stem"] for f in th["frames"]]
    frames = stretched([read_png(root / "thermal" / "smoky" / f"{n}.png") for n in names])
    K = intrinsics(th["fl_x"], th["fl_y"], th["cx"], th["cy"])
    t0 = time.perf_counter()
    try:
        res = run_sfm(names, frames, None, K, replace(settings, min_registered=0.5), cache=None, what="thermal frames")
    except SfmError as exc:
        return None, f"not estimated: {exc}"
    return res, (f"thermal SfM {int(res.registered.sum())}/{len(names)} frames in {time.perf_counter() - t0:.1f} s "
                 f"({res.stats['keypoints_median']:.0f} features per frame)")


def parse_settings(pairs: list[str]) -> SfmSettings:
    """``FIELD=VALUE`` overrides of ``SfmSettings``, each value read as its field's type."""
    overrides: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise ValueError(f"--set {pair}: expected FIELD=VALUE")
        overrides[key] = value
    return SfmSettings.from_overrides(overrides, text=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--mask-alpha", nargs="+", default=["none", "0.5"],
                    help="smoke-opacity thresholds above which features are masked ('none': no mask)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/sfm_poses"))
    ap.add_argument("--name", default="sfm_poses", help="the CSV's name in --out (without .csv)")
    ap.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE", help="override SfmSettings fields")
    ap.add_argument("--no-thermal", action="store_true", help="RGB poses only: no thermal SfM (no rig estimate)")
    args = ap.parse_args()
    try:
        settings = parse_settings(args.set)
    except ValueError as exc:
        ap.error(str(exc))
    rows, frame_rows = [], []
    for root in args.datasets:
        if not (root / transforms_name("rgb")).is_file():
            ap.error(f"{root}: no {transforms_name('rgb')} (not a generated dataset)")
        thermal = (None, "not run (--no-thermal)") if args.no_thermal else thermal_sfm(root, settings)
        for m in args.mask_alpha:
            row, frames = evaluate(root, None if m == "none" else float(m), settings, thermal)
            frame_rows += frames
            row.update(settings=" ".join(args.set) or "defaults",
                       filter_max_reproj_error_px=settings.filter_max_reproj_error,
                       filter_min_tri_angle_deg=settings.filter_min_tri_angle)
            row["load_1min"] = round(os.getloadavg()[0], 2)
            print(", ".join(f"{k}={v}" for k, v in row.items()), flush=True)
            rows.append(row)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    write_rows_csv(args.out / f"{args.name}.csv", [{k: r.get(k, "") for k in keys} for r in rows])
    if frame_rows:
        write_rows_csv(args.out / f"{args.name}_frames.csv", frame_rows)


if __name__ == "__main__":
    main()
