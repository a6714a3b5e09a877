"""The one config mechanism: nested dataclasses from TOML/dicts, checked keys and types, derived flags."""

import argparse
from dataclasses import dataclass, field

import pytest

from cliport.env.environment import EnvConfig
from cliport.errors import ConfigError
from cliport.utils.config import (
    add_flags,
    device_defaults,
    field_docs,
    from_dict,
    given_flags,
    load,
    merge,
    read_defaults,
)


@dataclass
class Inner:
    """Inner settings.

    Args:
        scale: a float
            that goes on.
        name: a name.
    """

    scale: float
    name: str = "x"


@dataclass
class Outer:
    """Outer settings.

    Args:
        steps: how many.
        ids: a list.
        inner: nested.
        maybe: optional.
        flag: on or off.
    """

    steps: int
    ids: list[int]
    inner: Inner
    maybe: str | None = None
    flag: bool = False
    extra: dict = field(default_factory=dict)


def test_from_dict_builds_nested_and_converts_ints_to_floats():
    config = from_dict(Outer, {"steps": 3, "ids": [1, 2], "inner": {"scale": 2}}, "test.toml")
    assert config.inner.scale == 2.0 and isinstance(config.inner.scale, float) and config.inner.name == "x"
    assert config.maybe is None and config.ids == [1, 2]


@pytest.mark.parametrize(
    "data, message",
    [
        ({"steps": 3, "ids": [], "inner": {"scale": 1.0}, "stpes": 1}, "test.toml: unknown Outer key(s) 'stpes'"),
        ({"steps": "3", "ids": [], "inner": {"scale": 1.0}}, "test.toml: steps must be int, got '3'"),
        ({"steps": True, "ids": [], "inner": {"scale": 1.0}}, "steps must be int, got True"),
        ({"steps": 3, "ids": [1, "a"], "inner": {"scale": 1.0}}, "test.toml: ids[1] must be int, got 'a'"),
        ({"steps": 3, "ids": [], "inner": {"scale": "big"}}, "test.toml [inner]: scale must be float"),
        ({"steps": 3, "ids": [], "inner": {"scale": 1.0, "nme": "y"}}, "did you mean 'name'?"),
        ({"ids": [], "inner": {"scale": 1.0}}, "test.toml: missing Outer key 'steps'"),
    ],
)
def test_bad_keys_and_types_name_the_source_and_key(data, message):
    with pytest.raises(ConfigError) as err:
        from_dict(Outer, data, "test.toml")
    assert message in str(err.value)


def test_field_docs_come_from_the_docstring():
    docs = field_docs(Inner)
    assert docs == {"scale": "a float that goes on.", "name": "a name."}


def test_flags_are_derived_from_fields_and_only_given_ones_come_back():
    parser = argparse.ArgumentParser()
    dests = add_flags(parser, [Outer])
    dests += add_flags(parser, [Inner], "inner")
    assert "--steps" in parser.format_help() and "how many." in parser.format_help()
    args = parser.parse_args(["--steps", "4", "--ids", "1", "2", "--scale", "0.5", "--flag"])
    assert given_flags(args, dests) == {"steps": 4, "ids": [1, 2], "flag": True, "inner": {"scale": 0.5}}
    with pytest.raises(ValueError, match="derived from two config fields"):
        add_flags(parser, [Outer], taken={"--steps"})


def test_a_command_takes_some_fields_with_its_own_choices_and_help():
    parser = argparse.ArgumentParser()
    dests = add_flags(
        parser, [Outer], only=["steps", "maybe"], extra={"maybe": {"choices": ["a", "b"], "help": "ours"}}
    )
    assert dests == ["steps", "maybe"]
    text = parser.format_help()
    assert "--ids" not in text and "{a,b}" in text and "ours" in text and "how many." in text
    assert parser.parse_args(["--maybe", "a"]).maybe == "a"
    with pytest.raises(SystemExit):
        parser.parse_args(["--maybe", "c"])
    with pytest.raises(ValueError, match="no field named stepz in Outer"):
        add_flags(argparse.ArgumentParser(), [Outer], only=["stepz"])


def test_load_reads_the_shipped_defaults_and_merges_overrides():
    env = load(EnvConfig, "env", {"camera_scale": 0.5})
    assert env.camera_scale == 0.5 and env.renderer == "auto"
    with pytest.raises(ConfigError, match="env.toml.*unknown EnvConfig key\\(s\\) 'camera_scal'"):
        load(EnvConfig, "env", {"camera_scal": 0.5})
    assert merge({"a": {"b": 1, "c": 2}}, {"a": {"c": 3}}) == {"a": {"b": 1, "c": 3}}


def test_device_defaults_put_a_device_table_over_its_section():
    language = read_defaults("quickstart")["language"]
    cpu = device_defaults("quickstart", "cpu", "language")
    assert cpu["batch_size"] == language["cpu"]["batch_size"] != language["batch_size"]
    assert cpu["task"] == language["task"] and cpu["width"] == language["cpu"]["width"]
    assert device_defaults("quickstart", "cuda", "language")["batch_size"] == language["batch_size"]
    assert device_defaults("quickstart", "cpu")["task"] == read_defaults("quickstart")["task"]
    with pytest.raises(ConfigError, match=r"no \[language.tpu\] table"):
        device_defaults("quickstart", "tpu", "language")
