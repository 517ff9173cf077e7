import subprocess
import sys

import pytest

from _helpers import kill_group, popen_interruptible
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


def _run_script(script, timeout=60):
    """Run ``script`` in a fresh interpreter of its own process group, with Python's SIGINT handler;
    kill the group afterwards (a hung run must not leave workers behind). Returns (returncode,
    stdout, stderr)."""
    proc = popen_interruptible([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        out, err = None, None
    finally:
        kill_group(proc)
    assert out is not None, f"the run did not end within {timeout} s of its Ctrl-C"
    return proc.returncode, out, err


def test_ctrl_c_inside_the_executors_own_locking_still_stops():
    # The interrupt lands half-way through concurrent.futures.wait acquiring its futures' locks,
    # with the first held. Raised there, KeyboardInterrupt left that lock held, the executor's
    # manager thread blocked on it and the shutdown waited forever (a silent CI hang).
    script = """
import concurrent.futures._base as base, signal, time
from sqsim.runs.parallel import map_unordered

enter, calls = base._AcquireFutures.__enter__, [0]

def interrupted_enter(self):
    calls[0] += 1
    if calls[0] != 3:
        return enter(self)
    for i, future in enumerate(self.futures):
        future._condition.acquire()
        if i == 0:
            signal.raise_signal(signal.SIGINT)

base._AcquireFutures.__enter__ = interrupted_enter
try:
    for _ in map_unordered(time.sleep, ((0.01,) for _ in range(10 ** 6)), workers=2):
        pass
except KeyboardInterrupt:
    print("interrupted", calls[0] >= 3, signal.getsignal(signal.SIGINT) is signal.default_int_handler)
"""
    code, out, err = _run_script(script)
    assert code == 0 and out.split() == ["interrupted", "True", "True"], err


def test_ctrl_c_handler_is_held_only_while_mapping():
    script = """
import signal, time
from sqsim.runs.parallel import map_unordered

assert sorted(map_unordered(abs, [(-1,), (-2,)], workers=2)) == [1, 2]
print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)
# a Ctrl-C while the caller handles a result is raised when it asks for the next one
results = map_unordered(time.sleep, ((0.01,) for _ in range(10 ** 6)), workers=2)
next(results)
signal.raise_signal(signal.SIGINT)
print("handled")
try:
    next(results)
except KeyboardInterrupt:
    print("raised", signal.getsignal(signal.SIGINT) is signal.default_int_handler)
# a process that ignores SIGINT (a background job) keeps ignoring it
signal.signal(signal.SIGINT, signal.SIG_IGN)
assert list(map_unordered(abs, [(-3,)], workers=2)) == [3]
print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
"""
    code, out, err = _run_script(script)
    assert code == 0 and out.split() == ["True", "handled", "raised", "True", "True"], err


def test_a_pending_ctrl_c_does_not_replace_the_callers_error_when_the_map_is_closed():
    # Ctrl-C recorded while the caller handles a result, then the caller fails and the map is closed
    # on the way out: the caller's error is what propagates (a pending Ctrl-C is raised after the
    # shutdown only of a run that ended on its own), and Python's handler is back
    script = """
import signal, time
from sqsim.runs.parallel import map_unordered

results = map_unordered(time.sleep, ((0.01,) for _ in range(10 ** 6)), workers=2)
next(results)
signal.raise_signal(signal.SIGINT)
try:
    try:
        raise ValueError("the caller's error")
    finally:
        results.close()
except BaseException as exc:
    print(type(exc).__name__, signal.getsignal(signal.SIGINT) is signal.default_int_handler)
"""
    code, out, err = _run_script(script)
    assert code == 0 and out.split() == ["ValueError", "True"], (out, err)
