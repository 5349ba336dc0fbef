"""Conformance: the streams (``STREAMS_DIR``), their runner, the mutation list, the fuzzer."""

from pathlib import Path

STREAMS_DIR = Path(__file__).resolve().parent / "streams"


def load_yaml(text: str):
    """yaml.safe_load, with libyaml's parser where PyYAML has it: the suite's test.yaml files and
    sources.yaml read about ten times faster (the same safe constructors and resolver)."""
    import yaml

    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
