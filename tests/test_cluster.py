"""`voxshape experiment paper --cluster`: the runs as Ray tasks on a real Ray cluster (a head
and a worker node on the loopback, started once for the module and ended by pid), run for
run the same as the local pool's; a lost worker node's runs retried; `--resume` after an
interrupt running only the missing runs; and without a cluster or Ray, errors that say what
to do."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from voxshape.cli import main
from voxshape.lab.experiment import cluster, runner
from voxshape.lab.experiment.inprocess import RunSpec, run

VOXSHAPE = str(Path(sys.executable).parent / "voxshape")
# one worker of a parallel run takes the module: its Ray cluster and local runs are made once
pytestmark = pytest.mark.xdist_group("cluster")


def paper_args(out: Path, *extra: str, tasks: str = "1", seeds: int = 2, episodes: int = 3):
    return ["experiment", "paper", "--tasks", tasks, "--settings", "rl,rl+f", "--seeds",
            str(seeds), "--max-episodes", str(episodes), "--out", str(out), "--no-progress",
            *extra]  # fmt: skip


def runs_of(out: Path) -> list[dict]:
    return json.loads((out / "results.json").read_text())["runs"]


def lines_of(out: Path) -> list[str]:
    path = out / "runs.jsonl"
    return path.read_text().splitlines() if path.exists() else []


def failing_run(spec: RunSpec, reference: bool = False):
    """`run`, but seed 1 fails as a run that fails for good would (a bug, a bad map)."""
    if spec.seed == 1:
        raise ValueError("the learner diverged")
    return run(spec, reference)


def test_a_run_that_fails_for_good_is_named_and_the_experiment_exits_non_zero(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(runner, "run", failing_run)  # the pool's forked workers see it too
    out = tmp_path / "paper"
    assert main(paper_args(out, "--workers", "2", episodes=1)) == 1
    err = capsys.readouterr().err
    assert "2 run(s) failed, 2 finished" in err
    assert "task 1 rl seed 1: ValueError: the learner diverged" in err
    assert "task 1 rl+f seed 1: ValueError" in err and f"--resume {out}" in err
    assert not (out / "results.json").exists()  # no table with runs missing from it
    assert sorted(json.loads(line)["seed"] for line in lines_of(out)) == [0, 0]


def test_resume_refuses_a_directory_of_another_experiment(tmp_path, capsys):
    out = tmp_path / "paper"
    assert main(["experiment", "paper", "--resume", str(out)]) == 2
    assert "runs.jsonl not found" in capsys.readouterr().err
    assert main(paper_args(out, seeds=1, episodes=1)) == 0
    assert main(paper_args(out, "--resume", str(out), seeds=1, episodes=2)) == 2
    assert "seed 0 was run with other arguments" in capsys.readouterr().err


def test_without_a_cluster_the_error_names_the_address_and_the_fix(tmp_path, capsys):
    pytest.importorskip("ray", reason="ray not installed: pip install 'voxshape[cluster]'")
    port = cluster._free_port()  # nothing listens there
    began = time.monotonic()
    code = main(paper_args(tmp_path / "out", "--cluster", f"127.0.0.1:{port}", seeds=1))
    err = capsys.readouterr().err
    assert code == 2 and time.monotonic() - began < 45  # not Ray's minute of retries
    assert f"no Ray cluster at 127.0.0.1:{port}: start one with `ray start --head`" in err


def test_without_ray_cluster_says_how_to_get_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as if not installed
    monkeypatch.setenv("VOXSHAPE_CLUSTER", "auto")  # the variable as --cluster
    assert main(paper_args(tmp_path / "out", seeds=1)) == 2
    assert "pip install 'voxshape[cluster]'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def ray_cluster():
    pytest.importorskip("ray", reason="ray not installed: pip install 'voxshape[cluster]'")
    with cluster.LocalCluster(workers=1, cpus=1) as running:
        yield running


def voxshape(ray_cluster, argv: list[str], **popen) -> subprocess.Popen:
    """`voxshape` in its own process group, a driver of the test cluster."""
    return subprocess.Popen([VOXSHAPE, *argv], env=ray_cluster.driver_env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, **popen)  # fmt: skip


def finish(process: subprocess.Popen, timeout: float = 90) -> str:
    try:
        _, err = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 0, err
    return err


def wait_for_lines(out: Path, count: int, process: subprocess.Popen, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while len(lines_of(out)) < count:
        assert process.poll() is None, process.communicate()[1]
        assert time.monotonic() < deadline, f"fewer than {count} runs done in {timeout} s"
        time.sleep(0.05)


# Every cluster test runs this experiment (task 3, 6 runs of 1-2 s: longer than a task's
# start), compared with the local pool's runs of it.
SMALL = {"tasks": "3", "seeds": 3, "episodes": 6}


@pytest.fixture(scope="module")
def local_runs(tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("local") / "paper"
    assert main(paper_args(out, "--workers", "2", **SMALL)) == 0
    return runs_of(out)


def wait_for_a_run_on(
    nodes: list[subprocess.Popen], process: subprocess.Popen, timeout: float = 60
) -> subprocess.Popen:
    """The first of the nodes seen running a run (a worker titled `ray::run`)."""
    deadline = time.monotonic() + timeout
    while True:
        for node in nodes:
            if "ray::run" in cluster.workers_of(node).values():
                return node
        assert process.poll() is None, process.communicate()[1]
        assert time.monotonic() < deadline, f"no run on the nodes in {timeout} s"
        time.sleep(0.05)


def test_on_a_cluster_the_runs_are_the_local_pools(ray_cluster, local_runs, tmp_path):
    out = tmp_path / "cluster"
    finish(voxshape(ray_cluster, paper_args(out, "--cluster", ray_cluster.address, **SMALL)))
    assert runs_of(out) == local_runs  # run for run, in the same order
    assert (out / "report.md").exists() and (out / "figure2.png").exists()


def test_a_lost_worker_nodes_runs_are_retried(ray_cluster, local_runs, tmp_path):
    ray_cluster.add_worker()  # 3 CPUs in all: a worker node is lost mid-experiment
    out = tmp_path / "cluster"
    experiment = voxshape(ray_cluster, paper_args(out, "--cluster", ray_cluster.address, **SMALL))
    ray_cluster.kill(wait_for_a_run_on(ray_cluster.nodes[1:], experiment))
    finish(experiment)
    assert runs_of(out) == local_runs  # none missing, none different
    logs = Path(ray_cluster.temp_dir, "session_latest", "logs").glob("python-core-driver-*")
    assert any("Will resubmit task" in log.read_text(errors="replace") for log in logs)


def test_resume_after_an_interrupt_runs_only_the_missing_runs(ray_cluster, local_runs, tmp_path):
    out = tmp_path / "cluster"
    argv = paper_args(out, "--cluster", ray_cluster.address, **SMALL)
    interrupted = voxshape(ray_cluster, argv)
    wait_for_lines(out, 2, interrupted)
    os.killpg(interrupted.pid, signal.SIGKILL)  # the driver's machine lost, say
    interrupted.wait()
    kept = [line for line in lines_of(out) if line.endswith("}")]
    assert 2 <= len(kept) < 6
    finish(voxshape(ray_cluster, [*argv, "--resume", str(out)]))
    assert lines_of(out)[: len(kept)] == kept and len(lines_of(out)) == 6  # none run twice
    assert json.loads((out / "results.json").read_text())["resumed_runs"] == len(kept)
    assert runs_of(out) == local_runs
