"""Zenoh sessions as the farm opens them: explicit endpoints, no multicast scouting.

Every process names where to listen or connect; discovery by multicast would let two farms on one
network find each other by accident.
"""

import json
import re
from collections.abc import Sequence
from typing import Literal

import zenoh


def session_config(
    mode: Literal["router", "client", "peer"],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
) -> zenoh.Config:
    """ValueError, in one line, for an endpoint Zenoh cannot parse."""
    config = zenoh.Config()
    try:
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    except zenoh.ZError as error:
        raise ValueError(f"bad endpoint: {_plain(error)}") from None
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    return config


def open_session(
    mode: Literal["router", "client", "peer"],
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
) -> zenoh.Session:
    """Open a session; ConnectionError with the endpoints in its message if that fails."""
    config = session_config(mode, listen, connect)
    try:
        return zenoh.open(config)
    except zenoh.ZError as error:
        where = ", ".join([*listen, *connect]) or "nowhere"
        reason = _plain(error)
        raise ConnectionError(f"cannot open a Zenoh {mode} session on {where}: {reason}") from None


def _plain(error: Exception) -> str:
    """Zenoh's message without the Rust source locations it appends."""
    text = re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(error))
    return re.sub(r"^Json5Err\(Message \{ msg: \"(.*?)\".*$", r"\1", text).strip()
