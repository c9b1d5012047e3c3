"""Counts said as a person says them: "1 worker", "2 workers", "1 study", "2 studies"."""

# Plurals that are not the noun and an s.
_PLURALS = {"study": "studies", "query": "queries", "trajectory": "trajectories", "is": "are"}


def counted(count: int, noun: str) -> str:
    """`count` and `noun`, plural unless the count is one."""
    return f"{count} {noun if count == 1 else _PLURALS.get(noun, noun + 's')}"
