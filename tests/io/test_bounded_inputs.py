"""Every input bounded before it is read (issue 45, item 4): one check
(:func:`gripper_env.io.config.check_input`) that every reader of a user's file goes through.
Named pipes and devices are refused from their stat, without being opened (opening a FIFO
blocks until a writer comes; a device never ends); files and folders larger than their cap
from their size; the refusal names the option and the cap."""

from __future__ import annotations

import json
import os

import pytest

from gripper_env.io.config import ConfigError, check_input, read_bounded
from gripper_env.io.files import read_format_json
from gripper_env.sysid.logfile import read_log


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe"
    os.mkfifo(path)
    return path


def test_a_device_and_a_fifo_are_refused_unopened_naming_the_option(fifo):
    # read_bounded would block for ever in open() on the FIFO if it opened it
    with pytest.raises(
        ConfigError, match=rf"^--log {fifo}: a named pipe \(FIFO\), not a log file$"
    ):
        read_bounded(fifo, 1 << 20, "log", "--log")
    with pytest.raises(ConfigError, match=r"^--storage /dev/zero: a character device, not a "):
        check_input("/dev/zero", 1 << 20, "journal storage", "--storage", missing_ok=True)
    with pytest.raises(ValueError, match="named pipe"):
        read_log(fifo)
    with pytest.raises(ValueError, match=r"--calibration .*named pipe"):
        read_format_json(fifo, "x", "calibration file", ValueError, "--calibration")


def test_sizes_are_checked_against_the_cap_before_reading(tmp_path):
    big = tmp_path / "big.csv"
    with big.open("wb") as f:
        f.truncate(3 << 20)  # sparse: costs no disk
    with pytest.raises(
        ConfigError, match=r"^--log .*big.csv: 3 MiB, more than the 2 MiB a log may"
    ):
        read_bounded(big, 2 << 20, "log", "--log")
    assert len(read_bounded(big, 3 << 20, "log")) == 3 << 20  # at the cap: read whole
    folder = tmp_path / "agent"
    folder.mkdir()
    (folder / "model.zip").write_bytes(b"x" * 3000)
    (folder / "agent.json").write_bytes(b"y" * 3000)
    assert check_input(folder, 6000, "agent", folder=True) is not None
    with pytest.raises(
        ConfigError, match=r"^AGENT .*agent: 5.86 KiB, more than the 5.86 KiB an? agent may hold$"
    ):
        check_input(folder, 5999, "agent", "AGENT", folder=True)
    with pytest.raises(
        ConfigError, match=r"model.zip: not a regular file|a regular file, not the folder"
    ):
        check_input(folder / "model.zip", 1 << 20, "agent", folder=True)


def test_a_missing_storage_is_one_to_create(tmp_path):
    assert check_input(tmp_path / "new.journal", 1, "journal", missing_ok=True) is None
    with pytest.raises(ConfigError, match="no such file"):
        check_input(tmp_path / "new.journal", 1, "journal")


def test_optuna_storages_refuse_pipes_devices_and_oversize_files(fifo, tmp_path):
    from tuners.optuna.storage import MAX_STORAGE_BYTES, open_storage
    from tuners.settings import OptunaSettings

    settings = OptunaSettings.model_construct()  # a journal or SQLite reads none of it
    for url in (str(fifo), f"sqlite:///{fifo}", "/dev/zero", "sqlite:////dev/zero"):
        with pytest.raises(ConfigError, match=r"^--storage .*(named pipe|character device)"):
            open_storage(url, settings)
    big = tmp_path / "big.journal"
    with big.open("wb") as f:
        f.truncate(MAX_STORAGE_BYTES + 1)
    with pytest.raises(ConfigError, match=r"--storage .*big.journal: 256 MiB, more than the 256"):
        open_storage(str(big), settings)
    assert not (tmp_path / "big.journal.flock").exists()  # refused before the lock is made


def test_an_agent_is_bounded_before_it_is_loaded(tmp_path):
    from tuners.rl.agents import load_any

    folder = tmp_path / "agent"
    folder.mkdir()
    (folder / "agent.json").write_text(json.dumps({"format": "gripper-agent"}))
    os.mkfifo(folder / "model.zip")  # is_file() is False: no agent, nothing opened
    with pytest.raises(ValueError, match="no agent in"):
        load_any(str(folder))
    zip_fifo = tmp_path / "model.zip"
    os.mkfifo(zip_fifo)
    with pytest.raises(
        ValueError,
        match=r"^AGENT .*model.zip: a named pipe \(FIFO\), not a stable-baselines3 model file$",
    ):
        load_any(str(zip_fifo))


def test_list_options_are_capped_before_any_name_is_looked_up():
    from tuners.conventions import MAX_LIST_ITEMS, split_list

    names = ",".join(["no-such-plant"] * 2001)
    with pytest.raises(
        ValueError, match=rf"^--plants: 2001 names, more than the {MAX_LIST_ITEMS} "
    ):
        split_list(names, "--plants")
    assert split_list(",".join(["a"] * MAX_LIST_ITEMS), "--plants") == ["a"] * MAX_LIST_ITEMS


def test_list_arguments_are_capped_by_every_commands_parser(capsys):
    from tuners.conventions import MAX_ARGUMENT_VALUES, command_parser

    parser = command_parser("tuners.x", "a list-taking command")
    parser.add_argument("records", nargs="+")
    parser.add_argument("--ids", type=int, nargs="*", default=[])
    args = parser.parse_args(["a", "b", "--ids", *map(str, range(MAX_ARGUMENT_VALUES))])
    assert args.records == ["a", "b"] and len(args.ids) == MAX_ARGUMENT_VALUES
    for argv, name in ((["r"] * (MAX_ARGUMENT_VALUES + 1), "records"),
                       (["r", "--ids", *["1"] * 2001], "--ids")):  # fmt: skip
        with pytest.raises(SystemExit) as caught:
            parser.parse_args(argv)
        assert caught.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1
        assert f"{name}: " in err and f"more than the {MAX_ARGUMENT_VALUES} a list may" in err


def test_a_pipe_in_an_output_folder_is_skipped_not_waited_on(tmp_path, fifo):
    """Files a command reads back from its own --out (a quick benchmark's check for a full
    run's results, the RL leaderboard's rows) go through the same check: a named pipe there
    is passed over (it blocked the command for ever)."""
    from tuners.benchmark.command import _quick_conflicts
    from tuners.rl.leaderboard import load_rows

    os.replace(fifo, tmp_path / "benchmark.json")
    _quick_conflicts(tmp_path, [])  # nothing of a full run: no refusal, no wait
    rows = tmp_path / "rows"
    rows.mkdir()
    os.mkfifo(rows / "row.json")
    assert load_rows(rows) == []
