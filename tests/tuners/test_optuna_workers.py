"""Several ``python -m tuners.optuna`` processes on one study, on one machine, with no server:
real processes, and the storage read back with Optuna's own reader."""

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter

import optuna
import pytest
from optuna.trial import TrialState

from tests.tuners.conftest import REPO
from tuners.optuna.workers import is_gone, stream_seed, this_worker

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)


def load(storage, name):
    """The study as Optuna reads it from a journal file path or an RDB URL."""
    if "://" not in str(storage):
        backend = optuna.storages.journal.JournalFileBackend(str(storage))
        storage = optuna.storages.JournalStorage(backend)
    return optuna.load_study(study_name=name, storage=storage)


def worker_cmd(out, config, eval_config, name, trials, seed, *extra):
    return [
        sys.executable, "-m", "tuners.optuna", "--plant", "test2", "--out", str(out),
        "--config", str(config), "--eval-config", str(eval_config), "--no-progress", "--json",
        "--study-name", name, "--trials", str(trials), "--seed", str(seed), *extra,
    ]  # fmt: skip


def start(cmd):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.Popen(
        cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )


def duplicates(trials):
    params = [tuple(sorted(t.params.items())) for t in trials]
    return len(params) - len(set(params))


def states(study):
    return Counter(t.state for t in study.get_trials(deepcopy=False))


@pytest.mark.parametrize(
    "n_workers, storage",
    [(3, None), (2, "sqlite")],
    ids=["3 workers, journal (default)", "2 workers, fresh SQLite"],
)
def test_workers_on_one_machine_share_a_study(
    tmp_path, small_optuna_config, small_eval_config, n_workers, storage
):
    """Workers started together with the SAME --seed (each must draw its own sampler stream,
    or their first batches coincide) finish exactly the requested total: no duplicate
    parameter set, no trial left RUNNING or WAITING, no traceback."""
    target = 16 * n_workers
    out = tmp_path / "runs"
    extra = []
    if storage == "sqlite":
        out.mkdir()
        extra = ["--storage", f"sqlite:///{out / 'studies.db'}"]
    cmd = worker_cmd(out, small_optuna_config, small_eval_config, "shared", target, 5, *extra)
    procs = [start(cmd) for _ in range(n_workers)]
    results = [p.communicate(timeout=240) for p in procs]
    for p, (_out, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
        assert "Traceback" not in err, err
    ran = [json.loads(o)["tuning"]["trials_this_run"] for o, _ in results]
    study = load(extra[1] if extra else out / "optuna.journal", "shared")
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    assert len(complete) == target == sum(ran)
    assert states(study) == {TrialState.COMPLETE: target}  # nothing RUNNING, WAITING, FAIL
    assert duplicates(complete) == 0
    assert sum(r > 0 for r in ran) >= 2  # they did share the work


def test_kill_9_of_one_worker(tmp_path, small_optuna_config, small_eval_config):
    """``kill -9`` of one of two workers while it simulates a batch: every trial finished by
    then is kept as it was, the other worker finishes the total, and the killed worker's
    trials in flight are failed (none stays RUNNING)."""
    out = tmp_path / "runs"
    journal = out / "optuna.journal"
    target = 48
    cmd = worker_cmd(out, small_optuna_config, small_eval_config, "kill", target, 3)
    victim, survivor = start(cmd), start(cmd)
    try:
        in_flight = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and victim.poll() is None:
            if journal.is_file():
                os.kill(victim.pid, signal.SIGSTOP)  # freeze it, then look
                trials = load(journal, "kill").get_trials(deepcopy=False) if _has(journal) else []
                running = [t for t in trials if t.state == TrialState.RUNNING]
                in_flight = [
                    t.number
                    for t in running
                    if str(t.user_attrs.get("worker", "")).split(":")[1:2] == [str(victim.pid)]
                ]
                # a trial asked for but not yet marked has no owner to tell: look again later
                unmarked = any("worker" not in t.user_attrs for t in running)
                done = sum(t.state == TrialState.COMPLETE for t in trials)
                if in_flight and done >= 8 and not unmarked:
                    victim.kill()
                    break
                os.kill(victim.pid, signal.SIGCONT)
            time.sleep(0.05)
        victim.wait(timeout=30)
        assert in_flight and victim.returncode == -signal.SIGKILL
        before = {
            t.number: t.values
            for t in load(journal, "kill").trials
            if t.state == TrialState.COMPLETE
        }
        _out, err = survivor.communicate(timeout=240)
    finally:
        for p in (victim, survivor):
            if p.poll() is None:
                p.kill()
    assert survivor.returncode == 0, err
    assert "Traceback" not in err, err
    study = load(journal, "kill")
    trials = {t.number: t for t in study.trials}
    assert all(trials[n].values == v for n, v in before.items())  # kept as they were
    assert all(trials[n].state == TrialState.FAIL for n in in_flight)  # failed, not lost
    assert states(study) == {TrialState.COMPLETE: target, TrialState.FAIL: len(in_flight)}
    assert duplicates([t for t in study.trials if t.state == TrialState.COMPLETE]) == 0


def _has(journal):
    """The study has been created in the journal."""
    try:
        load(journal, "kill")
        return True
    except KeyError:
        return False


def test_worker_identity_and_streams():
    me = this_worker()
    assert not is_gone(me)
    host, pid, start = me.split(":")
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)  # fmt: skip
    assert is_gone(f"{host}:{finished.stdout.strip()}:0")  # that process has ended
    if start:  # Linux: a process id reused by another process is not the worker
        assert is_gone(f"{host}:{pid}:{int(start) + 1}")
    assert not is_gone(f"elsewhere-{host}:1:0")  # another host: only heartbeats could tell
    assert stream_seed(7, 0) == 7  # a single worker keeps its --seed
    seeds = {stream_seed(7, r) for r in range(8)} | {stream_seed(8, r) for r in range(1, 8)}
    assert len(seeds) == 15


def test_a_single_worker_is_reproducible(tmp_path, capsys, small_optuna_config, small_eval_config):
    """Rank 0 keeps --seed: the same command in two fresh storages finds the same trials."""
    from tuners import cli
    from tuners.optuna import command

    found = []
    for run in ("a", "b"):
        argv = worker_cmd(tmp_path / run, small_optuna_config, small_eval_config, "one", 8, 4)
        assert cli.run(command.main, argv[3:]) == 0
        capsys.readouterr()
        study = load(tmp_path / run / "optuna.journal", "one")
        found.append([(t.params, t.values) for t in study.trials])
    assert found[0] == found[1] and len(found[0]) == 8
