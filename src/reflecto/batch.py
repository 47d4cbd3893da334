"""Batches: run one function over many items in worker processes or on a Dask cluster.

Every batch in reflecto (``reconstruct`` of several captures, ``sweep``, ``design``,
``gallery``) goes through :func:`run_batch`: each item runs guarded (a failure becomes
a one-line message naming the item, never a traceback, and never stops the others),
results arrive in this process as items end, workers die with this process, and a
worker process that dies takes only its own item with it. :class:`Progress` draws the
bar (or plain lines off a terminal).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from tqdm import tqdm

from .errors import ReflectoError, one_line

__all__ = ["Progress", "interactive", "run_batch", "run_on_dask"]


def interactive() -> bool:
    """Whether progress may be drawn as a bar.

    Returns
    -------
    bool
        stderr is a terminal and ``CI`` is unset, empty, ``0``, ``false`` or ``no``.
    """
    ci = os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")
    try:
        return sys.stderr.isatty() and not ci
    except (AttributeError, ValueError):
        return False


class Progress:
    """Progress of a batch on stderr: a tqdm bar on a terminal, else one plain line per item.

    A line reads ``sweep: 12/50 done (pvc, 8.1 s)`` or ``sweep: 13/50 failed (pvc)``.
    """

    def __init__(self, total: int, desc: str, enabled: bool = True, initial: int = 0) -> None:
        self.total, self.desc, self.enabled, self.done = total, desc, enabled, initial
        self.bar = None
        if enabled and interactive():
            self.bar = tqdm(total=total, initial=initial, desc=desc, unit="item", leave=False)

    def update(self, name: str, ok: bool, seconds: float) -> None:
        """Count one finished item: advance the bar, or print ``desc: k/n done (name, s)`` /
        ``desc: k/n failed (name)``.

        Parameters
        ----------
        name
            The item's name.
        ok
            Whether it succeeded.
        seconds
            Its wall time (s).
        """
        self.done += 1
        if self.bar is not None:
            self.bar.update()
        elif self.enabled:
            what = f"done ({name}, {seconds:.1f} s)" if ok else f"failed ({name})"
            print(f"{self.desc}: {self.done}/{self.total} {what}", file=sys.stderr, flush=True)

    def close(self) -> None:
        """Remove the bar (nothing to do for plain lines)."""
        if self.bar is not None:
            self.bar.close()


def _watch_parent(parent: int, ignore_interrupt: bool = False) -> None:
    """Pool initializer: end this worker as soon as its parent process is gone.

    Linux kills the worker when its parent dies (``PR_SET_PDEATHSIG``, SIGKILL, set
    by ``prctl``); elsewhere, and as a fallback, a thread polls ``os.getppid()``
    twice a second. Without this a SIGKILLed parent leaves its workers waiting on
    their task queue for ever. With ``ignore_interrupt`` the worker ignores SIGINT and
    SIGTERM (a terminal's Ctrl-C, or a service manager's SIGTERM, reaches the whole process
    group): its parent stops the batch, and the item running ends whole first (no
    traceback from a worker interrupted while it waits, no half-written file of one
    killed while it writes).
    """
    if ignore_interrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)

    def poll() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=poll, name="reflecto-parent-watch", daemon=True).start()


def _guarded(fn: Callable[..., Any], args: tuple[Any, ...], label: str) -> tuple[bool, Any, float]:
    """``(True, fn(*args), seconds)``, or ``(False, message, seconds)`` if it raised.

    The message is one line naming the item: a ReflectoError's own, anything else as
    an internal error with its type (no exception object crosses the process boundary).
    """
    t0 = time.perf_counter()
    try:
        return True, fn(*args), time.perf_counter() - t0
    except ReflectoError as e:
        msg = one_line(e)
    except MemoryError:
        msg = f"{label}: out of memory"
    except Exception as e:  # noqa: BLE001 — one item's bug must not end the batch
        msg = f"{label}: internal error ({type(e).__name__}: {one_line(e, 300)})"
    return False, msg, time.perf_counter() - t0


def run_batch(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], jobs: int,
              on_result: Callable[[int, bool, Any, float], None], scheduler: str | None = None,
              ignore_interrupt: bool = False) -> None:
    """Run ``fn(*items[k])`` for every ``k``, in ``jobs`` worker processes (1: in this one),
    or on the Dask cluster whose scheduler listens at ``scheduler`` (:func:`run_on_dask`).

    ``on_result(k, ok, value_or_message, seconds)`` is called in this process as each
    item ends, in completion order; a failed item never stops the others. Workers
    die with this process (:func:`_watch_parent`). If a worker process itself dies
    (a signal, the out-of-memory killer), the pool is lost: every item that had not
    finished is run again, each in a process of its own, so that only the item that
    kills its process is reported failed ("worker process died").

    Parameters
    ----------
    fn
        The work of one item (picklable for ``jobs > 1`` or a scheduler).
    items
        Argument tuples, one per item.
    labels
        One name per item, for messages.
    jobs
        Worker processes.
    on_result
        ``on_result(k, ok, value_or_message, seconds)``.
    scheduler
        A Dask scheduler's address, to run there instead.
    ignore_interrupt
        The worker processes ignore SIGINT and SIGTERM (:func:`_watch_parent`): a Ctrl-C
        stops this process, which cancels the items not started and waits for the running
        ones to end, with SIGINT and SIGTERM held meanwhile (a second Ctrl-C is taken once
        the workers are gone: it cannot leave them running).
    """
    if scheduler:
        run_on_dask(fn, items, labels, scheduler, on_result)
        return
    if jobs <= 1 or len(items) <= 1:
        for k, args in enumerate(items):
            on_result(k, *_guarded(fn, args, labels[k]))
        return
    unfinished: list[int] = []
    ex = ProcessPoolExecutor(max_workers=min(jobs, len(items)), initializer=_watch_parent,
                             initargs=(os.getpid(), ignore_interrupt))
    try:
        futs = {ex.submit(_guarded, fn, args, labels[k]): k for k, args in enumerate(items)}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                try:
                    res = f.result()
                except BrokenProcessPool:
                    unfinished.append(futs[f])
                    continue
                on_result(futs[f], *res)
    except BaseException:
        _shut_down(ex, ignore_interrupt, cancel=True)
        raise
    _shut_down(ex, ignore_interrupt)
    _run_isolated(fn, items, labels, sorted(unfinished), jobs, on_result, ignore_interrupt)


def _shut_down(ex: ProcessPoolExecutor, hold_signals: bool, cancel: bool = False) -> None:
    """End a pool once its running items have ended (``cancel``: the queued ones dropped);
    with ``hold_signals`` SIGINT and SIGTERM wait meanwhile (workers that ignore them
    would otherwise outlive an interrupted wait)."""
    held = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held) if hold_signals else None
    try:
        ex.shutdown(wait=True, cancel_futures=cancel)
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


#: How long (s) to try to reach a Dask scheduler before giving up.
DASK_CONNECT_TIMEOUT_S = 30.0


def run_on_dask(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], scheduler: str,
                on_result: Callable[[int, bool, Any, float], None]) -> None:
    """Run ``fn(*items[k])`` on a Dask cluster (``dask.distributed``, the ``dask`` extra).

    ``scheduler`` is the scheduler's address (``tcp://host:8786``). Each item is one
    task, wrapped as locally (:func:`_guarded`), so a failed item arrives as its message;
    ``on_result`` runs in this process as tasks end. The items write their results
    themselves (atomically, to a folder every worker must see under the same path),
    and every seed derives from the item, so the results equal a local run's. A worker
    that dies is the scheduler's to handle: it reruns the task elsewhere, and a task
    that kills workers repeatedly ends as failed ("worker process died"). Tasks are
    submitted with ``pure=False`` (a rerun of the batch recomputes what its records lack).

    Parameters
    ----------
    fn
        The work of one item (picklable).
    items
        Argument tuples, one per item.
    labels
        One name per item, for messages and task keys.
    scheduler
        The scheduler's address.
    on_result
        ``on_result(k, ok, value_or_message, seconds)``.

    Raises
    ------
    ReflectoError
        Without ``dask.distributed``, or when the scheduler cannot be reached.
    """
    try:
        import distributed  # deferred: the optional `dask` extra, needed only with --scheduler
    except ImportError:
        raise ReflectoError("--scheduler needs dask.distributed: pip install 'reflecto[dask]'") from None
    check_scheduler_address(scheduler)
    if not items:
        return
    try:
        client = distributed.Client(scheduler, timeout=DASK_CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise ReflectoError(f"{scheduler}: cannot reach the Dask scheduler ({one_line(e)})") from None
    # keys named for the dashboard and unique to this call: two batches on one cluster with the same
    # positions and labels (sweeps of one material on two devices) shared a key, and Dask gave one
    # batch the other's result
    call = uuid.uuid4().hex[:12]
    try:
        futs = {client.submit(_guarded, fn, args, labels[k], pure=False, key=f"reflecto-{call}-{k}-{labels[k]}"): k
                for k, args in enumerate(items)}
        for f in distributed.as_completed(list(futs), loop=client.loop):
            k = futs[f]
            try:
                res = f.result()
            except (distributed.scheduler.KilledWorker, distributed.client.FutureCancelledError):
                res = (False, f"{labels[k]}: worker process died (killed by a signal, or out of memory)", 0.0)
            on_result(k, *res)
    finally:
        client.close()


def check_scheduler_address(scheduler: str) -> None:
    """Refuse a Dask scheduler address that is not ``[scheme://]host:port`` of a transport
    ``distributed`` has, before any work: ``distributed.Client`` raises on a malformed one after
    starting its background loop, which then keeps the process from exiting.

    Parameters
    ----------
    scheduler
        The address, e.g. ``tcp://10.0.0.5:8786``.

    Raises
    ------
    ReflectoError
        A malformed address, or ``dask.distributed`` missing.
    """
    try:
        from distributed.comm.addressing import parse_address, parse_host_port  # deferred: the optional extra
        from distributed.comm.registry import backends  # deferred: the optional extra
    except ImportError:
        raise ReflectoError("--scheduler needs dask.distributed: pip install 'reflecto[dask]'") from None
    try:
        scheme, location = parse_address(scheduler)
        if scheme not in backends:
            raise ValueError(f"unknown scheme {scheme!r} (one of {', '.join(sorted(backends))})")
        if scheme != "inproc":
            parse_host_port(location)
    except ValueError as e:
        raise ReflectoError(f"--scheduler {scheduler}: not a scheduler address, [scheme://]host:port ({one_line(e)})"
                            ) from None


def _run_isolated(fn: Callable[..., Any], items: Sequence[tuple[Any, ...]], labels: Sequence[str], which: list[int],
                  jobs: int, on_result: Callable[[int, bool, Any, float], None],
                  ignore_interrupt: bool = False) -> None:
    """Run the items ``which`` each in a worker process of its own, ``jobs`` at a time."""
    queue = list(which)
    active: dict[Any, tuple[int, ProcessPoolExecutor, float]] = {}
    while queue or active:
        while queue and len(active) < jobs:
            k = queue.pop(0)
            ex = ProcessPoolExecutor(max_workers=1, initializer=_watch_parent, initargs=(os.getpid(), ignore_interrupt))
            active[ex.submit(_guarded, fn, items[k], labels[k])] = (k, ex, time.perf_counter())
        done, _ = wait(set(active), return_when=FIRST_COMPLETED)
        for f in done:
            k, ex, t0 = active.pop(f)
            try:
                res = f.result()
            except BrokenProcessPool:
                res = (False, f"{labels[k]}: worker process died (killed by a signal, or out of memory)",
                       time.perf_counter() - t0)
            ex.shutdown(wait=False)
            on_result(k, *res)
