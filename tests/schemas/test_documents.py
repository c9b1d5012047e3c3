"""schemas.documents: files read within bounds, refused in one short line, and every file a
person writes still read as it was."""

from pathlib import Path

import pytest
import yaml

from gainfarm.schemas.documents import (
    MAX_DEPTH,
    BadDocument,
    load_json,
    load_toml,
    load_yaml,
    quoted,
    read_bounded,
)


def refusal(load, text) -> str:
    with pytest.raises(BadDocument) as caught:
        load(text)
    reason = str(caught.value)
    assert reason and "\n" not in reason and len(reason) < 200
    return reason


def test_a_file_over_the_limit_is_refused_by_its_size(tmp_path: Path) -> None:
    path = tmp_path / "big"
    path.write_bytes(b"x" * 101)
    assert read_bounded(path, 101) == b"x" * 101
    with pytest.raises(BadDocument, match=r"^101 bytes, more than the 100 this file may have$"):
        read_bounded(path, 100)


def test_a_file_of_no_size_is_read_no_further_than_the_limit() -> None:
    # /dev/zero states no size and never ends: the read stops one byte past the limit.
    with pytest.raises(BadDocument, match=r"^more than the 1000 bytes"):
        read_bounded(Path("/dev/zero"), 1000)


@pytest.mark.parametrize("load", [load_json, load_yaml], ids=["json", "yaml"])
def test_nesting_to_the_limit_is_read_and_deeper_refused(load) -> None:
    def nested(depth: int) -> str:
        return "[" * depth + "1" + "]" * depth

    raw = nested(MAX_DEPTH)
    parsed = load(raw.encode() if load is load_json else raw)
    for _ in range(MAX_DEPTH - 1):
        parsed = parsed[0]
    assert parsed == [1]
    deep = nested(100_000)
    said = refusal(load, deep.encode() if load is load_json else deep)
    assert said == f"nesting deeper than {MAX_DEPTH} levels"


def test_brackets_in_strings_and_comments_are_not_nesting() -> None:
    assert load_json(b'{"why": "' + b"[" * 100 + b'\\"["}') == {"why": "[" * 100 + '"['}
    text = (
        f'why = "{"[" * 100}"\nalso = \'{"{" * 100}\'\n# {"[" * 100}\nmore = """\n{"[" * 99}"""\n'
    )
    assert load_toml(text)["why"] == "[" * 100


def test_toml_nesting_by_dotted_keys_and_tables_is_refused() -> None:
    assert refusal(load_toml, ".".join(["a"] * 100) + " = 1\n").startswith("nesting deeper")
    assert refusal(load_toml, "[" + ".".join(["a"] * 100) + "]\n").startswith("nesting deeper")
    assert load_toml("[a.b.c]\nd = 1\n") == {"a": {"b": {"c": {"d": 1}}}}


@pytest.mark.parametrize(
    "load, text",
    [
        (load_json, b"[" + b"9" * 5000 + b"]"),
        (load_toml, "a = " + "9" * 5000 + "\n"),
        (load_yaml, "a: " + "9" * 5000 + "\n"),
    ],
    ids=["json", "toml", "yaml"],
)
def test_an_integer_of_too_many_digits_is_refused_plainly(load, text) -> None:
    assert refusal(load, text) == "an integer of more than 4300 digits"


def test_yaml_aliases_are_refused_and_anchors_alone_read() -> None:
    laughs = 'a: &a ["lol", "lol"]\nb: [*a, *a]\n'
    assert refusal(load_yaml, laughs).startswith("an alias at line 2 column 5")
    assert load_yaml("a: &a [1, 2]\nb: 3\n") == {"a": [1, 2], "b": 3}


def test_what_is_not_the_language_is_left_to_its_own_error() -> None:
    import json
    import tomllib

    with pytest.raises(json.JSONDecodeError):
        load_json(b"{")
    with pytest.raises(tomllib.TOMLDecodeError):
        load_toml("a = ")
    with pytest.raises(yaml.YAMLError):
        load_yaml("a: [")


def test_a_quoted_value_is_cut() -> None:
    assert quoted("x" * 5) == "'xxxxx'"
    assert quoted([1] * 10_000) == "[1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, ..."
    assert len(quoted("x" * 10_000)) == 40
