"""The logs a worker keeps for its studies to fetch: bounded, least recently used out first, each
study's to itself."""

import threading

import pytest

from gainfarm.worker.logstore import LogStore


def test_logs_are_kept_within_the_bound_and_the_least_recently_used_go_first() -> None:
    store = LogStore(max_bytes=10)
    store.keep("s", "a", b"aaaa")
    store.keep("s", "b", b"bbbb")
    assert len(store) == 2 and store.bytes == 8
    assert store.get("s", "a") == b"aaaa"  # now "b" is the least recently used
    store.keep("s", "c", b"cccc")  # 12 bytes would not fit: "b" goes
    assert store.get("s", "b") is None
    assert store.get("s", "a") == b"aaaa" and store.get("s", "c") == b"cccc"
    assert len(store) == 2 and store.bytes == 8
    store.keep("s", "d", b"dddddddddd")  # the whole store: everything else goes
    assert len(store) == 1 and store.bytes == 10
    assert [store.get("s", name) for name in "acd"] == [None, None, b"dddddddddd"]


def test_keeping_a_log_again_replaces_it_and_counts_as_a_use() -> None:
    store = LogStore(max_bytes=10)
    store.keep("s", "a", b"aaaa")
    store.keep("s", "b", b"bbbb")
    store.keep("s", "a", b"aaa")
    assert len(store) == 2 and store.bytes == 7
    store.keep("s", "c", b"cccc")  # "b" is the least recently used now
    assert store.get("s", "b") is None and store.get("s", "a") == b"aaa"


def test_a_log_is_served_only_to_the_study_whose_job_made_it() -> None:
    store = LogStore(max_bytes=100)
    store.keep("s", "d", b"of s")
    store.keep("t", "d", b"of t")  # the same digest in another study: its own entry
    assert store.get("s", "d") == b"of s" and store.get("t", "d") == b"of t"
    assert store.get("u", "d") is None and store.get("s", "e") is None
    assert len(store) == 2 and store.bytes == 8


def test_a_log_larger_than_the_store_is_not_kept_and_evicts_nothing() -> None:
    store = LogStore(max_bytes=10)
    store.keep("s", "a", b"aaaa")
    store.keep("s", "big", b"x" * 11)
    assert store.get("s", "big") is None
    assert store.get("s", "a") == b"aaaa" and store.bytes == 4
    store.keep("s", "fits", b"x" * 6)
    assert len(store) == 2 and store.bytes == 10
    empty = LogStore(max_bytes=0)
    empty.keep("s", "a", b"a")
    assert len(empty) == 0 and empty.bytes == 0
    with pytest.raises(ValueError):
        LogStore(max_bytes=-1)


def test_threads_keeping_and_getting_at_once_leave_it_consistent() -> None:
    store = LogStore(max_bytes=1000)

    def keep(study: str) -> None:
        for index in range(2000):
            store.keep(study, str(index % 50), bytes(index % 40))
            store.get(study, str((index * 7) % 50))

    threads = [threading.Thread(target=keep, args=(study,)) for study in "stuv"]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    kept = [
        content
        for study in "stuv"
        for index in range(50)
        if (content := store.get(study, str(index))) is not None
    ]
    assert store.bytes == sum(map(len, kept)) <= 1000 and len(store) == len(kept)
