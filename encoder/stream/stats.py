"""What the encoder reports about one encoding (informative): typed records, and their JSON
form (``to_json``), the flat key-value object lghcc-enc --json writes under "stats".

A field that is None (or an empty table) was not measured in this encoding (no pruning, no
hierarchy, no context model fit, ...) and is left out of the JSON object.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..anchors.transcode import TranscodeStats


def _present(items: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in items.items() if v is not None}


@dataclass
class ContextFitStats:
    """The context-model fits of level 2: what each candidate coded to, and which was kept."""
    error: str | None = None  # why the last failed fit failed (the per-channel prior codes then)
    # the smallest stream (attribute unit + context model unit) of each candidate kind, when more than one is fitted
    bytes_by_neighbour_level: dict[int, int] = field(default_factory=dict)
    bytes_by_parent_base: dict[str, int] = field(default_factory=dict)
    bytes_with_context: int | None = None  # the smallest candidate's stream
    parent_base: str | None = None  # its parent_base mode ("twin": the fit started from the context twin)
    time_s: float = 0.0
    bytes_per_channel_prior: int = 0  # level 2 coded with the per-channel prior

    def to_json(self) -> dict[str, Any]:
        out = _present({"context_fit_error": self.error})
        out.update({f"level2_bytes_with_ggconv_neighbour_level_{lv}": b
                    for lv, b in self.bytes_by_neighbour_level.items()})
        out.update({f"level2_bytes_with_parent_base_{base}": b for base, b in self.bytes_by_parent_base.items()})
        if self.bytes_with_context is not None:
            out.update(level2_bytes_with_context=self.bytes_with_context, context_parent_base=self.parent_base)
        out.update(time_context_fit_s=self.time_s, level2_bytes_per_channel_prior=self.bytes_per_channel_prior)
        return out


@dataclass
class LevelStats:
    """The attribute unit of one hierarchy level (0: no hierarchy, 1, 2)."""
    context_model: str  # CONTEXT_MODEL_NAMES of the coding kept
    attribute_bytes: int  # its payload
    channel_predictions: int | None = None  # cross-channel predictions (Gaussian scenes)
    context_fit: ContextFitStats | None = None  # level 2 with a context model configured

    def to_json(self, level: int) -> dict[str, Any]:
        out = self.context_fit.to_json() if self.context_fit is not None else {}
        out[f"level{level}_context_model"] = self.context_model
        if self.channel_predictions is not None:
            out[f"level{level}_channel_predictions"] = self.channel_predictions
        out[f"attribute_bytes_level{level}"] = self.attribute_bytes
        return out


@dataclass
class PrepareStats:
    """The rate-aware preparation of a Gaussian scene (encoder/gaussians/gaussian_fit.py)."""
    gaussians_in: int
    time_contributions_s: float = 0.0
    time_sensitivities_s: float | None = None  # for rate-distortion optimized quantization (encoder/gaussians/rdoq.py)
    time_search_s: float | None = None  # the settings search (a quality or lambda asked for)
    search_trials: int | None = None
    search_sample_gaussians: int | None = None  # searched on a sample of the scene (encoder/gaussians/search_sample.py)
    search_sample_ratio: float | None = None  # the whole scene's squared error over the sample's, same settings
    time_whole_check_s: float | None = None  # the sampled choice checked (and moved) on the whole scene
    whole_check_trials: int | None = None
    gaussians_pruned: int = 0
    voxel_size: float = 0.0
    gaussians_moved_off_shared_voxels: int = 0
    time_fit_s: float | None = None  # the fit (fit_iterations > 0)
    fit_final_mse: float | None = None  # squared error on the fit views, mean of the last 20 steps
    time_trim_s: float | None = None  # the steps moved onto the target quality after the fit
    trim_bits_before: float | None = None
    trim_bits_after: float | None = None
    time_landing_s: float | None = None  # the steps moved onto the target on the landing views
    landing_trials: int | None = None
    views: str = "orbit"  # where the views looked from (encoder/gaussians/gaussian_views.py)
    views_reason: str = ""
    held_back_views: int | None = None  # the check on views the encoder did not use (check_views)
    held_back_psnr: float | None = None  # dB, of the mean squared error over them: what the target means
    held_back_worst_psnr: float | None = None  # dB, the worst of them
    time_held_back_s: float | None = None
    time_total_s: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return _present(dict(vars(self)))


@dataclass
class EncodeStats:
    """One encoding: what was done to the scene, the sizes of the coded levels, the timings."""
    pruning: str | None = None  # the PruneReport of an anchor scene's pruning
    anchors_before_pruning: int | None = None
    sh_degree_dropped_from: int | None = None  # a Gaussian scene coded at a lower SH degree (sh_degree)
    gaussians_moved_off_shared_voxels: int | None = None  # a Gaussian scene snapped to its grid here
    time_geometry_s: float = 0.0
    num_level1: int | None = None  # the hierarchy, when used
    num_level2: int | None = None
    num_tiles: int = 1  # tiles of the stream (format version 1; 1: no tiles)
    neighbour_prediction: bool | None = None  # a Gaussian scene without the hierarchy: the tool is used (1.1)
    context_twin_unused: str | None = None  # why the context twin given does not fit the configuration
    attribute_ideal_bits: float | None = None  # the model's ideal code length (measure_ideal)
    attribute_coded_bits: int = 0  # the attribute chunks as coded
    step_adjust_coded_bits: int | None = None  # the step-adjustment index chunks as coded (format 1.2)
    step_adjust_counts: list[int] | None = None  # how many Gaussians have each step-adjustment index
    step_adjust_flags: bool | None = None  # the indices coded as flags (format 1.5), else as symbols
    sh_degree_coded_bits: int | None = None  # the SH-degree flag chunks as coded (format 1.3)
    sh_degree_counts: list[int] | None = None  # how many Gaussians have each SH degree
    sh_transform: bool | None = None  # the SH rest coded as transform coefficients (format 1.6)
    levels: dict[int, LevelStats] = field(default_factory=dict)  # by attribute level
    time_attributes_s: float = 0.0
    time_total_s: float = 0.0
    stage_times_s: dict[str, float] = field(default_factory=dict)  # by stage of the coding (encode.stage)
    prepare: PrepareStats | None = None  # a Gaussian scene prepared before coding (lghcc.encoder.api)
    settings: str | None = None  # a Gaussian scene: the settings coded with, in words
    verified: bool = False  # the written stream was decoded again and gave the encoded scene's hash
    transcode: TranscodeStats | None = None  # the transcode that made the anchor scene (lghcc-enc --mode anchors)

    @property
    def context_fit(self) -> ContextFitStats | None:
        """The context-model fits of level 2 (None: none was fitted)."""
        return next((s.context_fit for s in self.levels.values() if s.context_fit is not None), None)

    def to_json(self) -> dict[str, Any]:
        """The flat JSON object (lghcc-enc --json "stats"); a prepare_ prefix on the preparation's keys,
        a transcode_ prefix on the transcode's."""
        out = _present({k: getattr(self, k) for k in (
            "pruning", "anchors_before_pruning", "sh_degree_dropped_from", "gaussians_moved_off_shared_voxels",
            "time_geometry_s", "num_level1", "num_level2", "num_tiles", "neighbour_prediction", "context_twin_unused", "attribute_ideal_bits",
            "attribute_coded_bits", "step_adjust_coded_bits", "step_adjust_counts", "step_adjust_flags",
            "sh_degree_coded_bits",
            "sh_degree_counts", "sh_transform")})
        for level, level_stats in self.levels.items():
            out.update(level_stats.to_json(level))
        out.update(time_attributes_s=self.time_attributes_s, time_total_s=self.time_total_s)
        if self.stage_times_s:
            out["stage_times_s"] = dict(self.stage_times_s)
        if self.prepare is not None:
            out.update({f"prepare_{k}": v for k, v in self.prepare.to_json().items()})
        out.update(_present({"settings": self.settings, "verified": True if self.verified else None}))
        if self.transcode is not None:
            out.update({f"transcode_{k}": v for k, v in self.transcode.to_json().items()})
        return out
