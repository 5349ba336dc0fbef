"""Exit codes that tell failures apart (lghcc.app.cli_common), for every command-line program:
0 success, 1 input or environment error, 2 usage, 3 invalid stream, 4 resource limit,
130 interrupted; one line on stderr, never a traceback, and no partial output."""

import os
import signal
import subprocess
import sys
import time

import pytest

from lghcc.app import cli_common
from lghcc.app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_OK, EXIT_RESOURCE_LIMIT,
                              EXIT_USAGE, exit_code_for, exit_code_for_class, parse_memory_size)
from lghcc.common.errors import (BitstreamError, HashMismatchError, InputError, LghccError, ResourceLimitError,
                                 UnsupportedStreamError, UsageError)
from lghcc.conformance import runner
from lghcc.decoder import cli as dec_cli
from lghcc.encoder import cli as enc_cli
from lghcc.encoder import train as train_cli

STREAMS = runner.STREAMS_DIR
GOOD = STREAMS / "c001_one_anchor" / "stream.lghcc"
CRC = STREAMS / "e007_crc_mismatch" / "stream.lghcc"
HASH = STREAMS / "e002_hash_mismatch" / "stream.lghcc"
PROFILE = STREAMS / "e011_unsupported_profile" / "stream.lghcc"


def _one_line(err: str) -> str:
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("exc, code", [
    (LghccError("x"), EXIT_ERROR), (InputError("x"), EXIT_ERROR), (BitstreamError("x"), EXIT_INVALID_STREAM),
    (UnsupportedStreamError("x"), EXIT_INVALID_STREAM), (HashMismatchError("x"), EXIT_INVALID_STREAM),
    (ResourceLimitError("x"), EXIT_RESOURCE_LIMIT), (MemoryError(), EXIT_RESOURCE_LIMIT), (UsageError("x"), EXIT_USAGE),
    (KeyboardInterrupt(), EXIT_INTERRUPTED)])
def test_one_rule_maps_every_failure_class(exc, code):
    assert exit_code_for(exc) == code
    if isinstance(exc, LghccError):
        assert exit_code_for_class(type(exc).__name__) == code
    assert len({EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INVALID_STREAM, EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED}) == 6


def test_a_resource_limit_is_not_an_invalid_stream():
    assert not issubclass(ResourceLimitError, BitstreamError)
    with pytest.raises(ValueError):
        exit_code_for_class("ValueError")


def test_prefixing_a_message_keeps_the_class():
    e = cli_common.with_prefix(HashMismatchError("does not match"), "s.lghcc")
    assert type(e) is HashMismatchError and str(e) == "s.lghcc: does not match"


@pytest.mark.parametrize("text, value", [("512M", 512 << 20), ("8G", 8 << 30), ("1.5GiB", 3 << 29), ("4096", 4096),
                                         ("64k", 64 << 10), ("2TB", 2 << 40), ("none", None), ("0", None)])
def test_memory_sizes_as_users_write_them(text, value):
    assert parse_memory_size(text) == value


@pytest.mark.parametrize("text", ["", "lots", "-1G", "8X", "nanG", "G"])
def test_malformed_memory_sizes_are_refused(text):
    with pytest.raises(ValueError, match="memory amount"):
        parse_memory_size(text)


# --- lghcc-dec --------------------------------------------------------------------------------------

def test_decoder_exit_codes(tmp_path, capsys):
    assert dec_cli.main([str(GOOD), "-q"]) == EXIT_OK
    assert dec_cli.main([str(tmp_path / "missing.lghcc")]) == EXIT_ERROR
    assert "cannot read" in _one_line(capsys.readouterr().err)
    for stream, fragment in ((CRC, "CRC-32"), (HASH, "does not match"), (PROFILE, "profile_idc 2")):
        assert dec_cli.main([str(stream), "-o", str(tmp_path / "out")]) == EXIT_INVALID_STREAM, stream
        err = _one_line(capsys.readouterr().err)
        assert fragment in err and str(stream) in err
    assert not (tmp_path / "out").exists()  # nothing written for a rejected stream
    assert dec_cli.main([str(GOOD), "--max-points", "0"]) == EXIT_RESOURCE_LIMIT
    assert "maximum 0" in _one_line(capsys.readouterr().err)
    assert dec_cli.main([str(GOOD), "--max-memory", "1K"]) == EXIT_RESOURCE_LIMIT
    err = _one_line(capsys.readouterr().err)
    assert "1.0 KiB" in err and "--max-memory" in err
    with pytest.raises(SystemExit) as e:
        dec_cli.main([str(GOOD), "--max-memory", "lots"])
    assert e.value.code == EXIT_USAGE and "memory amount" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        dec_cli.main([])
    assert e.value.code == EXIT_USAGE


@pytest.mark.parametrize("exc, code, fragment", [
    (KeyboardInterrupt(), EXIT_INTERRUPTED, "lghcc-dec: interrupted"),
    (MemoryError(), EXIT_RESOURCE_LIMIT, "out of memory"),
])
def test_decoder_interrupt_and_out_of_memory(tmp_path, capsys, monkeypatch, exc, code, fragment):
    import lghcc.decoder.decode as dec

    def fail(*a, **k):
        raise exc
    monkeypatch.setattr(dec, "decode_stream", fail)
    assert dec_cli.main([str(GOOD), "-o", str(tmp_path / "out")]) == code
    assert fragment in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_every_program_documents_its_exit_status(capsys):
    from lghcc.viewer import cli as view_cli

    for main in (dec_cli.main, enc_cli.main, runner.main, train_cli.main, view_cli.main):
        with pytest.raises(SystemExit) as e:
            main(["--help"])
        assert e.value.code == 0
        out = capsys.readouterr().out
        assert "exit status:" in out and "130" in out and "usage error" in out, main.__module__
    with pytest.raises(SystemExit):
        dec_cli.main(["--help"])
    out = capsys.readouterr().out
    assert "3    invalid stream" in out and "4    resource limit" in out and "--max-memory" in out


# --- lghcc-enc --------------------------------------------------------------------------------------

def test_encoder_exit_codes(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o.lghcc"
    assert enc_cli.main(["--procedural", "60", "-o", str(out), "-q"]) == EXIT_OK
    assert enc_cli.main([str(tmp_path / "missing"), "-o", str(tmp_path / "x.lghcc")]) == EXIT_ERROR
    assert "no such file" in _one_line(capsys.readouterr().err)
    assert enc_cli.main(["--procedural", "60", "-o", str(tmp_path / "m.lghcc"), "--max-memory", "1K"]) \
        == EXIT_RESOURCE_LIMIT  # refused before any work: the scene needs more than --max-memory
    assert "needs about" in _one_line(capsys.readouterr().err) and not (tmp_path / "m.lghcc").exists()
    with pytest.raises(SystemExit) as e:
        enc_cli.main(["--procedural", "60"])  # -o is required
    assert e.value.code == EXIT_USAGE and "required: -o" in capsys.readouterr().err
    import lghcc.encoder.stream.encode as enc
    import lghcc.decoder.decode as dec

    for target, attr, exc, code, fragment in (
            (enc, "encode_scene", KeyboardInterrupt(), EXIT_INTERRUPTED, "lghcc-enc: interrupted"),
            (enc, "encode_scene", MemoryError(), EXIT_RESOURCE_LIMIT, "out of memory"),
            (dec, "decode_stream", BitstreamError("garbled"), EXIT_INVALID_STREAM, "garbled")):
        def fail(*a, _e=exc, **k):
            raise _e
        with monkeypatch.context() as m:
            m.setattr(target, attr, fail)
            assert enc_cli.main(["--procedural", "60", "-o", str(tmp_path / "new.lghcc"), "-q"]) == code
        assert fragment in _one_line(capsys.readouterr().err)
        assert not (tmp_path / "new.lghcc").exists() and not list(tmp_path.glob(".new.lghcc.*"))


# --- lghcc-conformance ------------------------------------------------------------------------------

def test_conformance_exit_codes(capsys, monkeypatch):
    assert runner.main(["c001_one_anchor", "e007_crc_mismatch"]) == EXIT_OK
    capsys.readouterr()
    assert runner.main(["no_such_stream"]) == EXIT_USAGE
    capsys.readouterr()

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(runner, "run_case", interrupted)
    assert runner.main(["c001_one_anchor"]) == EXIT_INTERRUPTED
    assert _one_line(capsys.readouterr().err).startswith("lghcc-conformance: ")


def test_conformance_verdict_is_1(capsys):
    assert runner.main(["c001_one_anchor", "--decoder-cmd", "echo " + "0" * 64 + " {stream}"]) == 1
    assert "FAIL" in capsys.readouterr().out


# --- lghcc-train ------------------------------------------------------------------------------------

def test_training_exit_codes(tmp_path, capsys, monkeypatch):
    assert train_cli.main([str(tmp_path)]) == EXIT_ERROR  # no -o
    assert "give the output folder" in _one_line(capsys.readouterr().err)
    with pytest.raises(SystemExit) as e:
        train_cli.main(["--no-such-option"])
    assert e.value.code == EXIT_USAGE and "unrecognized arguments" in capsys.readouterr().err
    for exc, code, fragment in ((KeyboardInterrupt(), EXIT_INTERRUPTED, "continue with --resume"),
                                (MemoryError(), EXIT_RESOURCE_LIMIT, "out of memory")):
        def fail(*a, _e=exc, **k):
            raise _e
        monkeypatch.setattr(train_cli, "train", fail)
        assert train_cli.main([str(tmp_path), "-o", str(tmp_path / "run")]) == code
        assert fragment in _one_line(capsys.readouterr().err)


# --- a real Ctrl-C ------------------------------------------------------------------------------------

def test_sigint_during_decoding_exits_130_with_one_line_and_no_output(tmp_path):
    """SIGINT while the decoder works (a decode held up on purpose): exit status 130, one line,
    no traceback, and no output folder (outputs are only written after decoding, atomically)."""
    code = ("import sys, time\n"
            "import lghcc.decoder.decode as dec\n"
            "from lghcc.decoder import cli\n"
            "real = dec.decode_stream\n"
            "def slow(*a, **k):\n"
            "    print('decoding', flush=True)\n"
            "    time.sleep(30)\n"
            "    return real(*a, **k)\n"
            "dec.decode_stream = slow\n"
            "sys.exit(cli.main(sys.argv[1:]))\n")
    out = tmp_path / "decoded"
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
    p = subprocess.Popen([sys.executable, "-c", code, str(GOOD), "-o", str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=env)
    assert p.stdout.readline().strip() == "decoding"
    time.sleep(0.2)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == EXIT_INTERRUPTED, (p.returncode, stderr)
    assert stderr == "lghcc-dec: interrupted\n"
    assert not out.exists()


def test_encoder_self_check_failure_exits_3_and_writes_nothing(tmp_path, monkeypatch, capsys):
    """A written stream that does not decode to the encoded scene is the encoder's bug; lghcc-enc
    says so in one line, exits 3 (invalid stream, as its --help says) and leaves no output."""
    import types

    from lghcc.decoder import decode as dec
    from lghcc.encoder import cli as enc_cli

    real = dec.decode_stream

    def wrong_hash(data, *a, **k):
        out = real(data, *a, **k)
        return types.SimpleNamespace(stream_hash=b"\0" * 32, scene=getattr(out, "scene", None))

    monkeypatch.setattr(dec, "decode_stream", wrong_hash)
    out = tmp_path / "p.lghcc"
    assert enc_cli.main(["--procedural", "50", "-o", str(out), "-q"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lghcc-enc: error:") and "decode" in err[0], err
    assert list(tmp_path.iterdir()) == []
