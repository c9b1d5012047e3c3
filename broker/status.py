"""Ask a running broker how the farm is doing: one query, from any Zenoh session."""

import zenoh

from schemas import keys
from schemas.wire import BrokerStatus, decode


class BrokerUnavailable(ConnectionError):
    pass


def query_status(session: zenoh.Session, timeout: float = 10.0) -> BrokerStatus:
    """The broker's BrokerStatus; BrokerUnavailable if none answers, BadMessage if garbled."""
    for reply in session.get(keys.STATUS, timeout=timeout):
        if reply.ok is not None:
            return decode(BrokerStatus, reply.ok.payload.to_bytes())
    raise BrokerUnavailable("no gainfarm broker answered a status query")
