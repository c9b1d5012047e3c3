"""Ask the broker a question and hear only the broker's answer.

On a plain farm anyone can declare a queryable on the broker's keys and answer in its name (say,
"rejected" to every submission). A client of the farm is connected to one router, the broker, so
an answer counts only if it comes from a router this session is connected to (or from this very
session); every other answer is logged as an impostor's and ignored. On the secure profile the
access policy already stops anyone else from declaring such a queryable.
"""

import logging
from dataclasses import dataclass

import zenoh

log = logging.getLogger("gainfarm.ask")

ZENOH_TIMEOUT = "Timeout"  # the payload of the error reply Zenoh makes when a query times out


@dataclass(frozen=True)
class Answer:
    """The broker's reply: `payload` if it answered, else `error`, its one-line refusal."""

    payload: bytes | None = None
    error: str | None = None


def ask(
    session: zenoh.Session, key: str, payload: bytes | None = None, timeout: float = 10.0
) -> Answer | None:
    """Query `key` and return the broker's Answer, or None if the broker did not answer."""
    trusted = {str(zid) for zid in session.info.routers_zid()} | {str(session.zid())}
    replies = session.get(
        key,
        payload=payload,
        timeout=timeout,
        # Every queryable hears the query and every answer comes back, so an impostor's
        # queryable can neither take the question nor hide the broker's answer.
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
    )
    for reply in replies:
        if reply.ok is None and _text(reply.err.payload) == ZENOH_TIMEOUT:
            continue  # Zenoh's own error reply: nobody answered in time
        replier = reply.replier_id
        if replier is None:
            log.warning("ignored an answer on %s with no replier", key)
            continue
        if str(replier.zid) not in trusted:
            log.warning(
                "ignored an answer on %s from %s, which is not the broker", key, replier.zid
            )
            continue
        # The first answer from the broker is the answer: an impostor that never answers must
        # not make every question wait for the timeout.
        if reply.ok is not None:
            return Answer(payload=reply.ok.payload.to_bytes())
        return Answer(error=_text(reply.err.payload))
    return None


def _text(payload: zenoh.ZBytes) -> str:
    return payload.to_bytes().decode(errors="replace")
