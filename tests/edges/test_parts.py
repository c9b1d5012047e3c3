"""Big bytes in parts over real Zenoh (a broker's router on loopback, client sessions that take
no message larger than a wire message): served bytes of several parts come back whole, and an
answer that breaks the rules (a total over the limit or changing between parts, a part other
than the one asked, a part of the wrong length) is refused with its reason."""

from collections.abc import Callable, Iterator

import pytest
import zenoh

from gainfarm.broker.service import Broker
from gainfarm.edges.parts import fetch_parts, reply_part
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session
from gainfarm.schemas.parts import asked_part, part_count, span
from gainfarm.schemas.wire import MAX_EPISODE_BYTES, PART_BYTES, BadMessage, Part
from tests.helpers import wait_for

KEY = "gainfarm/study/s/log/w/" + "0" * 64
CONTENT = bytes(range(256)) * (PART_BYTES * 5 // 2 // 256) + b"tail"  # three parts, the last short


@pytest.fixture
def holder(broker: Broker) -> Iterator[zenoh.Session]:
    with open_session(
        "client", connect=broker.endpoints, max_message_bytes=SERVING_SESSION_BYTES
    ) as serving:
        yield serving


@pytest.fixture
def fetcher(broker: Broker) -> Iterator[zenoh.Session]:
    with open_session(
        "client", connect=broker.endpoints, max_message_bytes=SERVING_SESSION_BYTES
    ) as fetching:
        yield fetching


def serve(
    holder: zenoh.Session,
    fetcher: zenoh.Session,
    answer: Callable[[zenoh.Query], None],
    asked: list[int] | None = None,
) -> zenoh.Queryable:
    """Serve `answer` on KEY, once the router routes the fetcher's queries to it."""

    def on_query(query: zenoh.Query) -> None:
        if query.parameters.get("probe") is not None:
            query.reply_err("here")
            return
        if asked is not None:
            asked.append(asked_part(query.parameters.get("part")))
        answer(query)

    queryable = holder.declare_queryable(KEY, on_query)
    wait_for(lambda: list(fetcher.get(f"{KEY}?probe", timeout=1.0)), what="the queryable")
    return queryable


def test_bytes_of_several_parts_come_back_whole(
    holder: zenoh.Session, fetcher: zenoh.Session
) -> None:
    asked: list[int] = []
    _served = serve(holder, fetcher, lambda query: reply_part(query, CONTENT), asked)
    assert part_count(len(CONTENT)) == 3
    assert fetch_parts(fetcher, KEY, MAX_EPISODE_BYTES, timeout=5.0) == CONTENT
    assert sorted(asked) == [0, 1, 2] and asked[0] == 0


def test_empty_bytes_are_one_empty_part(holder: zenoh.Session, fetcher: zenoh.Session) -> None:
    _served = serve(holder, fetcher, lambda query: reply_part(query, b""))
    assert fetch_parts(fetcher, KEY, MAX_EPISODE_BYTES, timeout=5.0) == b""


def test_nobody_answering_is_none(holder: zenoh.Session, fetcher: zenoh.Session) -> None:
    _served = serve(holder, fetcher, lambda query: query.reply_err("no such log"))
    assert fetch_parts(fetcher, KEY, MAX_EPISODE_BYTES, timeout=5.0) is None


Rule = Callable[[int], int]


def lying(total: Rule, part: Rule, length: Rule) -> Callable[[zenoh.Query], None]:
    """An answer to part i: `length(i)` bytes, saying part `part(i)` of `total(i)` bytes
    (model_construct: a liar's Part need not be valid)."""

    def answer(query: zenoh.Query) -> None:
        index = asked_part(query.parameters.get("part"))
        header = Part.model_construct(total=total(index), part=part(index))
        query.reply(query.key_expr, bytes(length(index)), attachment=header.to_bytes())

    return answer


def always(value: int) -> Rule:
    return lambda index: value


def right_length(total: int) -> Callable[[int], int]:
    return lambda index: span(total, index)[1] - span(total, index)[0]


THREE = 3 * PART_BYTES - 7
LIES = {
    "a total over the limit": (
        lying(always(MAX_EPISODE_BYTES + 1), lambda i: i, lambda i: PART_BYTES),
        "total: must be at most",
    ),
    "a total over the fetcher's limit": (
        lying(always(THREE), lambda i: i, right_length(THREE)),
        f"a total of {THREE} bytes, over the limit of {2 * PART_BYTES}",
    ),
    "a total that changes": (
        lying(lambda i: THREE if i == 0 else THREE + 1, lambda i: i, right_length(THREE)),
        f"a total of {THREE + 1} bytes in part 1, part 0 said {THREE}",
    ),
    "a part out of range": (
        lying(always(THREE), lambda i: i + 5, right_length(THREE)),
        "part 5 in answer to part 0",
    ),
    "a part of the wrong length": (
        lying(always(THREE), lambda i: i, lambda i: 100 if i == 2 else PART_BYTES),
        f"part 2 of {THREE} bytes: 100 bytes, not {PART_BYTES - 7}",
    ),
}


@pytest.mark.parametrize("lie", LIES)
def test_an_answer_that_breaks_the_rules_is_refused(
    holder: zenoh.Session, fetcher: zenoh.Session, lie: str
) -> None:
    answer, reason = LIES[lie]
    _served = serve(holder, fetcher, answer)
    limit = 2 * PART_BYTES if lie == "a total over the fetcher's limit" else MAX_EPISODE_BYTES
    with pytest.raises(BadMessage, match=reason):
        fetch_parts(fetcher, KEY, limit, timeout=5.0)


def test_a_query_that_names_no_part_or_no_such_part_gets_a_reason(
    holder: zenoh.Session, fetcher: zenoh.Session
) -> None:
    _served = serve(holder, fetcher, lambda query: reply_part(query, CONTENT))
    for selector, reason in [
        (KEY, "ask for one part at a time (?part=N, from 0)"),
        (f"{KEY}?part=3", "part: no part 3, there are 3"),
        (f"{KEY}?part=01", "part: not a part number: '01'"),
        (f"{KEY}?part=x", "part: not a part number: 'x'"),
    ]:
        (reply,) = fetcher.get(selector, timeout=5.0)
        assert reply.ok is None and reply.err.payload.to_bytes().decode() == reason
