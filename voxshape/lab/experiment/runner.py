"""Many runs of an experiment: in a local process pool or as Ray tasks on a cluster, each
result appended to runs.jsonl as it finishes, so that an experiment cut short keeps what it ran
and `--resume` runs only the rest."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

from tqdm import tqdm

from voxshape.lab.experiment.cluster import failure, on_ray
from voxshape.lab.experiment.inprocess import RunResult, RunSpec, run


class RunsFailed(RuntimeError):
    """Runs that failed for good (after Ray's retries on a cluster), each named by task,
    setting and seed; the runs that finished are in the log, for `--resume`."""

    def __init__(self, failed: list[tuple[RunSpec, str]], finished: int) -> None:
        self.failed = failed
        named = "; ".join(f"task {s.task} {s.setting} seed {s.seed}: {why}" for s, why in failed)
        super().__init__(f"{len(failed)} run(s) failed, {finished} finished: {named}")


def spec_key(spec: RunSpec | dict) -> str:
    """A run's identity as runs.jsonl keeps it: its RunSpec (task, setting, seed, teacher,
    learner, episode limit), as JSON."""
    return json.dumps(asdict(spec) if isinstance(spec, RunSpec) else spec, sort_keys=True)


class ResumeError(ValueError):
    """An output directory without runs.jsonl, or whose runs are of another experiment."""


def resumed(log: Path, specs: list[RunSpec]) -> dict[str, RunResult]:
    """The runs of `specs` already in `log` (runs.jsonl of an interrupted experiment), by
    spec_key; a run of other arguments there is refused (ResumeError), a last line cut short
    by the interrupt is left out."""
    wanted = {spec_key(spec) for spec in specs}
    done: dict[str, RunResult] = {}
    if not log.exists():
        raise ResumeError(f"{log} not found: nothing to resume there (check --resume)")
    lines = log.read_text().splitlines()
    for number, line in enumerate(lines, 1):
        try:
            result = RunResult.from_json(json.loads(line))
        except (ValueError, TypeError):
            if number == len(lines):
                continue  # written when the experiment was stopped
            raise ResumeError(f"{log}:{number}: not a run of `voxshape experiment`") from None
        key = spec_key(result.spec)
        if key not in wanted:
            raise ResumeError(
                f"{log}:{number}: task {result.task} {result.setting} seed {result.seed} was "
                "run with other arguments (episode limit, --set, --teacher, --tasks or seeds): "
                "resume with the arguments the experiment was started with"
            )
        done[key] = result
    return done


def start_log(log: Path, specs: list[RunSpec], resume: bool) -> dict[str, RunResult]:
    """Readies runs.jsonl for an experiment: emptied, or with `resume` read for the runs
    done (`resumed`) and rewritten with them alone (a line cut short is dropped)."""
    if not resume:
        log.unlink(missing_ok=True)
        return {}
    done = resumed(log, specs)
    log.write_text("".join(json.dumps(r.to_json()) + "\n" for r in done.values()))
    return done


def _locally(
    specs: list[RunSpec], workers: int, reference: bool
) -> Iterator[tuple[int, RunResult | BaseException]]:
    """Each run in a local process pool: (index in `specs`, its result or its error)."""
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(run, spec, reference): i for i, spec in enumerate(specs)}
        for future in as_completed(futures):
            try:
                yield futures[future], future.result()
            except Exception as e:  # the run's own error, or its process lost
                yield futures[future], e


def run_all(
    specs: list[RunSpec],
    workers: int | None = None,
    progress: bool = True,
    log: Path | None = None,
    reference: bool = False,
    cluster: str | None = None,
    done: dict[str, RunResult] | None = None,
) -> list[RunResult]:
    """Every run (in the order of `specs`), in local processes or, with `cluster` (a Ray
    address), as Ray tasks on that cluster, with a progress bar on stderr; with `log`, each
    result is appended to it as a JSON line as soon as it is done (a long experiment cut short
    keeps what it ran); runs in `done` (by spec_key: `resumed`) are not run again;
    `reference`: on the simulator's reference path (`run`). Raises RunsFailed naming the runs
    that failed, once the others are done."""
    done = done or {}
    results: list[RunResult | None] = [done.get(spec_key(spec)) for spec in specs]
    # The longest runs first (plain RL learns 5-8x slower), so none is left alone at the end.
    todo = sorted((i for i, r in enumerate(results) if r is None),
                  key=lambda i: specs[i].setting != "rl")  # fmt: skip
    failed: list[tuple[RunSpec, str]] = []
    if cluster:
        outcomes = on_ray([specs[i] for i in todo], reference, cluster)
    else:
        outcomes = _locally([specs[i] for i in todo], workers or os.cpu_count() or 1, reference)
    with tqdm(total=len(specs), initial=len(specs) - len(todo), unit="run",
              disable=not progress, leave=False) as bar:  # fmt: skip
        for position, outcome in outcomes:
            index = todo[position]
            if isinstance(outcome, BaseException):
                failed.append((specs[index], failure(outcome)))
            else:
                results[index] = outcome
                if log is not None:
                    with log.open("a") as lines:
                        lines.write(json.dumps(outcome.to_json()) + "\n")
            bar.update(1)
    if failed:
        raise RunsFailed(failed, sum(r is not None for r in results))
    return [r for r in results if r is not None]
