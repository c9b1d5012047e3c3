"""Ask a running broker how the farm is doing: one query, from any Zenoh session."""

import zenoh

from gainfarm.edges.ask import ask
from gainfarm.schemas import keys
from gainfarm.schemas.wire import BadMessage, BrokerStatus, decode


class BrokerUnavailable(ConnectionError):
    pass


def query_status(session: zenoh.Session, timeout: float = 10.0) -> BrokerStatus:
    """The broker's BrokerStatus; BrokerUnavailable if none answers, BadMessage if garbled."""
    answer = ask(session, keys.STATUS, timeout=timeout)
    if answer is None:
        raise BrokerUnavailable("no gainfarm broker answered a status query")
    if answer.payload is None:
        raise BadMessage(f"the broker refused a status query: {answer.error}")
    return decode(BrokerStatus, answer.payload)
