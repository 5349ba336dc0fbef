"""The rejection conditions of spec clause 8.2 and their isolated error streams (issue 35).

An error stream made by editing a valid stream keeps the source's decoded hash: a decoder that
lacks the check the edit targets usually still rejects it, later, for another reason (a hash
mismatch, an exhausted chunk). An *isolated* error stream breaks one condition only: every
other element, its CRCs and counts, and the decoded scene hashes (one per tile) are those a
decoder that skips exactly that check computes, so such a decoder accepts it, and the suite
catches it through acceptance.

``CHECK_REMOVALS`` names, for each condition, the mutation of conformance/mutations.py that
removes its check; ``NOT_ISOLATED`` says why a condition has no isolated stream (another check
must fail first). ``mutant_decode`` runs the reference decoder with one mutation applied, in a
forked process, and returns the hashes it decodes (conformance/generate.py writes them into an
isolated stream; tools/mutation_test.py --conditions checks the mutant accepts the stream).
"""

from __future__ import annotations

import multiprocessing as mp
import re
import signal
import traceback
from dataclasses import dataclass

# every row of the table of clause 8.2
CONDITIONS: list[str] = [f"E{i}" for i in range(1, 69)]

# condition -> the mutation that removes its check (conformance/mutations.py)
CHECK_REMOVALS: dict[str, str] = {
    "E1": "check.E1", "E2": "container.no_magic_check", "E3": "container.major_version", "E4": "check.E4",
    "E5": "container.no_reserved_check", "E6": "check.E6", "E7": "check.E7", "E8": "check.E8",
    "E9": "container.no_crc_check", "E10": "decode.unknown_critical_skipped", "E11": "decode.ancillary_first_ok",
    "E12": "check.E12", "E13": "check.E13", "E14": "decode.no_order_check", "E15": "decode.attribute_count",
    "E16": "decode.context_without_hierarchy", "E17": "check.E17", "E18": "check.E18", "E19": "syntax.hash_type",
    "E20": "check.E20", "E21": "check.E21", "E22": "decode.attribute_limit",
    "E23": "render_model.no_duplicate_role_check", "E24": "render_model.no_parameter_limit",
    "E25": "render_model.no_weight_limit", "E26": "geometry.no_bbox_sign_check",
    "E27": "geometry.no_box_capacity_check", "E28": "geometry.no_depth0_data_check",
    "E29": "geometry.no_idcm_count_check", "E30": "geometry.no_duplicate_point_check",
    "E31": "geometry.no_depth_count_check", "E32": "geometry.fewer_points_ok",
    "E33": "geometry.no_min_attained_check", "E34": "geometry.no_coordinate_max_check",
    "E35": "entropy.no_word_alignment_check", "E36": "entropy.decode_error_unreported",
    "E37": "entropy.no_escape_limit", "E38": "entropy.no_exhaustion_check",
    "E40": "check.E40", "E41": "model_unit.no_parameter_limit", "E42": "ggconv.no_grid_check",
    "E43": "model_unit.no_model_fit_check", "E44": "check.E44", "E45": "check.E45",
    "E47": "decode.model_id_mismatch", "E48": "prediction.no_source_check", "E49": "prediction.no_order_check",
    "E50": "attributes.trailing_bytes", "E51": "prediction.no_magnitude_check", "E52": "attributes.no_finite_check",
    "E53": "decode.no_hash_check", "E54": "tiles.flag_not_checked", "E55": "tiles.no_offset_check",
    "E56": "tiles.no_order_check", "E57": "tiles.no_point_count_check", "E58": "tiles.no_cell_check",
    "E59": "neighbour.no_num_rows_check", "E60": "neighbour.with_hierarchy", "E61": "neighbour.unit_repeated",
    "E62": "neighbour.no_context_model_check", "E63": "neighbour.unit_count", "E64": "check.E64",
    "E65": "step_adjust.index_range_unchecked", "E66": "rotation_length.index_range_unchecked",
    "E67": "step_adjust_flags.header_unchecked", "E68": "sh_transform.no_magnitude_check",
}

# condition -> why it has no isolated stream: the check that fails first in every stream that
# meets it (spec clause 8.2 says the same), or what is still to build
NOT_ISOLATED: dict[str, str] = {
    "E1": "a stream of fewer than 8 bytes has no complete container header: reading it runs out (E17)",
    "E7": "a unit of type 0 is a critical type (bit 7 clear) that no version defines: without E7 it is E10",
    "E8": "the CRC-32 of a unit that extends beyond the end is missing or holds payload bytes: E9 (and E17)",
    "E12": "the units of a stream without a parameter set are out of the order of clause 6.3 (E14); nothing "
           "gives N, C or M",
    "E13": "a stream without a geometry, attribute or decoded_scene_hash unit has no tile of the order of "
           "clause 6.3 (E14)",
    "E18": "a ue(v) of 32 or more leading zeros is >= 2^32 - 1: beyond the range of every ue(v)/se(v) element "
           "(E19), or a chunk or coded_size beyond its payload (E17, E50)",
    "E22": "N * M > 2^31 attribute values take more than 8 GiB to decode: no stream breaks only it within the "
           "memory a conformance run has (the reference decoder refuses it as a resource limit first)",
    "E26": "a positive bounding-box minimum of 2^31 puts every decoded coordinate above 2^31 - 1 (E34)",
    "E27": "N distinct points do not fit a box of fewer than N voxels: the geometry decodes to fewer (E32) or "
           "leaves data over (E38)",
    "E29": "more than N points from direct coding leave more than N points at the end (E32)",
    "E31": "the point count never decreases with depth: more than N at a depth is more than N at the end (E32)",
    "E36": "once q >= 2^24 no symbol is defined: a decoder that goes on has no value to output",
    "E39": "a condition of version 0 only (in version 1: E15)",
    "E41": "not isolated yet: e061's model (a table of 257^3 values) also breaks E42 and E40; a model of more than "
           "2^24 values within every shape rule is not built yet",
    "E46": "no decoding of a level-0 or level-1 unit with a context model is defined (clause 11)",
    "E60": "with the hierarchy a tile's units are of level 1 (and 2), with neighbour prediction its one unit is of "
           "level 0 (clause 8.3 rule 15): every such stream breaks E45 or E63 as well",
    "E62": "a stream with neighbour prediction has no context_model unit (clause 8.3 rule 14): a unit with "
           "context_model_id 1 or 2 breaks E47 (or E46) as well",
}


# condition -> the checks to remove so that the reference decoder no longer rejects a stream for it
# at all (the differential fuzzer's confirm_condition, conformance/differential.py): CHECK_REMOVALS[c]
# (the check an isolated stream needs gone) and the condition's other checks, where the reference
# checks it in several places (E19: every range of clause 7.2; E59: with and without neighbour
# prediction ...). Each entry: a mutation id of conformance/mutations.py, or (target, edits) of a
# removal no isolated stream needs (not in its list, so not in the mutation report).
MORE_CHECK_REMOVALS: dict[str, tuple] = {
    "E19": ("lghcc.common.syntax:ReadVisitor._visit",
            (("if isinstance(value, int) and not _check_range(value, lo, hi):", "if False:"),)),
    "E19+": ("lghcc.common.syntax:_checked_f32",
             (('if x != x or x in (float("inf"), float("-inf")):', "if False:"), ("if positive and not x > 0:", "if False:"))),
    "E38": ("lghcc.common.entropy.range_coder:RangeDecoder.check_exhausted",
            (("if self._dec.maybe_exhausted() is False:", "if False:"),)),
    "E41": ("lghcc.common.context.model_unit:read_context_model_unit",
            (("if any(d > MAX_CONTEXT_PARAMETERS for d in a.shape):", "if False:"),)),
    "E45": ("lghcc.common.neighbour_prediction:_check_predicted_header",
            (("if h.attribute_level != LEVEL_ALL:", "if False:"),)),
    "E54": "tiles.several_without_index",
    "E55": "tiles.no_tile_count_check",
    "E55+": ("lghcc.decoder.core:tiles_of", (("if u.offset != at:", "if False:"),)),
    "E59": ("lghcc.common.attributes:read_attribute_unit", (("if h.num_rows_minus1 + 1 != num_rows:", "if False:"),)),
}


def all_check_removals(condition: str) -> list:
    """The mutations (conformance/mutations.py Mutation objects) that together remove every check of
    ``condition`` from the reference decoder; empty when no mutation removes it (E39, E46)."""
    from . import mutations

    by_id = {m.id: m for m in mutations.MUTATIONS}
    out = [by_id[CHECK_REMOVALS[condition]]] if condition in CHECK_REMOVALS else []
    for key in (condition, condition + "+"):
        more = MORE_CHECK_REMOVALS.get(key)
        if isinstance(more, str):
            out.append(by_id[more])
        elif more is not None:
            out.append(mutations.Mutation(f"all.{key}", "check", more[0], f"every check of {condition} removed",
                                          tuple(more[1])))
    return out


# condition -> the edit the differential fuzzer's confirm_condition makes in place of removing the
# check, where a decoder without the check cannot go on: a rotation length index beyond the table of
# clause 11.10 indexes out of the reference's table (IndexError), so E66's index is clamped into its
# range instead, and the decoder reads on to the next condition the stream breaks
CONFIRM_INSTEAD: dict[str, tuple] = {
    "E66": ("lghcc.common.attributes:check_rotation_length_index",
            (("if k.size and (int(k.min()) < 0 or int(k.max()) > max_index):",
              "if np.clip(k, 0, max_index, out=k) is None:"),)),
}


def confirm_removals(condition: str) -> list:
    """The mutations confirm_condition applies to get past ``condition``: CONFIRM_INSTEAD's edit where
    it has one, else ``all_check_removals``."""
    from . import mutations

    if condition in CONFIRM_INSTEAD:
        target, edits = CONFIRM_INSTEAD[condition]
        return [mutations.Mutation(f"confirm.{condition}", "check", target, f"{condition}: read on past it", edits)]
    return all_check_removals(condition)


def combined(removals: list) -> list:
    """``removals`` (Mutation objects) as one Mutation per function they edit: mutations.apply
    rewrites a function from its source file, so two edits of one function are applied together."""
    from . import mutations

    edits: dict[str, list] = {}
    out = []
    for m in removals:
        if m.value is not None:
            out.append(m)
            continue
        for target, e in ((m.target, m.edits),) + tuple(m.also):
            have = edits.setdefault(target, [])
            have += [x for x in e if x not in have]  # one check removed for two conditions (E64, E44: the k-NN's)
    return out + [mutations.Mutation(f"combined.{t}", "check", t, "checks removed together", tuple(e))
                  for t, e in edits.items()]


@dataclass(frozen=True)
class IsolatedStream:
    """One isolated error stream (test.yaml ``condition``): the condition it breaks, which bound or
    field of that condition's check it breaks (``bound``; a condition with one bound leaves it
    empty) and the mutation that removes exactly that check (``check_removal``: CHECK_REMOVALS of
    the condition unless the stream names a narrower one, e.g. one range of E19)."""

    id: str
    condition: str
    bound: str
    check_removal: str


def isolated_stream_list(root=None) -> list[IsolatedStream]:
    """Every isolated error stream, in the order of their ids."""
    from . import STREAMS_DIR, load_yaml

    out = []
    for meta_file in sorted((root or STREAMS_DIR).glob("*/test.yaml")):
        meta = load_yaml(meta_file.read_text())
        if meta.get("condition"):
            cond = meta["condition"]
            out.append(IsolatedStream(meta["id"], cond, meta.get("bound", ""),
                                      meta.get("check_removal") or CHECK_REMOVALS[cond]))
    return out


def isolated_streams(root=None) -> dict[str, str]:
    """condition -> the id of its first isolated error stream (the one clause 8.2's table names
    first; the streams of its other bounds: ``isolated_stream_list``)."""
    out: dict[str, str] = {}
    for s in isolated_stream_list(root):
        out.setdefault(s.condition, s.id)
    return out


CONDITION_ID = re.compile(r"E[1-9][0-9]?")

# E53's defect is the hash itself: its stream keeps the hash that does not match
HASH_CONDITION = "E53"


@dataclass(frozen=True)
class MutantResult:
    """What the decoder with one mutation applied did with a stream: ``digests`` (the decoded
    scene hash of each tile, in stream order) when it decoded, else the error's class, message and
    ``condition`` (the row of clause 8.2 it names; None for an error that names none)."""

    decoded: bool
    digests: tuple[bytes, ...] = ()
    error: str = ""
    message: str = ""
    condition: str | None = None

    def describe(self) -> str:
        if self.decoded:
            return f"decoded ({len(self.digests)} hashes)"
        return f"{self.error}" + (f" ({self.condition})" if self.condition else "") + f": {self.message}"


def _child(conn, mutation_ids: tuple, data: bytes, cpu_seconds: int | None = None) -> None:
    """In the forked process: apply the mutations, decode, record each tile's decoded scene hash
    in place of comparing it (clause 12). ``cpu_seconds``: the process's CPU bound (SIGXCPU ends it)."""
    try:
        if cpu_seconds:
            import resource

            resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds + 1))
        import torch

        torch.set_num_threads(1)
        from ..common import knn
        from ..common.hashing import digest_of
        from ..decoder import core, decode
        from . import mutations

        knn.set_candidate_threads(1)
        for m in mutation_ids:  # ids of the list, or Mutation objects (combined removals)
            mutations.apply(m if isinstance(m, mutations.Mutation) else next(x for x in mutations.MUTATIONS if x.id == m))
        digests: list[bytes] = []
        core.check_tile_hash = lambda scene, scene_hash, where="": digests.append(digest_of(scene))
        try:
            decode.decode_stream(data)
        except Exception as e:  # noqa: BLE001 - the mutant's verdict on the stream, reported as such
            conn.send(MutantResult(False, error=type(e).__name__, message=str(e)[:300],
                                   condition=getattr(e, "condition", None)))
            return
        conn.send(MutantResult(True, tuple(digests)))
    except Exception:  # noqa: BLE001 - the harness itself failed
        conn.send(MutantResult(False, error="harness error", message=traceback.format_exc()[-300:]))


def _call_child(conn, mutation_id: str, fn, args) -> None:
    try:
        import torch

        torch.set_num_threads(1)  # a forked child must not use the parent's OpenMP pool (it hangs)
        from . import mutations

        mutations.apply(next(m for m in mutations.MUTATIONS if m.id == mutation_id))
        conn.send((True, fn(*args)))
    except Exception as e:  # noqa: BLE001 - reported to the caller
        conn.send((False, f"{type(e).__name__}: {e}"))


def call_without_check(mutation_id: str, fn, *args, timeout: float = 600.0):
    """``fn(*args)`` in a forked child with the mutation applied: the edit of an isolated stream
    that needs the arithmetic beyond the check (e.g. the k-NN of points beyond the extent limit,
    which the encoder computes with the same common/ code). RuntimeError when it fails."""
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_call_child, args=(child, mutation_id, fn, args), daemon=True)
    p.start()
    child.close()
    try:
        if not parent.poll(timeout):
            raise RuntimeError(f"no result within {timeout:g} s")
        ok, value = parent.recv()
    finally:
        if p.is_alive():
            p.kill()
        p.join()
    if not ok:
        raise RuntimeError(value)
    return value


def mutant_decode(mutation_id, data: bytes, timeout: float = 120.0, cpu_seconds: int | None = None) -> MutantResult:
    """Decode ``data`` with the reference decoder and mutation ``mutation_id`` applied (several: a
    tuple of ids or Mutation objects, applied in turn), in a forked child: the mutation never
    reaches this process. ``cpu_seconds``: a bound on the child's CPU time as well as ``timeout``
    on the wall clock (a hang found on a busy machine by CPU time is one on a quiet machine too)."""
    ids = (mutation_id,) if isinstance(mutation_id, str) else tuple(mutation_id)
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(child, ids, data, cpu_seconds), daemon=True)
    p.start()
    child.close()
    try:
        if not parent.poll(timeout):
            return MutantResult(False, error="hang", message=f"no result within {timeout:g} s")
        try:
            return parent.recv()
        except EOFError:
            p.join()
            if cpu_seconds and p.exitcode == -signal.SIGXCPU:
                return MutantResult(False, error="hang", message=f"more than {cpu_seconds} s of CPU")
            return MutantResult(False, error="died", message=f"exit code {p.exitcode}")
    finally:
        if p.is_alive():
            p.kill()
        p.join()
