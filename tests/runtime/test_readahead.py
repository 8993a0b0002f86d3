"""The read-ahead stage: same items, same order, errors where they belong, no thread left."""

from __future__ import annotations

import threading
import time

import pytest

from care_maps.runtime.readahead import read_ahead


def _threads() -> set[str]:
    return {t.name for t in threading.enumerate() if t.name.startswith("care-read-ahead")}


@pytest.mark.parametrize("depth", [0, 1, 3])
def test_items_in_order(depth: int) -> None:
    assert list(read_ahead(iter(range(50)), depth)) == list(range(50))
    assert list(read_ahead([], depth)) == []
    assert not _threads()


def test_produces_at_most_depth_ahead_on_another_thread() -> None:
    made: list[tuple[int, str]] = []

    def source():
        for i in range(10):
            made.append((i, threading.current_thread().name))
            yield i

    stream = read_ahead(source(), 2)
    assert next(stream) == 0
    time.sleep(0.2)  # the producer fills its queue, then waits
    assert len(made) == 3  # the item handed out and two ahead, no more
    assert all(name.startswith("care-read-ahead") for _, name in made)
    assert list(stream) == list(range(1, 10))
    assert not _threads()


def test_error_is_raised_where_its_item_would_be() -> None:
    boom = ValueError("views.parquet: damaged")

    def source():
        yield 1
        yield 2
        raise boom

    stream = read_ahead(source(), 2)
    assert [next(stream), next(stream)] == [1, 2]
    with pytest.raises(ValueError, match=r"views\.parquet: damaged") as err:
        next(stream)
    assert err.value is boom  # the same one-line error, not a wrapper
    assert not _threads()


def test_closing_early_stops_the_producer_and_closes_the_source() -> None:
    closed = threading.Event()
    made = []

    def source():
        try:
            for i in range(1000):
                made.append(i)
                yield i
        finally:
            closed.set()

    stream = read_ahead(source(), 2)
    assert [next(stream) for _ in range(3)] == [0, 1, 2]
    stream.close()
    assert closed.is_set()
    assert not _threads()
    assert len(made) <= 6  # what was ahead when it stopped, not the rest


def _consume_until_five() -> None:
    for item in read_ahead(iter(range(100)), 2):
        if item == 5:
            raise KeyError(item)


def test_consumer_error_leaves_no_thread() -> None:
    with pytest.raises(KeyError):
        _consume_until_five()
    assert not _threads()
