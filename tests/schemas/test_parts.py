"""Cutting big bytes into parts and checking each part's answer, without a network."""

import pytest

from gainfarm.schemas.parts import asked_part, check_part, cut, part_count, selector
from gainfarm.schemas.wire import MAX_EPISODE_BYTES, PART_BYTES, BadMessage, Part, decode


@pytest.mark.parametrize(
    ("total", "count"),
    [(0, 1), (1, 1), (PART_BYTES, 1), (PART_BYTES + 1, 2), (MAX_EPISODE_BYTES, 128)],
)
def test_bytes_take_whole_parts_and_empty_bytes_one(total: int, count: int) -> None:
    assert part_count(total) == count


def test_the_parts_put_together_are_the_bytes() -> None:
    content = bytes(range(251)) * (PART_BYTES // 100)  # 2.5 parts
    parts = [cut(content, index) for index in range(part_count(len(content)))]
    assert b"".join(data for data, _ in parts) == content
    for index, (data, header) in enumerate(parts):
        assert decode(Part, header) == Part(total=len(content), part=index)
        assert check_part(header, len(data), index, len(content), len(content)) == len(content)
    with pytest.raises(BadMessage, match="no part 3, there are 3"):
        cut(content, 3)


def test_a_query_names_its_part_in_digits() -> None:
    assert selector("a/b", 3) == "a/b?part=3" and asked_part("3") == 3 and asked_part("0") == 0
    for bad in ("", "-1", "+1", "01", "1e3", "0x1", " 1", "9" * 12):
        with pytest.raises(BadMessage, match="not a part number"):
            asked_part(bad)
    with pytest.raises(BadMessage, match="ask for one part"):
        asked_part(None)


def test_a_part_header_that_is_no_part_header_is_refused() -> None:
    for raw in (None, b"", b"{}", b'{"protocol": 11, "total": -1, "part": 0}', b"x" * 2000):
        with pytest.raises(BadMessage):
            check_part(raw, 0, 0, None, MAX_EPISODE_BYTES)
