"""The studies' journal file survives a full disk and a torn last record (tuners.optuna.storage).

Independent truth: Optuna's own journal reader (a plain ``JournalFileBackend``) must read the
journal after the repair, and the trials counted before the disk filled must all be there.
"""

import json
import os

import optuna
import pytest
from optuna.storages.journal import JournalFileBackend

from tuners.optuna.storage import TORN_SUFFIX, open_storage
from tuners.settings import OptunaSettings, load_settings

optuna.logging.set_verbosity(optuna.logging.WARNING)
SETTINGS = load_settings(OptunaSettings)


def _objective(trial):
    return trial.suggest_float("x", 0.0, 1.0) ** 2


def _plain(path):
    """The journal as Optuna alone reads it."""
    return optuna.storages.JournalStorage(JournalFileBackend(str(path)))


def _trials(path, name="a"):
    return optuna.load_study(storage=_plain(path), study_name=name).trials


def test_a_torn_last_record_is_set_aside_and_the_studies_stay_readable(tmp_path, capsys):
    path = tmp_path / "optuna.journal"
    study = optuna.create_study(storage=open_storage(str(path), SETTINGS).optuna, study_name="a")
    study.optimize(_objective, n_trials=3)
    torn = b'{"op_code":4,"worker_id":"w","trial_id":3,"sta'
    with path.open("ab") as f:  # a crash, or a full disk, in the middle of a record
        f.write(torn)
    study = optuna.load_study(storage=open_storage(str(path), SETTINGS).optuna, study_name="a")
    assert "last record was torn" in capsys.readouterr().err
    assert (tmp_path / f"optuna.journal{TORN_SUFFIX}").read_bytes() == torn + b"\n"
    study.optimize(_objective, n_trials=2)  # appends after the cut, not glued to the torn bytes
    assert path.read_bytes().endswith(b"\n")
    assert [t.state for t in _trials(path)] == [optuna.trial.TrialState.COMPLETE] * 5


def test_a_record_glued_to_a_torn_one_is_recovered(tmp_path, capsys):
    """A journal damaged before this fix (a whole record appended to a torn one): Optuna
    itself then fails on it; the repair splits the line and keeps the whole record."""
    path = tmp_path / "optuna.journal"
    study = optuna.create_study(storage=_plain(path), study_name="a")
    study.optimize(_objective, n_trials=3)
    lines = path.read_bytes().splitlines(keepends=True)
    glued = b'{"op_code":4,"worker_id":"w","tri' + lines[-1]  # the last record, glued on
    path.write_bytes(b"".join(lines[:-1]) + glued + lines[-1])
    with pytest.raises(ValueError):  # Optuna refuses a bad line followed by another one
        _trials(path)
    open_storage(str(path), SETTINGS)
    assert "damaged record" in capsys.readouterr().err
    for line in path.read_bytes().splitlines():
        json.loads(line)
    assert len(_trials(path)) == 3


def test_a_full_disk_leaves_the_journal_whole(small_disk, filled):
    disk = small_disk(256)
    path = disk / "optuna.journal"
    study = optuna.create_study(storage=open_storage(str(path), SETTINGS).optuna, study_name="a")
    study.optimize(_objective, n_trials=3)
    before = len(_trials(path))
    filler = filled(disk, leave_bytes=300)  # room for a record or two, then none
    with pytest.raises(OSError) as info:  # asked and told as tuners.optuna.study does
        for _ in range(200):
            trial = study.ask()
            study.tell(trial, _objective(trial))
    assert info.value.errno == 28  # ENOSPC
    assert path.read_bytes().endswith(b"\n"), "a torn record was left behind"
    during = len(_trials(path))  # Optuna's own reader: every record whole
    assert during >= before
    os.remove(filler)
    study = optuna.load_study(storage=open_storage(str(path), SETTINGS).optuna, study_name="a")
    study.optimize(_objective, n_trials=2)
    assert len(_trials(path)) == during + 2
    assert not (disk / f"optuna.journal{TORN_SUFFIX}").exists()
