"""The process's cache of compiled program sets: least recently used dropped first."""

from emgail_jax.host.program_cache import SHARED, SHARED_PROGRAMS, ProgramCache


def test_builds_once_per_key():
    cache = ProgramCache(3)
    built = []
    build = lambda name: lambda: built.append(name) or name
    assert cache.get("a", build("a")) == "a"
    assert cache.get("a", build("again")) == "a"
    assert built == ["a"] and len(cache) == 1


def test_keeps_the_most_recently_used():
    cache = ProgramCache(2)
    a, b = (cache.get(key, object) for key in "ab")
    assert cache.get("a", object) is a  # a is now the most recently used
    cache.get("c", object)  # drops b, the least recently used
    assert cache.keys() == ["a", "c"]
    assert cache.get("a", object) is a
    assert cache.get("b", object) is not b


def test_clear_empties_it():
    cache = ProgramCache()
    cache.get("a", object)
    cache.clear()
    assert len(cache) == 0 and cache.keys() == []


def test_the_process_cache_keeps_a_sweeps_programs():
    assert SHARED.size == SHARED_PROGRAMS >= 2
