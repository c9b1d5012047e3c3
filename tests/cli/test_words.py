"""Counts said as a person says them."""

from gainfarm.cli.words import counted


def test_one_is_singular_and_every_other_count_plural() -> None:
    assert counted(1, "worker") == "1 worker"
    assert [counted(n, "worker") for n in (0, 2)] == ["0 workers", "2 workers"]
    assert (counted(1, "study"), counted(3, "study")) == ("1 study", "3 studies")
    assert counted(1, "job") + ", " + counted(10, "job") == "1 job, 10 jobs"
