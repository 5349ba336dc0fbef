"""Syntax of the data-unit payloads (spec clause 7). One class per structure; its
``syntax()`` is the single description that reads, writes, sizes and documents it.

Fields that are not syntax elements but context from earlier structures (counts the
syntax depends on) are plain dataclass fields listed in ``context`` comments.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .bitio import BitReader
from .entropy.scale_levels import SCALE_LEVEL_BITS as NUM_SCALE_LEVELS_BITS
from .syntax import SyntaxStructure, SyntaxVisitor

# Profile "main", level limits (spec clause 8). A decoder rejects streams beyond them,
# so no allocation is ever sized by an unchecked field.
MAX_POINTS = 1 << 24
MAX_FEATURE_DIM = 1024
MAX_NUM_OFFSETS = 64
MAX_ATTRIBUTE_VALUES = 1 << 31  # N * M: points x attribute channels
MAX_MLPS = 4
MAX_MLP_LAYERS = 8
MAX_MLP_WIDTH = 4096
MAX_EXPONENT = 64
MASK_PROB_BITS = 12
PRIOR_MEAN_MAX = (1 << 31) - 1  # |prior_mean|: the magnitudes se(v) codes (common/bitio.py)

MAX_COARSE_VOXEL_SCALE = 1 << 20
MAX_TILE_SCALE = 1 << 20  # tile side in coarse voxels (clause 7.3.1)
MAX_SH_DEGREE = 3
# Cross-channel prediction (Gaussian scenes, clause 11.6): weights are se(v) in units of
# 2^-CHANNEL_PREDICTION_SHIFT; decoded values must stay within +-MAX_PREDICTED_MAGNITUDE so that
# every prediction sum fits in 64 bits.
CHANNEL_PREDICTION_SHIFT = 8
MAX_CHANNEL_PREDICTION_WEIGHT = 1 << 15
MAX_PREDICTED_MAGNITUDE = 1 << 40
# attribute_level values
LEVEL_ALL = 0  # no hierarchy: one attribute unit holds every anchor
LEVEL_1 = 1  # one anchor per coarse voxel
LEVEL_2 = 2  # the rest, coded with a context from level 1
# context_model_id values
CONTEXT_PER_CHANNEL_PRIOR = 0
CONTEXT_PARENT_MLP = 1  # Context-GS style "vanilla EM": an MLP over the parent's decoded attributes
CONTEXT_GGCONV = 2  # LG-HCC: GG-Conv over the Ball k-NN graph of level 2
MAX_CONTEXT_MODEL_ID = CONTEXT_GGCONV
# Neighbour prediction (version 1.1, clause 7.3.12): levels of detail, neighbours, activity buckets
MAX_LOD_LEVELS = 16
MAX_PREDICTION_NEIGHBOURS = 32
MAX_ACTIVITY_BUCKETS = 16
# Step adjustment (version 1.2, clause 7.3.13): per-row indices into STEP_ADJUST_FACTORS (0..7)
MAX_STEP_ADJUST = 7
STEP_ADJUST_BITS = 3
MAX_ROTATION_LENGTH_INDEX = 15  # clause 11.10: lengths 2^(-k/2), k = 0 .. 15
ROTATION_LENGTH_BITS = 4
# Per-Gaussian SH degree (version 1.3, clause 7.3.14): binary band flags, one probability per band
# and context, u(12) in units of 2^-12
NUM_DEGREE_CONTEXTS = 6
NUM_STEP_FLAG_CONTEXTS = NUM_DEGREE_CONTEXTS  # version 1.5: the step-adjustment flags use the SH-degree flags' contexts
DEGREE_PROB_BITS = 12
# SH transform (version 1.6, clause 7.3.17): an integer matrix of NumShRest x NumShRest entries of
# sh_transform_bits_minus1 + 1 bits (offset binary) and a rounding shift (clause 11.11)
SH_TRANSFORM_SHIFT_BITS = 5
SH_TRANSFORM_MAX_SHIFT = 31
SH_TRANSFORM_BITS_BITS = 4
SH_TRANSFORM_MAX_BITS = 16

HASH_TYPE_SHA256 = 1


def tile_syntax(ps, v: SyntaxVisitor) -> None:
    """The tile elements ending both parameter sets (version 1, clause 7.3.1)."""
    v.flag(ps, "tiles_enabled_flag")
    for _ in v.when(ps.tiles_enabled_flag, "tiles_enabled_flag"):
        v.ue(ps, "tile_scale_minus1", hi=MAX_TILE_SCALE - 1)


def tile_size_of(ps) -> int:
    """TileSize, the side of a tile in voxels (clause 7.3.1): tile_scale_minus1 + 1 coarse voxels
    (voxels without the hierarchy), so that no coarse voxel straddles two tiles. 0: no tiles."""
    if not ps.tiles_enabled_flag:
        return 0
    return (ps.tile_scale_minus1 + 1) * (ps.coarse_voxel_scale if ps.hierarchy_enabled_flag else 1)


@dataclass
class SceneParameterSet(SyntaxStructure):
    """sps: the dimensions of the scene and the quantization of its attributes."""

    syntax_name = "scene_parameter_set"
    clause = "7.3.1"
    num_anchors_minus1: int = 0
    feature_dim_minus1: int = 0
    num_offsets_minus1: int = 0
    voxel_size: float = 1.0
    origin: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    offset_mask_present_flag: int = 0
    feature_step: float = 1.0
    scaling_step: float = 1.0
    offset_step: float = 1.0
    hierarchy_enabled_flag: int = 0
    coarse_voxel_scale_minus1: int = 0
    tiles_enabled_flag: int = 0
    tile_scale_minus1: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.ue(self, "num_anchors_minus1", hi=MAX_POINTS - 1)
        v.ue(self, "feature_dim_minus1", hi=MAX_FEATURE_DIM - 1)
        v.ue(self, "num_offsets_minus1", hi=MAX_NUM_OFFSETS - 1)
        v.f32(self, "voxel_size", positive=True)
        for i in v.loop(3, "3", self, ("origin",)):
            v.f32(self, "origin", i)
        v.flag(self, "offset_mask_present_flag")
        v.f32(self, "feature_step", positive=True)
        v.f32(self, "scaling_step", positive=True)
        v.f32(self, "offset_step", positive=True)
        v.flag(self, "hierarchy_enabled_flag")
        for _ in v.when(self.hierarchy_enabled_flag, "hierarchy_enabled_flag"):
            v.ue(self, "coarse_voxel_scale_minus1", hi=MAX_COARSE_VOXEL_SCALE - 1)
        tile_syntax(self, v)

    # derived values (spec 7.4.1)
    @property
    def coarse_voxel_scale(self) -> int:
        return self.coarse_voxel_scale_minus1 + 1

    @property
    def tile_size(self) -> int:
        return tile_size_of(self)

    @property
    def num_anchors(self) -> int:
        return self.num_anchors_minus1 + 1

    @property
    def num_points(self) -> int:  # N of clause 7.4.1: the geometry's points, as for the gps
        return self.num_anchors

    @property
    def feature_dim(self) -> int:
        return self.feature_dim_minus1 + 1

    @property
    def num_offsets(self) -> int:
        return self.num_offsets_minus1 + 1


@dataclass
class GaussianParameterSet(SyntaxStructure):
    """gps: the dimensions and quantization of an explicit-Gaussian scene (clause 7.3.9). Every
    Gaussian is a point of the geometry unit with its SH colour, opacity, scales and rotation."""

    syntax_name = "gaussian_parameter_set"
    clause = "7.3.9"
    num_gaussians_minus1: int = 0
    sh_degree: int = 0
    voxel_size: float = 1.0
    origin: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    sh_dc_step: float = 1.0
    sh_band_step: list = field(default_factory=list)
    opacity_step: float = 1.0
    scale_step: float = 1.0
    rotation_step: float = 1.0
    hierarchy_enabled_flag: int = 0
    coarse_voxel_scale_minus1: int = 0
    tiles_enabled_flag: int = 0
    tile_scale_minus1: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.ue(self, "num_gaussians_minus1", hi=MAX_POINTS - 1)
        v.u(2, self, "sh_degree", hi=MAX_SH_DEGREE)
        v.f32(self, "voxel_size", positive=True)
        for i in v.loop(3, "3", self, ("origin",)):
            v.f32(self, "origin", i)
        v.f32(self, "sh_dc_step", positive=True)
        for b in v.loop(self.sh_degree, "sh_degree", self, ("sh_band_step",), index="b"):
            v.f32(self, "sh_band_step", b, positive=True)
        v.f32(self, "opacity_step", positive=True)
        v.f32(self, "scale_step", positive=True)
        v.f32(self, "rotation_step", positive=True)
        v.flag(self, "hierarchy_enabled_flag")
        for _ in v.when(self.hierarchy_enabled_flag, "hierarchy_enabled_flag"):
            v.ue(self, "coarse_voxel_scale_minus1", hi=MAX_COARSE_VOXEL_SCALE - 1)
        tile_syntax(self, v)

    # derived values (clause 7.3.9)
    @property
    def num_gaussians(self) -> int:
        return self.num_gaussians_minus1 + 1

    @property
    def num_points(self) -> int:  # N: the geometry's points, as for the sps
        return self.num_gaussians

    @property
    def coarse_voxel_scale(self) -> int:
        return self.coarse_voxel_scale_minus1 + 1

    @property
    def tile_size(self) -> int:
        return tile_size_of(self)


@dataclass
class RenderMlpHeader(SyntaxStructure):
    syntax_name = "render_mlp_header"
    clause = "7.3.3"
    mlp_role: int = 0
    num_layers_minus1: int = 0
    input_dim_minus1: int = 0
    output_dim_minus1: list = field(default_factory=list)
    activation: list = field(default_factory=list)
    weight_exponent: list = field(default_factory=list)
    weight_level: list = field(default_factory=list)
    bias_exponent: list = field(default_factory=list)
    bias_level: list = field(default_factory=list)

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(2, self, "mlp_role")
        v.ue(self, "num_layers_minus1", hi=MAX_MLP_LAYERS - 1)
        v.ue(self, "input_dim_minus1", hi=MAX_MLP_WIDTH - 1)
        arrays = ("output_dim_minus1", "activation", "weight_exponent", "weight_level", "bias_exponent",
                  "bias_level")
        for l in v.loop(self.num_layers_minus1 + 1, "num_layers_minus1 + 1", self, arrays, index="l"):
            v.ue(self, "output_dim_minus1", l, hi=MAX_MLP_WIDTH - 1)
            v.u(2, self, "activation", l)
            v.se(self, "weight_exponent", l, lo=-MAX_EXPONENT, hi=MAX_EXPONENT)
            v.u(NUM_SCALE_LEVELS_BITS, self, "weight_level", l)
            v.se(self, "bias_exponent", l, lo=-MAX_EXPONENT, hi=MAX_EXPONENT)
            v.u(NUM_SCALE_LEVELS_BITS, self, "bias_level", l)


@dataclass
class RenderModelUnit(SyntaxStructure):
    """The render MLPs (R_model): layer shapes, per-tensor exponents and table levels,
    then every weight and bias entropy coded in one chunk."""

    syntax_name = "render_model_unit"
    clause = "7.3.2"
    num_mlps: int = 0
    mlps: list = field(default_factory=list)
    coded_size: int = 0
    coded_data: bytes = b""

    def syntax(self, v: SyntaxVisitor) -> None:
        v.ue(self, "num_mlps", hi=MAX_MLPS)
        for m in v.loop(self.num_mlps, "num_mlps", self, ("mlps",), index="m"):
            v.struct(self, "mlps", m, RenderMlpHeader)
        v.ue(self, "coded_size")
        v.byte_align()
        v.payload(self, "coded_data", self.coded_size)


@dataclass
class AttributeUnitHeader(SyntaxStructure):
    """Header of an attribute unit; the chunk payloads follow it, in order."""

    syntax_name = "attribute_unit_header"
    clause = "7.3.5"
    # context (from the sps and the level): not syntax elements
    num_channels: int = 1
    num_offsets: int = 1
    offset_mask_present: int = 0
    num_rows: int = 1
    channel_prediction_allowed: int = 0  # 1 in Gaussian scenes
    # syntax elements
    attribute_level: int = 0
    context_model_id: int = 0
    prior_mean: list = field(default_factory=list)
    prior_level: list = field(default_factory=list)
    mask_live_prob: list = field(default_factory=list)
    num_channel_predictions: int = 0
    pred_target_channel: list = field(default_factory=list)
    pred_source_channel: list = field(default_factory=list)
    pred_weight: list = field(default_factory=list)
    num_rows_minus1: int | None = None  # None: num_rows - 1 (the value an encoder writes)
    rows_per_chunk_minus1: int = 0
    # context (clause 7.3.12): the number of LoDs when the stream has a neighbour_prediction unit
    # (each LoD's rows are chunked on their own), 0 otherwise
    num_lods: int = 0
    # context (clause 7.3.13): 1 when the stream has a step_adjust unit
    step_adjust_present: int = 0
    adjust_mean: int = 0
    adjust_level: int = 0
    # context (clause 7.3.14): 1 when the stream has an sh_degree unit
    sh_degree_present: int = 0
    mask_chunk_size: list = field(default_factory=list)
    adjust_chunk_size: list = field(default_factory=list)
    degree_chunk_size: list = field(default_factory=list)
    chunk_size: list = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.num_rows_minus1 is None:
            self.num_rows_minus1 = self.num_rows - 1

    @property
    def rows_per_chunk(self) -> int:
        return self.rows_per_chunk_minus1 + 1

    @property
    def num_chunks(self) -> int:
        """NumChunks: ceil(NumRows / rows_per_chunk), or with LoDs the sum of that over the LoDs'
        row counts (clause 7.3.12), computed without materializing the rows."""
        rows = self.num_rows if self.num_rows_minus1 is None else self.num_rows_minus1 + 1
        rpc = self.rows_per_chunk
        if not self.num_lods:
            return -(-rows // rpc)
        return sum(-(-size // rpc) for size in lod_sizes_of(rows, self.num_lods))

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(2, self, "attribute_level", hi=LEVEL_2)
        v.u(3, self, "context_model_id", hi=MAX_CONTEXT_MODEL_ID)
        for _ in v.when(self.context_model_id == CONTEXT_PER_CHANNEL_PRIOR,
                        "context_model_id == 0"):
            for c in v.loop(self.num_channels, "NumChannels", self, ("prior_mean", "prior_level"), index="c"):
                v.se(self, "prior_mean", c, lo=-PRIOR_MEAN_MAX, hi=PRIOR_MEAN_MAX)
                v.u(NUM_SCALE_LEVELS_BITS, self, "prior_level", c)
        for _ in v.when(self.offset_mask_present, "offset_mask_present_flag"):
            for k in v.loop(self.num_offsets, "NumOffsets", self, ("mask_live_prob",), index="k"):
                v.u(MASK_PROB_BITS, self, "mask_live_prob", k, lo=1, hi=(1 << MASK_PROB_BITS) - 1)
        for _ in v.when(self.channel_prediction_allowed, "ChannelPredictionAllowed"):
            m = self.num_channels
            v.ue(self, "num_channel_predictions", hi=m * (m - 1) // 2)
            names = ("pred_target_channel", "pred_source_channel", "pred_weight")
            for i in v.loop(self.num_channel_predictions, "num_channel_predictions", self, names):
                v.ue(self, "pred_target_channel", i, lo=1, hi=m - 1)
                v.ue(self, "pred_source_channel", i, hi=m - 2)
                v.se(self, "pred_weight", i, lo=-MAX_CHANNEL_PREDICTION_WEIGHT, hi=MAX_CHANNEL_PREDICTION_WEIGHT)
        for _ in v.when(self.step_adjust_present, "StepAdjustPresent"):
            v.u(STEP_ADJUST_BITS, self, "adjust_mean")
            v.u(NUM_SCALE_LEVELS_BITS, self, "adjust_level")
        v.ue(self, "num_rows_minus1", hi=MAX_POINTS - 1)  # = NumRows - 1: checked after parsing (clause 8.3)
        v.ue(self, "rows_per_chunk_minus1", hi=self.num_rows_minus1)
        sizes = ("mask_chunk_size",) * bool(self.offset_mask_present) \
            + ("adjust_chunk_size",) * bool(self.step_adjust_present) \
            + ("degree_chunk_size",) * bool(self.sh_degree_present) + ("chunk_size",)
        for i in v.loop(self.num_chunks, "NumChunks", self, sizes):
            for _ in v.when(self.offset_mask_present, "offset_mask_present_flag"):
                v.ue(self, "mask_chunk_size", i)
            for _ in v.when(self.step_adjust_present, "StepAdjustPresent"):
                v.ue(self, "adjust_chunk_size", i)
            for _ in v.when(self.sh_degree_present, "ShDegreePresent"):
                v.ue(self, "degree_chunk_size", i)
            v.ue(self, "chunk_size", i)
        v.byte_align()


def lod_sizes_of(num_rows: int, num_lods: int) -> list[int]:
    """The number of rows of each LoD (clause 7.3.12): LoD 0 holds the multiples of 2^(L-1),
    LoD l >= 1 the rows i with ctz(i) = L - 1 - l."""
    if num_lods == 1:
        return [num_rows]
    top = 1 << (num_lods - 1)
    sizes = [-(-num_rows // top)]
    for level in range(1, num_lods):
        t = num_lods - 1 - level  # rows with exactly t trailing zeros: multiples of 2^t, not of 2^(t+1)
        sizes.append(-(-num_rows // (1 << t)) - -(-num_rows // (1 << (t + 1))))
    return sizes


@dataclass
class NeighbourPredictionUnit(SyntaxStructure):
    """neighbour_prediction unit (0x09, version 1.1, clause 7.3.12): the attribute units of a
    Gaussian stream without the hierarchy code their rows in levels of detail, each row of
    LoD >= 1 with a mean and scale level from its k nearest coarser neighbours (clause 11.7)."""

    syntax_name = "neighbour_prediction_unit"
    clause = "7.3.12"
    num_channels: int = 1  # context: NumChannels of the parameter set
    num_lods_minus1: int = 0
    num_neighbours_minus1: int = 0
    num_buckets_minus1: int = 0
    neighbour_mean_flag: list = field(default_factory=list)
    bucket_level: list = field(default_factory=list)
    # context (clause 7.3.13): the stream's step_adjust unit, None without one (not a syntax element)
    step_adjust: StepAdjustUnit | None = None
    # context (clause 7.3.14): the stream's sh_degree unit, None without one (not a syntax element)
    sh_degree_unit: ShDegreeUnit | None = None
    # context (clause 7.3.16): the stream's step_adjust_flags unit, None without one (not a syntax element)
    step_flags: StepAdjustFlagsUnit | None = None

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(4, self, "num_lods_minus1", hi=MAX_LOD_LEVELS - 1)
        v.u(5, self, "num_neighbours_minus1", hi=MAX_PREDICTION_NEIGHBOURS - 1)
        v.u(4, self, "num_buckets_minus1", hi=MAX_ACTIVITY_BUCKETS - 1)
        for c in v.loop(self.num_channels, "NumChannels", self, ("neighbour_mean_flag",), index="c"):
            v.flag(self, "neighbour_mean_flag", c)
        count = self.num_channels * (self.num_buckets_minus1 + 1)
        for i in v.loop(count, "NumChannels * (num_buckets_minus1 + 1)", self, ("bucket_level",)):
            v.u(NUM_SCALE_LEVELS_BITS, self, "bucket_level", i)
        v.byte_align()

    @property
    def num_lods(self) -> int:
        return self.num_lods_minus1 + 1

    @property
    def num_neighbours(self) -> int:
        return self.num_neighbours_minus1 + 1

    @property
    def num_buckets(self) -> int:
        return self.num_buckets_minus1 + 1


@dataclass
class StepAdjustUnit(SyntaxStructure):
    """step_adjust unit (0x0A, version 1.2, clause 7.3.13): every row of a Gaussian stream coded
    with neighbour prediction carries a step-adjustment index a in [0, max_step_adjust]; its
    values are in steps of float32(step) * STEP_ADJUST_FACTORS[a] (clause 11.8)."""

    syntax_name = "step_adjust_unit"
    clause = "7.3.13"
    max_step_adjust: int = MAX_STEP_ADJUST

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(STEP_ADJUST_BITS, self, "max_step_adjust")
        v.byte_align()


@dataclass
class ShDegreeUnit(SyntaxStructure):
    """sh_degree unit (0x0B, version 1.3, clause 7.3.14): every row of a Gaussian stream coded
    with neighbour prediction has an SH degree D in [0, sh_degree], coded as binary band flags
    (clause 11.9); ``degree_flag_prob[(b - 1) * NumDegreeContexts + x]`` is the probability (in
    2^-12, plus half a unit) of band b's flag in context x."""

    syntax_name = "sh_degree_unit"
    clause = "7.3.14"
    sh_degree: int = 0  # context: d of the gaussian_parameter_set
    degree_flag_prob: list = field(default_factory=list)

    def syntax(self, v: SyntaxVisitor) -> None:
        count = self.sh_degree * NUM_DEGREE_CONTEXTS
        for i in v.loop(count, "sh_degree * NumDegreeContexts", self, ("degree_flag_prob",)):
            v.u(DEGREE_PROB_BITS, self, "degree_flag_prob", i)
        v.byte_align()


@dataclass
class StepAdjustFlagsUnit(SyntaxStructure):
    """step_adjust_flags unit (0x0D, version 1.5, clause 7.3.16): the step-adjustment indices of a
    stream with a step_adjust unit are coded as binary flags "a >= b" (clause 11.8, as clause 11.9
    codes SH degrees); ``step_flag_prob[(b - 1) * NumStepFlagContexts + x]`` is the probability (in
    2^-12, plus half a unit) that a row whose flag of b is coded with context x has an index of at
    least b. The attribute unit headers' adjust_mean and adjust_level are then 0 (E67)."""

    syntax_name = "step_adjust_flags_unit"
    clause = "7.3.16"
    max_step_adjust: int = 0  # context: max_step_adjust of the step_adjust unit
    step_flag_prob: list = field(default_factory=list)

    def syntax(self, v: SyntaxVisitor) -> None:
        count = self.max_step_adjust * NUM_STEP_FLAG_CONTEXTS
        for i in v.loop(count, "max_step_adjust * NumStepFlagContexts", self, ("step_flag_prob",)):
            v.u(DEGREE_PROB_BITS, self, "step_flag_prob", i)
        v.byte_align()


@dataclass
class RotationLengthUnit(SyntaxStructure):
    """rotation_length unit (0x0C, version 1.4, clause 7.3.15): the rotation channel w of every
    Gaussian carries a length index k in [0, max_rotation_length_index], and the rotation's w
    component is implied by k and x, y, z (clause 11.10)."""

    syntax_name = "rotation_length_unit"
    clause = "7.3.15"
    max_rotation_length_index: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(ROTATION_LENGTH_BITS, self, "max_rotation_length_index")
        v.byte_align()


@dataclass
class ShTransformUnit(SyntaxStructure):
    """sh_transform unit (0x0E, version 1.6, clause 7.3.17): the SH-rest channels of every Gaussian
    (3 .. 3S - 1) carry transform coefficients t, and the row's SH-rest quantized values are the
    integer inverse transform (sum_k T[j][k] t_k + rounding) >> sh_transform_shift (clause 11.11),
    T[j][k] = sh_transform_coeff[j * NumShRest + k] - 2^sh_transform_bits_minus1."""

    syntax_name = "sh_transform_unit"
    clause = "7.3.17"
    sh_degree: int = 0  # context: d of the gaussian_parameter_set
    sh_transform_shift: int = 0
    sh_transform_bits_minus1: int = 0
    sh_transform_coeff: list = field(default_factory=list)

    @property
    def num_sh_rest(self) -> int:
        """NumShRest = 3 (d + 1)^2 - 3: the SH channels after the DC term."""
        return 3 * (self.sh_degree + 1) ** 2 - 3

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(SH_TRANSFORM_SHIFT_BITS, self, "sh_transform_shift", hi=SH_TRANSFORM_MAX_SHIFT)
        v.u(SH_TRANSFORM_BITS_BITS, self, "sh_transform_bits_minus1", hi=SH_TRANSFORM_MAX_BITS - 1)
        count = self.num_sh_rest * self.num_sh_rest
        bits = self.sh_transform_bits_minus1 + 1
        for i in v.loop(count, "NumShRest * NumShRest", self, ("sh_transform_coeff",)):
            v.u(bits, self, "sh_transform_coeff", i, width="sh_transform_bits_minus1 + 1")
        v.byte_align()


@dataclass
class DecodedSceneHashUnit(SyntaxStructure):
    syntax_name = "decoded_scene_hash_unit"
    clause = "7.3.6"
    hash_type: int = HASH_TYPE_SHA256
    scene_hash: bytes = bytes(32)

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(8, self, "hash_type", lo=HASH_TYPE_SHA256, hi=HASH_TYPE_SHA256)
        v.payload(self, "scene_hash", 32)


SE_MAX = (1 << 31) - 1  # the magnitudes se(v) codes (clause 2)
MAX_TILE_DATA_SIZE = (1 << 32) - 2  # the values ue(v) codes


@dataclass
class TileIndex(SyntaxStructure):
    """tile_index_unit (version 1, clause 7.3.11): the tiles of a tiled stream, in stream order.
    Tile t is the grid cell (tile_x, tile_y, tile_z) of side TileSize voxels; its units (geometry,
    attribute, decoded_scene_hash) take tile_data_size[t] bytes and start right after those of
    tile t - 1 (tile 0: right after this unit), so a decoder can seek to any tile."""

    syntax_name = "tile_index_unit"
    clause = "7.3.11"
    num_points: int = 1  # context: N from the parameter set
    num_tiles_minus1: int = 0
    tile_x: list = field(default_factory=list)
    tile_y: list = field(default_factory=list)
    tile_z: list = field(default_factory=list)
    tile_num_points_minus1: list = field(default_factory=list)
    tile_data_size: list = field(default_factory=list)

    def syntax(self, v: SyntaxVisitor) -> None:
        v.ue(self, "num_tiles_minus1", hi=self.num_points - 1)
        names = ("tile_x", "tile_y", "tile_z", "tile_num_points_minus1", "tile_data_size")
        for t in v.loop(self.num_tiles_minus1 + 1, "num_tiles_minus1 + 1", self, names, index="t"):
            for axis in ("tile_x", "tile_y", "tile_z"):
                v.se(self, axis, t, lo=-SE_MAX, hi=SE_MAX)
            v.ue(self, "tile_num_points_minus1", t, hi=self.num_points - 1)
            v.ue(self, "tile_data_size", t, hi=MAX_TILE_DATA_SIZE)
        v.byte_align()

    @property
    def num_tiles(self) -> int:
        return self.num_tiles_minus1 + 1

    @property
    def cells(self) -> list[tuple[int, int, int]]:
        return list(zip(self.tile_x, self.tile_y, self.tile_z))


@dataclass
class SourceInfo(SyntaxStructure):
    """source_info (ancillary unit 0x80, clause 7.3.10): informative facts about the scene the
    encoder was given that the decoded scene does not carry. An anchor stream transcoded from
    a 3DGS scene has no SH coefficients; ``source_sh_degree`` lets a decoder export its colours
    at the source's degree (lghcc-dec --export) instead of guessing one. Decoding never depends
    on it; bytes after these elements are reserved for later versions and ignored."""

    syntax_name = "source_info"
    clause = "7.3.10"
    source_sh_degree: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(2, self, "source_sh_degree", hi=MAX_SH_DEGREE)
        v.byte_align()

    @classmethod
    def from_payload(cls, data: bytes, trace: list | None = None) -> "SourceInfo":
        """Parse a source_info payload (clause 7.3.10): its elements, then any further bytes,
        which later versions may define and this version ignores (unlike ``from_bytes``, which
        rejects trailing bytes). Raises BitstreamError when the elements do not fit."""
        return cls.parse(BitReader(data, "source_info"), trace)
