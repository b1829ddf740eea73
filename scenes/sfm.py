"""Camera poses from RGB images alone: structure from motion with COLMAP (``pycolmap``).

SIFT features outside the smoke masks (moving smoke never triangulates), exhaustive matching
for short sequences and sequential matching with quadratic look-back (a frame also meets the
frames 2, 4, 8, ... steps back, the loop candidates a video needs without a downloaded
vocabulary tree) for long ones, then COLMAP's incremental mapper with bundle adjustment. Known
intrinsics are held fixed. The result is cached by the digest of the images, masks, intrinsics
and settings, so a rerun of the same capture costs nothing.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from contracts.atomic import atomic_path
from contracts.errors import DatasetError

CACHE_ENV = "SMOKESEER_SFM_CACHE"
MATCHERS = ("auto", "exhaustive", "sequential")


class SfmError(DatasetError):
    """Structure from motion could not pose enough frames; the message says how many and why."""


@dataclass(frozen=True)
class SfmSettings:
    """``exhaustive_max``: up to this many frames every pair is matched (``matcher=auto``);
    ``overlap``: sequential matching's neighbours on each side; ``min_registered``: the fraction
    of frames that must register, or the run stops (frames that do not are dropped and named);
    ``min_width``: narrower frames are upsampled (bicubic, by an integer factor) before SIFT,
    which on the 200 px standard scenes halved the rotation error (more, better-placed features);
    ``filter_max_reproj_error`` (pixels of the upsampled frames) and ``filter_min_tri_angle``
    (degrees): the mapper drops 3D points that reproject worse or are seen under a smaller angle,
    so features on drifting smoke and far, poorly triangulated points do not bend the poses; 2 px
    (COLMAP's 4) lowered the rotation error on all four held-out standard scenes that register,
    while a 4° angle cost one of them its registration. ``peak_threshold``: the least
    difference-of-Gaussians response SIFT keeps (COLMAP's 0.0067); smoke lowers the contrast of
    what lies behind it, and 0.002 (about 1.5-2.5× the features) lowered the centre error on all
    four held-out scenes that register and the rotation error on three (the fourth moved 0.05°).
    ``far_frames``: after bundle adjustment each registered frame's pose is estimated again
    (LO-RANSAC PnP, then refinement) from only the 3D points that at least two frames this many or
    more places away in the sequence also see (frames in capture order): smoke changes from frame
    to frame and the surface does not, so features on smoke that neighbouring frames share no
    longer pull a smoky frame; 0 is off (benchmarks/results/sfm_poses/README.md)."""

    matcher: str = "auto"
    min_width: int = 400
    exhaustive_max: int = 150
    overlap: int = 10
    max_features: int = 4096
    min_registered: float = 0.95
    threads: int = 1
    seed: int = 0
    filter_max_reproj_error: float = 2.0
    filter_min_tri_angle: float = 1.5
    peak_threshold: float = 0.002
    far_frames: int = 3

    def __post_init__(self) -> None:
        if self.matcher not in MATCHERS:
            raise ValueError(f"sfm.matcher: {self.matcher!r} is not one of {', '.join(MATCHERS)}")
        if not self.peak_threshold > 0.0:
            raise ValueError(f"sfm.peak_threshold: {self.peak_threshold} is not positive")
        if self.min_width < 0:
            raise ValueError(f"sfm.min_width: {self.min_width} is negative")
        if not 0.0 < self.min_registered <= 1.0:
            raise ValueError(f"sfm.min_registered: {self.min_registered} is not in (0, 1]")
        if not self.filter_max_reproj_error > 0.0:
            raise ValueError(f"sfm.filter_max_reproj_error: {self.filter_max_reproj_error} is not positive")
        if self.far_frames < 0:
            raise ValueError(f"sfm.far_frames: {self.far_frames} is negative")
        if not 0.0 <= self.filter_min_tri_angle < 90.0:
            raise ValueError(f"sfm.filter_min_tri_angle: {self.filter_min_tri_angle} is not in [0, 90) degrees")

    @classmethod
    def from_overrides(cls, values: Mapping[str, Any], text: bool = False) -> SfmSettings:
        """The defaults with ``values`` set, each field checked by name: typed values (JSON: an
        integer may stand for a float, text may not) or, with ``text``, strings read as the field's
        type (the command line). Raises ValueError naming ``sfm.FIELD``."""
        defaults = {f.name: f.default for f in fields(cls)}
        typed: dict[str, Any] = {}
        for key, value in values.items():
            if key not in defaults:
                raise ValueError(f"sfm.{key}: unknown field (known: {', '.join(defaults)})")
            want = type(defaults[key])
            kind = "a string" if want is str else "an integer" if want is int else "a number"
            if text:
                try:
                    typed[key] = want(value)
                except ValueError:
                    raise ValueError(f"sfm.{key}: {value!r} is not {kind}") from None
            elif isinstance(value, bool) or not isinstance(value, (int, float) if want is float else want):
                raise ValueError(f"sfm.{key}: {value!r} is not {kind}")
            else:
                typed[key] = want(value)
        return cls(**typed)


@dataclass
class SfmResult:
    """Poses of the registered frames (OpenCV world-to-camera, SfM units), their shared
    intrinsics, and the sparse points (with colours in [0, 1]) that can initialise Stage 2."""

    names: list[str]
    registered: np.ndarray
    viewmats: np.ndarray
    K: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)

    def record(self) -> dict[str, Any]:
        """What metrics.json keeps: counts, timings, the cache key and the unregistered frames."""
        return {"source": "sfm", "frames": len(self.names), "registered": int(self.registered.sum()),
                "unregistered": [n for n, ok in zip(self.names, self.registered) if not ok],
                "points": int(len(self.points)), **self.stats}

    def describe(self) -> str:
        """One log line: how many frames registered, the points, the intrinsics, the matcher and
        where the time went (or that the cache answered)."""
        r = self.record()
        timing = (f"from the cache ({r['load_s']} s)" if r.get("cached") else
                  f"extract {r['extract_s']} s, match {r['match_s']} s, map {r['map_s']} s")
        far = (f", {r['far_posed']} posed again from points frames {r['far_frames']} or more apart see"
               if r.get("far_frames") else "")
        return (f"{r['registered']} of {r['frames']} RGB frames registered, {r['points']} points, intrinsics "
                f"{r['intrinsics']}, matcher {r['matcher']}{far}, {timing}")


def cache_dir() -> Path | None:
    """``$SMOKESEER_SFM_CACHE`` (empty: no cache), else ``$XDG_CACHE_HOME`` or ``~/.cache``,
    ``/smokeseer/sfm``."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        return Path(env) if env else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "smokeseer" / "sfm"


def to_uint8(image: np.ndarray) -> np.ndarray:
    """An RGB frame as COLMAP reads it: 8-bit, 3 channels (16-bit and float frames are scaled)."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    a = a[..., :3]
    if a.dtype == np.uint8:
        return np.ascontiguousarray(a)
    if a.dtype == np.uint16:
        return (a.astype(np.float64) / 257.0).round().astype(np.uint8)
    return (np.clip(a.astype(np.float64), 0.0, 1.0) * 255.0).round().astype(np.uint8)


def stretched(frames: list[np.ndarray], low: float = 1.0, high: float = 99.0) -> list[np.ndarray]:
    """Frames of raw values (thermal counts fill a narrow band of 16 bits) mapped to [0, 1] by one
    percentile stretch over all of them, so SIFT sees their contrast and every frame the same curve."""
    stack = np.stack([np.asarray(f, np.float64) for f in frames])
    lo, hi = np.percentile(stack, [low, high])
    return [np.clip((f - lo) / max(hi - lo, 1e-12), 0.0, 1.0) for f in stack]


def digest(names: list[str], images: list[np.ndarray], masks: list[np.ndarray] | None,
           K: np.ndarray | None, settings: SfmSettings) -> str:
    """SHA-256 over the settings, the pycolmap version, the intrinsics, and every frame's name,
    shape and bytes (and its mask's): the cache key."""
    import pycolmap

    h = hashlib.sha256(json.dumps({"settings": asdict(settings), "pycolmap": pycolmap.__version__,
                                   "K": None if K is None else np.asarray(K, float).round(9).tolist()},
                                  sort_keys=True).encode())
    for i, (name, img) in enumerate(zip(names, images)):
        h.update(f"\0{name}\0{img.shape}\0".encode())
        h.update(np.ascontiguousarray(img).tobytes())
        if masks is not None:
            h.update(np.packbits(np.asarray(masks[i], bool)).tobytes())
    return h.hexdigest()


def run_sfm(names: list[str], images: list[np.ndarray], masks: list[np.ndarray] | None = None,
            K: np.ndarray | None = None, settings: SfmSettings = SfmSettings(),
            cache: Path | None = None, what: str = "RGB frames") -> SfmResult:
    """Pose ``images`` (uint8 H×W×3, one camera, in capture order) by SfM; ``masks`` (True = smoke)
    exclude features.

    ``K``, when given, is held fixed; otherwise one pinhole camera is estimated. Raises
    ``SfmError`` (one line) when fewer than ``settings.min_registered`` of the frames register.
    ``cache`` is the cache folder (None: no cache).
    """
    if len(names) != len(images) or (masks is not None and len(masks) != len(images)):
        raise ValueError("run_sfm: names, images and masks must have one entry per frame")
    if len(set(names)) != len(names):
        raise ValueError("run_sfm: frame names must be unique")
    images = [to_uint8(a) for a in images]
    if len({a.shape for a in images}) != 1:
        raise SfmError(f"sfm: the {what} differ in size ({sorted({a.shape[:2] for a in images})}); one camera is assumed")
    if masks is not None and any(np.shape(m) != a.shape[:2] for m, a in zip(masks, images)):
        raise ValueError("run_sfm: every mask must have its frame's height and width")
    key = digest(names, images, masks, K, settings)
    cached = None if cache is None else Path(cache) / f"{key}.npz"
    if cached is not None and cached.is_file():
        t0 = time.perf_counter()
        result = _load(cached)
        result.stats.update(cached=True, load_s=round(time.perf_counter() - t0, 3))
        _check(result, settings, what)
        return result
    result = _solve(names, images, masks, K, settings, what)
    result.stats.update(digest=key, cached=False)
    if cached is not None:
        _save(cached, result)
    _check(result, settings, what)
    return result


def _check(result: SfmResult, settings: SfmSettings, what: str) -> None:
    n, reg = len(result.names), int(result.registered.sum())
    need = int(np.ceil(settings.min_registered * n - 1e-9))
    if reg < max(need, 2):
        raise SfmError(f"sfm: {reg} of {n} {what} registered (need {max(need, 2)}, {100 * settings.min_registered:g} %): "
                       f"{result.stats.get('why', 'see the statistics')}")


@dataclass
class FeatureDatabase:
    """COLMAP's database of SIFT features and geometrically verified matches for frames written as
    ``files`` (upsampled by ``up``): what mapping and triangulation both start from."""

    path: Path
    image_dir: Path
    files: list[str]
    up: int
    keypoints: np.ndarray
    keep: list[float]
    pairs: int
    exhaustive: bool
    timings: dict[str, float]


def match_features(work: Path, images: list[np.ndarray], masks: list[np.ndarray] | None, K: np.ndarray | None,
                   settings: SfmSettings) -> FeatureDatabase:
    """Write ``images`` (uint8, one size) under ``work``, extract SIFT outside ``masks`` (True =
    smoke) and match them (exhaustive or sequential, ``settings.matcher``), with ``K`` held fixed
    when given."""
    import pycolmap
    from PIL import Image

    pycolmap.logging.minloglevel = 3  # COLMAP logs every step (and its failures) to stderr; ours is the one line
    timings: dict[str, float] = {}
    h, w = images[0].shape[:2]
    up = max(1, -(-settings.min_width // w))
    img_dir, mask_dir = work / "images", work / "masks"
    for d in (img_dir, mask_dir):
        d.mkdir()
    files = [f"{i:06d}.png" for i in range(len(images))]
    keep = []
    for i, (f, img) in enumerate(zip(files, images)):
        valid = np.ones((h, w), bool) if masks is None else ~np.asarray(masks[i], bool)
        keep.append(float(valid.mean()))
        picture, mask = Image.fromarray(img), Image.fromarray((valid * 255).astype(np.uint8))
        if up > 1:
            picture = picture.resize((w * up, h * up), Image.BICUBIC)
            mask = mask.resize((w * up, h * up), Image.NEAREST)
        picture.save(img_dir / f)
        mask.save(mask_dir / f"{f}.png")
    db_path = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.mask_path = str(mask_dir)
    if K is not None:
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(f"{up * v:.12g}" for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    else:
        reader.camera_model = "SIMPLE_PINHOLE"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = settings.threads
    extraction.sift.max_num_features = settings.max_features
    extraction.sift.peak_threshold = settings.peak_threshold
    t0 = time.perf_counter()
    pycolmap.extract_features(db_path, img_dir, image_names=files, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    timings["extract_s"] = time.perf_counter() - t0
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = settings.threads
    exhaustive = settings.matcher == "exhaustive" or (settings.matcher == "auto"
                                                      and len(files) <= settings.exhaustive_max)
    t0 = time.perf_counter()
    if exhaustive:
        pycolmap.match_exhaustive(db_path, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = settings.overlap
        pairing.quadratic_overlap = True
        pairing.num_threads = settings.threads
        pycolmap.match_sequential(db_path, matching_options=matching, pairing_options=pairing,
                                  device=pycolmap.Device.cpu)
    timings["match_s"] = time.perf_counter() - t0
    db = pycolmap.Database.open(db_path)
    ids = {im.name: im.image_id for im in db.read_all_images()}
    keypoints = np.array([db.num_keypoints_for_image(ids[f]) for f in files])
    pairs = int(db.num_verified_image_pairs())
    db.close()
    return FeatureDatabase(db_path, img_dir, files, up, keypoints, keep, pairs, exhaustive, timings)


def _solve(names: list[str], images: list[np.ndarray], masks: list[np.ndarray] | None, K: np.ndarray | None,
           settings: SfmSettings, what: str) -> SfmResult:
    import pycolmap

    with tempfile.TemporaryDirectory(prefix="sfm-") as tmp:
        work = Path(tmp)
        out_dir = work / "sparse"
        out_dir.mkdir()
        feats = match_features(work, images, masks, K, settings)
        db_path, img_dir, files, up = feats.path, feats.image_dir, feats.files, feats.up
        keypoints, keep, pairs, exhaustive, timings = (feats.keypoints, feats.keep, feats.pairs, feats.exhaustive,
                                                       feats.timings)
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = settings.threads
        options.random_seed = settings.seed
        options.mapper.num_threads = settings.threads
        options.mapper.random_seed = settings.seed
        options.mapper.filter_max_reproj_error = settings.filter_max_reproj_error
        options.mapper.filter_min_tri_angle = settings.filter_min_tri_angle
        if K is not None:
            options.ba_refine_focal_length = False
            options.ba_refine_principal_point = False
            options.ba_refine_extra_params = False
            options.mapper.abs_pose_refine_focal_length = False
            options.mapper.abs_pose_refine_extra_params = False
        t0 = time.perf_counter()
        models = pycolmap.incremental_mapping(db_path, img_dir, out_dir, options=options)
        timings["map_s"] = time.perf_counter() - t0
    stats: dict[str, Any] = {
        "upsampled": up, "matcher": "exhaustive" if exhaustive else f"sequential (overlap {settings.overlap}, quadratic look-back)",
        "intrinsics": "given, held fixed" if K is not None else "estimated (one pinhole camera)",
        "keypoints_median": float(np.median(keypoints)), "keypoints_min": int(keypoints.min()),
        "unmasked_fraction_mean": round(float(np.mean(keep)), 4), "verified_pairs": pairs,
        "models": len(models), **{k: round(v, 3) for k, v in timings.items()}}
    best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
    registered = np.zeros(len(files), bool)
    viewmats = np.tile(np.eye(4), (len(files), 1, 1))
    index = {f: i for i, f in enumerate(files)}
    if best is None:
        stats["why"] = _why_none(keypoints, keep, pairs, what)
        return SfmResult(list(names), registered, viewmats, np.full((3, 3), np.nan), np.zeros((0, 3)),
                         np.zeros((0, 3)), stats)
    for image in best.images.values():
        if image.has_pose:
            i = index[image.name]
            registered[i] = True
            viewmats[i, :3, :] = image.cam_from_world().matrix()
    if settings.far_frames > 0:
        far = far_point_poses(best, index, settings.far_frames)
        for i, viewmat in far.items():
            viewmats[i] = viewmat
        stats["far_frames"] = settings.far_frames
        stats["far_posed"] = len(far)
    K_found = next(iter(best.cameras.values())).calibration_matrix()
    K_found[:2] /= up
    points = np.array([p.xyz for p in best.points3D.values()]).reshape(-1, 3)
    colors = np.array([p.color for p in best.points3D.values()], dtype=np.float64).reshape(-1, 3) / 255.0
    stats["mean_reprojection_error_px"] = round(float(best.compute_mean_reprojection_error()), 4)
    if not registered.all():
        low = int((keypoints[~registered] < 50).sum())
        stats["why"] = (f"{len(models)} separate model(s), the largest holds {int(registered.sum())} frames; "
                        f"{low} unregistered frames have < 50 features outside the smoke masks, median "
                        f"{float(np.median(keypoints)):.0f} features per frame, {100 * float(np.mean(keep)):.0f} % of "
                        "the pixels outside the masks on average")
    return SfmResult(list(names), registered, viewmats, K_found, points, colors, stats)


FAR_MIN_POINTS = 12
"""A frame with fewer far-seen points keeps its bundle-adjusted pose."""


def far_point_poses(reconstruction: Any, index: dict[str, int], far: int) -> dict[int, np.ndarray]:
    """World-to-camera matrices of the registered frames (by sequence position, ``index`` maps an
    image name to it) estimated by PnP from the 3D points that at least two frames ``far`` or more
    positions away also see; frames with fewer than ``FAR_MIN_POINTS`` such points, or whose PnP
    fails, are left out."""
    import pycolmap

    position = {image.image_id: index[image.name] for image in reconstruction.images.values()}
    camera = next(iter(reconstruction.cameras.values()))
    poses: dict[int, np.ndarray] = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        i = position[image.image_id]
        xy, xyz = [], []
        for p in image.points2D:
            if p.has_point3D():
                point = reconstruction.points3D[p.point3D_id]
                if sum(abs(position[el.image_id] - i) >= far for el in point.track.elements) >= 2:
                    xy.append(p.xy)
                    xyz.append(point.xyz)
        if len(xy) < FAR_MIN_POINTS:
            continue
        found = pycolmap.estimate_and_refine_absolute_pose(np.array(xy), np.array(xyz), camera)
        if found is not None:
            viewmat = np.eye(4)
            viewmat[:3, :] = found["cam_from_world"].matrix()
            poses[i] = viewmat
    return poses


def _why_none(keypoints: np.ndarray, keep: list[float], pairs: int, what: str) -> str:
    """Why no model at all: the likeliest cause first."""
    if float(np.mean(keep)) < 0.05:
        return (f"the smoke masks cover {100 * (1 - float(np.mean(keep))):.0f} % of the pixels on average, "
                "leaving too little static surface for features")
    if float(np.median(keypoints)) < 50:
        return f"the {what} have a median of {float(np.median(keypoints)):.0f} features outside the smoke masks (low texture or smoke)"
    return f"no initial pair could be triangulated ({pairs} image pairs matched with geometric verification)"


def _save(path: Path, result: SfmResult) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, names=np.array(result.names), registered=result.registered, viewmats=result.viewmats,
                     K=result.K, points=result.points, colors=result.colors,
                     stats=np.array(json.dumps(result.stats)))


def _load(path: Path) -> SfmResult:
    with np.load(path, allow_pickle=False) as z:
        return SfmResult([str(n) for n in z["names"]], z["registered"], z["viewmats"], z["K"], z["points"],
                         z["colors"], json.loads(str(z["stats"])))
