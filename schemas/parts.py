"""Big bytes in parts: how an episode log or a model is cut for the wire and put back together.
No Zenoh here (gainfarm/edges/parts.py asks and answers).

Whoever holds the bytes answers a query for part i (`?part=i`) with bytes [i * PART_BYTES,
(i + 1) * PART_BYTES) and a Part attachment saying their total size; the fetcher asks part 0,
learns the total, asks the rest and assembles them. Every part is checked as it comes (a total
over the fetcher's limit, or other than part 0's; a part other than the one asked; a part of the
wrong length: BadMessage), so the fetcher never holds more than the total it accepted; the whole
is then checked by its digest, which is the trust.
"""

import re

from gainfarm.schemas.wire import PART_BYTES, BadMessage, Part, decode

PART_PARAMETER = "part"  # the selector's parameter naming the part asked for
# A part's number as a query writes it: digits, no sign, no leading zero, short.
_NUMBER = re.compile(r"0|[1-9][0-9]{0,8}")
MAX_PART_HEADER_BYTES = 1024  # a Part's JSON is some 50 bytes


def part_count(total: int) -> int:
    """How many parts `total` bytes take: at least one (empty bytes are one empty part)."""
    return max(1, -(-total // PART_BYTES))


def span(total: int, index: int) -> tuple[int, int]:
    """Where part `index` of `total` bytes starts and ends."""
    start = index * PART_BYTES
    return start, min(start + PART_BYTES, total)


def selector(key: str, index: int) -> str:
    """The selector asking for part `index` of what `key` names."""
    return f"{key}?{PART_PARAMETER}={index}"


def asked_part(value: str | None) -> int:
    """The part a query asks for, from its `part` parameter; BadMessage if it names none."""
    if value is None:
        raise BadMessage(f"ask for one part at a time (?{PART_PARAMETER}=N, from 0)")
    if not _NUMBER.fullmatch(value):
        raise BadMessage(f"{PART_PARAMETER}: not a part number: {value[:20]!r}")
    return int(value)


def cut(content: bytes, index: int) -> tuple[bytes, bytes]:
    """Part `index` of `content` and its Part attachment; BadMessage if there is no such part."""
    count = part_count(len(content))
    if index >= count:
        raise BadMessage(f"{PART_PARAMETER}: no part {index}, there are {count}")
    start, end = span(len(content), index)
    return content[start:end], Part(total=len(content), part=index).to_bytes()


def check_part(
    attachment: bytes | None, length: int, index: int, total: int | None, limit: int
) -> int:
    """The total a reply to part `index` says, once it is checked: a Part attachment, the total
    within `limit` (and `total`, part 0's, if known), this part and this part's length.
    BadMessage otherwise."""
    header = decode(Part, attachment, MAX_PART_HEADER_BYTES)
    if header.total > limit:
        raise BadMessage(f"a total of {header.total} bytes, over the limit of {limit}")
    if total is not None and header.total != total:
        raise BadMessage(f"a total of {header.total} bytes in part {index}, part 0 said {total}")
    if header.part != index:
        raise BadMessage(f"part {header.part} in answer to part {index}")
    if index >= part_count(header.total):
        raise BadMessage(f"part {index} of {header.total} bytes: out of range")
    start, end = span(header.total, index)
    if length != end - start:
        raise BadMessage(f"part {index} of {header.total} bytes: {length} bytes, not {end - start}")
    return header.total
