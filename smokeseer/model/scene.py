"""The SmokeSeer scene: static surface Gaussians, dynamic smoke Gaussians, and their renders.

Surface tensors: ``means quats log_scales opacity`` (one opacity for both modalities), ``thermal``
(a logit; thermal emission is treated as view-independent) and ``sh_dc``/``sh_rest`` (RGB SH).
Smoke tensors: ``means quats log_scales opacity_rgb opacity_thermal color thermal`` plus the
temporal-opacity parameters ``t_lo t_hi t_log_sigma``, and with ``deform.kind=fourier`` the
coefficients ``motion_*``; smoke lives in a canonical space moved by a motion field (the
deformation MLP or the plane field) or by those coefficients. A renderer call takes any subset of
the two sets, so the composite, the surface-only prediction and smoke-only views all come from
the same code path.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from smokeseer.model.background import EnvironmentBackground, composite_over
from smokeseer.model.deform import MOTION_KEYS, DeformNetwork, Encoded, Offsets, motion_offsets, temporal_opacity
from smokeseer.model.frustum import near_frustum
from smokeseer.model.gaussians import GaussianSet, knn_log_scales, logit, rgb_to_sh_dc
from smokeseer.model.planes import PlaneField
from smokeseer.raster import RasterOutput, rasterize
from smokeseer.raster.api import NEAR_PLANE


@dataclass
class View:
    """One camera as batched tensors, plus the normalised time of its frame. ``sky_bases`` keeps
    the environment's ray basis per SH degree: training renders each view hundreds of times and
    the camera never moves (a camera whose pose requires grad is never cached)."""

    viewmat: Tensor
    K: Tensor
    width: int
    height: int
    time: float
    sky_bases: dict[int, Tensor] = field(default_factory=dict, repr=False, compare=False)

    def sky(self, env: EnvironmentBackground) -> Tensor:
        """The environment ``env`` seen from this view, [H, W, channels]."""
        if self.viewmat.requires_grad or self.K.requires_grad:
            return env(self.viewmat[0], self.K[0], self.width, self.height)
        basis = self.sky_bases.get(env.degree)
        if basis is None:
            basis = self.sky_bases[env.degree] = env.basis(self.viewmat[0], self.K[0], self.width, self.height)
        return env.from_basis(basis)

    def supersampled(self, factor: int) -> View:
        """The same camera drawn as ``factor`` × ``factor`` sub-pixels to each pixel, for a render
        that ``box_filtered`` averages back to this view's pixels. Pixel centres sit at +0.5, so
        scaling the focal lengths and the principal point tiles every pixel exactly."""
        if factor == 1:
            return self
        rows = torch.tensor([factor, factor, 1.0], dtype=self.K.dtype, device=self.K.device)
        return View(self.viewmat, self.K * rows[None, :, None], self.width * factor, self.height * factor, self.time)


def make_view(viewmat: np.ndarray, K: np.ndarray, width: int, height: int, time: float,
              device: torch.device) -> View:
    return View(torch.as_tensor(viewmat, dtype=torch.float32, device=device)[None],
                torch.as_tensor(K, dtype=torch.float32, device=device)[None], width, height, time)


def init_gaussians(points: np.ndarray, opacity: float, max_scale: float, device: torch.device) -> dict[str, Tensor]:
    """3DGS initialisation: identity rotation, kNN isotropic scale capped at ``max_scale``
    (sparse random clouds otherwise start with Gaussians covering whole images, which costs
    rasterization time and gains nothing), uniform low opacity."""
    n = len(points)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return {
        "means": torch.as_tensor(points, dtype=torch.float32, device=device),
        "quats": torch.as_tensor(quats, dtype=torch.float32, device=device),
        "log_scales": torch.as_tensor(np.minimum(knn_log_scales(points), np.log(max_scale)), dtype=torch.float32,
                                      device=device),
        "opacity": torch.full((n,), logit(opacity), device=device),
    }


def add_rgb_sh(tensors: dict[str, Tensor], sh_degree: int, init_rgb: Tensor | None = None) -> None:
    """Give Gaussians an RGB SH colour (grey unless ``init_rgb`` is given), on the means' device."""
    means = tensors["means"]
    n = means.shape[0]
    rgb = init_rgb if init_rgb is not None else means.new_full((n, 3), 0.5)
    tensors["sh_dc"] = rgb_to_sh_dc(rgb)[:, None, :].float()
    tensors["sh_rest"] = means.new_zeros((n, (sh_degree + 1) ** 2 - 1, 3))


def make_smoke(points: np.ndarray, opacity: float, scale: float, max_scale: float,
               rng: np.random.Generator, device: torch.device) -> GaussianSet:
    """Smoke Gaussians at random positions, grey, faint
    (opacity and kNN scale × ``scale`` chosen so the initial cloud hides little of the surface),
    with random temporal windows."""
    base = init_gaussians(points, opacity, max_scale, device)
    base["log_scales"] = base["log_scales"] + float(np.log(scale))
    n = len(points)
    base["opacity_rgb"] = base.pop("opacity")
    base["opacity_thermal"] = torch.full((n,), logit(opacity), device=device)
    base["color"] = torch.zeros((n, 3), device=device)
    base["thermal"] = torch.zeros((n, 1), device=device)
    centre = torch.as_tensor(rng.uniform(0.0, 1.0, n), dtype=torch.float32, device=device)
    half = torch.as_tensor(rng.uniform(0.25, 0.5, n), dtype=torch.float32, device=device)
    base["t_lo"] = centre - half
    base["t_hi"] = centre + half
    base["t_log_sigma"] = torch.full((n,), float(np.log(0.2)), device=device)
    return GaussianSet(base)


@dataclass
class Placed:
    """Gaussians placed at one time, ready to concatenate into one rasterizer call."""

    means: Tensor
    quats: Tensor
    log_scales: Tensor


def place_static(g: GaussianSet) -> Placed:
    return Placed(g["means"], g.quats, g["log_scales"])


def scaled_gradient(x: Tensor, share: Tensor) -> Tensor:
    """``x`` unchanged in the forward pass, with the gradient that reaches it through this
    value multiplied by ``share``, whose shape is ``x``'s leading dimensions (one value per
    Gaussian, or per pixel of an image)."""
    held = x.detach()
    return held + share.reshape(*share.shape, *([1] * (x.dim() - share.dim()))) * (x - held)


MotionField = DeformNetwork | PlaneField
"""A field of offsets over position and time: ``field(means, t, center)``, or ``encode`` once and
``decode`` per time (``smokeseer.model.deform``)."""

CULL_SIGMAS = 4.0
"""The view cut keeps a Gaussian whose centre lies within the margin plus this many of its
largest standard deviation of the frustum: the rasterizer's 3σ footprint, linearised at the
centre, grows off-axis by up to its 1.3× frustum clamp."""


@dataclass
class SmokeMotion:
    """The smoke-motion work one Stage-3 iteration shares between its RGB and thermal renders:
    the field's time-independent part for every smoke Gaussian (``deform.shared_position``, else
    None), and the view cut's margin in scene units (``deform.view_cull``, else None)."""

    encoded: Encoded | None
    cull_margin: float | None


def field_offsets(field: MotionField, means: Tensor, t: float, center: Tensor, encoded: Encoded | None,
                  rows: Tensor | None) -> Offsets:
    """The field's offsets at time ``t``, from ``encoded`` where given; with ``rows`` (a mask) only
    for those Gaussians, the others' offsets zero (they get no gradient through the field)."""
    if rows is None:
        return field(means, t, center) if encoded is None else field.decode(encoded, t)
    part = field(means[rows], t, center) if encoded is None else field.decode(tuple(e[rows] for e in encoded), t)
    return tuple(None if d is None else d.new_zeros((means.shape[0], d.shape[1])).index_put((rows,), d)
                 for d in part)


def place_deformed(g: GaussianSet, deform: MotionField | None, t: float, center: Tensor,
                   active: bool, encoded: Encoded | None = None, rows: Tensor | None = None) -> Placed:
    """Canonical Gaussians moved to time t by their own Fourier coefficients where the set has
    them, else by the motion field (unchanged during warm-up, or with neither); ``encoded`` and
    ``rows``: see ``field_offsets``."""
    if not active:
        return place_static(g)
    if MOTION_KEYS[0] in g:
        d_xyz, d_rot, d_scale = motion_offsets(g.params, t)
    elif deform is not None:
        d_xyz, d_rot, d_scale = field_offsets(deform, g["means"], t, center, encoded, rows)
    else:
        return place_static(g)
    means = g["means"] + d_xyz
    if d_rot is None:
        return Placed(means, g.quats, g["log_scales"])
    q = g["quats"] + d_rot
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return Placed(means, q, g["log_scales"] + d_scale)


def smoke_time_opacity(smoke: GaussianSet, t: float, static: bool) -> Tensor:
    if static:
        return torch.ones(smoke.n, device=smoke["means"].device)
    return temporal_opacity(t, smoke["t_lo"], smoke["t_hi"], smoke["t_log_sigma"])


def sh_coeffs(g: GaussianSet) -> Tensor:
    return torch.cat([g["sh_dc"], g["sh_rest"]], dim=1)


def smoke_sh(colours: Tensor, k: int) -> Tensor:
    """Smoke's view-independent RGB ``colours`` as SH (DC only) so they join the surface's SH pass."""
    dc = rgb_to_sh_dc(colours)[:, None, :]
    return torch.cat([dc, torch.zeros(colours.shape[0], k - 1, 3, device=dc.device)], dim=1)


@dataclass(frozen=True)
class SmokeAnchor:
    """The haze-line smoke colour and its trust: each smoke Gaussian shows trust × ``colour`` +
    (1 − trust) × its own learned colour. Why a blend and not a switch: an estimate just under or
    over a threshold would otherwise train a different method (docs/method.md, "Smoke colour")."""

    colour: Tensor
    trust: float

    def blend(self, own: Tensor) -> Tensor:
        return self.trust * self.colour + (1.0 - self.trust) * own


def render(view: View, parts: list[tuple[Placed, Tensor, Tensor]], sh_degree: int | None,
           background: Tensor | EnvironmentBackground | None, subset: int | None = None,
           normalize_depth: bool = True, rest_alone: bool = False, depth: bool = True,
           background_grad: Tensor | None = None) -> RasterOutput:
    """Rasterize several placed sets in one pass. Each part is (placed, opacity, colour); with
    ``subset`` = k, the k-th part's accumulated alpha is returned in the same pass, and with
    ``rest_alone`` also the depth and alpha of the other parts rendered without it
    (``rest_depths``/``rest_alphas``; without a subset, the render's own). The background is a
    constant colour, a learned environment, or None (black).

    Why ``rest_alone``: Stage 3's depth term needs the surface's depth without the smoke in front,
    and a separate surface render cost a sixth of a demo iteration. One consequence: the depth
    term's screen-space gradient joins the pass's ``means2d`` gradient, the statistic surface
    densification reads (as where depth is rendered in the image pass).

    ``depth=False`` leaves out the depth image (``depths`` is None) unless ``rest_alone`` needs
    it: each channel costs kernel work per blended pair, and a training pass without a depth
    term never reads it. Colours, alphas and their gradients are the same bytes either way.

    ``background_grad`` (H, W): a learned environment's gradient is multiplied by it pixel by
    pixel (``background_from=clear-pixels``); the image is the same."""
    means = torch.cat([p.means for p, _, _ in parts])
    quats = torch.cat([p.quats for p, _, _ in parts])
    scales = torch.cat([p.log_scales for p, _, _ in parts])
    opac = torch.cat([o for _, o, _ in parts])
    cols = torch.cat([c for _, _, c in parts])
    channels = cols.shape[-1]
    env = background if isinstance(background, EnvironmentBackground) else None
    flat = torch.zeros(channels, dtype=means.dtype, device=means.device) if background is None or env is not None \
        else background
    mask = None
    if subset is not None:
        flags = [torch.full((p.means.shape[0],), i == subset, dtype=torch.bool, device=means.device)
                 for i, (p, _, _) in enumerate(parts)]
        mask = torch.cat(flags)
    out = rasterize(means, quats, scales, opac, cols, view.viewmat, view.K, view.width, view.height,
                    sh_degree=sh_degree, log_scales=True, backgrounds=flat,
                    subset_mask=mask, render_depth=depth or rest_alone, normalize_depth=normalize_depth,
                    render_rest_alone=rest_alone and mask is not None)
    if rest_alone and mask is None:
        out = replace(out, rest_depths=out.depths, rest_alphas=out.alphas)
    if env is None:
        return out
    sky = view.sky(env) if background_grad is None else scaled_gradient(view.sky(env), background_grad)
    return replace(out, colors=composite_over(out.colors, out.alphas, sky))


def render_depth(view: View, placed: Placed, opacities: Tensor) -> RasterOutput:
    """Normalised expected depth and alpha of one set on black, with no colour channel: the depth
    prior and the depth term read nothing else, and every colour channel costs kernel work."""
    return render(view, [(placed, opacities, opacities.new_zeros((opacities.shape[0], 0)))], None, None,
                  normalize_depth=True)


@dataclass
class SceneModel:
    """Surface (static) + optional smoke (deformable) Gaussians, rendered per modality."""

    surface: GaussianSet
    smoke: GaussianSet | None
    deform: MotionField | None
    smoke_static: bool
    center: Tensor
    sh_degree: int
    surface_deform: DeformNetwork | None = None
    background_rgb: EnvironmentBackground | None = None
    background_thermal: EnvironmentBackground | None = None
    smoke_anchor: SmokeAnchor | None = None

    def smoke_colours(self) -> Tensor:
        """Each smoke Gaussian's RGB colour: its own, blended with the anchor where there is one."""
        if self.smoke is None:
            raise ValueError("smoke_colours: this model has no smoke Gaussians")
        own = torch.sigmoid(self.smoke["color"])
        return own if self.smoke_anchor is None else self.smoke_anchor.blend(own)

    def surface_at(self, t: float) -> Placed:
        """Surface Gaussians are static, except in the deformable-3dgs baseline."""
        if self.surface_deform is None:
            return place_static(self.surface)
        return place_deformed(self.surface, self.surface_deform, t, self.center, True)

    def smoke_motion(self, deform_active: bool, shared: bool, cull_margin: float | None) -> SmokeMotion | None:
        """What this iteration's renders share of the smoke's motion (``SmokeMotion``); None when
        the smoke has no motion field or it is not active yet."""
        if self.smoke is None or self.deform is None or self.smoke_static or not deform_active:
            return None
        return SmokeMotion(self.deform.encode(self.smoke["means"], self.center) if shared else None, cull_margin)

    def smoke_near_view(self, view: View, margin: float) -> Tensor:
        """The smoke Gaussians whose canonical centre lies within ``margin`` (scene units) plus
        ``CULL_SIGMAS`` of their scale of ``view``'s frustum."""
        g = self.smoke
        radius = margin + CULL_SIGMAS * g["log_scales"].detach().max(dim=1).values.exp()
        return near_frustum(g["means"].detach(), radius, view.viewmat[0].detach(), view.K[0].detach(), view.width,
                            view.height, NEAR_PLANE)

    def smoke_at(self, t: float, deform_active: bool = True, view: View | None = None,
                 motion: SmokeMotion | None = None) -> tuple[Placed, Tensor, Tensor]:
        """Smoke placed at time t with its RGB and thermal opacities (temporal opacity applied);
        ``motion`` (with the ``view`` rendered): this iteration's shared motion work and view cut."""
        if self.smoke is None:
            raise ValueError("smoke_at: this model has no smoke Gaussians")
        encoded = rows = None
        if motion is not None and deform_active:
            encoded = motion.encoded
            if motion.cull_margin is not None and view is not None:
                rows = self.smoke_near_view(view, motion.cull_margin)
        placed = place_deformed(self.smoke, self.deform, t, self.center, deform_active and not self.smoke_static,
                                encoded, rows)
        tw = smoke_time_opacity(self.smoke, t, self.smoke_static)
        return (placed, torch.sigmoid(self.smoke["opacity_rgb"]) * tw,
                torch.sigmoid(self.smoke["opacity_thermal"]) * tw)

    def render_rgb(self, view: View, surface: bool = True, smoke: bool = True, degree: int | None = None,
                   deform_active: bool = True, surface_depth: bool = False, depth: bool = True,
                   motion: SmokeMotion | None = None, background: bool = True,
                   background_grad: Tensor | None = None) -> RasterOutput:
        """RGB = surface ∪ smoke with RGB opacities; with both, smoke alpha comes from the same pass.
        The environment is drawn behind any render that includes the surface (a smoke-only
        view is shown on black), unless ``background`` is false (the evaluation's check of how much
        of a score the environment carries). ``surface_depth``: the surface's own depth and alpha as
        ``rest_depths``/``rest_alphas``, from the same pass; ``depth``: the depth image (both: see
        ``render``); ``motion``: see ``smoke_at``; ``background_grad``: see ``render``."""
        if surface_depth and not surface:
            raise ValueError("render_rgb: surface_depth needs the surface in the render")
        degree = self.sh_degree if degree is None else degree
        k = self.surface["sh_dc"].shape[1] + self.surface["sh_rest"].shape[1]
        parts = []
        if surface:
            placed, opacity = self.surface_at(view.time), torch.sigmoid(self.surface["opacity"])
            parts.append((placed, opacity, sh_coeffs(self.surface)))
        use_smoke = smoke and self.smoke is not None
        if use_smoke:
            placed, o_rgb, _ = self.smoke_at(view.time, deform_active, view, motion)
            parts.append((placed, o_rgb, smoke_sh(self.smoke_colours(), k)))
        subset = len(parts) - 1 if use_smoke else None
        if not parts:
            raise ValueError("render_rgb: nothing to render (no surface and no smoke)")
        return render(view, parts, degree, self.background_rgb if surface and background else None, subset=subset,
                      rest_alone=surface_depth, depth=depth, background_grad=background_grad)

    def render_thermal(self, view: View, surface: bool = True, smoke: bool = True,
                       deform_active: bool = True, surface_depth: bool = False, depth: bool = True,
                       motion: SmokeMotion | None = None, surface_grad_share: Tensor | None = None) -> RasterOutput:
        """Thermal = surface ∪ smoke with thermal opacities and 1-channel thermal colours.
        ``surface_depth``, ``depth``, ``motion``: as for ``render_rgb``. ``surface_grad_share``:
        one value per surface Gaussian by which the gradient into its position, shape and opacity
        through this render is multiplied (``stage3.thermal_surface_grad``); its thermal value
        learns in full."""
        if surface_depth and not surface:
            raise ValueError("render_thermal: surface_depth needs the surface in the render")
        parts = []
        if surface:
            placed, opacity = self.surface_at(view.time), torch.sigmoid(self.surface["opacity"])
            if surface_grad_share is not None:
                placed = Placed(*(scaled_gradient(x, surface_grad_share)
                                  for x in (placed.means, placed.quats, placed.log_scales)))
                opacity = scaled_gradient(opacity, surface_grad_share)
            parts.append((placed, opacity, torch.sigmoid(self.surface["thermal"])))
        use_smoke = smoke and self.smoke is not None
        if use_smoke:
            placed, _, o_th = self.smoke_at(view.time, deform_active, view, motion)
            parts.append((placed, o_th, torch.sigmoid(self.smoke["thermal"])))
        return render(view, parts, None, self.background_thermal if surface else None,
                      subset=len(parts) - 1 if use_smoke else None, rest_alone=surface_depth, depth=depth)
