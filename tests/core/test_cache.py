"""core.cache.BoundedCache: the named least-recently-used cache behind the bridge's module-level caches."""
import pytest

from core.cache import BoundedCache


def test_keeps_at_most_capacity_entries_dropping_the_least_recently_used():
    c = BoundedCache("test", capacity=2)
    c.put("a", 1)
    c.put("b", 2)
    assert c.get("a") == 1            # "a" is now the most recently used
    c.put("c", 3)
    assert len(c) == 2 and c.get("b") is None and c.get("a") == 1 and c.get("c") == 3


def test_an_entry_failing_its_check_is_dropped():
    c = BoundedCache("test", capacity=4)
    c.put("k", (1, "old"))
    assert c.get("k", valid=lambda e: e[0] == 2) is None
    assert len(c) == 0
    c.put("k", (2, "new"))
    assert c.get("k", valid=lambda e: e[0] == 2) == (2, "new")


def test_clear_forgets_everything_and_capacity_is_checked():
    c = BoundedCache("test", capacity=3)
    for k in range(3):
        c.put(k, k)
    c.clear()
    assert len(c) == 0 and c.get(0) is None
    assert "test" in repr(c)
    with pytest.raises(ValueError):
        BoundedCache("bad", capacity=0)
