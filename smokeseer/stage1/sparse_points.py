"""Stage 2's starting points from the training RGB frames at their given poses
(``stage2.init_from=images``): features matched across those frames and triangulated at the
known cameras (``scenes.triangulation``).

Why: with no points a run starts from random ones in the box the cameras look at
(``scenes.cameras.scene_bounds``: the point nearest every optical axis). A flyover's axes do not
meet near the scene, so that box can lie far from it (a drawn flyover's centre 45 m above its
cameras, and a Stage 2 that never found the surface): what a capture's camera path looks like
decided whether a run worked. The images fix where the surface is whatever the path; 3DGS starts
from points seen in the images too. Only training frames go in (an evaluation frame's image never
shapes the model), and no smoke mask is used, as in ``poses_from_images`` (on the standard scenes
masking lost features without helping): a feature on drifting smoke does not reproject within
the filters from frame to frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from scenes.scene import SceneData
from scenes.sfm import SfmSettings, cache_dir
from scenes.triangulation import one_camera, triangulate_known


@dataclass
class SparsePoints:
    """The points in the dataset's world (None when none were found), what happened, in one line,
    and the record metrics.json keeps."""

    points: np.ndarray | None
    note: str
    record: dict[str, Any]


def sparse_points(scene: SceneData, settings: SfmSettings = SfmSettings()) -> SparsePoints:
    """The triangulated points of ``scene``'s training RGB frames (frames of differing
    intrinsics, or too few, give none, and the note says why)."""
    rgb = scene.rgb
    idx = rgb.indices("train")
    if len(idx) < 2:
        return SparsePoints(None, "no points from the images (fewer than 2 training RGB frames); Stage 2 starts "
                                  "from random points", {"source": "random", "why": "fewer than 2 training frames"})
    viewmats, Ks = rgb.cameras("train")
    if not one_camera(Ks):
        return SparsePoints(None, "no points from the images (the training RGB frames differ in intrinsics); Stage 2 "
                                  "starts from random points", {"source": "random", "why": "intrinsics differ"})
    tri = triangulate_known([rgb.frames[i].file_stem for i in idx], [rgb.images[i] for i in idx], viewmats, Ks,
                            settings, cache=cache_dir())
    record = {"source": "triangulated from the training RGB frames at their poses", "points": int(len(tri.points)),
              "frames": len(idx), **tri.stats}
    if len(tri.points) == 0:
        return SparsePoints(None, f"no points from the images ({tri.stats.get('tracks', 0)} feature tracks, none "
                                  "passing the reprojection and angle filters); Stage 2 starts from random points",
                            {**record, "source": "random"})
    note = (f"{len(tri.points)} starting points triangulated from {len(idx)} training RGB frames at their poses "
            f"(of {tri.stats['tracks']} feature tracks{', from the cache' if tri.stats.get('cached') else ''})")
    return SparsePoints(tri.points, note, record)
