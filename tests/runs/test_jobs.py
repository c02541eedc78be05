"""The one job runner (``runs.jobs``): grouping by known config, progress in episodes, failures."""

from __future__ import annotations

import re

import pytest

from kinadapt_nn.runs.jobs import Job, Runner, Task, group_tasks, known_key

TOOLS = [f"tool.offset_f_m=[0.00{i}, 0.0, 0.1]" for i in range(1, 6)]


def _job(i: int, *over: str) -> Job:
    return Job(id=f"j{i}", overrides=(TOOLS[i % len(TOOLS)], f"run.seed={i}", *over))


def test_jobs_that_differ_only_in_the_hidden_truth_share_a_task():
    """Tools, arm errors and seeds are per episode; insertions of one tool are prefixes of one
    cell; a known setting (features, gains) starts another task. Cells are dealt round-robin,
    at most max_cells per task, at least min_tasks where there are that many."""
    jobs = [_job(i) for i in range(5)]
    jobs += [Job(id="arm", overrides=(TOOLS[0], "arm.joint_offset_rad=[0.001,0,0,0,0,0,0]"))]
    jobs += [Job(id="x2", overrides=(TOOLS[0], "run.seed=0", "run.insertions=2"))]  # j0's run, twice as long
    jobs += [Job(id="rbf", overrides=(TOOLS[0], "run.features=rbf"))]
    assert len({known_key(j.config()) for j in jobs}) == 2
    tasks = group_tasks(jobs, max_cells=4)
    ids = [[j.id for j in t.jobs] for t in tasks]
    assert ids == [["j0", "x2", "j2", "j4"], ["j1", "j3", "arm"], ["rbf"]]  # 6 cells -> 2 tasks, round-robin
    assert [t.cells for t in tasks] == [((0, 1), (2,), (3,)), ((0,), (1,), (2,)), ((0,),)]
    assert [t.episodes for t in tasks] == [4, 3, 1]  # j0's cell simulates its longest run: 2 insertions
    assert [len(t.jobs) for t in group_tasks(jobs, max_cells=8, min_tasks=3)] == [3, 2, 2, 1]
    assert all(len(t.cells) == 1 for t in group_tasks(jobs, max_cells=1))


def _square(x: int) -> int:
    return x * x


def _reporting(task: Task, report) -> list:
    out = []
    for x in task.jobs:
        out.append(-x)
        report(1)
    return out


def _failing(task: Task, report) -> list:
    if task.jobs[0].id == "bad":
        raise ValueError("no such bore")
    return [0] * len(task.jobs)


def test_runner_returns_results_in_task_order_and_counts_episodes(capsys):
    """map and run: results in the tasks' order whatever order they end in; the bar ends at the
    episodes simulated, the earlier runs' included."""
    with Runner(2, progress=True) as r:
        assert r.map(_square, list(range(7))) == [x * x for x in range(7)]
        tasks = [Task(jobs=(1, 2, 3), episodes=3, cost=1.0), Task(jobs=(4,), episodes=1, cost=5.0)]
        seen = []
        out = r.run(_reporting, tasks, "demo", on_done=lambda t, res: seen.append(res), done_before=2)
    assert out == [[-1, -2, -3], [-4]] and sorted(seen) == [[-4], [-1, -2, -3]]
    err = capsys.readouterr().err
    assert re.search(r"demo: 100%.*\b6\.0/6 episodes\b", err), err  # 2 before + 4 simulated, each counted once


def test_a_failing_task_is_raised_naming_its_job():
    tasks = [Task(jobs=(Job(id="good", overrides=()),)), Task(jobs=(Job(id="bad", overrides=()),))]
    with pytest.raises(ValueError, match="no such bore") as info, Runner(1) as r:
        r.run(_failing, tasks, "demo")
    assert any("'bad'" in n for n in info.value.__notes__)


def test_bad_executor_and_address_are_one_line_errors():
    from kinadapt_nn.errors import KinadaptError

    with pytest.raises(KinadaptError, match="choose one of local, ray"):
        Runner(1, executor="dask")
    with pytest.raises(KinadaptError, match="--executor ray"):
        Runner(1, address="10.0.0.1:6379")


@pytest.mark.slow
def test_a_local_ray_is_the_runners_own_and_stops_with_it():
    """Without an address the runner starts a Ray of its own (never joins one already running)
    and shuts it down: its processes -- children of this one -- end with the runner."""
    ray = pytest.importorskip("ray")
    psutil = pytest.importorskip("psutil")
    with Runner(2, executor="ray") as r:
        assert ray.is_initialized() and len(ray.nodes()) == 1
        assert ray.cluster_resources()["CPU"] == 2
        own = [p for p in psutil.Process().children(recursive=True) if p.name() in ("raylet", "gcs_server")]
        assert {p.name() for p in own} == {"raylet", "gcs_server"}
        assert r.map(_square, [3, 4]) == [9, 16]
    assert not ray.is_initialized()
    gone, alive = psutil.wait_procs(own, timeout=30)
    assert not alive


def test_the_bar_says_what_it_waits_for_at_once_and_times_the_work_only(capsys):
    """``WorkBar``: the waiting line comes before any work (the workers' start-up is no part of the
    bar's clock: the bar starts at the first credited work), and the remaining time shows only
    once ETA_AFTER of the work is done -- never a rate from the first sliver of an episode."""
    from kinadapt_nn.runs.jobs import ETA_AFTER, WorkBar

    bar = WorkBar("demo", 100, 0, "episode", "starting 2 worker processes")
    first = capsys.readouterr().err
    assert first == "demo: starting 2 worker processes ...\n" and bar.bar is None  # no bar, no clock yet
    bar.update(0.001)
    assert bar.bar is not None and "<" not in bar.bar.bar_format
    bar.update(100 * ETA_AFTER)
    assert "<{remaining}" in bar.bar.bar_format
    bar.close()
    err = capsys.readouterr().err
    assert "100.0/100" not in err and re.search(r"demo:\s+\d+%.*5\.0/100 episodes \[\d\d:\d\d<", err), err


def test_a_run_prints_its_waiting_line_before_its_bar(capsys):
    with Runner(1, progress=True) as r:
        r.run(_reporting, [Task(jobs=(1, 2), episodes=2)], "demo")
    err = capsys.readouterr().err
    assert err.index("demo: starting 1 worker process ...") < err.index("demo:  ")
