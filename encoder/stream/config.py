"""Encoder configuration: presets are YAML files (encoder/presets/*.yaml); a user's YAML
file or command-line options override single fields."""

from __future__ import annotations

import dataclasses
import functools
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from ...common.errors import InputError, InputWarning

DEFAULT_ATTRIBUTE_STEP = 0.02  # the feature, scaling and offset step of anchor scenes (preset medium)


# Where the explicit-Gaussian encoder's views look from (GaussianEncoderConfig.views)
VIEW_KINDS = ("auto", "orbit", "inside", "both")

@dataclass
class AttributeCodingConfig:
    """How attribute units are coded: the fields both kinds of scene use (EncoderConfig adds those of
    anchor scenes, GaussianEncoderConfig those of explicit-Gaussian scenes). A point is an anchor or
    a Gaussian."""
    # Points per independently decodable attribute chunk.
    rows_per_chunk: int = 65536
    # Rows sampled when choosing each channel's prior (informative speed/accuracy knob).
    prior_fit_rows: int = 50000
    # Tiles (format version 1): the smallest tile side (a power of two of coarse voxels) whose
    # occupied tiles hold at least this many points on average; 0: no tiles. A scene that fits one
    # tile has none (the tool costs it no bits). Cost and decode speed: tools/results/tiles.md.
    tile_points: int = 16384
    # The tile side in coarse voxels (voxels without the hierarchy), 1 .. 2^20, instead of the
    # choice from tile_points; tiles are then used even when the scene fits one. 0: chosen.
    tile_scale: int = 0
    # Two-level hierarchy: level 1 = one point per coarse voxel of this many voxels per side.
    hierarchy: bool = False
    coarse_voxel_scale: int = 4
    # Level-2 context model: per_channel (the spine's prior), parent_mlp (vanilla EM) or ggconv.
    context_model: str = "per_channel"
    context_k: int = 8  # neighbours of the Ball k-NN graph (GG-Conv)
    # GG-Conv neighbours: 1 = the level-1 points with their own decoded attributes (default:
    # fewer bits on most scenes, tools/results/context.md), 2 = the other level-2 points carrying
    # their parents' attributes (the paper's graph over A_pre^(2)), "auto" = fit both, keep the smaller.
    context_neighbour_level: int | str = 1
    # Base of each channel's mean (parent_base, Annex H.5.3): "choose" = the parent's value where it
    # predicts the channel better than the channel's median, else the median (one fit); "parent" =
    # the parent's value on every channel (the paper's skip); "auto" = fit both, keep the smaller
    # stream (twice the fit time; neither wins on every scene: tools/results/context.md).
    context_parent_base: str = "auto"
    # Context-model size; None: chosen from the number of level-2 points (context_model_size), so
    # that a small scene is not charged for a model it cannot pay back.
    context_channels: int | None = None  # GG-Conv context channels Ch (geometry table and feature MLP outputs)
    context_feat_hidden: int | None = None  # GG-Conv feature-MLP hidden width
    context_head_hidden: int | None = None  # head-MLP hidden width (GG-Conv and parent MLP)
    context_lambda: float = 16.0  # distortion weight of the step adjustment, bits per squared step
    context_float_steps: int = 1200  # training steps in float
    context_qat_steps: int = 300  # quantization-aware steps (GG-Conv; the parent MLP trains float_steps + qat_steps)
    context_weight_bits: int | None = None  # integer precision of the context model's weights: 8 or 16
    context_train_points: int = 200_000  # level-2 points sampled for training
    context_fallback: bool = True  # use the context model only when it saves bytes over the prior

    def validate(self) -> "AttributeCodingConfig":
        if self.rows_per_chunk < 1:
            raise InputError("rows_per_chunk must be at least 1")
        if not 1 <= self.coarse_voxel_scale <= (1 << 20):
            raise InputError(f"coarse_voxel_scale must be in [1, 2^20], got {self.coarse_voxel_scale}")
        if self.context_model not in ("per_channel", "parent_mlp", "ggconv"):
            raise InputError(f"context_model must be per_channel, parent_mlp or ggconv, got {self.context_model!r}")
        if self.context_model != "per_channel" and not self.hierarchy:
            raise InputError(f"context_model {self.context_model} needs the hierarchy (hierarchy: true)")
        if self.context_weight_bits not in (None, 8, 16):
            raise InputError("context_weight_bits must be 8 or 16")
        if not 1 <= self.context_k <= 64:
            raise InputError("context_k must be in [1, 64]")
        if self.context_parent_base not in ("choose", "parent", "auto"):
            raise InputError("context_parent_base must be choose, parent or auto")
        if self.context_neighbour_level not in (1, 2, "auto"):
            raise InputError("context_neighbour_level must be 1 (level-1 points), 2 (level-2 points) or auto")
        for name in ("context_channels", "context_feat_hidden", "context_head_hidden"):
            if getattr(self, name) is not None and not 1 <= getattr(self, name) <= 4096:
                raise InputError(f"{name} must be in [1, 4096], got {getattr(self, name)}")
        for name in ("context_float_steps", "context_qat_steps"):
            if getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0")
        if self.prior_fit_rows < 1:
            raise InputError("prior_fit_rows must be at least 1")
        self._validate_tiles()
        return self

    def _validate_tiles(self) -> None:
        if self.tile_points < 0:
            raise InputError(f"tile_points must be >= 0 (0: no tiles), got {self.tile_points}")
        if not 0 <= self.tile_scale <= (1 << 20):
            raise InputError(f"tile_scale must be in [0, 2^20] (0: chosen from tile_points), got {self.tile_scale}")


@dataclass
class EncoderConfig(AttributeCodingConfig):
    """Anchor scenes (Scaffold-GS / HAC checkpoints)."""
    # Quantization steps of the attribute groups (decoded value = q * step).
    feature_step: float = DEFAULT_ATTRIBUTE_STEP
    scaling_step: float = DEFAULT_ATTRIBUTE_STEP
    offset_step: float = DEFAULT_ATTRIBUTE_STEP
    # Render MLP weights: signed integers of this many bits with a power-of-two scale per tensor.
    mlp_weight_bits: int = 14
    # Anchor pruning before coding (informative): none, naap (Neighborhood-Aware Anchor Pruning:
    # low-importance anchors merged into their nearest retained neighbour) or opacity (Context-GS's
    # plain threshold, for comparison). Give a keep ratio or an importance threshold tau.
    pruning: str = "none"
    prune_keep_ratio: float | None = None  # keep this fraction of the anchors
    prune_tau: float | None = None  # or: prune anchors whose importance (accumulated opacity) is below tau
    naap_k: int = 8  # NAAP neighbours
    naap_lambda: float = 0.5  # NAAP: weight of the neighbourhood opacity in the importance
    naap_gamma: float = 0.2  # NAAP: share of a pruned anchor merged into its target

    def validate(self) -> "EncoderConfig":
        super().validate()
        _check_steps(self, ("feature_step", "scaling_step", "offset_step"))
        if not (2 <= self.mlp_weight_bits <= 24):
            raise InputError(f"mlp_weight_bits must be in [2, 24], got {self.mlp_weight_bits}")
        if self.pruning not in ("none", "naap", "opacity"):
            raise InputError(f"pruning must be none, naap or opacity, got {self.pruning!r}")
        if self.pruning != "none" and (self.prune_keep_ratio is None) == (self.prune_tau is None):
            raise InputError(f"pruning {self.pruning} needs exactly one of prune_keep_ratio or prune_tau")
        if self.prune_keep_ratio is not None and not 0 < self.prune_keep_ratio <= 1:
            raise InputError(f"prune_keep_ratio must be in (0, 1], got {self.prune_keep_ratio}")
        if not 1 <= self.naap_k <= 64 or not 0 <= self.naap_lambda <= 1 or not 0 <= self.naap_gamma <= 1:
            raise InputError("naap_k must be in [1, 64], naap_lambda and naap_gamma in [0, 1]")
        return self


def _check_steps(cfg, names) -> None:
    for name in names:
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < float("inf")):
            raise InputError(f"{name} must be a positive finite number, got {v!r}")


@dataclass
class GaussianEncoderConfig(AttributeCodingConfig):
    """Explicit-Gaussian scenes (3DGS PLY, SPZ, SOG input): every Gaussian coded as a point of
    the geometry unit with its attributes. The presets' gaussians sections (encoder/presets/*.yaml) set it."""
    # Quantization steps (decoded value = q * step): SH DC term, each higher SH band (1, 2, 3),
    # opacity logit, log scales, rotation quaternion components.
    sh_dc_step: float = 0.03
    sh_band_steps: tuple = (0.06, 0.08, 0.1)
    opacity_step: float = 0.2
    scale_step: float = 0.1
    rotation_step: float = 0.03
    # Position grid: voxel size = position_step x the median size of the Gaussians that make the
    # picture (size = exp of the mean log scale, weighted by contribution when it is known).
    position_step: float = 0.5
    # SH degree coded: None keeps the source's; lower values drop the higher bands.
    sh_degree: int | None = None
    # Cross-channel prediction (colours of an SH coefficient, the three scales, rotation).
    channel_prediction: bool = True
    # Neighbour prediction (version 1.1, without the hierarchy): rows coded in prediction_lods
    # levels of detail, each value from the mean of its prediction_neighbours nearest coarser
    # points with a scale level per activity bucket (prediction_buckets); used where it codes
    # smaller than the per-channel prior (encoder/stream/neighbour_coding.py); "always": wherever the
    # scene admits it (tests, conformance streams); False: never.
    neighbour_prediction: bool | str = True
    prediction_lods: int = 6
    prediction_neighbours: int = 6
    prediction_buckets: int = 5
    # Rate-distortion optimized quantization (encoder/gaussians/rdoq.py): each value rounded, moved one step
    # towards its prediction, or set to it, by the pictures' sensitivity to it against the bits
    # saved; this weighs the bits (1: the slope of each group's own step; 0: plain rounding).
    # Needs the sensitivities, which the rate-aware preparation measures.
    rd_quantization: float = 1.0
    # The sensitivities where no rate-aware preparation measures them: "none" (plain rounding) or
    # "uniform": every value of a group as sensitive as the next, so that RDOQ trades each value's
    # error against its bits at the group step's own slope, without renders (the fast preset: bench_real
    # fast -2.0 to -4.3% bytes at equal PSNR on the four shared scenes; a model from each Gaussian's
    # opacity, size and shape did no better, tools/results/search_sampling.md (i)).
    sensitivity_model: str = "none"
    # Step adjustment (version 1.2, clause 11.8; encoder/gaussians/rdoq.py step_adjust_indices): each
    # Gaussian's steps made 2^(a/4) times coarser, a in [0, step_adjust_max], by how little the
    # pictures see it: the Gaussians above the step_adjust_quantile of visibility keep the steps.
    # Needs the sensitivities and neighbour prediction (0: off).
    step_adjust_max: int = 0
    step_adjust_quantile: float = 0.9
    # The step-adjustment indices as flags (version 1.5, clause 11.8; a step_adjust_flags unit): used
    # where they code smaller than as symbols, the unit included (False: always as symbols, a version
    # 1.2-1.4 stream; tools/results/step_flags.md).
    step_adjust_flags: bool = True
    # Per-Gaussian SH degree (version 1.3, clause 11.9; encoder/gaussians/rdoq.py sh_degree_choice):
    # each Gaussian's SH bands above its own degree are not coded (they decode to 0) where the
    # pictures' error of dropping them costs less than their bits and flags by RDOQ's slopes; the
    # stream carries the tool only where some Gaussian drops a band and it codes smaller. Needs the
    # sensitivities, RDOQ and neighbour prediction (False: every band of every Gaussian coded). On in
    # the low preset only (tools/results/sh_degree.md).
    sh_degree_choice: bool = False
    # Rotations as a length index and x, y, z (version 1.4, clause 11.10; encoder/gaussians/rdoq.py):
    # channel w carries the index k of the quaternion's length 2^(-k/2), RDOQ's choice of length
    # per Gaussian, and w is implied by it and x, y, z (False: the four components coded). Without
    # sensitivities (no RDOQ) each quaternion is coded as given, w >= 0: a small w is then implied
    # from the rounded x, y, z poorly (playbot lod4 at fast's steps: -2.2 dB), so pair it with RDOQ.
    rotation_length: bool = False
    # The SH rest as coefficients of a per-scene transform (format 1.6, clause 11.11;
    # encoder/gaussians/sh_transform.py): the KLT of each Gaussian's SH-rest vector, fitted per scene,
    # quantized and coded in its coefficients; used where the rounded coefficients' ideal bits fall by
    # more than the unit's (False: the SH rest coded value by value; "always": wherever the scene has
    # an SH rest, for tests and conformance streams; tools/results/sh_coding.md).
    sh_transform: bool | str = False
    # Drop before anything else the Gaussians whose opacity (after the sigmoid) is below this: at
    # 1/255 those that 3DGS rasterizers never draw (alpha < 1/255 is skipped, render/rasterizer.py),
    # found without renders (the fast preset; 0: keep all)
    min_opacity: float = 0.0
    # Rate-aware preparation (encoder/gaussians/gaussian_fit.py), against renders of the source from
    # fit_views cameras at fit_resolution pixels, placed where the scene is watched from
    # (encoder/gaussians/gaussian_views.py): "orbit" (around an object), "inside" (from the free
    # space a room or street surrounds, looking outward), "both", or "auto" (free_space.py decides);
    # the capture's cameras instead where they are given (lghcc-enc --cameras, found beside an
    # INRIA training output)
    views: str = "auto"
    # After coding, the decoded scene is checked against the source on this many views of the same
    # kind that none of the encoder's stages used, at check_resolution pixels, so that what the
    # target promises can be seen (lghcc-enc's log, stats held_back_psnr; 0: no check)
    check_views: int = 12
    check_resolution: int = 256
    # With a target, the prepared scene's steps are moved onto it at the end (one common factor, as
    # the whole-scene check does: encoder/gaussians/gaussian_fit.py land_on_target) on this many
    # views of landing_resolution pixels, of the same kind again and seen by no other stage, in the
    # place of the trim after the fit and of the whole-scene check. Why: the search's views are
    # small (8 of 128 px at 150,000 Gaussians and above), and a target met on them leaves what a
    # viewer sees at larger sizes 1.9-4.3 dB below it (the donut). 12 views of 256 px, the check's
    # size, land the donut's low 0.8 dB under on 320 px views where 16 of 192 px left it 1.6 dB
    # under, at the same bytes / SPZ (tools/results/views.md (d)). (0: the trim and the check on
    # the search's views)
    landing_views: int = 12
    landing_resolution: int = 256
    fit_views: int = 24
    fit_resolution: int = 160
    # drop the least contributing Gaussians whose contributions add up to this share of the total;
    # from inside or the capture's cameras, as many as their largest shares of any one view add up
    # to at most this: no view loses more than this share of what it shows (0: keep all)
    prune_share: float = 0.0
    # what becomes of them: "drop" removes them, "merge" merges each into its nearest kept
    # neighbour within reach with the pair's moments kept (encoder/gaussians/merging.py)
    prune_mode: str = "drop"
    # then tune the kept Gaussians' attributes for this many steps with their quantization
    # simulated (0: code the source values as they are)
    fit_iterations: int = 0
    fit_lr_scale: float = 1.0
    # rate term of the fit: each step moves the values down the gradient of their estimated bits,
    # lr x fit_rate_lambda x step^2 per bit (encoder/gaussians/gaussian_fit.py; 0: distortion only)
    fit_rate_lambda: float = 0.0
    # Rate-distortion search of the settings above (encoder/gaussians/gaussian_rd.py): lambda in dB of
    # PSNR per doubling of the stream (0: code with the preset's settings as they are), on
    # search_views renders of search_resolution pixels.
    rd_lambda: float = 0.0
    # Quality asked for instead (the presets' way): PSNR in dB of the quantized scene against the
    # source on the search views; the search then finds the fewest bits that reach it (lambda
    # follows from it; 0: minimize at rd_lambda).
    target_psnr: float = 0.0
    search_views: int = 8
    search_resolution: int = 128
    # A smaller scene renders faster, so the search looks at it more closely: a scene of N
    # Gaussians gets s = search_reference_gaussians / N times the pixels (1 <= s <=
    # search_max_scale), sqrt(s) times the views (at most twice) and the rest as resolution
    # (encoder/gaussians/gaussian_rd.py, search_view_plan; 0: the views above on every scene).
    search_reference_gaussians: int = 150_000
    search_max_scale: float = 8.0
    # A larger scene than this is searched on a sample of about this many Gaussians in whole cells
    # of space (encoder/gaussians/search_sample.py), on the views its whole would get; the choice is then
    # checked on the whole scene (after the fit) and moved onto the target there by one common
    # factor on the steps if it misses (encoder/gaussians/gaussian_rd.py, meet_on_whole_scene). 0: the whole
    # scene, whatever its size. The search's time stops growing with the scene here: its trials
    # render and code every Gaussian they are given, so at 1M each whole-scene trial would cost
    # about 10x a sample's (the sampled medium takes about 15 min of a quiet machine there,
    # tools/results/scale.md). What the sample
    # costs in bytes at equal PSNR, against SPZ's envelope: +2.3% on the logo (307k), -1.1% to
    # +0.5% on the donut and playbot (forced samples); against the whole search's own curve +0.2%
    # to +0.9%, the donut +3.6% (tools/results/search_sampling.md (f), (h)).
    search_sample_gaussians: int = 100000
    # The sensitivities and the fit render every Gaussian for each view or step: a scene of N above
    # this many Gaussians gets fit_views x this / N views for its sensitivities (at least
    # MIN_SENSITIVITY_VIEWS, encoder/gaussians/gaussian_fit.py) and fit_iterations x this / N fitting steps,
    # so that neither costs more than on a scene of this size (0: the full views and steps).
    fit_reference_gaussians: int = 150_000
    # The fit and search views must resolve the scene's typical Gaussian to this many pixels: when
    # the orbit views do not, the contributions are measured on finer whole views and the fit and
    # the search add as many magnified crops (encoder/gaussians/gaussian_fit.py, "views that resolve the
    # Gaussians"). Raise it for scenes meant to be seen closer up.
    resolve_px: float = 0.1

    def validate(self) -> "GaussianEncoderConfig":
        super().validate()
        _check_steps(self, ("sh_dc_step", "opacity_step", "scale_step", "rotation_step", "position_step"))
        if len(self.sh_band_steps) != 3:
            raise InputError(f"sh_band_steps must give 3 steps (bands 1, 2, 3), got {self.sh_band_steps!r}")
        for v in self.sh_band_steps:
            if not (isinstance(v, (int, float)) and 0 < v < float("inf")):
                raise InputError(f"sh_band_steps must be positive finite numbers, got {self.sh_band_steps!r}")
        if self.neighbour_prediction not in (True, False, "always"):
            raise InputError(f"neighbour_prediction must be true, false or always, got {self.neighbour_prediction!r}")
        for name, hi in (("prediction_lods", 16), ("prediction_neighbours", 32), ("prediction_buckets", 16)):
            v = getattr(self, name)
            if not (isinstance(v, int) and 1 <= v <= hi):
                raise InputError(f"{name} must be an integer in [1, {hi}], got {v!r}")
        self._validate_rdoq()
        if self.sh_transform not in (True, False, "always"):
            raise InputError(f"sh_transform must be true, false or always, got {self.sh_transform!r}")
        for name in ("sh_degree_choice", "rotation_length"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.sh_degree is not None and self.sh_degree not in (0, 1, 2, 3):
            raise InputError(f"sh_degree must be 0..3 or None, got {self.sh_degree!r}")
        if not 0 <= self.target_psnr < 200 or not 0 <= self.rd_lambda < float("inf"):
            raise InputError(f"target_psnr must be in [0, 200) dB and rd_lambda >= 0, got {self.target_psnr}, "
                             f"{self.rd_lambda}")
        self._validate_pruning()
        self._validate_views()
        return self

    def _validate_rdoq(self) -> None:
        """How the values are chosen: RDOQ's weight, its sensitivities' source, step adjustment."""
        if not (isinstance(self.rd_quantization, (int, float)) and 0 <= self.rd_quantization < float("inf")):
            raise InputError(f"rd_quantization must be a number >= 0, got {self.rd_quantization!r}")
        if self.sensitivity_model not in ("none", "uniform"):
            raise InputError(f"sensitivity_model must be none or uniform, got {self.sensitivity_model!r}")
        if not (isinstance(self.step_adjust_max, int) and 0 <= self.step_adjust_max <= 7) \
                or not 0 < self.step_adjust_quantile <= 1:
            raise InputError(f"step_adjust_max must be an integer in [0, 7] and step_adjust_quantile in (0, 1], got "
                             f"{self.step_adjust_max!r}, {self.step_adjust_quantile!r}")

    def _validate_pruning(self) -> None:
        """What is removed before the coding, and how."""
        if not 0 <= self.min_opacity < 1:
            raise InputError(f"min_opacity must be in [0, 1), got {self.min_opacity}")
        if not 0 <= self.prune_share < 1:
            raise InputError(f"prune_share must be in [0, 1), got {self.prune_share}")
        if self.prune_mode not in ("drop", "merge"):
            raise InputError(f"prune_mode must be drop or merge, got {self.prune_mode!r}")

    def _validate_views(self) -> None:
        """The views of the fit, the search, the landing and the check."""
        for name, least in (("search", 1), ("landing", 0), ("check", 0)):
            views, resolution = getattr(self, f"{name}_views"), getattr(self, f"{name}_resolution")
            if views < least or resolution < 8:
                raise InputError(f"{name}_views must be >= {least} and {name}_resolution >= 8, got {views} and "
                                 f"{resolution}")
        if self.search_sample_gaussians < 0 or self.fit_reference_gaussians < 0:
            raise InputError(f"search_sample_gaussians and fit_reference_gaussians must be >= 0 (0: the whole scene), "
                             f"got {self.search_sample_gaussians} and {self.fit_reference_gaussians}")
        if self.search_reference_gaussians < 0 or not 1 <= self.search_max_scale <= 64:
            raise InputError(f"search_reference_gaussians must be >= 0 and search_max_scale in [1, 64], got "
                             f"{self.search_reference_gaussians} and {self.search_max_scale}")
        if not 0 <= self.resolve_px < float("inf"):
            raise InputError(f"resolve_px must be >= 0 and finite, got {self.resolve_px}")
        if self.fit_views < 1 or self.fit_resolution < 8 or self.fit_iterations < 0:
            raise InputError("fit_views must be >= 1, fit_resolution >= 8 and fit_iterations >= 0")
        if self.views not in VIEW_KINDS:
            raise InputError(f"views must be one of {', '.join(VIEW_KINDS)}, got {self.views!r}")


def channel_prediction_on(cfg: AttributeCodingConfig) -> bool:
    """Whether ``cfg`` asks for cross-channel prediction, a tool of explicit-Gaussian scenes."""
    return isinstance(cfg, GaussianEncoderConfig) and cfg.channel_prediction


def neighbour_prediction_on(cfg: AttributeCodingConfig) -> bool:
    """Whether ``cfg`` asks for neighbour prediction (true or "always"), a tool of explicit-Gaussian scenes."""
    return isinstance(cfg, GaussianEncoderConfig) and cfg.neighbour_prediction is not False


# Context-model sizes by number of level-2 points: (Ch, feature hidden, head hidden, weight bits).
# Measured on anchor scenes (tools/results/context.md): a 16-bit Ch=32 model (about 65 kB) pays for
# itself from about 20k level-2 points on; below, smaller 8-bit models (7-20 kB) keep most of the gain.
CONTEXT_MODEL_SIZES = ((8_000, (8, 16, 16, 8)), (50_000, (16, 32, 32, 8)), (None, (32, 64, 64, 16)))


def context_model_size(cfg: AttributeCodingConfig, num_level2: int) -> tuple[int, int, int, int]:
    """(Ch, feature hidden, head hidden, weight bits): the configured values, and for those left
    at None the size for ``num_level2`` points from CONTEXT_MODEL_SIZES."""
    auto = next(size for limit, size in CONTEXT_MODEL_SIZES if limit is None or num_level2 < limit)
    given = (cfg.context_channels, cfg.context_feat_hidden, cfg.context_head_hidden, cfg.context_weight_bits)
    return tuple(g if g is not None else a for g, a in zip(given, auto))


# lghcc-enc --mode anchors: what each preset asks of the transcoder (encoder/anchors/transcode.py, step 4
# of its module doc). The anchors section of the coding preset (presets/<name>.yaml or
# lghcc-<name>.yaml) gives the quantization steps the fit simulates and the hierarchy and context
# its rate term models (transcode.preset_transcode_config); the lghcc-* presets share these
# settings. A step up asks for a smaller rate weight and a longer fit (measurements:
# tools/results/transcode.md). Fit renders are 256 px: at 128 px the same stream size lost 2 dB
# against 320 px orbit renders of the source (playbot lod4, 32.0 -> 30.0 dB).
TRANSCODE_PRESETS: dict[str, dict] = {
    "low": {"rate_lambda": 0.02, "iterations": 300, "distill_steps": 300, "prune_keep": 0.8, "resolution": 256},
    "medium": {"rate_lambda": 0.005, "iterations": 500, "distill_steps": 400, "prune_keep": 0.9, "resolution": 256},
    "high": {"rate_lambda": 0.001, "iterations": 800, "distill_steps": 400, "prune_keep": 1.0, "resolution": 256},
}


# The kinds of scene a preset can have a section for (encoder/presets/<name>.yaml), as the messages name them
PRESET_KINDS = {"anchors": "anchor scenes", "gaussians": "explicit-Gaussian scenes"}


@functools.cache
def _presets() -> dict[str, dict[str, dict]]:
    """Every preset: its name (the file's, less .yaml) -> {kind of scene: its fields}."""
    presets = {}
    for p in resources.files("lghcc.encoder").joinpath("presets").iterdir():
        if p.name.endswith(".yaml"):
            data = yaml.safe_load(p.read_text()) or {}
            if not isinstance(data, dict) or not set(data) <= set(PRESET_KINDS):
                raise InputError(f"preset file {p.name}: expected sections {' and/or '.join(PRESET_KINDS)}")
            presets[p.name[:-5]] = data
    return presets


def preset_names(kind: str | None = "anchors") -> list[str]:
    """The presets of anchor scenes (``kind`` "anchors"), of explicit-Gaussian scenes ("gaussians")
    or all of them (None): the names lghcc-enc --preset takes, one file each."""
    if kind is not None and kind not in PRESET_KINDS:
        raise ValueError(f"kind must be one of {', '.join(PRESET_KINDS)}, got {kind!r}")
    return sorted(name for name, sections in _presets().items() if kind is None or kind in sections)


def _preset_fields(preset: str, kind: str) -> dict:
    """The section of ``preset`` for ``kind``; InputError naming the choices when there is none."""
    presets = _presets()
    if preset not in presets:
        raise InputError(f"unknown preset {preset!r}; choose one of {', '.join(preset_names(None))}")
    if kind not in presets[preset]:
        raise InputError(f"preset {preset!r} has no settings for {PRESET_KINDS[kind]} (it is for "
                         f"{' and '.join(PRESET_KINDS[k] for k in presets[preset])}); for {PRESET_KINDS[kind]} "
                         f"choose one of {', '.join(preset_names(kind))}")
    return presets[preset][kind] or {}


# Fields renamed, each old name kept one release: it warns (InputWarning) and sets the new field
RENAMED_FIELDS = {"context_train_anchors": "context_train_points"}


def _renamed(data: dict, source: str) -> dict:
    for old, new in RENAMED_FIELDS.items():
        if old in data:
            if new in data:
                raise InputError(f"{source}: {old} and {new} are the same option; give {new} only")
            warnings.warn(InputWarning(f"{source}: {old} is deprecated and will be removed: use {new}"), stacklevel=4)
            data = {(new if k == old else k): v for k, v in data.items()}
    return data


def _apply(cfg, data: dict, source: str):
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a mapping of option: value")
    data = _renamed(data, source)
    fields = {f.name for f in dataclasses.fields(cfg)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise InputError(f"{source}: unknown option(s) {', '.join(unknown)} (known: {', '.join(sorted(fields))})")
    if "sh_band_steps" in data and isinstance(data["sh_band_steps"], list):
        data = {**data, "sh_band_steps": tuple(data["sh_band_steps"])}
    return dataclasses.replace(cfg, **data)


def load_config(preset: str = "medium", config_file: str | Path | None = None,
                overrides: dict | None = None, kind: str = "anchors"):
    """The configuration of ``preset`` for anchor scenes (EncoderConfig: the preset file's anchors
    section) or, with ``kind`` "gaussians", explicit-Gaussian scenes (GaussianEncoderConfig: its
    gaussians section), then the fields of ``config_file`` (YAML) and ``overrides`` (None values
    ignored). InputError for an unknown preset or one without a section for ``kind``."""
    fields = _preset_fields(preset, kind)
    base = GaussianEncoderConfig() if kind == "gaussians" else EncoderConfig()
    cfg = _apply(base, fields, f"preset {preset}")
    if config_file is not None:
        try:
            data = yaml.safe_load(Path(config_file).read_text())
        except (OSError, yaml.YAMLError) as e:
            raise InputError(f"{config_file}: cannot read the configuration ({e})") from None
        cfg = _apply(cfg, data or {}, str(config_file))
    if overrides:
        cfg = _apply(cfg, {k: v for k, v in overrides.items() if v is not None}, "command line")
    return cfg.validate()
