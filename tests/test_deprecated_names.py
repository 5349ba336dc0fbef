"""Spellings kept for one release after a rename: each still works, and warns (one InputWarning
line on stderr) naming the spelling that replaces it."""

import argparse
import warnings

import pytest

from lghcc.app.cli_common import EXIT_RESOURCE_LIMIT
from lghcc.app.cliargs import add_deprecated_alias
from lghcc.common.errors import InputError, InputWarning
from lghcc.conformance import runner
from lghcc.decoder import cli as dec_cli

GOOD = runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc"


def test_deprecated_alias_sets_the_new_option_and_warns():
    p = argparse.ArgumentParser()
    p.add_argument("--max-points", type=int)
    add_deprecated_alias(p, "--max-anchors", "--max-points", type=int)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert p.parse_args(["--max-anchors", "7"]).max_points == 7
        assert p.parse_args(["--max-points", "8"]).max_points == 8
    assert [str(w.message) for w in caught if issubclass(w.category, InputWarning)] == \
        ["--max-anchors is deprecated and will be removed: use --max-points"]
    assert "--max-anchors" not in p.format_help()  # hidden: --help shows only the new spelling


@pytest.mark.parametrize("option", ["--max-points", "--max-anchors"])
def test_lghcc_dec_max_points_and_its_old_spelling(option, capsys):
    assert dec_cli.main([str(GOOD), option, "0"]) == EXIT_RESOURCE_LIMIT
    err = capsys.readouterr().err.splitlines()
    assert "maximum 0" in err[-1]
    warned = [line for line in err if "warning:" in line]
    assert warned == ([] if option == "--max-points" else
                      ["lghcc-dec: warning: --max-anchors is deprecated and will be removed: use --max-points"])


@pytest.mark.parametrize("kind", ["anchors", "gaussians"])
def test_context_train_anchors_is_context_train_points(tmp_path, kind):
    from lghcc.encoder.stream.config import load_config

    f = tmp_path / "c.yaml"
    f.write_text("context_train_anchors: 1234\n")
    with pytest.warns(InputWarning, match="context_train_anchors is deprecated and will be removed: "
                                          "use context_train_points"):
        assert load_config("medium", f, kind=kind).context_train_points == 1234
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_config("medium", overrides={"context_train_points": 99}, kind=kind).context_train_points == 99
    with pytest.raises(InputError, match="give context_train_points only"):
        load_config("medium", overrides={"context_train_anchors": 1, "context_train_points": 2}, kind=kind)
