"""Typed training configuration: profiles, loss weights, deformation and densification.

Every default names its source in docs/method.md. Profiles are full configs; overrides use
dotted keys (``"stage3.iterations"``) so the CLI, the metrics harness and tests share one path.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

from scenes.thermal_scale import check_thermal_scale

MODES: tuple[str, ...] = (
    "full",
    "rgb-only",
    "no-smoke-alpha",
    "no-smoke-color",
    "no-mono",
    "no-depth",
    "no-mask",
    "deformable-3dgs",
)
PROFILES: tuple[str, ...] = ("quick", "standard", "paper")
SMOKE_COLOR_SOURCES: tuple[str, ...] = ("learned", "haze-lines")
DENSIFY_UNDER_CAP: tuple[str, ...] = ("index", "gradient")
SURFACE_INITS: tuple[str, ...] = ("thermal", "by-smoke-colour")
CARVE_BY: tuple[str, ...] = ("depth", "depth-and-smoke")
THERMAL_SURFACE_GRAD: tuple[str, ...] = ("all", "smoky-views")
BACKGROUND_FROM: tuple[str, ...] = ("all", "clear-pixels")
MAX_THERMAL_SUPERSAMPLE = 4
"""Sub-pixels a side of a thermal pixel (``stage3.thermal_supersample``): at 4 the thermal render is
16 times the work, past which a pixel's Gaussians are already resolved at the RGB's scale."""
INIT_FROM: tuple[str, ...] = ("random", "images")
POSE_SOURCES: tuple[str, ...] = ("given", "sfm")
MASK_FLOOR_WHERE: tuple[str, ...] = ("all", "never-clear", "estimated-meeting", "estimated-bound")
MASK_FLOOR_MEETING: tuple[str, ...] = ("present", "trusted")
DEFORM_KINDS: tuple[str, ...] = ("mlp", "fourier", "planes")
LPIPS_NETS: tuple[str, ...] = ("alex", "vgg")


@dataclass
class LossWeights:
    """Paper λ's (render, smoke_alpha, smoke_color, mono, depth, mask) plus the public code's
    penalty on mean smoke thermal opacity (weight is ours: the paper does not state it)."""

    render: float = 1.0
    thermal: float = 1.0
    """The thermal render term's weight as a share of ``render`` (the paper weighs both alike)."""
    smoke_alpha: float = 0.1
    smoke_color: float = 0.05
    mono: float = 0.1
    depth: float = 2.0
    mask: float = 0.5
    thermal_smoke_opacity: float = 0.01
    dssim: float = 0.2
    mask_alpha_floor: float = 0.4
    """Inside the mask, smoke alpha at or above this counts as full smoke (the public code's 0.4;
    1 is the paper's plain L1). It sets how much of a dense smoke's darkening the surface may
    absorb: at 0.4 a pixel whose smoke is 0.8 opaque can be explained by half that smoke over a
    darker surface (docs/experiments/2026-11-24-dense-smoke-colour.md)."""
    divergence_factor: float = 20.0
    """A stage whose loss, smoothed over ``divergence_span`` iterations, rises past this many times
    its best smoothed value stops as diverged (``smokeseer/train/divergence.py``). The committed runs'
    rose at most 5.4× over their best (docs/method.md, "Input and optimisation checks")."""
    divergence_span: int = 100
    """Iterations the divergence watch smooths the loss over (its moving average's span)."""
    mask_floor_where: str = "all"
    """Which masked pixels the floor acts on (``smokeseer/train/mask_floor.py``): "all";
    "never-clear", those whose surface point no other training view sees smoke-free, so that
    thin smoke over a surface seen clear elsewhere is not forced up to the floor; or
    "estimated-meeting", those whose smoke alpha, read off the smoky frames by the image formation
    with the colour where the haze lines meet (held, or too bright to hold), may reach the floor,
    and where the lines do not meet (thin smoke) none that no other view sees clear; or
    "estimated-bound", no step at all: every masked pixel is pushed up to the alpha the same
    estimate proves there (the reading off a clear view, else the lower bound), a floor of its own
    (``mask_floor.estimated_alpha_bound``)."""
    mask_floor_meeting: str = "present"
    """How the "estimated" floors read where the haze lines meet: "present", wherever enough of the
    lines meet to give a point (a whole run's floor then turns on one line more or less, as
    food_plate's did between two float setups: 106 lines against fewer than 100); "trusted", as a
    blend of the rule with the point and the rule without it, weighted by how far the point is
    trusted (``haze_lines.SmokeColourEstimate.meeting_weight``), so the floor moves little when the
    line count does."""


@dataclass
class DeformConfig:
    """Deformable 3DGS MLP defaults: 8×256, skip at layer 4, 10 xyz / 6 t frequencies. Its
    warm-up is a schedule of the stage that trains it (``stage2.deform_warmup`` for the
    deformable-3dgs baseline, ``stage3.deform_warmup`` for the smoke)."""

    depth: int = 8
    width: int = 256
    skip_layer: int = 4
    xyz_frequencies: int = 10
    t_frequencies: int = 6
    lr_init: float = 8e-4
    lr_final: float = 1.6e-6
    predict_rotation_scale: bool = False  # smoke offsets in rotation and log-scale too (the paper)
    kind: str = "mlp"
    """How the smoke moves: ``mlp`` (the paper's network on position and time), ``fourier``
    (each smoke Gaussian's own offsets, a linear term plus ``fourier_terms`` sine and cosine
    pairs in time; no network) or ``planes`` (a factorised space-time feature field, six planes
    over (x,y), (x,z), (y,z), (x,t), (y,t), (z,t), read bilinearly and decoded by a small head;
    the ``planes_*`` settings). The deformable-3dgs baseline is the MLP by definition."""
    fourier_terms: int = 4
    planes_resolution: int = 32
    """kind=planes: cells along each spatial axis of the coarsest level's planes."""
    planes_levels: int = 2
    """kind=planes: levels of planes, each twice the spatial resolution of the one before (the
    time resolution is the same at every level); their features are concatenated."""
    planes_time_resolution: int = 16
    """kind=planes: cells along the time axis of the (x,t), (y,t), (z,t) planes."""
    planes_features: int = 16
    """kind=planes: features per plane and level."""
    planes_head_width: int = 64
    """kind=planes: the width of the head's one hidden layer (features → width → offsets)."""
    planes_margin: float = 0.1
    """kind=planes: the planes span the smoke's starting points' bounding box grown by this
    share of its size on every side; a point outside reads the border (clamped)."""
    planes_lr_scale: float = 10.0
    """kind=planes: the planes learn at this multiple of the head's rate (4DGS's ratio)."""
    planes_tv: float = 2e-4
    """kind=planes: Stage-3 weight of the planes' total variation (mean squared difference of
    neighbouring cells, every plane, both axes; 4DGS's weight)."""
    planes_time_smoothness: float = 1e-3
    """kind=planes: Stage-3 weight of the space-time planes' squared second difference along
    time (K-Planes' temporal smoothness; 4DGS's weight)."""
    shared_position: bool = True
    """Stage 3 evaluates the smoke's motion at the RGB frame's time and at the thermal frame's:
    compute the time-independent part once for both (the MLP's first and skip layers' products
    with γ(x), the planes' spatial lookups). Exact: the same offsets up to float rounding."""
    view_cull: bool = False
    """Stage 3 deforms only the smoke Gaussians near each rendered view's frustum (within
    ``view_cull_margin`` × the scene extent plus 4σ); the others keep zero offset. Exact where
    every skipped Gaussian's offset is under the margin; training renders only (evaluation
    deforms every Gaussian). Not for kind=fourier, whose offsets cost a few multiply-adds."""
    view_cull_margin: float = 0.05

    @property
    def fourier_lr_scale(self) -> float:
        """The Fourier coefficients learn at their tensor's rate over the number of bases: Adam
        moves every coefficient by about its rate, so an offset would otherwise move several
        times faster than the Gaussian's own parameter."""
        return 1.0 / (1 + 2 * self.fourier_terms)


PLANES_MAX_RESOLUTION = 1024
"""The finest plane's cells per axis, and the time cells, refused above this: 1024² cells × 16
features are 64 MiB per plane."""


def check_motion_field(d: DeformConfig) -> None:
    """The planes' sizes and weights, and the cuts, each refused with one line naming it."""
    for name, least in (("planes_resolution", 2), ("planes_time_resolution", 2), ("planes_levels", 1),
                        ("planes_features", 1), ("planes_head_width", 1)):
        if getattr(d, name) < least:
            raise ValueError(f"deform.{name}: must be at least {least}, got {getattr(d, name)}")
    finest = d.planes_resolution * 2 ** (d.planes_levels - 1)
    if max(finest, d.planes_time_resolution) > PLANES_MAX_RESOLUTION:
        raise ValueError(f"deform.planes_resolution: the finest level has {finest} cells per axis and time "
                         f"{d.planes_time_resolution}; at most {PLANES_MAX_RESOLUTION} each")
    for name in ("planes_margin", "planes_tv", "planes_time_smoothness", "view_cull_margin"):
        if not 0.0 <= getattr(d, name) < float("inf"):
            raise ValueError(f"deform.{name}: must be a number >= 0, got {getattr(d, name)}")
    if not 0.0 < d.planes_lr_scale < float("inf"):
        raise ValueError(f"deform.planes_lr_scale: must be a number > 0, got {d.planes_lr_scale}")
    if d.view_cull and d.kind == "fourier":
        raise ValueError("deform.view_cull: culls a motion field (mlp or planes); kind=fourier has none")


def at_iteration(fraction: float, iterations: int) -> int:
    """The iteration a schedule fraction names in a stage of ``iterations`` (nearest, halves up).
    Every schedule is resolved here, so ``--set stage3.iterations=6000`` moves them all."""
    return int(fraction * iterations + 0.5)


@dataclass(frozen=True)
class DensifyWindow:
    """A ``DensifyConfig`` resolved to iterations of one stage."""

    start: int
    stop: int
    every: int
    opacity_reset_every: int


@dataclass
class DensifyConfig:
    """3DGS adaptive density control. ``start``, ``stop`` and ``opacity_reset_every`` are fractions
    of the iterations of the stage it runs in (3DGS: 500, 15000 and 3000 of a 15000-iteration
    stage), so a longer stage densifies over the same share of it. ``every`` stays in iterations:
    it sets how many gradient samples each decision averages, which the budget does not change."""

    start: float = 1 / 30
    stop: float = 1.0
    every: int = 100
    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    opacity_reset_every: float = 0.2
    """0: no opacity reset."""
    prune_opacity: float = 0.005
    screen_size_threshold: float = 20.0
    max_gaussians: int = 1_000_000
    under_cap: str = "index"
    """Which candidates grow when they outnumber the room under ``max_gaussians``. "index" (3DGS):
    clones before splits, each in index order, so a full cap keeps growing the first Gaussians and
    never splits a large one. "gradient": the candidates with the largest mean gradient, clones and
    splits alike."""

    def window(self, iterations: int) -> DensifyWindow:
        return DensifyWindow(at_iteration(self.start, iterations), at_iteration(self.stop, iterations), self.every,
                             at_iteration(self.opacity_reset_every, iterations))


@dataclass
class LearningRates:
    """3DGS learning rates; means are scaled by the scene extent and decay exponentially."""

    means_init: float = 1.6e-4
    means_final: float = 1.6e-6
    sh_dc: float = 2.5e-3
    sh_rest: float = 2.5e-3 / 20.0
    thermal: float = 2.5e-3
    opacity: float = 0.05
    scales: float = 5e-3
    quats: float = 1e-3
    temporal: float = 1e-3
    background: float = 3e-2


@dataclass
class Stage2Config:
    """Vanilla 3DGS on the geometry modality (thermal; RGB when there is no thermal)."""

    iterations: int = 15000
    init_points: int = 100_000
    init_from: str = "random"
    """Where Stage 2 starts when the dataset brings no points of its own. "random": ``init_points``
    random points in the box the training cameras look at. "images": the training RGB frames'
    feature tracks triangulated at their given poses (``smokeseer.stage1.sparse_points``), filled
    up with random points to ``init_points`` in the box those points span; with no such points,
    random alone, and the notes say so. A flyover's optical axes do not meet near the scene, so
    its cameras' box can miss it."""
    init_opacity: float = 0.1
    init_scale_max: float = 0.02
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    deform_warmup: float = 0.2
    """The deformable-3dgs baseline trains its deformation network from this fraction of the
    stage on (D3DGS: 3k iterations; 3000 of the paper's 15000)."""


@dataclass
class Stage3Config:
    """Joint surface + smoke optimisation."""

    iterations: int = 15000
    deform_warmup: float = 0.2
    """The smoke's deformation network trains from this fraction of Stage 3 on (before it, the
    smoke is static): D3DGS's 3k-iteration warm-up, 3000 of the paper's 15000."""
    smoke_points: int = 20_000
    smoke_init_opacity: float = 0.02
    smoke_init_scale: float = 0.5
    smoke_densify: DensifyConfig = field(default_factory=lambda: DensifyConfig(opacity_reset_every=0.0))
    train_surface_geometry: bool = True
    surface_densify: DensifyConfig = field(default_factory=lambda: DensifyConfig(every=0, opacity_reset_every=0.0))
    """3DGS density control of the surface from the RGB views' gradients ("refining geometry": the
    thermal-only Stage 2 surface is as coarse as the thermal images); ``every`` 0 is off. Needs
    ``train_surface_geometry``. On in the standard profile, which has no depth term: with the
    depth term the refined surface collapsed (docs/method.md, "Profiles")."""
    surface_densify_max_smoke: float = 0.02
    """Surface refinement counts a view's gradient for a Gaussian only where the smoke covering its
    projected centre (the rendered smoke alpha, or the Stage 1 mask where the run has one) is at
    most this, so RGB gradients from smoky pixels grow no surface; 1.0 counts every centre in the image."""
    smoke_color: str = "learned"
    """Where the RGB smoke colour comes from. "learned": every smoke Gaussian learns its own from
    grey, held together by the smoke-colour and monochromaticity priors (the paper). "haze-lines":
    one colour read off the smoky training frames before Stage 3 (``smokeseer.stage1.haze_lines``, with
    Stage 2's geometry), with a trust t in [0, 1]: each smoke Gaussian shows t × that colour +
    (1 − t) × its own learned one. t = 1 holds the colour; t = 0 (thin smoke: the lines do not
    meet; or a bright, scattering smoke) learns it as the paper does. Under dense smoke the images
    alone let a brighter, denser smoke stand in for a darker surface (docs/method.md)."""
    smoke_color_min_meeting: float = 0.2
    """With smoke_color=haze-lines: the trust's meeting factor is 0 at or under this fraction of
    observation lines passing near the estimate ..."""
    smoke_color_full_meeting: float = 0.3
    """... and 1 at or over this one. The lines meet under dense smoke (room 0.79-0.83, excavator
    0.65-0.66, machine 0.33-0.67) and not under thin smoke (house 0.03-0.08, forest 0.04-0.05), so
    every dense scene's estimate meets this (docs/experiments/2026-12-02-haze-line-trust.md)."""
    smoke_color_max_brightness: float = 0.5
    """With smoke_color=haze-lines: the trust's darkness factor is 0 for an estimate whose channel
    mean is at or over this ... A scattering (bright) smoke's radiance follows the light and the
    viewing angle, so no single colour fits it from every view, while an absorbing (dark) one adds
    little light of its own."""
    smoke_color_full_brightness: float = 0.3
    """... and 1 at or under this one. At 0.4 the excavator's estimate (channel mean 0.41) had
    trust 0.93 and Full's validation PSNR fell from 22.0 at iteration 500 to 20.2, 1.5 dB under
    RGB-only; at trust 0.47 it climbed to 22.6. Machine's (0.35-0.36) at trust 0.69-0.75 ended
    level with its held colour (docs/experiments/2026-12-02-colour-ramp.md)."""
    surface_init: str = "thermal"
    """Where Stage 3's surface starts. "thermal": the thermal Stage 2 (the paper).
    "by-smoke-colour": by the haze-line surface trust t (``surface_full_brightness``). At t = 1
    (dense absorbing smoke, which a Stage 2 on the RGB frames takes for surface) the thermal
    Stage 2 alone. Under t < 1 a Stage 2 on the smoky RGB frames (RGB-only's) with its opacities
    scaled by 1 − t, carved where it lies in front of the thermal surface and joined by the
    thermal Gaussians in its holes (``smokeseer.train.surface_union``), so that where the RGB sees
    the surface through thin or scattering smoke Stage 3 starts as RGB-only does. Needs
    smoke_color=haze-lines."""
    surface_full_brightness: float = 0.4
    """With surface_init=by-smoke-colour: the trust t of the start takes the colour's meeting and
    line factors, but its darkness factor reaches 1 here, at a brighter colour than the colour's
    (smoke_color_full_brightness), because an RGB start under dense smoke costs far more than a
    partly learned colour: machine's estimate (channel mean 0.35) with the RGB Stage 2 at a quarter
    of its opacities fell from 13.7 to 9.4 dB at iteration 250, and with the thermal start and the
    colour at trust 0.75 it ended level (docs/experiments/2026-12-02-colour-ramp.md)."""
    thermal_surface_grad: str = "all"
    """Which surface Gaussians the thermal render term may move (position, shape, opacity; their
    thermal values always learn). "all": every one (the paper). "smoky-views": each one's gradient
    from that term times the share of the RGB training views whose Stage-1 mask covers its centre
    (1 where no RGB view sees it), so that the low-resolution thermal frames shape the surface only
    where the RGB cannot see it, and a scene without smoke trains its surface as RGB-only does
    (``smokeseer.train.surface_union.smoky_share``)."""
    thermal_supersample: int = 1
    """The thermal render term draws each thermal pixel as this many × this many sub-pixels and
    averages them (``View.supersampled``, ``box_filtered``), as a sensor pixel integrates its area.
    1: one sample at the pixel centre (the paper), where a surface Gaussian sized for the finer RGB
    pixels is dilated to the coarse thermal pixel's size at its full opacity, and the thermal term
    then pulls the shared surface away from what the RGB frames show. Costs the thermal render's
    work times this squared."""
    carve_tolerance: float = 0.05
    """With two surfaces: an RGB Gaussian nearer than (1 − this) × the thermal
    surface's depth in most views that see it is smoke taken for surface, and is dropped."""
    carve_by: str = "depth"
    """How the joined start carves the RGB Stage 2. "depth": a Gaussian in front of the thermal
    surface (``carve_tolerance``) in more than half of the views that check it is dropped, smoke or
    not. "depth-and-smoke": none is dropped; each one's opacity is scaled by 1 − the share of the
    checking views in which it lies in front on a pixel Stage 1 marks smoke (its mask there), so
    only smoke can be taken for surface, a scene without smoke loses nothing to the coarse thermal
    surface, and no Gaussian sits on a cliff at half its views."""
    test_every: int = 1000


@dataclass
class TrainConfig:
    """Everything that decides a run; its JSON hash goes in metrics.json."""

    mode: str = "full"
    profile: str = "quick"
    seed: int = 0
    device: str = "cpu"
    max_width: int = 0
    thermal_scale: str = "linear"
    """How raw thermal values become the trainer's [0, 1]: "linear" (dataset percentiles 0.5-99.5)
    or "equalised" (plateau histogram equalisation over the dataset; scenes.thermal_scale)."""
    thermal_equalised_share: float = 1.0
    """With thermal_scale=equalised: the share of the equalised curve, the rest linear (0, 1]."""
    sh_degree: int = 3
    sh_increase_every: int = 1000
    stage2: Stage2Config = field(default_factory=Stage2Config)
    stage3: Stage3Config = field(default_factory=Stage3Config)
    deform: DeformConfig = field(default_factory=DeformConfig)
    loss: LossWeights = field(default_factory=LossWeights)
    lr: LearningRates = field(default_factory=LearningRates)
    background: str = "environment"
    background_sh_degree: int = 2
    background_from: str = "all"
    """Which pixels the RGB environment learns from. "all": every pixel of the training frames
    (the environment shows through wherever the surface is not opaque, so on smoky frames it can
    learn the smoke's colour and put it back behind the de-smoked surface). "clear-pixels": each
    pixel's gradient into the environment is multiplied by 1 − Stage 1's smoke mask there, in
    every RGB Stage 2 and in Stage 3; the thermal environment learns from every pixel."""
    depth_prior: str = "thermal-render"
    depth_camera: str = "thermal"
    mono_weights: str = ""
    pose_noise_rot_deg: float = 0.0
    """Robustness studies: training poses turned about a random axis by N(0, this) degrees."""
    pose_noise_trans: float = 0.0
    """Robustness studies: training camera centres moved by N(0, this × scene extent) per axis."""
    registration: str = "auto"
    registration_lever_arm: tuple[float, ...] = ()
    stage1: str = "ground-truth"
    poses: str = "given"
    """"given": the dataset's poses. "sfm": Stage 1 poses from the images alone even where the
    dataset brings poses (``smokeseer.stage1.poses_from_images``): the RGB frames by structure from
    motion, the thermal frames from the rig, so a generated dataset can score the whole Stage 1."""
    mask_dir: str = ""
    validation_every: int = 8
    checkpoint_every: int = 1000
    log_every: int = 10
    smoke_ply_times: tuple[float, ...] = (0.0, 0.5, 1.0)
    lpips_net: str = "alex"
    lpips_weights: str = ""
    lpips_heads: str = ""
    progress: bool = True

    def validate(self) -> None:
        """Reject configs that cannot run, naming the field."""
        if self.mode not in MODES:
            raise ValueError(f"mode: {self.mode!r} is not one of {', '.join(MODES)}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile: {self.profile!r} is not one of {', '.join(PROFILES)}")
        if self.seed < 0:
            raise ValueError(f"seed: must be >= 0, got {self.seed}")
        self._check_trainable()
        check_thermal_scale(self.thermal_scale, self.thermal_equalised_share)
        if not 0 <= self.sh_degree <= 3:
            raise ValueError(f"sh_degree: must be in 0..3, got {self.sh_degree}")
        if self.background not in ("environment", "black"):
            raise ValueError(f"background: {self.background!r} is not environment or black")
        if self.background_from not in BACKGROUND_FROM:
            raise ValueError(f"background_from: {self.background_from!r} is not one of {', '.join(BACKGROUND_FROM)}")
        if self.background_from != "all" and self.background == "black":
            raise ValueError("background_from: a black background learns nothing; leave it at all")
        if not 0 <= self.background_sh_degree <= 3:
            raise ValueError(f"background_sh_degree: must be in 0..3, got {self.background_sh_degree}")
        if self.depth_prior not in ("thermal-render", "mono", "files", "none"):
            raise ValueError(f"depth_prior: {self.depth_prior!r} is not thermal-render, mono, files or none")
        if self.depth_camera not in ("thermal", "rgb"):
            raise ValueError(f"depth_camera: {self.depth_camera!r} is not thermal or rgb")
        if self.registration not in ("auto", "off", "trajectory"):
            raise ValueError(f"registration: {self.registration!r} is not auto, off or trajectory")
        if len(self.registration_lever_arm) not in (0, 3):
            raise ValueError("registration_lever_arm: give 3 numbers (thermal centre in the RGB camera's "
                             "OpenCV axes), or none to leave the offset unmodelled")
        if self.stage1 not in ("ground-truth", "estimate"):
            raise ValueError(f"stage1: {self.stage1!r} is not ground-truth or estimate")
        if self.poses not in POSE_SOURCES:
            raise ValueError(f"poses: {self.poses!r} is not one of {', '.join(POSE_SOURCES)}")
        if self.stage3.smoke_color not in SMOKE_COLOR_SOURCES:
            raise ValueError(f"stage3.smoke_color: {self.stage3.smoke_color!r} is not one of "
                             f"{', '.join(SMOKE_COLOR_SOURCES)}")
        if self.stage3.surface_init not in SURFACE_INITS:
            raise ValueError(f"stage3.surface_init: {self.stage3.surface_init!r} is not one of {', '.join(SURFACE_INITS)}")
        for name in ("smoke_color_min_meeting", "smoke_color_full_meeting", "smoke_color_max_brightness",
                     "smoke_color_full_brightness"):
            if not 0.0 <= getattr(self.stage3, name) <= 1.0:
                raise ValueError(f"stage3.{name}: must be in [0, 1], got {getattr(self.stage3, name)}")
        s3 = self.stage3
        if not s3.smoke_color_min_meeting < s3.smoke_color_full_meeting:
            raise ValueError("stage3.smoke_color_full_meeting: must exceed stage3.smoke_color_min_meeting "
                             f"({s3.smoke_color_full_meeting} <= {s3.smoke_color_min_meeting})")
        if not s3.smoke_color_full_brightness < s3.smoke_color_max_brightness:
            raise ValueError("stage3.smoke_color_full_brightness: must be under stage3.smoke_color_max_brightness "
                             f"({s3.smoke_color_full_brightness} >= {s3.smoke_color_max_brightness})")
        if not s3.smoke_color_full_brightness <= s3.surface_full_brightness < s3.smoke_color_max_brightness:
            raise ValueError("stage3.surface_full_brightness: must lie from stage3.smoke_color_full_brightness up to "
                             f"under stage3.smoke_color_max_brightness ({s3.surface_full_brightness} outside "
                             f"[{s3.smoke_color_full_brightness}, {s3.smoke_color_max_brightness}))")
        if self.stage3.surface_init == "by-smoke-colour" and self.stage3.smoke_color != "haze-lines":
            raise ValueError("stage3.surface_init: by-smoke-colour reads the haze lines; it needs "
                             "stage3.smoke_color=haze-lines")
        if self.stage2.init_from not in INIT_FROM:
            raise ValueError(f"stage2.init_from: {self.stage2.init_from!r} is not one of {', '.join(INIT_FROM)}")
        if self.stage3.thermal_surface_grad not in THERMAL_SURFACE_GRAD:
            raise ValueError(f"stage3.thermal_surface_grad: {self.stage3.thermal_surface_grad!r} is not one of "
                             f"{', '.join(THERMAL_SURFACE_GRAD)}")
        if not 1 <= self.stage3.thermal_supersample <= MAX_THERMAL_SUPERSAMPLE:
            raise ValueError(f"stage3.thermal_supersample: must be 1 to {MAX_THERMAL_SUPERSAMPLE} sub-pixels a side, "
                             f"got {self.stage3.thermal_supersample}")
        if self.stage3.carve_by not in CARVE_BY:
            raise ValueError(f"stage3.carve_by: {self.stage3.carve_by!r} is not one of {', '.join(CARVE_BY)}")
        if not 0.0 <= self.stage3.carve_tolerance < 1.0:
            raise ValueError(f"stage3.carve_tolerance: must be in [0, 1), got {self.stage3.carve_tolerance}")
        if not 0.0 < self.stage3.surface_densify_max_smoke <= 1.0:
            raise ValueError("stage3.surface_densify_max_smoke: must be in (0, 1], "
                             f"got {self.stage3.surface_densify_max_smoke}")
        for name, densify in (("stage2.densify", self.stage2.densify), ("stage3.smoke_densify", self.stage3.smoke_densify),
                              ("stage3.surface_densify", self.stage3.surface_densify)):
            for key in ("start", "stop", "opacity_reset_every"):
                if not 0.0 <= getattr(densify, key) <= 1.0:
                    raise ValueError(f"{name}.{key}: a fraction of the stage's iterations, in [0, 1]; "
                                     f"got {getattr(densify, key)}")
            if densify.start > densify.stop:
                raise ValueError(f"{name}.start: must not be after {name}.stop ({densify.start} > {densify.stop})")
        for name, warmup in (("stage2.deform_warmup", self.stage2.deform_warmup),
                             ("stage3.deform_warmup", self.stage3.deform_warmup)):
            if not 0.0 <= warmup <= 1.0:
                raise ValueError(f"{name}: a fraction of the stage's iterations, in [0, 1]; got {warmup}")
        if self.loss.mask_floor_where not in MASK_FLOOR_WHERE:
            raise ValueError(f"loss.mask_floor_where: {self.loss.mask_floor_where!r} is not one of "
                             f"{', '.join(MASK_FLOOR_WHERE)}")
        if self.loss.mask_floor_meeting not in MASK_FLOOR_MEETING:
            raise ValueError(f"loss.mask_floor_meeting: {self.loss.mask_floor_meeting!r} is not one of "
                             f"{', '.join(MASK_FLOOR_MEETING)}")
        if self.loss.mask_floor_where.startswith("estimated") and self.stage3.smoke_color != "haze-lines":
            raise ValueError(f"loss.mask_floor_where: {self.loss.mask_floor_where} reads the haze lines; it needs "
                             "stage3.smoke_color=haze-lines")
        if not 0.0 <= self.loss.thermal <= 10.0:
            raise ValueError(f"loss.thermal: must be in [0, 10], got {self.loss.thermal}")
        if not 0.0 < self.loss.mask_alpha_floor <= 1.0:
            raise ValueError(f"loss.mask_alpha_floor: must be in (0, 1], got {self.loss.mask_alpha_floor}")
        if self.validation_every < 0 or self.validation_every == 1:
            raise ValueError(f"validation_every: must be 0 (none) or at least 2, got {self.validation_every}")
        if self.deform.skip_layer >= self.deform.depth:
            raise ValueError("deform.skip_layer: must be below deform.depth")
        if self.deform.kind not in DEFORM_KINDS:
            raise ValueError(f"deform.kind: {self.deform.kind!r} is not one of {', '.join(DEFORM_KINDS)}")
        if self.deform.kind != "mlp" and self.mode == "deformable-3dgs":
            raise ValueError("deform.kind: the deformable-3dgs baseline is the MLP by definition; use mlp")
        if self.deform.fourier_terms < 1:
            raise ValueError(f"deform.fourier_terms: must be at least 1, got {self.deform.fourier_terms}")
        check_motion_field(self.deform)
        if self.lpips_net not in LPIPS_NETS:
            raise ValueError(f"lpips_net: {self.lpips_net!r} is not one of {', '.join(LPIPS_NETS)}")
        for t in self.smoke_ply_times:
            if not 0.0 <= t <= 1.0:
                raise ValueError(f"smoke_ply_times: {t} is outside [0, 1]")

    def _check_trainable(self) -> None:
        """Refuse settings under which a stage cannot train (nothing to iterate, no step to take,
        nothing to fit), naming the field: such a run would finish and report an untrained model."""
        at_least_one = {"stage2.iterations": self.stage2.iterations, "stage3.iterations": self.stage3.iterations,
                        "stage2.init_points": self.stage2.init_points, "log_every": self.log_every,
                        "loss.divergence_span": self.loss.divergence_span, "deform.depth": self.deform.depth,
                        "deform.width": self.deform.width}
        for name, value in at_least_one.items():
            if value < 1:
                raise ValueError(f"{name}: must be at least 1, got {value} (a stage needs it to train)")
        positive = {**{f"lr.{f.name}": getattr(self.lr, f.name) for f in dataclasses.fields(self.lr)},
                    "deform.lr_init": self.deform.lr_init, "deform.lr_final": self.deform.lr_final,
                    "loss.render": self.loss.render, "stage2.init_scale_max": self.stage2.init_scale_max,
                    "stage3.smoke_init_scale": self.stage3.smoke_init_scale}
        for name, value in positive.items():
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name}: must be a positive finite number, got {value}")
        for name in ("smoke_alpha", "smoke_color", "mono", "depth", "mask", "thermal_smoke_opacity"):
            value = getattr(self.loss, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"loss.{name}: must be a finite weight >= 0, got {value}")
        if not 0.0 <= self.loss.dssim <= 1.0:
            raise ValueError(f"loss.dssim: must be in [0, 1], got {self.loss.dssim}")
        if not self.loss.divergence_factor > 1.0:
            raise ValueError(f"loss.divergence_factor: must exceed 1, got {self.loss.divergence_factor}")
        for name, value in (("stage2.init_opacity", self.stage2.init_opacity),
                            ("stage3.smoke_init_opacity", self.stage3.smoke_init_opacity)):
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name}: must be in (0, 1), got {value}")
        for name, value in (("stage3.smoke_points", self.stage3.smoke_points), ("checkpoint_every", self.checkpoint_every),
                            ("stage3.test_every", self.stage3.test_every), ("max_width", self.max_width),
                            ("deform.xyz_frequencies", self.deform.xyz_frequencies),
                            ("deform.t_frequencies", self.deform.t_frequencies)):
            if value < 0:
                raise ValueError(f"{name}: must be >= 0, got {value}")
        for name, densify in (("stage2.densify", self.stage2.densify), ("stage3.smoke_densify", self.stage3.smoke_densify),
                              ("stage3.surface_densify", self.stage3.surface_densify)):
            if densify.every < 0 or densify.max_gaussians < 1 or not densify.grad_threshold >= 0:
                raise ValueError(f"{name}: every must be >= 0, max_gaussians at least 1 and grad_threshold >= 0 "
                                 f"(got {densify.every}, {densify.max_gaussians}, {densify.grad_threshold})")
            if densify.under_cap not in DENSIFY_UNDER_CAP:
                raise ValueError(f"{name}.under_cap: {densify.under_cap!r} is not one of {', '.join(DENSIFY_UNDER_CAP)}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def stage2_sha256(self) -> str:
        """Hash of the settings Stage 2 depends on, so a Stage 2 checkpoint is reused by runs
        that differ only in Stage 3 (ablations, Stage 3 budgets) or in where Stage 1's masks come
        from (Stage 2 reads no mask, unless an RGB Stage 2's environment learns from the
        clear pixels only: ``stage1``, ``mask_dir``, ``background_from``) on the same geometry."""
        d = self.to_dict()
        d["mode"] = {"rgb-only": "rgb", "deformable-3dgs": "deformable-3dgs"}.get(self.mode, "thermal")
        reads_masks = d["mode"] == "rgb" and self.background_from == "clear-pixels"
        for key in ("stage3", "loss", "depth_prior", "depth_camera", "mono_weights", "smoke_ply_times", "progress",
                    "log_every", "checkpoint_every", "profile", "lpips_net", "lpips_weights", "lpips_heads",
                    *(() if reads_masks else ("stage1", "mask_dir", "background_from"))):
            d.pop(key)
        if d["mode"] != "deformable-3dgs":
            d.pop("deform")
            d["stage2"].pop("deform_warmup")
        if d["mode"] != "thermal":
            d.pop("thermal_scale")
            d.pop("thermal_equalised_share")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def sha256(self) -> str:
        """Hash of the settings that change results (progress display excluded)."""
        d = self.to_dict()
        d.pop("progress")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def _quick() -> TrainConfig:
    """Minutes on 2 CPU cores: reduced resolution, iterations and Gaussian counts, with the
    3DGS schedules set for the shorter runs (windows 150-800 of 1000 and 200-600 of 800, warm-up
    200). No opacity reset: 3DGS trains 15k iterations after its last reset, and a reset half-way
    through 1000 leaves too few to regrow opacity."""
    s2 = Stage2Config(
        iterations=1000,
        init_points=2000,
        densify=DensifyConfig(start=0.15, stop=0.8, every=100, opacity_reset_every=0.0,
                              max_gaussians=12_000),
        deform_warmup=0.2,
    )
    s3 = Stage3Config(
        iterations=800,
        deform_warmup=0.25,
        smoke_points=800,
        smoke_densify=DensifyConfig(start=0.25, stop=0.75, every=100, opacity_reset_every=0.0,
                                    max_gaussians=4_000),
        test_every=200,
    )
    deform = DeformConfig(depth=4, width=64, skip_layer=2)
    return TrainConfig(profile="quick", max_width=64, sh_degree=1, sh_increase_every=300,
                       stage2=s2, stage3=s3, deform=deform, checkpoint_every=200, validation_every=0,
                       depth_camera="rgb")


def _standard() -> TrainConfig:
    """The benchmark's scale on one CPU core with the compiled rasterizer (a `standard` dataset:
    60 frames, 200x150 RGB, 80x60 thermal): full resolution, 3000 + 3000 iterations with the
    3DGS schedules scaled to them (densification 300-2400, warm-up 500), Stage 2 from the points
    seen in the training frames, and a validation split for every choice. No opacity reset, a gated surface refinement, no depth term, a
    half-equalised thermal curve, the haze-line smoke colour weighted by its trust (many lines,
    meeting, dark), Stage 3's surface chosen by the same trust, and the mask floor where the images say the smoke may
    be dense: each chosen on the validation views, with its measurements in docs/method.md,
    "Profiles"."""
    s2 = Stage2Config(
        iterations=3000,
        init_points=5000,
        init_from="images",
        densify=DensifyConfig(start=0.1, stop=0.8, every=100, opacity_reset_every=0.0,
                              max_gaussians=40_000),
        deform_warmup=1 / 6,
    )
    s3 = Stage3Config(
        iterations=3000,
        deform_warmup=1 / 6,
        smoke_points=2000,
        smoke_densify=DensifyConfig(start=0.1, stop=0.8, every=100, opacity_reset_every=0.0,
                                    max_gaussians=10_000),
        surface_densify=DensifyConfig(start=0.1, stop=0.8, every=100, opacity_reset_every=0.0,
                                      max_gaussians=80_000),
        smoke_color="haze-lines",
        surface_init="by-smoke-colour",
        test_every=250,
    )
    deform = DeformConfig(depth=6, width=128, skip_layer=3, predict_rotation_scale=True)
    return TrainConfig(profile="standard", max_width=0, thermal_scale="equalised", thermal_equalised_share=0.5,
                       sh_degree=2, sh_increase_every=800, stage2=s2, stage3=s3, deform=deform,
                       loss=LossWeights(mask_floor_where="estimated-meeting"), checkpoint_every=500, depth_prior="none")


def _paper() -> TrainConfig:
    """The paper's schedule: 15k + 15k iterations at full resolution (meant for GPUs)."""
    return TrainConfig(profile="paper", max_width=0, deform=DeformConfig(predict_rotation_scale=True))


def make_config(mode: str = "full", profile: str = "quick", seed: int = 0,
                overrides: dict[str, Any] | None = None) -> TrainConfig:
    """Build a profile's config, then apply dotted-key overrides (``{"stage3.iterations": 30}``)."""
    if profile not in PROFILES:
        raise ValueError(f"profile: {profile!r} is not one of {', '.join(PROFILES)}")
    cfg = {"quick": _quick, "standard": _standard, "paper": _paper}[profile]()
    cfg.mode = mode
    cfg.seed = seed
    for key, value in (overrides or {}).items():
        _set_dotted(cfg, key, value)
    cfg.validate()
    return cfg


def _set_dotted(cfg: Any, key: str, value: Any) -> None:
    parts = key.split(".")
    target = cfg
    for p in parts[:-1]:
        if not dataclasses.is_dataclass(target) or not hasattr(target, p):
            raise ValueError(f"overrides: unknown key {key!r}")
        target = getattr(target, p)
    leaf = parts[-1]
    if not dataclasses.is_dataclass(target) or leaf not in {f.name for f in dataclasses.fields(target)}:
        raise ValueError(f"overrides: unknown key {key!r}")
    current = getattr(target, leaf)
    if dataclasses.is_dataclass(current):
        raise ValueError(f"overrides: {key!r} is a section; set one of its fields")
    setattr(target, leaf, _coerce(key, current, value))


def _coerce(key: str, current: Any, value: Any) -> Any:
    """``value`` as the type of the field's current value; a ValueError names the key."""
    words = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}
    try:
        if isinstance(current, bool):
            if isinstance(value, bool):
                return value
            return words[str(value).strip().lower()]
        if isinstance(current, int):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        if isinstance(current, float):
            return float(value)
        if isinstance(current, tuple):
            if not isinstance(value, (list, tuple)):
                raise ValueError
            return tuple(float(v) for v in value)
        return str(value)
    except (KeyError, TypeError, ValueError):
        kind = {bool: "true or false", int: "an integer", float: "a number", tuple: "a list such as [0.0, 0.5]"}
        raise ValueError(f"overrides: {key!r} needs {kind.get(type(current), 'a string')}, got {value!r}") from None
