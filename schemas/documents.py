"""Files a person hands a command, read within bounds: size, nesting, expansion and numbers.

A gains, limits, plant or uncertainty file is a few kB of JSON, YAML or TOML. Python's readers
have no bounds of their own: json.loads and tomllib recurse once per nesting level (a file of
"[[[[..." ends in RecursionError), YAML's aliases expand a 1 kB file into gigabytes ("billion
laughs"), and an integer of more than 4,300 digits raises a bare ValueError. So every such file
is read here: its size checked before it is read, its nesting before it is parsed, and what the
parsers raise on hostile input turned into BadDocument, one short line. The contract's own
readers (plant files, episode logs) use it, so it lives in the contract; it reads files, and
imports nothing of the project.
"""

import json
import os
import re
import stat
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import yaml

MAX_DEPTH = 32  # no file a person writes for gainfarm nests deeper than 5 levels
MAX_TEXT_BYTES = 1 << 20  # a gains, limits, plant or uncertainty file is a few kB
QUOTED = 40  # at most this many characters of the input are quoted back in an error


class BadDocument(ValueError):
    """A file refused before or while it was parsed: the message says why, in one short line."""


def read_bounded(path: Path, limit: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of `path`, refused (BadDocument) if it holds more than `limit`: its size is
    checked before it is read, and no more than `limit` + 1 bytes are ever read (a file growing,
    or a device such as /dev/zero that has no size). OSError as open and read raise it."""
    with Path(path).open("rb") as stream:
        size = _size(stream.fileno())
        if size > limit:
            raise BadDocument(f"{size} bytes, more than the {limit} this file may have")
        content = stream.read(limit + 1)
    if len(content) > limit:
        raise BadDocument(f"more than the {limit} bytes this file may have")
    return content


def _size(fd: int) -> int:
    status = os.fstat(fd)
    return status.st_size if stat.S_ISREG(status.st_mode) else 0


def quoted(value: object) -> str:
    """`value` as an error message may quote it: its repr, cut to QUOTED characters."""
    text = repr(value)
    return text if len(text) <= QUOTED else f"{text[: QUOTED - 3]}..."


# --- nesting ----------------------------------------------------------------------------------

# What brackets inside are not nesting: strings (and TOML's comments), removed before counting.
_JSON_SKIP = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_TOML_SKIP = re.compile(
    rb'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*'
)
_OPEN = np.frombuffer(b"[{", dtype=np.uint8)
_CLOSE = np.frombuffer(b"]}", dtype=np.uint8)


def _bracket_depth(raw: bytes, skip: re.Pattern[bytes]) -> int:
    """The deepest the brackets of `raw` nest, strings aside: what a recursive parser recurses."""
    data = np.frombuffer(skip.sub(b"", raw), dtype=np.uint8)
    if data.size == 0:
        return 0
    steps = np.isin(data, _OPEN).astype(np.int32) - np.isin(data, _CLOSE).astype(np.int32)
    return int(np.cumsum(steps).max(initial=0))


def _check_depth(depth: int) -> None:
    if depth > MAX_DEPTH:
        raise BadDocument(f"nesting deeper than {MAX_DEPTH} levels")


def _value_depth(value: Any) -> int:
    """How deep the containers in a parsed value nest, counted without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list | tuple):
            deepest = max(deepest, depth)
            if depth > MAX_DEPTH:
                return depth
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children)
    return deepest


def _too_many_digits(error: ValueError) -> BadDocument | None:
    """Python's refusal of an integer too long to convert, said plainly; None for another."""
    if "digits" not in str(error):
        return None
    limit = sys.get_int_max_str_digits()
    return BadDocument(f"an integer of more than {limit} digits")


# --- the parsers ------------------------------------------------------------------------------


def load_json(raw: bytes) -> Any:
    """The JSON document in `raw`. json.JSONDecodeError (and UnicodeDecodeError) as json.loads
    raises them for what is not JSON; BadDocument for nesting deeper than MAX_DEPTH or an
    integer too long to read."""
    _check_depth(_bracket_depth(raw, _JSON_SKIP))
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        raise
    except ValueError as error:
        raise _too_many_digits(error) or error from None


def load_toml(text: str) -> dict[str, Any]:
    """The TOML document in `text`: tomllib.TOMLDecodeError for what is not TOML, BadDocument for
    nesting deeper than MAX_DEPTH (brackets, or dotted keys and table names) or an integer too
    long to read."""
    _check_depth(_bracket_depth(text.encode(), _TOML_SKIP))
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        raise
    except ValueError as error:
        raise _too_many_digits(error) or error from None
    _check_depth(_value_depth(table))
    return table


def load_yaml(text: str) -> Any:
    """The YAML document in `text`, plain data only (YAML's safe loader), with no aliases: an
    alias is how a tiny file expands to gigabytes, and no gainfarm file needs one. yaml.YAMLError
    for what is not YAML, BadDocument for an alias, nesting deeper than MAX_DEPTH or an integer
    too long to read."""
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    except RecursionError:  # left to no parser: the composer's depth is bounded below
        raise BadDocument(f"nesting deeper than {MAX_DEPTH} levels") from None
    except ValueError as error:
        if isinstance(error, BadDocument):
            raise
        raise _too_many_digits(error) or error from None
    finally:
        loader.dispose()


def _bounded_loader() -> type:
    class BoundedLoader(yaml.SafeLoader):
        """The safe loader, refusing aliases and nesting deeper than MAX_DEPTH as it composes
        the document's nodes (the composer is where PyYAML recurses)."""

        depth = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise BadDocument(
                    f"an alias at line {mark.line + 1} column {mark.column + 1}: aliases "
                    "(*name) are not read, write the value out"
                )
            if self.check_event(yaml.ScalarEvent):  # a leaf: no level of nesting
                return super().compose_node(parent, index)
            self.depth += 1
            try:
                if self.depth > MAX_DEPTH:
                    raise BadDocument(f"nesting deeper than {MAX_DEPTH} levels")
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1

    return BoundedLoader


class _LazyLoader:
    """BoundedLoader, built on first use: PyYAML is imported only for a YAML file."""

    cls: type | None = None

    def __call__(self, text: str) -> Any:
        if self.cls is None:
            self.cls = _bounded_loader()
        return self.cls(text)


_BoundedLoader = _LazyLoader()
