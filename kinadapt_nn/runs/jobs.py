"""One job runner for ``kinadapt compare``, ``sweep`` and ``reproduce``.

A :class:`Job` is one run: a name and the online config overrides that make it (a command's
subclass adds its labels). Jobs that share every *known* setting -- they differ only in the hidden
truth (tool, arm errors, seed) or in ``run.insertions`` -- are grouped into a :class:`Task` by
:func:`group_tasks`: one worker steps them together (``runs.insertions.run_cells`` on
``runs.batch.run_episodes``; each job's results are what it gives alone, to the last bit but the
wall times), and jobs that differ only in ``run.insertions`` are simulated once, the longest
(a run of n insertions holds every shorter one as its prefix).

:class:`Runner` runs tasks on a local pool of worker processes or on Ray, in one place for the
three commands: the kernels compiled once before the workers start (with one line saying so), the
longest tasks first, one progress bar that counts *episodes simulated* (one insertion of one tool;
a worker reports each insertion as it ends, so the bar moves while a batch runs), and a failure
cancels the tasks not yet started and is raised naming the task's first job.

Ray: without an address the runner starts a Ray of its own on this machine (``address="local"``:
never one already running), with ``workers`` CPUs, no dashboard and its node address asked to be
127.0.0.1, and shuts it down at the end (its processes end with it; no other Ray on the machine is
touched); with ``address`` it connects to that cluster and only disconnects. Ray 2.60 rewrites a
127.0.0.1 node address to the machine's primary address and its GCS and raylet listen on every
interface whatever the node address (measured with ``ss -ltn``); its token authentication, on by
default there, is what keeps other machines out.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from kinadapt_nn.errors import KinadaptError

EXECUTORS = ("local", "ray")

#: config fields that may differ between the jobs of one task: the hidden truth a batch steps per
#: episode (``runs.batch``), and ``run.insertions`` (prefixes, simulated once)
PER_EPISODE = {"tool": ("offset_f_m",), "arm": ("link_length_error_m", "joint_offset_rad"),
               "run": ("seed", "insertions")}


@dataclass(frozen=True)
class Job:
    """One run of a command."""

    id: str  #: unique among a command's jobs (a file name, a TensorBoard run, a row key)
    overrides: tuple[str, ...]  #: online config keys, ``load_config(None, overrides)``

    def config(self):
        """The job's online config (``run.progress`` off: the runner shows the progress)."""
        from kinadapt_nn.config import load_config

        return load_config(None, ["run.progress=false", *self.overrides])


@dataclass(frozen=True)
class Task:
    """What one worker runs in one call: jobs that share every known setting (or one item of
    :meth:`Runner.map`)."""

    jobs: tuple  #: the task's jobs (``Job``; any picklable item for ``Runner.map``)
    episodes: int = 1  #: episodes it simulates (the progress bar's unit)
    cost: float = 1.0  #: expected relative cost (the longest tasks start first)
    cells: tuple[tuple[int, ...], ...] = field(default=())  #: positions in ``jobs`` per tool (prefix group)


def known_key(cfg) -> str:
    """``cfg`` with the per-episode fields (:data:`PER_EPISODE`) reset: equal for configs a batch
    can step together. -> JSON text."""
    return _reset(cfg, PER_EPISODE).model_dump_json()


def cell_key(cfg) -> str:
    """``cfg`` with ``run.insertions`` reset: equal for runs that are prefixes of one another."""
    return _reset(cfg, {"run": ("insertions",)}).model_dump_json()


def _reset(cfg, fields: dict[str, tuple[str, ...]]):
    """``cfg`` with ``fields`` ({section: names}) set to a blank default (each section's own)."""
    update = {}
    for sec, names in fields.items():
        part = getattr(cfg, sec)
        blank = type(part)()
        update[sec] = part.model_copy(update={n: getattr(blank, n) for n in names})
    return cfg.model_copy(update=update)


def group_tasks(jobs: Sequence[Job], max_cells: int, min_tasks: int = 1,
                cost: Callable[[Job], float] | None = None) -> list[Task]:
    """``jobs`` grouped into tasks: the jobs of one task share every known setting
    (:func:`known_key`), those that differ only in ``run.insertions`` form one cell (simulated once,
    its longest), and a known config's cells are dealt round-robin into
    ``max(ceil(cells / max_cells), min(min_tasks, cells))`` tasks (at most ``max_cells`` cells each;
    at least ``min_tasks`` where there are that many cells, so every worker has work). ``cost(job)``:
    a job's expected cost (default 1); a task's is the sum over its cells of the longest job's.
    Order: first appearance."""
    cfgs = [j.config() for j in jobs]
    known: dict[str, dict[str, list[int]]] = {}
    for i, c in enumerate(cfgs):
        known.setdefault(known_key(c), {}).setdefault(cell_key(c), []).append(i)
    tasks = []
    for cells in known.values():
        cells = list(cells.values())
        k = max(math.ceil(len(cells) / max_cells), min(min_tasks, len(cells)))
        for part in (cells[i::k] for i in range(k)):
            tasks.append(_task(jobs, cfgs, part, cost))
    return tasks


def _task(jobs: Sequence[Job], cfgs: list, cells: list[list[int]], cost) -> Task:
    """One task of the cells ``cells`` (job indices)."""
    order = [i for c in cells for i in c]
    pos = {i: p for p, i in enumerate(order)}
    longest = [max(cfgs[i].run.insertions for i in c) for c in cells]
    job_cost = cost or (lambda _j: 1.0)
    return Task(jobs=tuple(jobs[i] for i in order), episodes=sum(longest),
                cost=sum(max(job_cost(jobs[i]) for i in c) for c in cells),
                cells=tuple(tuple(pos[i] for i in c) for c in cells))


def run_task_cells(task: Task, report: Callable[[int], None]) -> list:
    """The default worker: each cell of ``task`` simulated once (its longest run), the cells'
    insertion i stepped as one batch (``runs.insertions.run_cells``); ``report(n)`` after each
    insertion (n episodes). -> per job, in the task's order, (config, ``EpisodeResult``)."""
    from kinadapt_nn.runs.insertions import run_cells

    cfgs = [j.config() for j in task.jobs]
    longest = [max((cfgs[p] for p in ps), key=lambda c: c.run.insertions) for ps in task.cells]
    runs = run_cells(longest, [c.run.insertions for c in cfgs], on_insertion=report)
    out: list = [None] * len(cfgs)
    for ps, run in zip(task.cells, runs):
        for p in ps:
            out[p] = (cfgs[p], run[cfgs[p].run.insertions])
    return out


def _each(fn: Callable, task: Task, report: Callable[[int], None]) -> list:
    """``fn`` of every item of a :meth:`Runner.map` task, reported one by one."""
    out = []
    for x in task.jobs:
        out.append(fn(x))
        report(1)
    return out


_QUEUE: list = [None]  # a local worker's progress queue (set by _init_worker)


def _init_worker(queue, setup: Callable[[], None] | None = None) -> None:
    _QUEUE[0] = queue
    if setup is not None:
        setup()


def _local_call(fn: Callable, index: int, task: Task) -> list:
    """A local worker's call: ``fn(task, report)``, each report sent to the parent's bar."""
    queue = _QUEUE[0]
    return fn(task, lambda n: queue.put((index, n)))


def _ray_call(fn: Callable, task: Task, setup: Callable[[], None] | None = None) -> list:
    """A Ray worker's call: ``setup()`` (if given), then ``fn(task, report)``; the bar moves when the task ends."""
    if setup is not None:
        setup()
    return fn(task, lambda n: None)


class Runner:
    """Tasks on ``workers`` local processes (``executor="local"``) or on Ray (``"ray"``; module
    docstring). A context manager: the pool (or Ray) lives until the ``with`` block ends.
    ``progress``: one bar per :meth:`run`, lines on stderr. ``setup``: a module-level callable each
    worker calls before its first task (what a worker process needs that this one has set up: the live
    monitor's registration with the episode loop, ``kinadapt compare --monitor``)."""

    def __init__(self, workers: int, executor: str = "local", address: str | None = None,
                 progress: bool = False, setup: Callable[[], None] | None = None) -> None:
        if executor not in EXECUTORS:
            raise KinadaptError(f"executor {executor!r}: choose one of {', '.join(EXECUTORS)}")
        if address and executor != "ray":
            raise KinadaptError("--address is a Ray cluster's address: pass it with --executor ray")
        self.workers, self.executor, self.address, self.progress = workers, executor, address, progress
        self.setup = setup
        self._pool = self._queue = self._ray = None

    def __enter__(self) -> Runner:
        if self.executor == "ray":
            self._ray = _start_ray(self.address, self.workers)
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            ctx = mp.get_context()
            self._queue = ctx.Queue()
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=_init_worker,
                                             initargs=(self._queue, self.setup))
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        if self._ray is not None:
            self._ray.shutdown()  # a Ray this runner started stops; a cluster it joined is only left

    def precompile(self, cfgs: Iterable) -> None:
        """The kernels of every features type and law among ``cfgs``, compiled here before the
        local workers start (they then load them from numba's cache instead of each compiling
        them), with one line saying so when the cache is cold. Ray workers compile their own."""
        if self.executor != "local":
            return
        from kinadapt_nn.runs.episode import precompile

        cfgs = list(cfgs)
        if self.progress:
            kinds = _uncached_kinds(cfgs)
            if kinds:
                print(f"compiling the controller's kernels for {', '.join(kinds)} first (once on this machine; "
                      "cached for later runs) ...", file=sys.stderr, flush=True)
        precompile(cfgs, self.progress)

    def run(self, fn: Callable, tasks: Sequence[Task], desc: str, on_done: Callable | None = None,
            meanwhile: Callable[[], Any] | None = None, done_before: int = 0, unit: str = "episode") -> list:
        """``fn(task, report) -> list`` (a module-level function) for every task, the costliest
        first; ``on_done(task, results)`` in this process as each task ends; ``meanwhile()`` once
        the tasks are submitted. ``done_before``: episodes finished in an earlier run (the bar
        starts there); ``unit``: the bar's unit (a task's ``episodes`` of it). -> the results per
        task, in ``tasks``' order."""
        order = sorted(range(len(tasks)), key=lambda i: -tasks[i].cost)
        bar = self._bar(desc, sum(t.episodes for t in tasks) + done_before, done_before, unit)
        results: list = [None] * len(tasks)
        try:
            for i, res in self._completions(fn, tasks, order, bar, meanwhile):
                results[i] = res
                if on_done is not None:
                    on_done(tasks[i], res)
        finally:
            if bar is not None:
                bar.close()
        return results

    def map(self, fn: Callable, items: Sequence, desc: str = "runs") -> list:
        """``[fn(x) for x in items]`` on the workers (``fn`` module-level), one task per item, in order."""
        from functools import partial

        out = self.run(partial(_each, fn), [Task(jobs=(x,)) for x in items], desc, unit="run")
        return [r[0] for r in out]

    def _bar(self, desc: str, total: int, initial: int, unit: str) -> WorkBar | None:
        if not self.progress:
            return None
        waiting = (f"starting {self.workers} worker process{'es' if self.workers != 1 else ''}"
                   if self.executor == "local" else "waiting for Ray's workers")
        return WorkBar(desc, total, initial, unit, waiting)

    def _completions(self, fn, tasks, order, bar, meanwhile):
        """(task index, results) as the tasks end; the bar credited with each reported episode."""
        if self.executor == "ray":
            yield from self._ray_completions(fn, tasks, order, bar, meanwhile)
            return
        from concurrent.futures import FIRST_COMPLETED, wait

        futs = {self._pool.submit(_local_call, fn, i, tasks[i]): i for i in order}
        if meanwhile is not None:
            meanwhile()
        credited = [0] * len(tasks)
        pending = set(futs)
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            self._drain(credited, bar)
            for f in done:
                i = futs[f]
                res = _result(f.result, tasks[i])
                _credit(bar, credited, i, tasks[i].episodes - credited[i])
                credited[i] = -1  # ended: later reports are ignored
                yield i, res

    def _drain(self, credited: list[int], bar) -> None:
        import queue

        while True:
            try:
                i, n = self._queue.get_nowait()
            except queue.Empty:
                return
            if credited[i] >= 0:
                _credit(bar, credited, i, n)

    def _ray_completions(self, fn, tasks, order, bar, meanwhile):
        ray = self._ray
        remote = ray.remote(_ray_call)
        refs = {remote.remote(fn, tasks[i], self.setup): i for i in order}
        if meanwhile is not None:
            meanwhile()
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            ref = ready[0]
            i = refs[ref]
            res = _result(lambda ref=ref: ray.get(ref), tasks[i])
            if bar is not None:
                bar.update(tasks[i].episodes)
            yield i, res


ETA_AFTER = 0.05  #: a bar shows its remaining time once this share of its work is done


class WorkBar:
    """The runner's progress bar (on stderr). A line at once says what the first work waits for
    (the workers import, build and load their kernels: 11 s of a ``compare`` on a 2-core machine);
    the tqdm bar starts when the first work is credited, so its clock and rate are the work's, and
    shows its remaining time once ``ETA_AFTER`` of the work is done (a rate from the first fraction
    of an episode, over the workers' start-up, read "297:07:56")."""

    def __init__(self, desc: str, total: float, initial: float, unit: str, waiting: str) -> None:
        self.desc, self.total, self.initial, self.unit = desc, total, initial, unit
        self.bar = None  # the tqdm bar, from the first credited work
        self.eta = False  # the remaining time shown
        print(f"{desc}: {waiting} ...", file=sys.stderr, flush=True)

    def _format(self) -> str:
        eta = "<{remaining}" if self.eta else ""
        if self.unit == "episode":  # episodes move in fractions as a batch steps (``run_cells``' reports)
            return "{l_bar}{bar}| {n:.1f}/{total} {unit}s [{elapsed}" + eta + "]"
        return "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}" + eta + ", {rate_fmt}]"

    def update(self, n: float) -> None:
        """``n`` more units done."""
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=self.total, initial=self.initial, desc=self.desc, unit=self.unit,
                            bar_format=self._format())
        if not self.eta and self.bar.n + n - self.initial >= ETA_AFTER * (self.total - self.initial):
            self.eta = True
            self.bar.bar_format = self._format()
        self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _credit(bar, credited: list[int], i: int, n: int) -> None:
    credited[i] += n
    if bar is not None and n:
        bar.update(n)


def _result(get: Callable[[], list], task: Task) -> list:
    """A task's results, or its error with a note naming its first job (the pool's remaining
    tasks are then cancelled by the runner's exit)."""
    try:
        return get()
    except Exception as exc:
        first = task.jobs[0]
        exc.add_note(f"(in the task of job {getattr(first, 'id', first)!r})")
        raise


def _uncached_kinds(cfgs: list) -> list[str]:
    """The distinct "features/law" of ``cfgs`` whose kernels numba's cache lacks (none when every
    one is cached, or when that cannot be told)."""
    from kinadapt_nn.controller import core
    from kinadapt_nn.runs.build import make_controller

    kinds = {}
    for c in cfgs:
        kinds.setdefault(f"{c.run.features}/{c.adaptation.mode}", c)
    out = []
    for name, c in kinds.items():
        k = make_controller(c)
        if not core.calls_cached(k.kernel_calls(), k.law_spec):
            out.append(name)
    return out


def _python_path() -> str:
    """PYTHONPATH with the folder that holds this process's kinadapt_nn first."""
    import os
    from pathlib import Path

    import kinadapt_nn

    root = str(Path(kinadapt_nn.__file__).resolve().parents[1])
    return os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH")])])


def _start_ray(address: str | None, workers: int):
    """Ray, started here (no ``address``: on 127.0.0.1 with ``workers`` CPUs, owned by this
    process) or joined (``address``). -> the ``ray`` module."""
    try:
        import ray
    except ImportError:
        raise KinadaptError("--executor ray needs the [ray] extra: pip install -e \".[ray]\"") from None
    try:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:  # "local": a new Ray of this process's own, never one already running on the machine;
            # its workers import the kinadapt_nn this process runs (a source checkout as well as an install)
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False,
                     _node_ip_address="127.0.0.1", runtime_env={"env_vars": {"PYTHONPATH": _python_path()}})
    except Exception as exc:  # ray raises ConnectionError and friends
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        hint = "check the address, or leave --address out to start a local Ray" if address else \
            "pass --address of a running cluster, or use --executor local"
        raise KinadaptError(f"cannot start or reach {where} ({str(exc).splitlines()[0]}); {hint}") from None
    return ray
