"""Map independent trials over local processes or a Dask cluster, with a bounded queue.

One place for the executor choice shared by ``sqsim experiment`` and ``sqsim generate``:

- ``workers == 1`` and no scheduler: the caller runs its loop in-process (nothing here);
- ``workers > 1``: a spawn-context ``ProcessPoolExecutor`` (spawn: no OpenGL context or thread
  state is inherited from the parent);
- ``scheduler="tcp://HOST:PORT"``: a ``distributed.Client`` executor on that cluster (workers need
  ``sqkit`` importable and, for ``generate``, the output directory on a shared file system).

At most ``in_flight`` tasks are submitted at any time (default ``IN_FLIGHT_PER_WORKER`` per worker
slot), so a run of 100 000 trials holds a few futures, not 100 000, and Ctrl-C stops promptly:
the queued tasks are cancelled and only those already running finish.

Ctrl-C is taken at a point of this module's choosing, never inside the executor. Python raises
``KeyboardInterrupt`` wherever the main thread happens to be, and inside ``concurrent.futures`` that
can be half-way through ``wait``'s acquisition of its futures' locks: the locks stay held, the
executor's manager thread blocks on the first of them as it completes that future, and the shutdown
waits for it forever (one CI run in a few dozen hung so, silent; ``tests/test_parallel.py`` makes the
interrupt land exactly there). So while :func:`map_unordered` runs, Python's default SIGINT handler is
replaced by one that only records the signal; the loop looks every ``POLL_S`` and raises
``KeyboardInterrupt`` itself, outside the executor's code.
"""

from __future__ import annotations

import signal
import threading
from concurrent.futures import FIRST_COMPLETED, wait

__all__ = ["map_unordered", "IN_FLIGHT_PER_WORKER"]

#: Seconds to wait for a Dask scheduler to answer before giving up.
CONNECT_TIMEOUT_S = 20

#: Tasks kept submitted per worker slot: one running, one queued so no worker waits for the parent.
IN_FLIGHT_PER_WORKER = 2


#: Seconds between two looks at a Dask cluster's size (workers may join or leave during a run).
RESIZE_INTERVAL_S = 2.0

#: Seconds between two looks for a recorded Ctrl-C while waiting for results.
POLL_S = 0.1


class _Interrupts:
    """Ctrl-C recorded by a signal handler and raised by :meth:`check`.

    Installed only from the main thread and only over Python's own handler
    (``signal.default_int_handler``): a process that ignores SIGINT (a background job) or handles it
    itself keeps its handler.
    """

    def __init__(self):
        self.pending = False
        self.previous = None

    def install(self):
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
            self.previous = signal.signal(signal.SIGINT, self._record)

    def _record(self, signum, frame):
        self.pending = True

    def check(self):
        if self.pending:
            self.pending = False
            raise KeyboardInterrupt

    def restore(self):
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
            self.previous = None


def _cluster_slots(client):
    """Worker threads of a Dask cluster now, polled at most every ``RESIZE_INTERVAL_S``."""
    import time

    state = {"at": -float("inf"), "slots": 1}

    def slots():
        now = time.monotonic()
        if now - state["at"] >= RESIZE_INTERVAL_S:
            state["at"], state["slots"] = now, max(sum(client.nthreads().values()), 1)
        return state["slots"]
    return slots


def map_unordered(fn, args, *, workers=1, scheduler=None, initializer=None, in_flight=None,
                  wait_on_exit=False):
    """Yield ``fn(*a)`` for every ``a`` in ``args``, in completion order.

    Parameters
    ----------
    fn : callable
        Importable by the workers (a module-level function); takes and returns plain data.
    args : iterable of tuple
        Consumed lazily, as slots free up.
    workers : int
        Local processes (ignored with ``scheduler``), >= 1.
    scheduler : str, optional
        Dask scheduler address ``tcp://HOST:PORT``.
    initializer : callable, optional
        Run once in each local worker process (e.g. to ignore SIGINT).
    in_flight : int, optional
        Maximum submitted, unfinished tasks (default: ``IN_FLIGHT_PER_WORKER`` per worker slot;
        on a Dask cluster the slots are its worker threads, re-read as workers join or leave).
    wait_on_exit : bool
        On an error or interrupt, wait for the local workers to finish their running task (needed
        when a task must not be killed half-way, e.g. while it writes files).

    Yields
    ------
    result
        What ``fn`` returned; an exception raised by ``fn`` propagates after queued tasks are
        cancelled.
    """
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers}")
    if in_flight is not None and (int(in_flight) != in_flight or in_flight < 1):
        raise ValueError(f"in_flight must be an integer >= 1, got {in_flight}")
    client = None
    if scheduler is not None:
        from distributed import Client

        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise OSError(f"cannot connect to the Dask scheduler {scheduler!r}: {exc}") from None
        executor = client.get_executor()
        cluster_slots = _cluster_slots(client)
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        executor = ProcessPoolExecutor(int(workers), mp_context=multiprocessing.get_context("spawn"),
                                       initializer=initializer)
    pending = iter(args)
    futures = set()

    def capacity():
        if in_flight is not None:
            return int(in_flight)
        return IN_FLIGHT_PER_WORKER * (int(workers) if client is None else cluster_slots())

    def refill():
        while len(futures) < capacity():
            a = next(pending, None)
            if a is None:
                return
            futures.add(executor.submit(fn, *a))

    interrupts = _Interrupts()
    interrupts.install()
    finished = False
    try:
        refill()
        while futures:
            done, futures = wait(futures, timeout=POLL_S, return_when=FIRST_COMPLETED)
            interrupts.check()
            for future in done:
                result = future.result()
                refill()
                yield result
                interrupts.check()
        finished = True
    finally:
        try:
            for future in futures:
                future.cancel()
            if client is None:
                executor.shutdown(wait=wait_on_exit, cancel_futures=True)
            else:
                client.close()
        finally:
            interrupts.restore()
        if finished:  # a Ctrl-C during the shutdown of a run that ended on its own
            interrupts.check()
