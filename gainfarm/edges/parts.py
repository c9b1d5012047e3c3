"""Big bytes over Zenoh in parts (schemas.parts): answering a query for one part, and fetching
all of them. No message on the way is larger than PART_BYTES and a small attachment, so every
session, the broker's router included, takes no message larger than a wire message."""

import logging
from collections import deque

import zenoh

from gainfarm.schemas.parts import (
    PART_PARAMETER,
    asked_part,
    check_part,
    cut,
    part_count,
    selector,
    span,
)
from gainfarm.schemas.wire import BadMessage

log = logging.getLogger("gainfarm.parts")

IN_FLIGHT = 4  # parts asked for at once: loopback stays busy, the fetcher holds 4 more at most


def reply_part(query: zenoh.Query, content: bytes) -> None:
    """Answer `query` with the part of `content` it asks for (its `part` parameter), and the
    Part attachment; an error reply, saying why, for a query that names no part or no such part."""
    try:
        data, header = cut(content, asked_part(query.parameters.get(PART_PARAMETER)))
    except BadMessage as error:
        query.reply_err(str(error))
        return
    query.reply(query.key_expr, data, attachment=header)


def fetch_parts(
    session: zenoh.Session, key: str, limit: int, timeout: float, everyone: bool = False
) -> bytes | None:
    """The bytes served in parts on `key`, at most `limit` of them; None if no one answered part
    0 (or only with an error: it has them no more). BadMessage if an answer breaks the rules
    (schemas.parts.check_part) or a later part does not come. `everyone`: ask every queryable on
    `key` (several may serve it), the first good answer to each part taken. The caller checks
    the digest: the parts' checks bound what is held, not whose bytes they are."""
    first = _answer(_ask(session, key, 0, timeout, everyone), key, 0, None, limit)
    if first is None:
        return None
    data, total = first
    content = bytearray(total)
    content[: len(data)] = data
    asked: deque[tuple[int, zenoh.Handler]] = deque()
    for index in range(1, part_count(total)):
        asked.append((index, _ask(session, key, index, timeout, everyone)))
        if len(asked) == IN_FLIGHT:
            _take(content, *asked.popleft(), key, total, limit)
    while asked:
        _take(content, *asked.popleft(), key, total, limit)
    return bytes(content)


def _ask(
    session: zenoh.Session, key: str, index: int, timeout: float, everyone: bool
) -> zenoh.Handler:
    """Ask for part `index`; the replies come on the handler returned (not waited for here)."""
    if everyone:
        return session.get(
            selector(key, index),
            timeout=timeout,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
        )
    return session.get(selector(key, index), timeout=timeout)


def _take(
    content: bytearray, index: int, replies: zenoh.Handler, key: str, total: int, limit: int
) -> None:
    """Put part `index`'s answer in its place in `content`; BadMessage if none came."""
    answer = _answer(replies, key, index, total, limit)
    if answer is None:
        raise BadMessage(f"{key}: no answer to part {index}")
    start, end = span(total, index)
    content[start:end] = answer[0]


def _answer(
    replies: zenoh.Handler, key: str, index: int, total: int | None, limit: int
) -> tuple[bytes, int] | None:
    """The first good answer among `replies` to part `index`: its bytes and the total it says;
    None if none came. A bad one is skipped if another answers well, else its reason is raised
    (BadMessage)."""
    refused: BadMessage | None = None
    for reply in replies:
        if reply.ok is None:
            continue
        sample = reply.ok
        # At most a message the session takes: decode checks its size against MAX_PART_HEADER_BYTES.
        raw = None if sample.attachment is None else sample.attachment.to_bytes()
        try:
            said = check_part(raw, len(sample.payload), index, total, limit)
        except BadMessage as error:
            log.warning("ignored an answer on %s to part %d: %s", key, index, error)
            refused = error
            continue
        return sample.payload.to_bytes(), said
    if refused is not None:
        raise BadMessage(f"{key}: {refused}")
    return None
