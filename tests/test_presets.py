"""Presets: one name is one file (encoder/presets/<name>.yaml) with a section per kind of scene it
applies to; a name is refused, with the names that apply, for a kind it has no section for."""

import dataclasses
from importlib import resources

import pytest
import yaml

from lghcc.common.errors import InputError
from lghcc.encoder import cli as enc_cli
from lghcc.encoder.stream.config import (PRESET_KINDS, EncoderConfig, GaussianEncoderConfig, load_config,
                                         preset_names)

CONFIG_OF = {"anchors": EncoderConfig, "gaussians": GaussianEncoderConfig}


def _files() -> dict[str, dict]:
    folder = resources.files("lghcc.encoder").joinpath("presets")
    return {p.name[:-5]: yaml.safe_load(p.read_text()) for p in folder.iterdir() if p.name.endswith(".yaml")}


def test_each_name_is_one_file_with_a_section_per_kind():
    files = _files()
    assert preset_names(None) == sorted(files)
    for name, sections in files.items():
        assert sections and set(sections) <= set(PRESET_KINDS), name
        for kind in sections:
            cfg = load_config(name, kind=kind)
            assert type(cfg) is CONFIG_OF[kind]
            # the section's fields, and nothing else, differ from the defaults
            assert {k: getattr(cfg, k) for k in sections[kind]} == \
                {k: tuple(v) if isinstance(v, list) else v for k, v in sections[kind].items()}, name


def test_the_names_of_each_kind():
    assert preset_names("anchors") == ["high", "lghcc-high", "lghcc-low", "lghcc-medium", "low", "medium"]
    assert preset_names("gaussians") == ["fast", "high", "low", "medium", "web"]
    assert preset_names() == preset_names("anchors")
    with pytest.raises(ValueError, match="kind must be one of anchors, gaussians"):
        preset_names("points")


@pytest.mark.parametrize("name, kind", [("fast", "anchors"), ("lghcc-low", "gaussians")])
def test_a_name_without_a_section_for_the_kind_is_refused_naming_the_choices(name, kind):
    with pytest.raises(InputError) as e:
        load_config(name, kind=kind)
    msg = str(e.value)
    assert f"preset {name!r} has no settings for {PRESET_KINDS[kind]}" in msg
    assert msg.endswith("choose one of " + ", ".join(preset_names(kind)))


def test_an_unknown_name_is_refused_naming_every_preset():
    with pytest.raises(InputError) as e:
        load_config("ultra", kind="gaussians")
    assert str(e.value) == "unknown preset 'ultra'; choose one of " + ", ".join(preset_names(None))


def test_web_is_fast_with_the_decoders_choices():
    """web (for the JavaScript decoder) codes as fast does but without neighbour prediction and in
    chunks of 2048 rows: a change to fast's steps is one to web's too (tools/results/js_decoder.md, Round 12)."""
    assert load_config("web", kind="gaussians") == dataclasses.replace(
        load_config("fast", kind="gaussians"), neighbour_prediction=False, rows_per_chunk=2048)


def test_a_user_file_overrides_the_section(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("target_psnr: 42\n")
    assert load_config("medium", f, kind="gaussians").target_psnr == 42
    assert dataclasses.replace(load_config("medium", kind="gaussians"), target_psnr=42) == \
        load_config("medium", f, kind="gaussians")


def test_lghcc_enc_refuses_a_preset_of_the_other_kind(tmp_path, capsys):
    out = tmp_path / "s.lghcc"
    assert enc_cli.main(["--procedural", "50", "--preset", "fast", "-o", str(out), "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "preset 'fast' has no settings for anchor scenes" in err[0], err
    assert not out.exists()
