"""The sweep file of lghcc-batch: which scenes, presets and rate lambdas, and how to evaluate.

Everything a user can get wrong in it (an unknown key, a missing scene, an unknown preset, a
field the encoder, trainer or transcoder does not have) is reported by ``load_sweep`` before
any work starts, naming the key and where it is. Paths are relative to the sweep file.

    output: rd_sweep                  # results folder (default: <sweep>_results beside the file)
    scenes:
      - name: donut                   # names the rows, plots and files: letters, digits, . _ -
        path: ../shared/data/donut/donut.ply   # anchor model (folder or PLY) or a plain 3DGS PLY
        up: 0,0,1                     # the scene's up direction for the orbit views (default 0,0,1)
      - name: demo
        procedural: 2000              # the built-in procedural scene (about N anchors)
        seed: 0
      - name: lego
        train: ../shared/data/lego/lego_100    # posed images: trained once per lambda, then encoded
        train_options: {iterations: 2000}      # lghcc-train's TrainConfig fields
    presets: [low, medium, lghcc-medium]
    lambdas: [0, 0.004]               # lghcc-train --rate-lambda values, for the `train` scenes
    encoder: {prior_fit_rows: 20000}  # EncoderConfig fields over every preset
    transcode: {iterations: 200}      # TranscodeConfig fields for 3DGS PLY scenes
    evaluation: {views: 8, size: 256x256, background: black}
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..common.errors import InputError


class SweepError(InputError):
    """The sweep file cannot be run; the message names the key and the place."""


TOP_KEYS = ("output", "scenes", "presets", "lambdas", "encoder", "transcode", "evaluation")
SCENE_KEYS = ("name", "path", "procedural", "train", "seed", "up", "train_options")
SCENE_KINDS = ("path", "procedural", "train")
EVAL_KEYS = ("views", "size", "background")
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


@dataclass(frozen=True)
class SceneSpec:
    name: str
    kind: str  # path | procedural | train
    path: str | None = None  # absolute (path, train)
    procedural: int | None = None
    seed: int = 0
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    train_options: tuple = ()  # sorted (key, value) pairs of TrainConfig fields


@dataclass(frozen=True)
class Evaluation:
    views: int = 8
    width: int = 256
    height: int = 256
    background: str = "black"


@dataclass(frozen=True)
class PrepKey:
    """One prepared anchor scene: a scene, and for trained scenes the rate lambda."""
    scene: str
    lam: float | None = None

    @property
    def id(self) -> str:
        return self.scene if self.lam is None else f"{self.scene}__lam{_num(self.lam)}"


@dataclass(frozen=True)
class CellKey:
    """One cell: a prepared scene coded with one preset."""
    prep: PrepKey
    preset: str

    @property
    def id(self) -> str:
        return f"{self.prep.id}__{self.preset}"


@dataclass
class Sweep:
    file: Path
    output: Path
    scenes: dict[str, SceneSpec]
    presets: list[str]
    lambdas: list[float]
    encoder: dict = field(default_factory=dict)
    transcode: dict = field(default_factory=dict)
    evaluation: Evaluation = field(default_factory=Evaluation)

    def preps(self) -> list[PrepKey]:
        out = []
        for s in self.scenes.values():
            if s.kind == "train":
                out += [PrepKey(s.name, lam) for lam in (self.lambdas or [0.0])]
            else:
                out.append(PrepKey(s.name))
        return out

    def cells(self) -> list[CellKey]:
        return [CellKey(p, preset) for p in self.preps() for preset in self.presets]


def _num(x: float) -> str:
    return f"{x:g}"


def _where(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _check_keys(d: dict, allowed: tuple, where: str, file: Path) -> None:
    if not isinstance(d, dict):
        raise SweepError(f"{file}: {where or 'the file'} must be a mapping (key: value), got {type(d).__name__}")
    unknown = [k for k in d if k not in allowed]
    if unknown:
        raise SweepError(f"{file}: unknown key {_where(where, str(unknown[0]))!r}"
                         f"{' (and ' + ', '.join(map(repr, unknown[1:])) + ')' if unknown[1:] else ''}; "
                         f"allowed {'at ' + where if where else 'at the top'}: {', '.join(allowed)}")


def _fields_of(cls) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


def _check_fields(d, cls, where: str, file: Path, forbidden: tuple = ()) -> dict:
    """A mapping of fields of dataclass ``cls`` (EncoderConfig, TrainConfig, TranscodeConfig)."""
    if d is None:
        return {}
    allowed = tuple(f for f in _fields_of(cls) if f not in forbidden)
    _check_keys(d, allowed, where, file)
    return dict(d)


def _up(v, where: str, file: Path) -> tuple[float, float, float]:
    try:
        t = tuple(float(x) for x in (v.split(",") if isinstance(v, str) else v))
    except (TypeError, ValueError):
        t = ()
    if len(t) != 3 or not all(math.isfinite(x) for x in t) or not any(t):
        raise SweepError(f"{file}: {where} must be three numbers x,y,z, not all zero, got {v!r}")
    return t  # type: ignore[return-value]


def _scene(d, i: int, base: Path, file: Path) -> SceneSpec:
    where = f"scenes[{i}]"
    _check_keys(d, SCENE_KEYS, where, file)
    name = d.get("name")
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise SweepError(f"{file}: {where}.name must be 1-64 letters, digits, '.', '_' or '-' (it names files), "
                         f"got {name!r}")
    kinds = [k for k in SCENE_KINDS if k in d]
    if len(kinds) != 1:
        raise SweepError(f"{file}: {where} ({name}) needs exactly one of {', '.join(SCENE_KINDS)}, got "
                         f"{', '.join(kinds) or 'none'}")
    kind = kinds[0]
    seed = d.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise SweepError(f"{file}: {where}.seed must be an integer, got {seed!r}")
    if "seed" in d and kind != "procedural":
        raise SweepError(f"{file}: {where}.seed applies to procedural scenes only")
    if "train_options" in d and kind != "train":
        raise SweepError(f"{file}: {where}.train_options applies to train scenes only")
    up = _up(d["up"], f"{where}.up", file) if "up" in d else (0.0, 0.0, 1.0)
    if kind == "procedural":
        n = d["procedural"]
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise SweepError(f"{file}: {where}.procedural must be a positive anchor count, got {n!r}")
        return SceneSpec(name, kind, procedural=n, seed=seed, up=up)
    p = d[kind]
    if not isinstance(p, str) or not p:
        raise SweepError(f"{file}: {where}.{kind} must be a path, got {p!r}")
    path = (base / p).resolve() if not Path(p).is_absolute() else Path(p)
    opts = ()
    if kind == "train":
        from ..encoder.training.config import TrainConfig

        opts = tuple(sorted(_check_fields(d.get("train_options"), TrainConfig, f"{where}.train_options", file,
                                          forbidden=("data", "rate_lambda")).items()))
    return SceneSpec(name, kind, path=str(path), up=up, train_options=opts)


def _lambdas(v, file: Path) -> list[float]:
    if v is None:
        return []
    if not isinstance(v, list) or not v:
        raise SweepError(f"{file}: lambdas must be a non-empty list of numbers, got {v!r}")
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x < 0:
            raise SweepError(f"{file}: lambdas must be numbers >= 0, got {x!r}")
        out.append(float(x))
    if len(set(out)) != len(out):
        raise SweepError(f"{file}: lambdas lists a value twice: {v}")
    return out


def _evaluation(v, file: Path) -> Evaluation:
    if v is None:
        return Evaluation()
    _check_keys(v, EVAL_KEYS, "evaluation", file)
    e = Evaluation()
    views = v.get("views", e.views)
    if not isinstance(views, int) or isinstance(views, bool) or views < 1:
        raise SweepError(f"{file}: evaluation.views must be a positive integer, got {views!r}")
    size = str(v.get("size", f"{e.width}x{e.height}"))
    m = re.fullmatch(r"(\d+)x(\d+)", size)
    if not m or min(int(m.group(1)), int(m.group(2))) < 1:
        raise SweepError(f"{file}: evaluation.size must be WxH, got {size!r}")
    bg = v.get("background", e.background)
    if bg not in ("black", "white"):
        raise SweepError(f"{file}: evaluation.background must be black or white, got {bg!r}")
    return Evaluation(views, int(m.group(1)), int(m.group(2)), bg)


def _read_yaml(file: Path):
    """The sweep file's data; SweepError naming the file (and the line of a YAML error)."""
    try:
        data = yaml.safe_load(file.read_text())
    except OSError as e:
        raise SweepError(f"{file}: cannot read the sweep file ({e.strerror or e})") from None
    except yaml.YAMLError as e:
        mark, what = getattr(e, "problem_mark", None), getattr(e, "problem", None) or str(e).splitlines()[0]
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise SweepError(f"{file}: not valid YAML: {what}{where}") from None
    if data is None:
        raise SweepError(f"{file}: the sweep file is empty; it needs at least `scenes:`")
    return data


def _scenes(scenes_in, base: Path, file: Path) -> dict[str, SceneSpec]:
    """The scenes by name: each checked, no name twice, every missing path named at once."""
    if not isinstance(scenes_in, list) or not scenes_in:
        raise SweepError(f"{file}: scenes must be a non-empty list of scenes (name and one of "
                         f"{', '.join(SCENE_KINDS)})")
    scenes: dict[str, SceneSpec] = {}
    for i, d in enumerate(scenes_in):
        s = _scene(d, i, base, file)
        if s.name in scenes:
            raise SweepError(f"{file}: scenes[{i}].name {s.name!r} is used twice")
        scenes[s.name] = s
    missing = [f"{s.name}: {s.path}" for s in scenes.values() if s.path and not Path(s.path).exists()]
    if missing:
        raise SweepError(f"{file}: {len(missing)} scene{'s' if len(missing) > 1 else ''} not found: "
                         + "; ".join(missing))
    return scenes


def _presets(presets, known: list[str], file: Path) -> list[str]:
    if isinstance(presets, str):
        presets = [presets]
    if not isinstance(presets, list) or not presets:
        raise SweepError(f"{file}: presets must be a non-empty list, got {presets!r}")
    for p in presets:
        if p not in known:
            raise SweepError(f"{file}: unknown preset {p!r} in presets; known: {', '.join(known)}")
    if len(set(presets)) != len(presets):
        raise SweepError(f"{file}: presets lists a preset twice: {presets}")
    return list(presets)


def _output_path(file: Path, base: Path, output, data: dict) -> Path:
    """--output as given; else the file's `output:` (relative to the sweep file); else <stem>_results."""
    out = output if output is not None else data.get("output")
    if out is None:
        return file.resolve().parent / f"{file.stem}_results"
    return Path(out) if output is not None or Path(out).is_absolute() else base / out


def load_sweep(file: str | Path, output: str | Path | None = None) -> Sweep:
    """Read and check a sweep file (module doc). Raises SweepError naming the first problem;
    every missing scene path is named at once."""
    from ..encoder.stream.config import EncoderConfig, load_config, preset_names
    from ..encoder.anchors.transcode import TranscodeConfig

    file = Path(file)
    data = _read_yaml(file)
    _check_keys(data, TOP_KEYS, "", file)
    base = file.resolve().parent
    scenes = _scenes(data.get("scenes"), base, file)
    presets = _presets(data.get("presets", ["medium"]), preset_names(), file)
    lambdas = _lambdas(data.get("lambdas"), file)
    if lambdas and not any(s.kind == "train" for s in scenes.values()):
        raise SweepError(f"{file}: lambdas are rate lambdas of training (lghcc-train --rate-lambda) and no scene "
                         "is trained (train: <images folder>); remove lambdas or add a train scene")
    encoder = _check_fields(data.get("encoder"), EncoderConfig, "encoder", file)
    for p in presets:  # every preset with the overrides must make a valid configuration
        try:
            load_config(p, overrides=encoder)
        except InputError as e:
            raise SweepError(f"{file}: encoder with preset {p}: {e}") from None
    transcode = _check_fields(data.get("transcode"), TranscodeConfig, "transcode", file,
                              forbidden=("progress",))
    return Sweep(file, _output_path(file, base, output, data), scenes, presets, lambdas, encoder, transcode,
                 _evaluation(data.get("evaluation"), file))

