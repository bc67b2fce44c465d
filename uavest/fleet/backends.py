"""Where tasks run: in-process (serial), a local process pool, or a Dask cluster.

Every backend calls ``done(task, outcome)`` in the driver once per task, as tasks finish,
with ``outcome`` one of

- ``{"status": "ok", "value": <run_task output>, "attempts": n}``
- ``{"status": "failed", "failure": "error", "reason": "...", "attempts": n}``: the task
  raised (a corrupt or unreadable log, a bad scenario); deterministic, not retried;
- ``{"status": "failed", "failure": "worker-died", "reason": "worker died (signal 9)",
  "attempts": 2}``: its worker process died twice (retried once).

Process pool: at most ``workers`` tasks are in flight, so when a worker dies the tasks
that were running are the only suspects (``concurrent.futures`` breaks the whole pool and
fails every pending future). The pool is rebuilt and each suspect is re-run *alone*: an
innocent neighbour then finishes, and a task whose worker dies again alone is the one
that kills it. Dask: the scheduler reschedules a task whose worker died, up to its
``distributed.scheduler.allowed-failures`` (default 3; a LocalCluster started here uses
1 = retry once), then reports ``KilledWorker``; since a task merely queued on the dying
worker is counted too, every KilledWorker task is run once more alone after the others,
and only one that kills its worker again then is reported as failed.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from collections import deque
from collections.abc import Callable

from ..errors import InputError
from .worker import BLAS_ENV, Task, init_worker, run_task, worker_env

__all__ = ["DaskBackend", "PoolBackend", "SerialBackend", "make_backend", "reason_of"]

Done = Callable[[Task, dict], None]

#: Modules a forkserver imports before forking workers (a missing one is skipped): the
#: MAVLink dialects alone take ~0.6 s to import on an idle core, which a fresh worker
#: would pay again on its first log.
PRELOAD = ["uavest.fleet.worker", "uavest.apps.replay", "uavest.ingest",
           "uavest.experiments.montecarlo", "uavest.experiments.systems",
           "pymavlink.mavutil", "pymavlink.DFReader", "pymavlink.dialects.v10.all",
           "pymavlink.dialects.v20.all", "pymavlink.dialects.v20.ardupilotmega", "pyulog"]


def reason_of(e: BaseException) -> str:
    """One line saying why a task failed (input errors as their message)."""
    msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
    if isinstance(e, InputError | OSError) and msg:
        text = msg
    else:
        text = f"{type(e).__name__}: {msg}" if msg else type(e).__name__
    return text if len(text) <= 300 else text[:300] + "..."


def _ok(value: dict, attempts: int = 1) -> dict:
    return {"status": "ok", "value": value, "attempts": attempts}


def _error(e: BaseException, attempts: int = 1) -> dict:
    return {"status": "failed", "failure": "error", "reason": reason_of(e), "attempts": attempts}


def _died(reason: str, attempts: int) -> dict:
    return {"status": "failed", "failure": "worker-died", "reason": reason, "attempts": attempts}


class SerialBackend:
    """In the driver's process, one task after the other (``--workers 0``)."""

    name = "serial"
    workers = 0

    def run(self, tasks: list[Task], done: Done) -> None:
        for t in tasks:
            try:
                value = run_task(t)
            except Exception as e:  # noqa: BLE001 - a bad input fails alone
                done(t, _error(e))
            else:
                done(t, _ok(value))

    def describe(self) -> str:
        return "serial (in-process)"

    def close(self) -> None:
        pass


def _signal_text(code: int | None) -> str:
    if code is None:
        return "worker died"
    if code < 0:
        try:
            return f"worker died (signal {-code}, {signal.Signals(-code).name})"
        except ValueError:
            return f"worker died (signal {-code})"
    return f"worker died (exit code {code})"


class PoolBackend:
    """A local ``ProcessPoolExecutor`` of ``workers`` processes (forkserver where the
    platform has it, else spawn: no inherited threads or locks), BLAS pinned to one
    thread in each (environment set before the workers start, so before numpy loads)."""

    name = "pool"

    def __init__(self, workers: int, context: str | None = None, max_attempts: int = 2):
        if workers < 1:
            raise InputError(f"--workers must be >= 1 for a process pool, got {workers}")
        self.workers = workers
        methods = mp.get_all_start_methods()
        self.context = context or ("forkserver" if "forkserver" in methods else "spawn")
        self.max_attempts = max_attempts
        self._ex = None
        self._procs: dict = {}

    def describe(self) -> str:
        return f"process pool, {self.workers} worker(s) ({self.context})"

    def _new(self):
        from concurrent.futures import ProcessPoolExecutor

        for k, v in BLAS_ENV.items():
            os.environ.setdefault(k, v)
        self._procs = {}
        ctx = mp.get_context(self.context)
        if self.context == "forkserver":
            # the server imports numpy, the estimators and the log readers once; each
            # worker is then a cheap fork of it (the server starts with the BLAS env set
            # above; a server already running keeps what it has)
            ctx.set_forkserver_preload(PRELOAD)
        self._ex = ProcessPoolExecutor(self.workers, mp_context=ctx,
                                       initializer=init_worker, initargs=(worker_env(),))
        return self._ex

    def _submit(self, t: Task):
        f = self._ex.submit(run_task, t)
        self._procs.update(getattr(self._ex, "_processes", None) or {})
        return f

    def _death_reason(self) -> str:
        """From the exit codes of the pool's processes: the one that did not get the
        pool's own SIGTERM (sent to the survivors of a broken pool)."""
        codes = []
        for p in list(self._procs.values()):
            try:
                p.join(timeout=2)
            except Exception:  # noqa: BLE001
                pass
            codes.append(p.exitcode)
        died = [c for c in codes if c not in (None, 0, -signal.SIGTERM)]
        if died:
            # a worker killed by a signal is the cause; a survivor of the broken pool may
            # exit with an error code of its own while it is torn down
            return _signal_text(min(died, key=lambda c: c >= 0))
        if -signal.SIGTERM in codes:
            return _signal_text(-signal.SIGTERM)
        return "worker died"

    def run(self, tasks: list[Task], done: Done) -> None:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        queue = deque(tasks)
        suspects: deque[Task] = deque()
        attempts: dict[str, int] = {}
        inflight: dict = {}
        dead: list[Task] = []

        def settle(f, t: Task) -> None:
            """A finished future's result (or error) to ``done``; a dead worker's task to
            ``dead``."""
            n = attempts.get(t.key, 0) + 1
            try:
                value = f.result()
            except BrokenProcessPool:
                dead.append(t)
            except Exception as e:  # noqa: BLE001
                done(t, _error(e, n))
            else:
                done(t, _ok(value, n))

        self._new()
        try:
            while queue or suspects or inflight:
                dead.clear()
                broken = False
                try:
                    if suspects:  # isolation: a suspect runs with nothing beside it
                        if not inflight:
                            t = suspects.popleft()
                            inflight[self._submit(t)] = t
                    else:
                        while queue and len(inflight) < self.workers:
                            t = queue.popleft()
                            inflight[self._submit(t)] = t
                except BrokenProcessPool:  # a worker died since the last wait
                    (suspects if attempts.get(t.key) else queue).appendleft(t)
                    broken = True
                if not broken:
                    finished, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
                    for f in finished:
                        settle(f, inflight.pop(f))
                    broken = bool(dead)
                if not broken:
                    continue
                # the pool is broken: every other future fails too; collect them
                wait(list(inflight))
                for f, t in list(inflight.items()):
                    settle(f, t)
                inflight.clear()
                # the executor's manager thread reaps the broken pool's processes: read
                # their exit codes only after it has finished (a forkserver child's status
                # is read once from a pipe; two threads polling it race, and the loser
                # sees exit code 255)
                self._ex.shutdown(wait=True, cancel_futures=True)
                reason = self._death_reason() if len(dead) == 1 else "worker died"
                self._new()
                for t in dead:
                    attempts[t.key] = attempts.get(t.key, 0) + 1
                    if attempts[t.key] >= self.max_attempts:
                        done(t, _died(reason, attempts[t.key]))
                    else:
                        suspects.append(t)
        except BaseException:
            self._abort()
            raise
        finally:
            self.close()

    def _abort(self) -> None:
        """Ctrl-C: drop queued work and stop the workers this pool started."""
        if self._ex is None:
            return
        procs = list(self._procs.values())
        self._ex.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)
        self._ex = None

    def close(self) -> None:
        if self._ex is not None:
            self._ex.shutdown(wait=True)
            self._ex = None


class DaskBackend:
    """A Dask distributed client: an existing cluster (``--scheduler tcp://...``) or a
    LocalCluster started here (``--scheduler local``). Log bytes travel with the task
    (``ship=True``, workers need not see the driver's files); ``ship=False`` sends paths
    (a filesystem shared by every worker)."""

    name = "dask"

    def __init__(self, client, ship: bool = True, cluster=None) -> None:
        self.client = client
        self.cluster = cluster
        self.ship = ship
        self.workers = max(1, sum(client.nthreads().values()))

    @classmethod
    def connect(cls, address: str, workers: int | None = None, ship: bool = True,
                dashboard: str | None = ":0") -> DaskBackend:
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError:
            raise InputError("--scheduler needs Dask: pip install 'uavest[dask]'") from None
        if address == "local":
            # retry a task whose worker died once (the default allows 3 more attempts),
            # and give a worker only as many tasks as it has threads, so that when it
            # dies only the task it was running is a suspect (default saturation 1.1)
            dask.config.set({"distributed.scheduler.allowed-failures": 1,
                             "distributed.scheduler.worker-saturation": 1.0})
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1,
                                   threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address=dashboard)
            return cls(Client(cluster), ship=ship, cluster=cluster)
        try:
            client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as e:
            raise InputError(f"cannot reach the Dask scheduler at {address}: {e}") from None
        return cls(client, ship=ship)

    def dashboard(self) -> str | None:
        try:
            return self.client.dashboard_link
        except Exception:  # noqa: BLE001
            return None

    def describe(self) -> str:
        return (f"dask {self.client.scheduler.address}, {len(self.client.nthreads())} "
                f"worker(s), {self.workers} thread(s)")

    def _prepare(self, t: Task) -> Task:
        if t.kind == "log" and self.ship and t.data is None:
            with open(t.path, "rb") as f:
                return t.shipped(f.read())
        return t

    def run(self, tasks: list[Task], done: Done) -> None:
        import uuid

        from distributed import as_completed

        try:
            from distributed.scheduler import KilledWorker
        except ImportError:  # pragma: no cover - older layouts
            from distributed import KilledWorker

        queue = deque(tasks)
        fmap: dict = {}
        window = max(4, 2 * self.workers)  # bounds the bytes in flight when shipping logs

        def submit(t: Task):
            key = f"uavest-evaluate-{t.key}-{uuid.uuid4().hex[:8]}"
            f = self.client.submit(run_task, self._prepare(t), key=key, pure=False)
            fmap[f] = t
            return f

        first = [submit(queue.popleft()) for _ in range(min(window, len(queue)))]
        ac = as_completed(first)
        killed: list[Task] = []
        try:
            for f in ac:
                t = fmap.pop(f)
                try:
                    value = f.result()
                except KilledWorker:
                    # a task queued on a worker that died counts as a suspect too: run
                    # each such task once more alone, after the others (as the pool does)
                    killed.append(t)
                except Exception as e:  # noqa: BLE001
                    done(t, _error(e))
                else:
                    done(t, _ok(value))
                f.release()
                if queue:
                    ac.add(submit(queue.popleft()))
            for t in killed:
                f = submit(t)
                try:
                    value = f.result()
                except KilledWorker as e:
                    done(t, _died(f"worker died ({_killed_text(e)})", None))
                except Exception as e:  # noqa: BLE001
                    done(t, _error(e))
                else:
                    done(t, _ok(value))
                fmap.pop(f, None)
                f.release()
        except BaseException:
            self.client.cancel(list(fmap))
            raise

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()


def _killed_text(e: BaseException) -> str:
    s = str(e)
    import re

    m = re.search(r"on (\d+) different workers", s)
    if m:
        return f"on {m.group(1)} attempts, Dask KilledWorker"
    return "Dask KilledWorker"


def make_backend(workers: int | None, scheduler: str | None = None, ship: bool = True):
    """``--workers 0`` serial; ``--scheduler ADDR`` Dask (``local``: a LocalCluster of
    ``workers`` processes); else a process pool of ``workers`` (default: CPU count)."""
    if scheduler:
        return DaskBackend.connect(scheduler, workers, ship=ship)
    if workers == 0:
        return SerialBackend()
    return PoolBackend(workers if workers is not None else (os.cpu_count() or 1))
