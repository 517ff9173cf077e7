import pytest

from sqsim.runs.parallel import map_unordered


def _square(x):
    return x * x


def _fail(x):
    raise ValueError(f"bad {x}")


def test_map_unordered_local_processes_consumes_lazily():
    consumed = []

    def args():
        for i in range(20):
            consumed.append(i)
            yield (i,)

    results = map_unordered(_square, args(), workers=2, in_flight=3)
    first = next(results)
    # Three submitted; each finished task frees a slot that is refilled before its result is yielded,
    # and up to all three may finish together: at most 3 + 3 consumed by then (not all 20).
    assert first in {0, 1, 4} and len(consumed) <= 6
    assert sorted([first, *results]) == [i * i for i in range(20)]


def test_map_unordered_errors():
    with pytest.raises(ValueError, match="bad"):
        list(map_unordered(_fail, [(1,), (2,)], workers=2))
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        list(map_unordered(_square, [(1,)], workers=0))
    with pytest.raises(ValueError, match="in_flight must be an integer >= 1"):
        list(map_unordered(_square, [(1,)], workers=2, in_flight=0))


def test_cluster_slots_follow_workers_joining(monkeypatch):
    import sqsim.runs.parallel as parallel

    class FakeClient:
        threads = {}

        def nthreads(self):
            return dict(self.threads)

    client = FakeClient()
    monkeypatch.setattr(parallel, "RESIZE_INTERVAL_S", 0.0)
    slots = parallel._cluster_slots(client)
    assert slots() == 1  # no worker yet: still submit
    client.threads = {"a": 2, "b": 1}
    assert slots() == 3
    monkeypatch.setattr(parallel, "RESIZE_INTERVAL_S", 3600.0)
    client.threads = {}
    assert slots() == 3  # not polled again within the interval
