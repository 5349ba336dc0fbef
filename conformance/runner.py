"""lghcc-conformance: decode every conformance stream and check its decoded-scene hash.

Each stream lives in ``conformance/streams/<id>/`` as ``stream.lghcc`` and ``test.yaml``:
  id, purpose, profile, stream_bytes, stream_sha256
  tools            what the stream exercises, derived by conformance/generate.py from what the
                   reference decoder decoded (e.g. 'escape' iff an escaped residual was decoded)
  expect: decode   decoded_sha256: SHA-256 of the decoded scene (spec clause 12, lghcc.md)
  expect: error    expect_error: the reference decoder's error class (BitstreamError,
                   UnsupportedStreamError or HashMismatchError) and expect_message: a fragment
                   of its message (the reason); both are checked for the reference decoder;
                   expect_condition: the row of spec clause 8.2 (E1 .. E68) its rejection names
                   (the error's ``condition``), checked for the reference decoder in process
  condition        (isolated error streams) the one row of clause 8.2 the stream breaks: every
                   decoder shall reject it for that row (checked for the reference decoder in
                   process and for the JavaScript decoder by js/lghcc-decoder/conformance.mjs)
  renders          (optional, informative) reference images of fixed cameras and a tolerance;
                   checked with --render (the renderer is not normative, hence no hash)
  partial_decodes  (tiled streams, version 1) decodes of part of the stream, each with the SHA-256 of
                   what it outputs: ``box`` [x0, y0, z0, x1, y1, z1]: the tiles whose cell meets the
                   box (``tiles_decoded`` of them, ``tiles``: their indices in stream order; none: the
                   empty scene), ``level: 1``: the level-1 preview (clause 13.3), both: the preview
                   of the tiles the box selects; ``level: 1`` with ``refused: true`` (no hash): a stream
                   without the hierarchy, whose preview a decoder shall refuse and output nothing
                   (clause 13.3; exit status 2, usage); ``purpose`` says what the box tests. Checked for the
                   reference decoder (hash and tile count), and for another with ``{options}`` in
                   its --decoder-cmd (replaced by lghcc-dec's options: --box=..., --level 1)
  source_info      (streams with a source_info unit, informative: clauses 6.3, 7.3.10)
                   source_sh_degree: what a decoder that interprets source_info outputs (null:
                   nothing, its first source_info unit is malformed) and ignored: how many
                   source_info units it ignores (a malformed first one, every later one); the
                   decoded scene never depends on them. Checked for the reference decoder only
A decoder conforms when it reproduces every hash and rejects every stream marked
``expect: error``.

Another implementation is tested with ``--decoder-cmd``, a command template: ``{stream}``
(required) is replaced by the stream's path, ``{out}`` (needed with --render) by an empty
folder where the decoder writes the decoded scene in the Scaffold-GS layout (as lghcc-dec -o).
Rejection protocol (its exit status; the rule of every lghcc program, lghcc.app.cli_common):
  0        decoded: the last line of stdout is the decoded scene's SHA-256 (spec clause 12)
           as 64 hex digits
  3        the stream was rejected as invalid (non-conforming): passes the error streams whose
           expected class maps to 3 (BitstreamError, UnsupportedStreamError, HashMismatchError:
           every error stream of the suite)
  1        an input or environment error (e.g. the file cannot be read): FAIL, it is not a verdict
           on the stream
  2        usage error (the command line is wrong): FAIL
  4        resource limit (the decoder refused the stream for memory): FAIL, every stream of the
           suite decodes within the default bound of 4 GiB
  other    any other exit status (130: interrupted), death by a signal, or no exit within
           --timeout: FAIL
Exit codes carry the class of a rejection only as far as the rule distinguishes it: the reference
decoder run in process is held to the exact class and a fragment of the message.
An argument ``{options}`` is replaced by a partial decode's options (--box=X0,...,Z1 or --level 1)
when the partial decodes of tiled streams are checked, and by nothing otherwise; without it they
are not checked.
``--js`` runs the project's JavaScript decoder (js/lghcc-decoder/cli.mjs, with Node) as such an external
decoder on the streams of the explicit-Gaussian profile (spec clause 8.4; the profile's rule is
js/lghcc-decoder/profile.mjs, which lists them) and says how many streams lie outside it.
Example: ``lghcc-conformance --decoder-cmd "lghcc-dec {stream} {options} --print-hash"``, or with renders
``lghcc-conformance --render --decoder-cmd "lghcc-dec {stream} -o {out} --print-hash"``.
Exit status of lghcc-conformance: 0 all passed, 1 a stream failed, 2 usage or suite error
(an unknown stream id, a damaged test.yaml), 4 out of memory, 130 interrupted.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

# the context models' inference runs torch's OpenMP kernels: passive waiting keeps threads from spinning
# against other jobs on a shared machine (set before torch is imported; a user's own setting wins)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from ..app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_RESOURCE_LIMIT,  # noqa: E402
                              EXIT_USAGE, exit_code_for_class)
from ..common.errors import LghccError, UsageError  # noqa: E402
from .conditions import CONDITION_ID  # noqa: E402

from . import STREAMS_DIR, load_yaml  # noqa: E402
JS_DECODER_DIR = Path(__file__).resolve().parent.parent / "js" / "lghcc-decoder"
# the error classes an error stream may expect (lghcc.common.errors); an external decoder's exit
# status for each is lghcc.app.cli_common.exit_code_for_class (3, invalid stream, for all of them)
ERROR_KINDS = ("BitstreamError", "UnsupportedStreamError", "HashMismatchError")
EXIT_REJECTED = EXIT_INVALID_STREAM
_EXTERNAL_FAILS = {EXIT_ERROR: "an input or environment error, not a verdict on the stream",
                   EXIT_USAGE: "usage error: check --decoder-cmd",
                   EXIT_RESOURCE_LIMIT: "refused for a resource limit, not a verdict on the stream",
                   EXIT_INTERRUPTED: "interrupted"}
_HEX64 = re.compile(r"[0-9a-f]{64}")


@dataclass
class Case:
    id: str
    folder: Path
    meta: dict

    @property
    def stream(self) -> Path:
        return self.folder / "stream.lghcc"

    @property
    def expect(self) -> str:
        return self.meta.get("expect", "decode")


@dataclass
class Outcome:
    case: Case
    passed: bool
    seconds: float
    note: str


def _bad(folder: Path, what: str) -> LghccError:
    return LghccError(f"{folder / 'test.yaml'}: {what}")


def _validate_hashes(meta: dict, expect: str, folder: Path) -> None:
    for key in ("stream_sha256",) + (("decoded_sha256",) if expect == "decode" else ()):
        v = meta.get(key)
        if v is None:
            raise _bad(folder, f"missing {key}")
        if not isinstance(v, str) or not _HEX64.fullmatch(v):
            raise _bad(folder, f"{key} is not 64 lower-case hex digits: {v!r}")
    if not isinstance(meta.get("stream_bytes"), int):
        raise _bad(folder, "missing or non-integer stream_bytes")


def _validate_expected_error(meta: dict, expect: str, folder: Path) -> None:
    """An error stream names its class and a fragment of the message; a decode stream neither."""
    if expect != "error":
        if "expect_error" in meta or "expect_message" in meta:
            raise _bad(folder, "expect_error / expect_message on a stream that must decode")
        return
    if "decoded_sha256" in meta:
        raise _bad(folder, "an error stream has a decoded_sha256")
    if meta.get("expect_error") not in ERROR_KINDS:
        raise _bad(folder, f"expect_error {meta.get('expect_error')!r} is not one of {', '.join(ERROR_KINDS)}")
    if not isinstance(meta.get("expect_message"), str) or not meta["expect_message"].strip():
        raise _bad(folder, "missing expect_message (a fragment of the reference decoder's message)")


def validate_meta(meta, folder: Path) -> dict:
    """Check one test.yaml; raise LghccError naming the file and the problem."""
    if not isinstance(meta, dict):
        raise _bad(folder, "not a mapping")
    if meta.get("id") != folder.name:
        raise _bad(folder, f"id {meta.get('id')!r} is not the folder name {folder.name!r}")
    expect = meta.get("expect", "decode")
    if expect not in ("decode", "error"):
        raise _bad(folder, f"unknown expect value {expect!r} (decode or error)")
    _validate_hashes(meta, expect, folder)
    _validate_expected_error(meta, expect, folder)
    for key in ("condition", "expect_condition"):
        if key in meta and (expect != "error" or not isinstance(meta[key], str) or not CONDITION_ID.fullmatch(meta[key])):
            raise _bad(folder, f"{key} {meta[key]!r}: a row of spec clause 8.2 (E1 .. E68), on an error stream")
    for key in ("bound", "check_removal"):  # which bound of the condition an isolated stream breaks
        if key in meta and ("condition" not in meta or not isinstance(meta[key], str) or not meta[key].strip()):
            raise _bad(folder, f"{key} {meta[key]!r}: a non-empty text, on an isolated stream (condition)")
    if "renders" in meta:
        if expect != "decode":
            raise _bad(folder, "renders on an error stream")
        validate_renders(meta["renders"], folder)
    if "source_info" in meta:
        validate_source_info(meta["source_info"], folder)
    if "partial_decodes" in meta:
        validate_partial_decodes(meta["partial_decodes"], expect, folder)
    if not (folder / "stream.lghcc").is_file():
        raise _bad(folder, "no stream.lghcc beside it")
    return meta


def validate_partial_decodes(parts, expect: str, folder: Path) -> None:
    if expect != "decode" or not isinstance(parts, list) or not parts:
        raise _bad(folder, "partial_decodes must be a non-empty list, on a stream that must decode")
    for p in parts:
        if isinstance(p, dict) and p.get("refused") is not None:
            if p["refused"] is not True or p.get("level") != 1 or "decoded_sha256" in p or "box" in p:
                raise _bad(folder, f"partial decode {p!r}: refused: true goes with level: 1 alone, without a hash")
            continue
        if not isinstance(p, dict) or not _HEX64.fullmatch(str(p.get("decoded_sha256", ""))):
            raise _bad(folder, f"partial decode {p!r}: missing or malformed decoded_sha256")
        box_ok = "box" in p and isinstance(p["box"], list) and len(p["box"]) == 6 and \
            all(isinstance(x, (int, float)) for x in p["box"])
        if not (box_ok or p.get("level") == 1) or p.get("level", 1) != 1:
            raise _bad(folder, f"partial decode {p!r}: needs box (six numbers) or level: 1, or both")
        if not isinstance(p.get("tiles_decoded", 0), int) or ("tiles" in p and not _tiles_ok(p)):
            raise _bad(folder, f"partial decode {p!r}: tiles_decoded is not a count, or tiles not "
                               "tiles_decoded increasing tile indices")


def _tiles_ok(p: dict) -> bool:
    """A partial decode's ``tiles``: tiles_decoded tile indices in increasing order."""
    t = p["tiles"]
    return (isinstance(t, list) and all(isinstance(i, int) and i >= 0 for i in t) and len(t) == p.get("tiles_decoded")
            and all(a < b for a, b in zip(t, t[1:])))


def validate_renders(r, folder: Path) -> None:
    if not isinstance(r, dict):
        raise _bad(folder, "renders is not a mapping")
    for key in ("cameras", "size", "background", "images", "min_psnr_db", "max_abs_error"):
        if key not in r:
            raise _bad(folder, f"renders: missing {key}")
    if not re.fullmatch(r"orbit:\d+", str(r["cameras"])):
        raise _bad(folder, f"renders.cameras must be 'orbit:N', got {r['cameras']!r}")
    if not re.fullmatch(r"\d+x\d+", str(r["size"])):
        raise _bad(folder, f"renders.size must be WxH, got {r['size']!r}")
    if r["background"] not in ("black", "white"):
        raise _bad(folder, f"renders.background must be black or white, got {r['background']!r}")
    n = int(str(r["cameras"]).split(":")[1])
    if not isinstance(r["images"], list) or len(r["images"]) != n:
        raise _bad(folder, f"renders.images must list {n} files")
    for name in r["images"]:
        if not (folder / str(name)).is_file():
            raise _bad(folder, f"renders: reference image {name} is missing")
    for key in ("min_psnr_db", "max_abs_error"):
        if not isinstance(r[key], (int, float)) or r[key] < 0:
            raise _bad(folder, f"renders.{key} must be a non-negative number")


def load_cases(root: Path = STREAMS_DIR, ids: list[str] | None = None) -> list[Case]:
    if not root.is_dir():
        raise LghccError(f"{root}: no conformance streams folder")
    cases = []
    for folder in sorted(p for p in root.iterdir() if (p / "test.yaml").is_file()):
        if ids and folder.name not in ids:
            continue
        try:
            meta = load_yaml((folder / "test.yaml").read_text())
        except yaml.YAMLError as e:
            raise _bad(folder, f"not valid YAML ({e})") from None
        cases.append(Case(folder.name, folder, validate_meta(meta, folder)))
    if ids:
        missing = sorted(set(ids) - {c.id for c in cases})
        if missing:
            raise LghccError(f"no such conformance stream: {', '.join(missing)}")
    return cases


# --- the reference decoder, in process ----------------------------------------------------------

def validate_source_info(info, folder: Path) -> None:
    """test.yaml's source_info: {source_sh_degree: 0..3 or null, ignored: a count}."""
    if not isinstance(info, dict) or set(info) != {"source_sh_degree", "ignored"}:
        raise _bad(folder, "source_info is not a mapping of source_sh_degree and ignored")
    if info["source_sh_degree"] not in (None, 0, 1, 2, 3):
        raise _bad(folder, f"source_info.source_sh_degree {info['source_sh_degree']!r} is not 0..3 or null")
    if not isinstance(info["ignored"], int) or isinstance(info["ignored"], bool) or info["ignored"] < 0:
        raise _bad(folder, f"source_info.ignored {info['ignored']!r} is not a count")


def warm_up(render: bool = False) -> None:
    """Import the decoder (torch, the entropy tables ...) so that the first stream's time is its own."""
    from ..common import hashing  # noqa: F401
    from ..decoder import decode  # noqa: F401
    if render:
        from ..render import rasterizer, views  # noqa: F401


def decode_scene_internal(stream: Path):
    """The reference decoder: -> (decoded scene's SHA-256 hex, scene, its DecodeResult);
    raises LghccError."""
    from ..common.hashing import digest_of
    from ..decoder.decode import decode_stream

    result = decode_stream(stream.read_bytes())
    return digest_of(result.scene).hex(), result.scene, result


def decode_internal(stream: Path) -> str:
    """The reference decoder: returns the decoded scene's SHA-256 (hex); raises LghccError."""
    return decode_scene_internal(stream)[0]


# --- an external decoder ---------------------------------------------------------------------------

@dataclass
class External:
    status: str  # 'exit', 'signal', 'timeout'
    code: int  # exit code or signal number
    last_line: str
    stderr_tail: str

    def describe(self) -> str:
        if self.status == "timeout":
            return f"timed out after {self.code} s"
        if self.status == "signal":
            try:
                name = signal.Signals(self.code).name
            except ValueError:
                name = f"signal {self.code}"
            return f"killed by {name}"
        tail = f" ({self.stderr_tail})" if self.stderr_tail else ""
        return f"exit code {self.code}{tail}"


def check_template(template: str, render: bool = False) -> None:
    """A --decoder-cmd must name {stream} in one of its arguments (and {out} for --render)."""
    try:
        args = shlex.split(template)
    except ValueError as e:
        raise LghccError(f"--decoder-cmd cannot be split into arguments: {e}") from None
    if not args:
        raise LghccError("--decoder-cmd is empty")
    if not any("{stream}" in a for a in args):
        raise LghccError("--decoder-cmd must contain {stream}, replaced by the path of each stream")
    if render and not any("{out}" in a for a in args):
        raise LghccError("--render with --decoder-cmd needs {out} in the command: a folder where the decoder "
                         "writes the decoded scene (Scaffold-GS layout, as lghcc-dec -o)")


def decode_external(template: str, stream: Path, timeout: float, out: Path | None = None,
                    options: list[str] | None = None) -> External:
    """Run the decoder command: {stream}, {out} replaced, and an argument {options} by ``options``
    (a partial decode's; none for a whole decode)."""
    cmd = []
    for a in shlex.split(template):
        if a == "{options}":
            cmd += options or []
        else:
            cmd.append(a.replace("{stream}", str(stream)).replace("{out}", str(out) if out else ""))
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, errors="replace", timeout=timeout)
    except subprocess.TimeoutExpired:
        return External("timeout", int(math.ceil(timeout)), "", "")
    except OSError as e:
        raise LghccError(f"cannot run the decoder command: {e}") from None
    lines = res.stdout.strip().splitlines()
    err = res.stderr.strip().splitlines()
    last = lines[-1].strip() if lines else ""
    if res.returncode < 0:
        return External("signal", -res.returncode, last, err[-1][:80] if err else "")
    return External("exit", res.returncode, last, err[-1][:80] if err else "")


# --- the JavaScript decoder (explicit-Gaussian profile) -------------------------------------------

def node_path() -> str:
    node = shutil.which("node")
    if node is None:
        raise LghccError("--js needs Node.js (node) on the PATH: the JavaScript decoder runs in it")
    return node


def js_decoder_cmd() -> str:
    """The --decoder-cmd template of the JavaScript decoder."""
    return f"{shlex.quote(node_path())} {shlex.quote(str(JS_DECODER_DIR / 'cli.mjs'))} {{stream}} {{options}}"


def js_profile_ids(streams: Path) -> list[str]:
    """Ids of the streams of the explicit-Gaussian profile (spec clause 8.4), as the JavaScript decoder's
    runner decides them (js/lghcc-decoder/profile.mjs: one rule, in one place)."""
    res = subprocess.run([node_path(), str(JS_DECODER_DIR / "conformance.mjs"), "--streams", str(streams), "--list"],
                         capture_output=True, text=True, errors="replace", timeout=120)
    if res.returncode != 0:
        raise LghccError(f"the JavaScript decoder's runner cannot list the profile: {res.stderr.strip()[-300:]}")
    return [line.split()[1] for line in res.stdout.splitlines() if line.startswith("in ")]


# --- renders (informative) ---------------------------------------------------------------------------

def render_views(scene, cameras: str, size: str, background: str = "black") -> list[np.ndarray]:
    """Images [H, W, 3] float32 in [0, 1] of the scene from the cameras of ``cameras`` ('orbit:N')
    at ``size`` ('WxH'), as lghcc-dec --render draws them (the renderer is informative)."""
    import torch

    from ..render.imageio import background_color
    from ..render.neural_gaussians import SceneTensors
    from ..render.rasterizer import render_scene
    from ..render.views import cameras_from_spec

    w, h = (int(x) for x in size.split("x"))
    cams = cameras_from_spec(cameras, scene.positions(), width=w, height=h)
    bg = background_color(background)
    st = SceneTensors.from_scene(scene)
    with torch.no_grad():
        return [render_scene(st, cam, background=bg).image.clamp(0, 1).numpy().astype(np.float32) for cam in cams]


def to_uint16(img: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.asarray(img, np.float64), 0, 1) * 65535.0).astype(np.uint16)


def compare_renders(scene, spec: dict, folder: Path) -> tuple[bool, str]:
    """Render the scene as ``spec`` says and compare each image with its reference within the
    tolerance (PSNR >= min_psnr_db and max |difference| <= max_abs_error). -> (ok, note)."""
    imgs = render_views(scene, spec["cameras"], spec["size"], spec["background"])
    worst_psnr, worst_err = math.inf, 0.0
    for img, name in zip(imgs, spec["images"]):
        ref = np.load(folder / name).astype(np.float64) / 65535.0
        if ref.shape != img.shape:
            return False, f"render {name}: shape {list(img.shape)} != reference {list(ref.shape)}"
        d = img.astype(np.float64) - ref
        mse = float(np.mean(d * d))
        worst_psnr = min(worst_psnr, math.inf if mse == 0 else -10 * math.log10(mse))
        worst_err = max(worst_err, float(np.abs(d).max()))
    ok = worst_psnr >= spec["min_psnr_db"] and worst_err <= spec["max_abs_error"]
    psnr_txt = "inf" if worst_psnr == math.inf else f"{worst_psnr:.1f}"
    note = (f"{len(imgs)} renders: PSNR >= {psnr_txt} dB, max error {255 * worst_err:.2f}/255"
            + ("" if ok else f" (tolerance: >= {spec['min_psnr_db']} dB, <= "
                             f"{255 * spec['max_abs_error']:.2f}/255)"))
    return ok, note


# --- one case --------------------------------------------------------------------------------------

def _judge_error(case: Case, kind: str, message: str | None, condition: str | None = None) -> tuple[bool, str]:
    """The reference decoder rejected the stream with ``kind`` for ``condition`` (the row of clause
    8.2 its error names): right class, reason and, where test.yaml records it (an isolated
    stream's ``condition``), right condition?"""
    if case.expect != "error":
        return False, f"error: {kind}: {message}"
    want, frag = case.meta["expect_error"], case.meta["expect_message"]
    if kind != want:
        return False, f"rejected with {kind} instead of {want}: {message}"
    if message is not None and frag not in message:
        return False, f"rejected for another reason (expected '{frag}'): {message}"
    want_condition = case.meta.get("condition") or case.meta.get("expect_condition")
    if want_condition and condition != want_condition:
        return False, f"rejected for {condition or 'no condition of clause 8.2'} instead of {want_condition}: {message}"
    return True, f"rejected: {kind} ({condition}): {message}"


def _run_internal(case: Case, render: bool) -> tuple[bool, str]:
    try:
        digest, scene, result = decode_scene_internal(case.stream)
    except LghccError as e:
        return _judge_error(case, type(e).__name__, str(e), getattr(e, "condition", None))
    except Exception as e:  # noqa: BLE001 - any other exception is a decoder bug: a FAIL row
        return False, f"unexpected {type(e).__name__}: {e}"
    ok, note = _judge_decoded(case, digest, scene, render)
    if ok and "source_info" in case.meta:
        ok, note = _judge_source_info(case.meta["source_info"], result, note)
    if ok and "partial_decodes" in case.meta:
        ok, note = _judge_partial_internal(case, note)
    return ok, note


def partial_options(p: dict) -> list[str]:
    """lghcc-dec's options for one partial decode of test.yaml."""
    box = ["--box=" + ",".join(repr(float(x)) for x in p["box"])] if "box" in p else []
    return box + (["--level", str(int(p["level"]))] if "level" in p else [])


def _judge_partial_internal(case: Case, note: str) -> tuple[bool, str]:
    """The partial decodes of a tiled stream (box, level-1 preview) by the reference decoder."""
    from ..common.hashing import digest_of
    from ..common.tiles import Box
    from ..decoder.decode import decode_stream

    data = case.stream.read_bytes()
    for p in case.meta["partial_decodes"]:
        box = Box(tuple(p["box"][:3]), tuple(p["box"][3:])) if "box" in p else None
        try:
            res = decode_stream(data, box=box, max_level=int(p.get("level", 2)))
        except UsageError as e:
            if p.get("refused"):  # a preview of a stream without the hierarchy (clause 13.3)
                continue
            return False, f"{note}; partial decode {' '.join(partial_options(p))} failed: {e}"
        except LghccError as e:
            return False, f"{note}; partial decode {' '.join(partial_options(p))} failed: {e}"
        if p.get("refused"):
            return False, f"{note}; partial decode {' '.join(partial_options(p))}: decoded, expected a refusal"
        got = digest_of(res.scene).hex()
        if got != p["decoded_sha256"]:
            return False, f"{note}; partial decode {' '.join(partial_options(p))}: hash {got[:16]}... differs"
        if res.tiles_decoded != p.get("tiles_decoded", res.tiles_decoded):
            return False, (f"{note}; partial decode {' '.join(partial_options(p))}: {res.tiles_decoded} tiles "
                           f"decoded, {p['tiles_decoded']} expected")
    return True, f"{note}; {len(case.meta['partial_decodes'])} partial decodes match"


def _judge_source_info(want: dict, result, note: str) -> tuple[bool, str]:
    """The reference decoder's source_info (clause 7.3.10) and the units it ignored (clause 6.3)."""
    got = None if result.source_info is None else int(result.source_info.source_sh_degree)
    if got != want["source_sh_degree"] or len(result.notes) != want["ignored"]:
        return False, (f"{note}; source_info: source_sh_degree {got}, {len(result.notes)} ignored; expected "
                       f"{want['source_sh_degree']}, {want['ignored']} ignored")
    return True, f"{note}; source_info: source_sh_degree {got}, {want['ignored']} ignored"


def _judge_decoded(case: Case, digest: str, scene, render: bool) -> tuple[bool, str]:
    if case.expect == "error":
        return False, "decoded a stream that must be rejected"
    want = case.meta["decoded_sha256"]
    if digest != want:
        return False, f"hash {str(digest)[:16]}... != {want[:16]}..."
    note = "hash matches"
    if render and "renders" in case.meta:
        if scene is None:
            return False, "hash matches; no decoded scene to render"
        try:
            ok, rnote = compare_renders(scene, case.meta["renders"], case.folder)
        except Exception as e:  # noqa: BLE001 - a scene the renderer cannot draw fails the check
            return False, f"hash matches; render failed: {type(e).__name__}: {e}"
        return ok, f"{note}; {rnote}"
    return True, note


def _run_external(case: Case, template: str, timeout: float, render: bool) -> tuple[bool, str]:
    with tempfile.TemporaryDirectory(prefix="lghcc-conf-") as tmp:
        out = Path(tmp) / "decoded"
        ext = decode_external(template, case.stream, timeout, out if render else None)
        if ext.status != "exit" or ext.code not in (0, EXIT_REJECTED):
            why = _EXTERNAL_FAILS.get(ext.code) if ext.status == "exit" else None
            return False, ext.describe() + (f" ({why})" if why else "")
        if ext.code == EXIT_REJECTED:
            if case.expect != "error":
                return False, f"rejected a stream that must decode: {ext.describe()}"
            want = exit_code_for_class(case.meta["expect_error"])
            if ext.code != want:
                return False, f"rejected with exit code {ext.code}; {case.meta['expect_error']} is exit code {want}"
            return True, f"rejected (exit code {ext.code}: invalid stream; expected {case.meta['expect_error']})"
        digest = ext.last_line.lower()
        if case.expect == "decode" and not _HEX64.fullmatch(digest):
            return False, f"exit code 0 but the last line of output is not a SHA-256: {ext.last_line[:40]!r}"
        scene = None
        if render and case.expect == "decode" and "renders" in case.meta and digest == case.meta["decoded_sha256"]:
            from ..formats.scaffold_io import read_scaffold

            try:
                scene = read_scaffold(out)
            except LghccError as e:
                return False, f"hash matches; cannot read the decoder's output scene in {{out}}: {e}"
        ok, note = _judge_decoded(case, digest, scene, render)
        if ok and "partial_decodes" in case.meta and "{options}" in shlex.split(template):
            for p in case.meta["partial_decodes"]:
                ext = decode_external(template, case.stream, timeout, None, partial_options(p))
                if p.get("refused"):  # refused with the usage status, nothing decoded (clause 13.3)
                    if ext.status != "exit" or ext.code != 2:
                        return False, f"{note}; partial decode {' '.join(partial_options(p))}: {ext.describe()}, " \
                                      "expected a refusal (exit status 2)"
                    continue
                if ext.status != "exit" or ext.code != 0 or ext.last_line.lower() != p["decoded_sha256"]:
                    return False, f"{note}; partial decode {' '.join(partial_options(p))}: {ext.describe()}"
            note += f"; {len(case.meta['partial_decodes'])} partial decodes match"
        return ok, note


def run_case(case: Case, decoder_cmd: str | None = None, timeout: float = 120.0, render: bool = False) -> Outcome:
    t0 = time.perf_counter()
    if hashlib.sha256(case.stream.read_bytes()).hexdigest() != case.meta["stream_sha256"]:
        return Outcome(case, False, 0.0, "stream.lghcc does not match its stream_sha256: a damaged suite")
    if decoder_cmd is None:
        ok, note = _run_internal(case, render)
    else:
        ok, note = _run_external(case, decoder_cmd, timeout, render)
    return Outcome(case, ok, time.perf_counter() - t0, note)


def format_table(outcomes: list[Outcome], total_s: float | None = None, warm_up_s: float | None = None) -> str:
    w = max([len(o.case.id) for o in outcomes] + [6])
    lines = [f"{'stream':<{w}}  {'expect':<7} {'result':<6} {'ms':>8}  note"]
    for o in outcomes:
        lines.append(f"{o.case.id:<{w}}  {o.case.expect:<7} "
                     f"{'pass' if o.passed else 'FAIL':<6} {1000 * o.seconds:>8.1f}  {o.note[:140]}")
    n_pass = sum(o.passed for o in outcomes)
    tail = f" in {total_s:.2f} s" if total_s is not None else ""
    if warm_up_s is not None:
        tail += f" (after {warm_up_s:.2f} s of imports, not counted)"
    lines.append(f"{n_pass} passed, {len(outcomes) - n_pass} failed{tail}")
    return "\n".join(lines)


def setup_args() -> argparse.ArgumentParser:
    from ..app.cli_common import EXIT_OK, exit_status_epilog
    from ..app.cliargs import add_version_option

    p = argparse.ArgumentParser(prog="lghcc-conformance", description=__doc__,
                                epilog=exit_status_epilog(
                                    {EXIT_OK: "every stream passed", EXIT_ERROR: "a stream FAILed (the table says which)",
                                     EXIT_USAGE: "usage error, or a suite that cannot be run as asked (an unknown "
                                                 "stream id, a damaged test.yaml)",
                                     EXIT_RESOURCE_LIMIT: "the system ran out of memory"},
                                    codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED)),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    p.add_argument("ids", nargs="*", help="stream ids to run (default: all)")
    p.add_argument("--streams", default=str(STREAMS_DIR), help="folder of conformance streams")
    p.add_argument("--decoder-cmd", help="external decoder command template with {stream} (and {out} for --render); "
                                         "see the rejection protocol above")
    p.add_argument("--js", action="store_true",
                   help="run the JavaScript decoder (js/lghcc-decoder, with Node) on the streams of the "
                        "explicit-Gaussian profile (spec clause 8.4) as an external decoder")
    p.add_argument("--timeout", type=float, default=120.0,
                   help="seconds per stream for an external decoder; a decoder still running then FAILs (120)")
    p.add_argument("--threads", type=int, help="torch threads for the reference decoder")
    p.add_argument("--render", action="store_true",
                   help="also render the decoded scene of every stream with reference renders and compare "
                        "within the stream's tolerance (informative: the renderer is not normative)")
    p.add_argument("--coverage", action="store_true",
                   help="also report which syntax elements and value classes the suite exercises")
    return p


def main(argv: list[str] | None = None) -> int:
    """Exit status: 0 all streams passed, 1 a stream failed, 2 usage or suite error, 4 out of memory,
    130 interrupted."""
    from ..app.cliargs import run_cli

    return run_cli("lghcc-conformance", _main, argv)


def _main(argv: list[str] | None) -> int:
    parser = setup_args()
    args = parser.parse_args(argv)
    if args.js and (args.decoder_cmd is not None or args.render):
        parser.error("--js runs the JavaScript decoder: it takes no --decoder-cmd and no --render")
    if args.decoder_cmd is not None:
        try:
            check_template(args.decoder_cmd, args.render)
        except LghccError as e:
            parser.error(str(e))  # exit status 2
    outside = 0
    try:
        if args.js:
            args.decoder_cmd = js_decoder_cmd()
        if args.threads:
            import torch
            torch.set_num_threads(args.threads)
        cases = load_cases(Path(args.streams), args.ids or None)
        if args.js:
            profile = set(js_profile_ids(Path(args.streams)))
            outside = sum(c.id not in profile for c in cases)
            cases = [c for c in cases if c.id in profile]
        t0 = time.perf_counter()
        if args.decoder_cmd is None or args.render:
            warm_up(args.render)
        warm_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        outcomes = [run_case(c, args.decoder_cmd, args.timeout, args.render) for c in cases]
        total = time.perf_counter() - t0
    except LghccError as e:  # the suite cannot be run as asked (unknown id, damaged test.yaml)
        print(f"lghcc-conformance: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    print(format_table(outcomes, total, warm_s))
    if args.js:
        print(f"JavaScript decoder: {len(outcomes)} streams of the explicit-Gaussian profile run, {outside} outside it")
    if args.coverage:
        from .coverage import coverage_report
        print()
        print(coverage_report([c.stream for c in cases if c.expect == "decode"],
                              [c for c in cases if c.expect == "error"]).text())
    return 0 if all(o.passed for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
