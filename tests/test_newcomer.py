"""What a new user meets first (issue 16): the demo runs twice, the install is quiet, every
program has --version and documents its exit codes, one overwrite rule, progress reaches a
log, Ctrl-C stops cleanly, and the README's commands write nowhere inside the repository."""

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PROGRAMS = ("lghcc-enc", "lghcc-dec", "lghcc-train", "lghcc-view", "lghcc-batch", "lghcc-conformance")
MODULES = {"lghcc-enc": "lghcc.encoder.cli", "lghcc-dec": "lghcc.decoder.cli", "lghcc-train": "lghcc.encoder.train",
           "lghcc-view": "lghcc.viewer.cli", "lghcc-batch": "lghcc.batch.cli",
           "lghcc-conformance": "lghcc.conformance.runner"}


def _main(prog):
    import importlib

    return importlib.import_module(MODULES[prog]).main


@pytest.fixture(scope="module")
def small_stream(tmp_path_factory):
    from lghcc.encoder import cli as enc

    out = tmp_path_factory.mktemp("stream") / "s.lghcc"
    assert enc.main(["--procedural", "200", "-o", str(out), "-q"]) == 0
    return out


@pytest.mark.parametrize("prog", PROGRAMS)
def test_every_program_has_version_and_documents_its_exit_codes(prog, capsys):
    import lghcc

    with pytest.raises(SystemExit) as e:
        _main(prog)(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"{prog} {lghcc.__version__} (lghcc)"
    with pytest.raises(SystemExit):
        _main(prog)(["--help"])
    text = capsys.readouterr().out
    assert "exit status:" in text and re.search(r"^\s+130\s+interrupted", text, re.M), prog
    readme = (ROOT / "README.md").read_text()
    assert "130" in readme and "Exit status" in readme


def test_version_matches_the_package_metadata():
    import tomllib

    import lghcc

    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["version"] == lghcc.__version__
    assert meta["license"] == "Apache-2.0" and "Apache License" in (ROOT / "LICENSE").read_text()[:200]
    torch_req = next(d for d in meta["dependencies"] if d.startswith("torch"))
    assert "==" not in torch_req and ">=" in torch_req  # a range: installable beside another torch
    # ... while the set-up installs the exact CPU build first
    assert "pip install -q torch==2.13.0" in (ROOT / "Makefile").read_text()


def test_voxels_per_extent_is_documented(capsys):
    with pytest.raises(SystemExit):
        _main("lghcc-train")(["--help"])
    assert "--voxels-per-extent" in capsys.readouterr().out


@pytest.mark.parametrize("prog", ("lghcc-enc", "lghcc-dec", "lghcc-view", "lghcc-train"))
def test_one_overwrite_rule_in_every_program(prog, capsys):
    with pytest.raises(SystemExit):
        _main(prog)(["--help"])
    text = capsys.readouterr().out
    assert "-y, --overwrite, -f, --force" in text and "-n, --no-overwrite" in text


def test_every_decoder_output_follows_the_overwrite_rule(tmp_path, small_stream, capsys):
    """-o, --json, --trace, --export, --render-out: an existing file or a non-empty folder is
    kept (exit 1, before decoding) unless -y; with -y each is replaced."""
    from lghcc.decoder import cli as dec

    outs = {"--json": tmp_path / "d.json", "--trace": tmp_path / "t.txt", "--export": tmp_path / "e.ply"}
    for opt, path in outs.items():
        path.write_text("old")
        assert dec.main([str(small_stream), opt, str(path)]) == 1
        assert "exists; use -y (--overwrite)" in capsys.readouterr().err
        assert path.read_text() == "old"
        assert dec.main([str(small_stream), opt, str(path), "-y", "-q"]) == 0
        assert path.read_bytes() != b"old"
    views = tmp_path / "views"
    views.mkdir()
    (views / "000_orbit_000.png").write_text("old")
    argv = [str(small_stream), "--render", "orbit:1", "--render-size", "8x8", "--render-out", str(views)]
    assert dec.main(argv) == 1
    assert "is not empty; use -y" in capsys.readouterr().err
    assert dec.main(argv + ["-y", "-q"]) == 0
    assert (views / "000_orbit_000.png").read_bytes()[:4] == b"\x89PNG"


def test_train_refuses_an_existing_run_unless_resume_or_overwrite(tmp_path, capsys):
    from lghcc.encoder.train import check_fresh_output

    run = tmp_path / "run"
    (run / "point_cloud" / "iteration_10").mkdir(parents=True)
    (run / "train_state.pth").write_bytes(b"x")
    (run / "notes.txt").write_text("mine")
    from lghcc.common.errors import InputError

    with pytest.raises(InputError, match=r"training run\b.*--resume .* -y"):
        check_fresh_output(run, overwrite=False)
    check_fresh_output(run, overwrite=True)
    assert sorted(p.name for p in run.iterdir()) == ["notes.txt"]  # only the run's own files went


@pytest.mark.integration
def test_make_demo_runs_twice(tmp_path):
    """The demo target's commands (from the Makefile, with a smaller scene), twice in a row."""
    text = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^demo:.*\n((?:\t.*\n)+)", text, re.M).group(1)
    cmds = [ln.strip().replace("$(VENV)/bin/", str(BIN) + "/").replace("20000", "1500")
            for ln in recipe.splitlines() if ln.strip()]
    assert len(cmds) == 2 and "lghcc-dec" in cmds[1]
    for attempt in range(2):
        for cmd in cmds:
            r = subprocess.run(shlex.split(cmd), cwd=tmp_path, capture_output=True, text=True)
            assert r.returncode == 0, (attempt, cmd, r.stderr)
    assert (tmp_path / "demo_out" / "decoded" / "point_cloud" / "iteration_0" / "checkpoint.pth").is_file()


def test_progress_lines_reach_a_log_and_ctrl_c_stops_cleanly(tmp_path):
    """stderr to a pipe (as in a log or a batch job): plain progress lines, not a silent run;
    SIGINT: one line, exit 130, no output file and no temporary file left."""
    env = {**os.environ, "LGHCC_PROGRESS_INTERVAL": "0.2", "PYTHONUNBUFFERED": "1"}
    out = tmp_path / "big.lghcc"
    p = subprocess.Popen([sys.executable, "-m", "lghcc.encoder.cli", "--procedural", "400000", "-o", str(out)],
                         stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    lines = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = p.stderr.readline()
        if not line:
            break
        lines.append(line)
        if line.startswith("lghcc: procedural scene:"):
            break
    assert any(ln.startswith("lghcc: procedural scene:") and "%" in ln for ln in lines), lines
    p.send_signal(signal.SIGINT)
    rest = p.stderr.read()
    assert p.wait(timeout=60) == 130
    tail = [ln for ln in rest.splitlines() if not ln.startswith("lghcc: ")]
    assert tail == ["lghcc-enc: interrupted"], rest
    assert "Traceback" not in rest
    assert list(tmp_path.iterdir()) == []


def test_log_progress_prints_percent_and_time_left(capsys, monkeypatch):
    from lghcc.app.progress import LogProgress, progress_bar

    bar = LogProgress(total=4, desc="fit", unit="step", interval=0)
    for _ in range(2):
        bar.update()
    bar.set_postfix_str("loss 0.1")
    bar.update()
    bar.close()
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("lghcc: fit: 25% (1/4 step)") and "left" in err[0]
    assert err[-1].endswith(", done [loss 0.1]") and "100% (3/4" not in err[-1]
    # nothing at all when the step is quicker than the interval
    monkeypatch.setenv("LGHCC_PROGRESS_INTERVAL", "60")
    for _ in progress_bar(range(3), desc="quick"):
        pass
    assert capsys.readouterr().err == ""


@pytest.fixture(scope="module")
def built_wheel(tmp_path_factory):
    """A wheel of the tracked sources (and of lghcc-view's bundle where `make viewer-bundle` built
    it: a release ships it) -> (the wheel, pip's output, the tracked files)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs the git checkout (git ls-files)")
    try:
        import setuptools  # noqa: F401
    except ImportError:
        pytest.skip("setuptools is not installed in this environment")
    tmp_path = tmp_path_factory.mktemp("wheel")
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    src = tmp_path / "src"
    bundle = [str(p.relative_to(ROOT)) for p in (ROOT / "viewer" / "assets").glob("*.js")]
    for f in files + bundle:
        if f.startswith(("tests/", "tools/", "docs/", "spec/")):
            continue
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, src / f)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w",
                        str(tmp_path / "dist"), str(src)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    (whl,) = (tmp_path / "dist").glob("lghcc-*.whl")
    return whl, r.stdout + r.stderr, files


@pytest.mark.integration
def test_install_is_quiet(built_wheel):
    """A wheel of the tracked sources builds without one warning from setuptools (it printed
    ~1,900 lines: every conformance stream folder, and the license table), and ships the
    license, py.typed and the conformance streams."""
    whl, text, files = built_wheel
    ours = [ln for ln in text.splitlines() if "warning" in ln.lower() and "Location 'file:" not in ln]
    assert ours == [], ours[:10]
    import zipfile

    names = zipfile.ZipFile(whl).namelist()
    assert "lghcc/py.typed" in names and any(n.endswith("licenses/LICENSE") for n in names)
    assert "lghcc/conformance/streams/c001_one_anchor/stream.lghcc" in names
    # every package folder ships (pyproject lists each: a new subpackage missing there would not)
    inits = {f"lghcc/{f}" for f in files if f.endswith("__init__.py") and not f.startswith(("tests/", "tools/"))}
    assert inits - set(names) == set()


def _fresh_venv_with_the_wheel(whl: Path, where: Path) -> Path:
    """A new virtual environment outside the checkout with the wheel installed and its dependencies
    taken from this environment's site-packages (a path in a .pth file: no network, and not this
    environment's editable install of the checkout, whose own .pth is not read from there)."""
    import sysconfig

    venv = where / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)  # its own pip (ensurepip, offline)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    (Path(site) / "deps_of_the_test.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    r = subprocess.run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(whl)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return venv


@pytest.mark.integration
def test_the_wheel_installs_and_runs_outside_the_checkout(built_wheel, tmp_path):
    """The wheel in a fresh environment, run from a folder outside the checkout: the installed
    lghcc (not the checkout's) prints its version, encodes a 3DGS PLY, decodes it with the hash
    checked and writes lghcc-view's page (where the bundle was built; CI builds it)."""
    whl, _, _ = built_wheel
    if os.name != "posix":
        pytest.skip("the environment's scripts are in bin/ on POSIX")
    venv = _fresh_venv_with_the_wheel(whl, tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["OMP_WAIT_POLICY"] = "PASSIVE"

    def run(*cmd):
        r = subprocess.run([str(c) for c in cmd], cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (cmd, r.stderr[-2000:])
        return r.stdout + r.stderr

    where = run(venv / "bin" / "python", "-c", "import lghcc, sys; print(lghcc.__file__)").strip()
    assert str(venv) in where and str(ROOT) not in where
    assert "lghcc" in run(venv / "bin" / "lghcc-enc", "--version")
    run(venv / "bin" / "python", "-c", "from lghcc.formats import write_scene; from lghcc.formats.procedural import "
        "make_room_scene; write_scene(make_room_scene(500), 'room.ply')")
    run(venv / "bin" / "lghcc-enc", "room.ply", "-o", "room.lghcc", "--preset", "fast", "-q")
    run(venv / "bin" / "lghcc-dec", "room.lghcc", "--export-ply", "back.ply", "-q")
    assert (work / "back.ply").stat().st_size > 0
    if not list((ROOT / "viewer" / "assets").glob("lghcc-viewer.js")):
        pytest.skip("lghcc-view's bundle is not built here (make viewer-bundle): the page is not checked")
    run(venv / "bin" / "lghcc-view", "room.lghcc", "-o", "room.html", "--no-psnr", "-q")
    assert (work / "room.html").stat().st_size > (ROOT / "viewer" / "assets" / "lghcc-viewer.js").stat().st_size


def test_readme_commands_write_outside_the_repository():
    """Every -o / --render-out / --export / --json of a README command names out/ (ignored by
    git) or another folder outside the sources, never the repository root."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```sh\n(.*?)```", text, re.S)
    bad = []
    for block in blocks:
        for line in block.splitlines():
            if "lghcc-" not in line or line.lstrip().startswith("#"):
                continue
            for m in re.finditer(r"(?:-o|--render-out|--export(?:-ply)?|--json)\s+(\S+)", line):
                path = m.group(1)
                if not path.startswith(("out/", "runs/", "demo_out/", "/tmp/")):
                    bad.append(line.strip())
    assert bad == [], bad
    assert "hours" in text  # the training example says how long the default takes
    assert "/out/" in (ROOT / ".gitignore").read_text() and "/runs/" in (ROOT / ".gitignore").read_text()


def test_lghcc_presets_say_how_long_first(tmp_path, capsys, monkeypatch):
    """A context-model preset prints its time estimate before the minutes of fitting; an
    interrupt then leaves nothing behind (exit 130)."""
    from lghcc.encoder import api
    from lghcc.encoder import cli as enc

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "encode", interrupted)
    out = tmp_path / "x.lghcc"
    assert enc.main(["--procedural", "3000", "--preset", "lghcc-medium", "-o", str(out)]) == 130
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "preset lghcc-medium:" in ln)
    assert re.search(r"2 GG-Conv fits of 1,500 steps on 3,\d{3} anchors, about \d+ s on 2 CPU threads", line), line
    assert "the preset medium codes with the same steps in seconds" in line
    assert err.strip().endswith("lghcc-enc: interrupted") and not out.exists()
    # the fast presets: no estimate
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.encoder.stream.config import load_config

    scene = make_procedural_scene(200)
    assert api.estimate_seconds(scene, load_config("medium")) is None
    low, high = (api.estimate_seconds(scene, load_config(p))[0] for p in ("lghcc-low", "lghcc-high"))
    assert 20 < low < high < 600
