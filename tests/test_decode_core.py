"""The decoder's core (decoder/core.py, clause 13) on its own, without the driver: its steps decode
conformance streams to their hashes, the attribute context is one of its tagged kinds, and the
driver's arguments (admit, checks, on_rows) are called as the core promises."""

import numpy as np
import pytest

from lghcc.common.errors import BitstreamError, UsageError
from lghcc.common.hashing import digest_of
from lghcc.common.units import LEVEL_1, NeighbourPredictionUnit
from lghcc.conformance import runner
from lghcc.decoder import core



def _case(case_id: str):
    return runner.load_cases(ids=[case_id])[0]


def _decode_with_the_core(data: bytes) -> bytes:
    """Clause 13 step by step with the core's functions alone: the SHA-256 of the decoded scene."""
    s = core.parse_stream(data)
    parts = [core.decode_tile(tile, t, s.ps, s.layout, s.context_model, s.mlps) for t, tile in enumerate(s.tiles)]
    coords, attributes = core.join_tiles(parts, s.layout)
    return digest_of(core.scene_of(s.ps, s.layout, coords, attributes, s.mlps))


@pytest.mark.parametrize("case_id, kind", [
    ("c002_procedural_medium", type(None)),
    ("c012_parent_mlp_context", core.ParentMlpContext),
    ("c030_ggconv_level1_neighbours", core.GgconvContext),
    ("c078_neighbour_prediction_tiles", NeighbourPredictionUnit),
    ("c065_tiles_small", type(None)),
])
def test_the_core_alone_decodes_streams_to_their_hashes(case_id, kind):
    case = _case(case_id)
    data = case.stream.read_bytes()
    assert isinstance(core.parse_stream(data).context_model, kind)
    assert _decode_with_the_core(data).hex() == case.meta["decoded_sha256"]


def test_the_driver_arguments_are_called_as_promised():
    """admit: once, with the parameter set, before the tiles; checks: before each attribute unit, with
    its row count; on_rows: the rows of every chunk, adding up to the tile's points."""
    data = _case("c012_parent_mlp_context").stream.read_bytes()
    admitted = []
    s = core.parse_stream(data, admit=lambda ps, layout, by_type: admitted.append((ps.num_points,
                                                                                   layout.num_channels)))
    assert admitted == [(s.ps.num_points, s.layout.num_channels)]

    class Checks:
        def __init__(self):
            self.units = []

        def check_attribute_unit(self, payload, num_rows, level, context_model, num_level1):
            self.units.append((level, num_rows, context_model is s.context_model))
            return 0

        def check_predicted_attribute_unit(self, num_rows, unit):
            raise AssertionError("no neighbour prediction in this stream")

    checks, rows = Checks(), []
    tile = core.decode_tile(s.tiles[0], 0, s.ps, s.layout, s.context_model, s.mlps, checks=checks,
                            on_rows=rows.append)
    n1, n2 = tile.level_counts
    assert checks.units == [(1, n1, True), (2, n2, True)]
    assert sum(rows) == n1 + n2 == tile.num_points


def test_admit_refuses_before_the_tiles_are_read():
    """A driver's refusal in admit comes before anything of the tiles (a stream whose tiles are cut off
    is refused by admit, not by the tile checks)."""
    data = _case("c065_tiles_small").stream.read_bytes()

    def refuse(ps, layout, by_type):
        raise MemoryError("refused by the driver")

    with pytest.raises(MemoryError, match="refused by the driver"):
        core.parse_stream(data, admit=refuse)


def test_a_preview_without_the_hierarchy_is_refused_before_the_limits():
    data = _case("c065_tiles_small").stream.read_bytes()
    with pytest.raises(UsageError, match="no level-1 preview"):
        core.parse_stream(data, max_level=LEVEL_1, admit=lambda *a: pytest.fail("admitted"))


def test_a_tile_hash_mismatch_names_the_tile():
    case = _case("c065_tiles_small")
    s = core.parse_stream(case.stream.read_bytes())
    tile = s.tiles[1]
    payload = bytearray(tile.scene_hash.payload)
    payload[-1] ^= 1  # the hash's last byte (the unit ends with the SHA-256)
    wrong = type(tile.scene_hash)(tile.scene_hash.unit_type, bytes(payload), tile.scene_hash.offset)
    bad = core.TileUnits(tile.cell, tile.num_points, tile.geometry, tile.attributes, wrong)
    with pytest.raises(BitstreamError, match="^tile 1: the decoded scene does not match"):
        core.decode_tile(bad, 1, s.ps, s.layout, s.context_model, s.mlps)
    unchecked = core.decode_tile(bad, 1, s.ps, s.layout, s.context_model, s.mlps, verify_hash=False)
    assert not unchecked.hash_checked and unchecked.num_points == tile.num_points


def test_joining_no_tile_gives_the_empty_scene_of_the_layout():
    s = core.parse_stream(_case("c065_tiles_small").stream.read_bytes())
    coords, attributes = core.join_tiles([], s.layout)
    assert coords.shape == (0, 3) and attributes.values.shape == (0, s.layout.num_channels)
    assert attributes.values.dtype == np.float32
