import json
import os
import signal
import subprocess
import sys
import time
import uuid
from typing import ClassVar

import numpy as np
import pytest

from tests.tuners.conftest import REPO, run_cli
from tuners import cli
from tuners.optuna import command as optuna_tuner
from tuners.optuna import knee_point
from tuners.optuna.storage import _driver_url


def run(argv, capsys):
    code = cli.run(optuna_tuner.main, [str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def small(tmp_path, small_optuna_config, small_eval_config, *extra):
    return [
        "--plant",
        "test2",
        "--out",
        tmp_path,
        "--config",
        small_optuna_config,
        "--eval-config",
        small_eval_config,
        "--no-progress",
        "--json",
        *extra,
    ]


def stored_trials(journal, name):
    """The study's trials as Optuna reads them from the journal file; [] until the worker has
    created the study."""
    import optuna

    backend = optuna.storages.journal.JournalFileBackend(str(journal))
    try:
        return optuna.load_study(
            study_name=name, storage=optuna.storages.JournalStorage(backend)
        ).trials
    except KeyError:
        return []


def complete_trials(journal, name):
    """Finished trials (number -> values)."""
    return {t.number: t.values for t in stored_trials(journal, name) if t.state.name == "COMPLETE"}


@pytest.mark.slow
def test_study_writes_gains_file_and_resumes(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    args = small(tmp_path, small_optuna_config, small_eval_config)
    code, out, _ = run([*args, "--trials", 12, "--seed", 1], capsys)
    assert code == 0
    first = json.loads(out)
    assert first["tuner"] == "optuna" and first["tuning"]["trials_in_study"] == 12
    assert first["tuning"]["episodes_this_run"] == 12 * 2  # two tuning seeds per trial
    best = [c for _, c in first["tuning"]["history"]]
    assert best == sorted(best, reverse=True)  # best so far only improves
    assert (tmp_path / "optuna.journal").is_file() and (tmp_path / "test2" / "optuna.png").is_file()
    # rerunning with a larger budget continues the same study
    code, out, _ = run([*args, "--trials", 16, "--seed", 1], capsys)
    second = json.loads(out)
    assert second["tuning"]["trials_in_study"] == 16
    assert second["tuning"]["trials_this_run"] == 4
    assert second["tuning"]["best_value_tuning"] <= first["tuning"]["best_value_tuning"]


def test_search_beats_the_paper_on_the_tuning_cost(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    args = small(tmp_path, small_optuna_config, small_eval_config)
    _code, out, _ = run([*args, "--trials", 40, "--seed", 0], capsys)
    found = json.loads(out)
    from tuners import manual

    cli.run(
        manual.main,
        [
            "--plant",
            "test2",
            "--gains",
            "paper-tuned",
            "--json",
            "--out",
            str(tmp_path),
            "--eval-config",
            str(small_eval_config),
        ],
    )
    paper = json.loads(capsys.readouterr().out)
    assert found["metrics"]["actual"]["mean"]["cost"] < paper["metrics"]["actual"]["mean"]["cost"]


def test_multi_objective_gives_a_front_and_its_knee(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    args = small(tmp_path, small_optuna_config, small_eval_config)
    code, out, _ = run([*args, "--trials", 16, "--multi-objective"], capsys)
    assert code == 0
    content = json.loads(out)
    front = content["tuning"]["pareto_front"]
    assert front and content["tuning"]["best_trial"] in [p["trial"] for p in front]
    assert set(front[0]["values"]) == {"iae", "overshoot_pct", "servo_effort_deg"}
    assert (tmp_path / "test2" / "optuna-mo.json").is_file()


def test_knee_point_by_hand():
    front = np.array([[0.0, 10.0], [1.0, 1.0], [10.0, 0.0]])
    assert knee_point(front) == 1


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--storage", "postgresql://u:secret@127.0.0.1:1/none"], "cannot open storage"),
        (["--storage", "nosuchdb://x"], "cannot open storage"),
        (["--trials", "0"], "--trials"),
        (["--plant", "test0"], "unknown plant"),
    ],
)
def test_bad_input_exit_2_nothing_written(tmp_path, capsys, small_optuna_config, extra, message):
    out_dir = tmp_path / "results"
    code, _, err = run(
        ["--plant", "test2", "--out", out_dir, "--config", small_optuna_config, *extra], capsys
    )
    assert code == 2 and message in err and err.count("\n") == 1
    assert "secret" not in err
    assert not out_dir.exists()


def test_malformed_and_overlapping_configs(tmp_path, capsys, small_optuna_config):
    bad = tmp_path / "bad.yaml"
    bad.write_text(small_optuna_config.read_text().replace("scale: log", "scale: logarithmic"))
    out_dir = tmp_path / "results"
    code, _, err = run(["--plant", "test2", "--out", out_dir, "--config", bad], capsys)
    assert code == 2 and "search.I.scale" in err
    overlap = tmp_path / "overlap.yaml"
    overlap.write_text(small_optuna_config.read_text().replace("start: 0", "start: 100001"))
    code, _, err = run(["--plant", "test2", "--out", out_dir, "--config", overlap], capsys)
    assert code == 2 and "overlap" in err
    assert not out_dir.exists()


@pytest.mark.slow
def test_killed_worker_loses_no_finished_trial(tmp_path, small_optuna_config, small_eval_config):
    """``kill -9`` of the only worker: the rerun keeps every finished trial, fails the trials
    the killed worker had in flight (none stays RUNNING) and continues the study."""
    out = tmp_path / "results"
    journal = out / "optuna.journal"
    cmd = [
        sys.executable,
        "-m",
        "tuners.optuna",
        "--plant",
        "test2",
        "--out",
        str(out),
        "--config",
        str(small_optuna_config),
        "--eval-config",
        str(small_eval_config),
        "--no-progress",
        "--study-name",
        "killed",
        "--trials",
    ]
    worker = subprocess.Popen(
        [*cmd, "100000"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if journal.is_file() and len(complete_trials(journal, "killed")) >= 12:
                break
            time.sleep(0.2)
        worker.send_signal(signal.SIGKILL)
        worker.wait(timeout=30)
    finally:
        if worker.poll() is None:
            worker.kill()
    before = complete_trials(journal, "killed")
    in_flight = [t.number for t in stored_trials(journal, "killed") if t.state.name == "RUNNING"]
    assert len(before) >= 12
    target = len(before) + 8
    proc = run_cli("tuners.optuna", *cmd[3:], target, "--json")
    assert proc.returncode == 0, proc.stderr
    content = json.loads(proc.stdout)
    after = complete_trials(journal, "killed")
    assert all(after[n] == v for n, v in before.items())  # every finished trial kept as it was
    trials = stored_trials(journal, "killed")
    assert all(trials[n].state.name == "FAIL" for n in in_flight)
    assert not [t for t in trials if t.state.name == "RUNNING"]
    assert content["tuning"]["trials_in_study"] == target
    assert content["tuning"]["trials_this_run"] == 8  # continued, did not start over


@pytest.fixture
def fresh_postgres_database():
    """A new, empty database on the test server (dropped afterwards), so that workers started
    together always race to create Optuna's tables, as on a user's first run."""
    import psycopg2

    base = os.environ["GRIPPER_TEST_POSTGRES_URL"]
    name = f"gripper_{uuid.uuid4().hex[:10]}"
    admin = psycopg2.connect(base)
    admin.autocommit = True
    try:
        with admin.cursor() as cur:
            cur.execute(f"CREATE DATABASE {name}")
    except psycopg2.errors.InsufficientPrivilege:
        admin.close()
        pytest.skip("the test role may not create databases (scripts/start-postgres.sh grants it)")
    yield base.rsplit("/", 1)[0] + "/" + name
    with admin.cursor() as cur:
        cur.execute(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")
    admin.close()


@pytest.mark.slow
@pytest.mark.postgres
@pytest.mark.skipif(
    not os.environ.get("GRIPPER_TEST_POSTGRES_URL"),
    reason="set GRIPPER_TEST_POSTGRES_URL=postgresql://user:pw@127.0.0.1/db (see .ci/run)",
)
def test_two_workers_share_one_postgres_study(
    tmp_path, small_optuna_config, small_eval_config, fresh_postgres_database
):
    """Two workers started at once on an empty database (both create the tables: the loser of
    that race opens again) share one study: every trial counted once."""
    url = fresh_postgres_database
    name = f"two-workers-{uuid.uuid4().hex[:8]}"
    target = 32
    procs = []
    for seed in (1, 2):
        procs.append(
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "tuners.optuna",
                    "--plant",
                    "test2",
                    "--storage",
                    url,
                    "--study-name",
                    name,
                    "--trials",
                    str(target),
                    "--seed",
                    str(seed),
                    "--out",
                    str(tmp_path / f"w{seed}"),
                    "--config",
                    str(small_optuna_config),
                    "--eval-config",
                    str(small_eval_config),
                    "--no-progress",
                    "--json",
                ],
                cwd=REPO,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        )
    results = [p.communicate(timeout=300) for p in procs]
    for p, (_out, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
    contents = [json.loads(out) for out, _ in results]
    import optuna

    study = optuna.load_study(study_name=name, storage=_driver_url(url))
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    numbers = [t.number for t in study.trials]
    assert len(numbers) == len(set(numbers))
    ran = [c["tuning"]["trials_this_run"] for c in contents]
    assert sum(ran) == len(complete) >= target
    assert all(c["tuning"]["storage"].count("***") == 1 for c in contents)  # password hidden


def test_results_meet_the_constraints_and_flag_bounds(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    """The search's result meets Ms <= 1.6 and 6 dB with the hold (checked independently by
    stability_report), and any gain at a search bound is flagged."""
    args = small(tmp_path, small_optuna_config, small_eval_config)
    code, out, _ = run([*args, "--trials", 40], capsys)
    assert code == 0
    content = json.loads(out)
    assert content["tuning"]["feasible"] and content["robustness"]["meets_constraints"]
    from gripper_env.evaluation.stability import stability_report
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.pid import PIDGains
    from gripper_env.model.plants import load_plant

    gains = PIDGains(content["P"], content["I"], content["D"])
    report = stability_report(load_plant("test2"), gains, disturbance=load_disturbance("actual"))
    assert report.ms <= 1.6 and report.gain_margin_db >= 6.0
    space = content["tuning"]["search_space"]["ranges"]
    assert space["I"]["high"] == pytest.approx(3.0 * 90.83, rel=0.01)  # scaled by the plant
    assert isinstance(content["tuning"]["on_bound"], list)


def test_bound_flags_by_hand():
    from gripper_env.model.pid import PIDGains
    from tuners.search_space import SearchSpace
    from tuners.settings import ParamRange

    space = SearchSpace(
        {
            "P": ParamRange(scale="linear", low=0.0, high=10.0),
            "I": ParamRange(scale="log", low=1.0, high=100.0),
            "D": ParamRange(scale="symlog", low=1e-5, high=0.1),
        }
    )
    assert space.on_bound(PIDGains(5.0, 10.0, 0.0)) == []  # D = 0 is inside a symlog range
    flags = space.on_bound(PIDGains(9.9, 1.05, -0.099))
    assert len(flags) == 3
    assert "P = 9.9 is at its upper" in flags[0] and "I = 1.05 is at its lower" in flags[1]
    assert "D = -0.099 is at its upper" in flags[2]  # the largest magnitude


@pytest.mark.slow
def test_robust_mode_and_search_seed_spread(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    """--plants tunes on several identifications at once (constraints on every one); two search
    seeds give two studies and their spread."""
    args = small(tmp_path, small_optuna_config, small_eval_config)
    code, out, _ = run([*args, "--trials", 16, "--plants", "test2,test4", "--search-seeds", 2],
                       capsys)  # fmt: skip
    assert code == 0
    content = json.loads(out)
    t = content["tuning"]
    assert content["tuner"] == "optuna-robust" and t["tuned_on"] == ["test2", "test4"]
    assert t["episodes_per_trial"] == 2 * 2  # plants x tuning seeds
    assert len(t["per_seed"]) == 2 and t["best_cost"]["min"] <= t["best_cost"]["max"]
    assert len(t["study_names"]) == 2 and t["study_names"][0].endswith("-s0")
    if t["feasible"]:
        assert content["cross_model"]["plants"]["test4"]["meets_constraints"]


def test_only_public_optuna_api():
    """Issue 15: no private Optuna attributes (they break on upgrades)."""
    sources = (REPO / "tuners" / "optuna").glob("*.py")
    source = "".join(path.read_text() for path in sources)
    for private in ("._storage", "._study_id", "._trial_id", "storages._", "samplers._"):
        assert private not in source, private


def test_cmaes_minimises_the_penalised_cost(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    args = small(tmp_path, small_optuna_config, small_eval_config)
    code, out, _ = run([*args, "--trials", 12, "--sampler", "cmaes"], capsys)
    assert code == 0 and json.loads(out)["tuner"] == "optuna-cmaes"


def test_search_space_params_invert_gains():
    """A warm start enqueues gains in the searched coordinates: params() inverts gains()."""
    from gripper_env.model.pid import PIDGains
    from tuners.search_space import SearchSpace
    from tuners.settings import ParamRange

    space = SearchSpace(
        {
            "P": ParamRange(scale="linear", low=-1.0, high=10.0),
            "I": ParamRange(scale="log", low=1.0, high=100.0),
            "D": ParamRange(scale="symlog", low=1e-5, high=0.1),
        }
    )
    for g in (PIDGains(0.87, 14.3, -0.0081), PIDGains(3.0, 50.0, 0.002)):
        back = space.gains(space.params(g), 100.0)
        assert (back.P, back.I, back.D) == pytest.approx((g.P, g.I, g.D), rel=1e-9)
    clipped = space.gains(space.params(PIDGains(20.0, 0.5, 0.0)), 100.0)
    assert clipped.P == 10.0 and clipped.I == 1.0 and abs(clipped.D) == pytest.approx(1e-5)


def test_the_textbook_designs_are_the_first_trials(small_optuna_config):
    """The warm start: a new study's first trials are the textbook designs, as designed."""
    import optuna

    from gripper_env.evaluation.objective import load_objective
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.plants import load_plant
    from tuners.optuna.study import run_study
    from tuners.optuna.warm_start import textbook_designs
    from tuners.search_space import search_space
    from tuners.settings import OptunaSettings, load_settings
    from tuners.tasks import make_scorer

    inputs = cli.load_inputs("test2")
    settings = load_settings(OptunaSettings, small_optuna_config)
    designs = textbook_designs((load_plant("test2"),), load_disturbance("actual"), 100.0)
    assert len(designs) >= 10  # five rules at five knob settings, less the unreachable
    scorer = make_scorer(inputs, settings)
    space = search_space(scorer.task.plants, inputs.disturbance, settings)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    run_study(study, scorer, space, settings, 6, 100.0, progress=False, warm_start=designs)
    first = sorted(study.trials, key=lambda t: t.number)[:6]
    for trial, g in zip(first, designs, strict=False):
        got = space.gains(trial.params, 100.0)
        want = space.gains(space.params(g), 100.0)  # clipped into the searched ranges
        assert (got.P, got.I, got.D) == pytest.approx((want.P, want.I, want.D), rel=1e-9)
    assert load_objective().constraints.search_backoff_deg > 0  # the task is a search's
    assert scorer.task.search


def test_an_infeasible_search_names_its_binding_constraint(
    tmp_path, capsys, small_optuna_config, small_eval_config
):
    """No gains meet Ms <= 1.01: the search says so in one line naming the constraint."""
    import yaml

    obj = tmp_path / "objective.yaml"
    data = yaml.safe_load((REPO / "configs" / "objective.yaml").read_text())
    data["constraints"]["ms_max"] = 1.01
    obj.write_text(yaml.safe_dump(data))
    args = small(tmp_path, small_optuna_config, small_eval_config)
    args = [a for a in args if a != "--json"]
    code, out, _ = run([*args, "--trials", 8, "--objective", obj], capsys)
    assert code == 0
    line = next(x for x in out.splitlines() if "infeasible" in x)
    assert "no trial met the admission rule; binding constraint 'ms'" in line
    assert "Ms " in line and "> 1.01" in line


@pytest.mark.slow
@pytest.mark.postgres
@pytest.mark.skipif(
    not os.environ.get("GRIPPER_TEST_POSTGRES_URL"),
    reason="set GRIPPER_TEST_POSTGRES_URL=postgresql://user:pw@127.0.0.1/db (see .ci/run)",
)
def test_a_trial_being_scored_keeps_its_heartbeat(fresh_postgres_database, small_optuna_config):
    """CI beside two busy processes: a batch scored for longer than the grace period was failed
    as stale by the other worker, whose fail then refused this worker's result (a traceback).
    While a batch is scored its trials' heartbeats go on; a trial left alone goes stale."""
    import optuna
    from optuna.trial import TrialState

    from tuners.optuna.storage import open_storage
    from tuners.optuna.workers import Worker
    from tuners.settings import OptunaSettings, load_settings

    settings = load_settings(OptunaSettings, small_optuna_config).model_copy(
        update={"heartbeat_interval_s": 1, "heartbeat_grace_s": 6}
    )
    storage = open_storage(fresh_postgres_database, settings)
    study = optuna.create_study(storage=storage.optuna, study_name="beats")
    with Worker(study, storage) as worker:
        scored, alone = study.ask(), study.ask()
        worker.mark(scored), worker.mark(alone)
        with worker.beating([scored]):
            time.sleep(9)  # longer than the grace period: the scoring of a slow batch
            worker.fail_stale(study.get_trials(deepcopy=False))
        states = {t.number: t.state for t in study.get_trials(deepcopy=False)}
    assert states[scored.number] == TrialState.RUNNING
    assert states[alone.number] == TrialState.FAIL


class _Bar:
    """A tqdm stand-in that records what a bar was told."""

    made: ClassVar[list] = []

    def __init__(self, total, initial=0, **_):
        self.total, self.n, self.closed = total, initial, False
        _Bar.made.append(self)

    def update(self, k):
        self.n += k

    def refresh(self):
        pass

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def test_one_bar_per_search_seed_counts_to_its_whole_budget(small_optuna_config, monkeypatch):
    """Issue 45: a search's bar reached 100 % at 800 (the TPE phase), then a second bar for the
    same seed restarted at 800/2000 (the CMA-ES phase). Now one bar counts to the budget."""
    import optuna

    import tuners.optuna.study as study_module
    from tuners.optuna.study import run_search
    from tuners.search_space import search_space
    from tuners.settings import OptunaSettings, load_settings
    from tuners.tasks import make_scorer

    monkeypatch.setattr(study_module, "tqdm", _Bar)
    _Bar.made = []
    inputs = cli.load_inputs("test2")
    settings = load_settings(OptunaSettings, small_optuna_config)
    assert 0 < settings.local_fraction < 1  # two phases
    scorer = make_scorer(inputs, settings)
    space = search_space(scorer.task.plants, inputs.disturbance, settings)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    run_search(study, scorer, space, settings, 20, 100.0, sampler_name="tpe", seed=0)
    assert [(b.total, b.n, b.closed) for b in _Bar.made] == [(20, 20, True)]
    assert len(study.trials) == 20


def test_the_budget_and_an_estimate_come_before_the_search(tmp_path, small_optuna_config):
    from tuners.optuna.command import budget_line, estimate_line
    from tuners.optuna.storage import open_storage
    from tuners.tasks import make_scorer

    argv = ["--plant", "test2", "--out", str(tmp_path), "--config", str(small_optuna_config),
            "--trials", "30", "--search-seeds", "2"]  # fmt: skip
    args = cli.parse(optuna_tuner.build_parser(), argv)
    inputs = cli.resolve(args)
    plan = optuna_tuner._plan(args, inputs, [])
    storage = open_storage(plan.url, plan.settings)
    scorer = make_scorer(inputs, plan.settings)
    line, left = budget_line(plan, storage, scorer)
    assert line.startswith("budget: 2 search seeds x 30 trials = 60 trials of 2 episodes each;")
    assert left == 60
    estimate = estimate_line(plan, scorer, left, 100.0)
    assert estimate.startswith("estimate: about ") and " on this machine (the scoring" in estimate
    assert scorer.episodes == 0  # the timing is no part of the run's budget
    import optuna

    study = optuna.create_study(storage=storage.optuna, study_name=f"{plan.base_name}-s0")
    for _ in range(12):
        study.enqueue_trial({})
        study.tell(study.ask(), 1.0)
    line, left = budget_line(plan, storage, scorer)
    assert "(12 already in the storage)" in line and left == 48


def test_help_states_what_the_defaults_cost():
    """--help names the shipped budget (read here from the shipped config) and its time."""
    import yaml

    from gripper_env.io.config import CONFIG_DIR

    shipped = yaml.safe_load((CONFIG_DIR / "tuners" / "optuna.yaml").read_text())
    text = " ".join(optuna_tuner.build_parser().format_help().split())
    n, k = shipped["first_trials"], shipped["first_search_seeds"]
    assert f"'first_trials', {n} in the shipped one: with its {k} search seeds {n * k} trials" in (
        text)  # fmt: skip
    full, seeds = shipped["trials"], shipped["search_seeds"]
    assert f"--full takes the config's 'trials', {full} x {seeds} seeds" in text
    assert "minutes" in text and "of CPU" in text


def test_the_first_tune_runs_the_first_budget_and_full_the_configs(tmp_path, small_optuna_config):
    """Without --trials the command runs the config's first tune; --full its full budget; an
    explicit --trials or --search-seeds wins over either."""
    import yaml

    from tuners import cli as tuner_cli

    data = yaml.safe_load(small_optuna_config.read_text())
    data.update(trials=12, search_seeds=2, first_trials=8, first_search_seeds=1)
    config = tmp_path / "budget.yaml"
    config.write_text(yaml.safe_dump(data))
    plans = {}
    cases = {"first": [], "full": ["--full"], "given": ["--full", "--trials", "5"]}
    for label, extra in cases.items():
        argv = ["--plant", "test2", "--config", str(config), "--out", str(tmp_path / label)]
        args = tuner_cli.parse(optuna_tuner.build_parser(), [*argv, *extra])
        inputs = tuner_cli.resolve(args)
        plan = optuna_tuner._plan(args, inputs, [])
        plans[label] = (plan.n_trials, plan.n_seeds)
    assert plans == {"first": (8, 1), "full": (12, 2), "given": (5, 2)}


def test_sqlites_write_ahead_log_is_checkpointed_often(tmp_path):
    """Issue 45: with SQLite's default checkpoint (1000 pages) the write-ahead log alone filled
    2 MiB after 24 trials on a full disk, the database at 4 KiB; every connection now copies it
    into the database every 128 pages (512 KiB) and cuts it back to 1 MiB."""
    from sqlalchemy import text

    from tuners.optuna.storage import open_storage
    from tuners.settings import OptunaSettings

    storage = open_storage(f"sqlite:///{tmp_path}/s.db", OptunaSettings.model_construct())
    with storage.optuna.engine.connect() as connection:
        names = ("journal_mode", "wal_autocheckpoint", "journal_size_limit")
        pragma = {name: connection.execute(text(f"PRAGMA {name}")).scalar() for name in names}
    assert pragma == {"journal_mode": "wal", "wal_autocheckpoint": 128,
                      "journal_size_limit": 1 << 20}  # fmt: skip
