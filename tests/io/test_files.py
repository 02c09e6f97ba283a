"""The one atomic writer and JSON helper (``gripper_env.io.files``)."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from gripper_env.io.files import (
    json_ready,
    path_in,
    read_format_json,
    safe_name,
    save_figure,
    write_atomic,
    write_csv,
    write_group,
    write_json,
)


def test_write_atomic_text_and_bytes(tmp_path):
    p = write_atomic(tmp_path / "a" / "b.txt", "x\ny\n")
    assert p.read_bytes() == b"x\ny\n"  # no newline translation, parents created
    write_atomic(p, b"\x89PNG")
    assert p.read_bytes() == b"\x89PNG"
    assert sorted(os.listdir(p.parent)) == ["b.txt"]


def test_a_failed_write_leaves_the_old_file(tmp_path, monkeypatch):
    p = write_atomic(tmp_path / "f.txt", "old")

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_atomic(p, "new")
    assert p.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["f.txt"]


def test_write_json_makes_numpy_plain_and_non_finite_null(tmp_path):
    data = {"a": np.float64(1.5), "b": np.arange(3), "c": math.inf, "d": (np.int64(2), None)}
    p = write_json(tmp_path / "x.json", data)
    assert json.loads(p.read_text()) == {"a": 1.5, "b": [0, 1, 2], "c": None, "d": [2, None]}
    assert p.read_text().endswith("\n")
    assert json_ready({1: np.bool_(True)}) == {"1": True}


def test_json_ready_turns_inf_and_nan_into_null():
    out = json_ready({"a": math.inf, "b": [np.float64("nan"), np.int64(3)], "c": np.bool_(True)})
    assert out == {"a": None, "b": [None, 3], "c": True}
    json.dumps(out, allow_nan=False)


def test_write_csv_header_six_decimals_and_nan(tmp_path):
    data = np.array([[0.0, 1.23456789], [0.001, np.nan]])
    p = write_csv(tmp_path / "log.csv", ("t_s", "position_deg"), data)
    assert p.read_text() == "t_s,position_deg\n0.000000,1.234568\n0.001000,nan\n"
    with pytest.raises(ValueError, match="3 columns named, data of shape"):
        write_csv(tmp_path / "bad.csv", ("a", "b", "c"), data)


def test_save_figure_writes_the_format_of_the_suffix_and_closes(tmp_path):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    p = save_figure(fig, tmp_path / "f.png", dpi=50)
    assert p.read_bytes()[:4] == b"\x89PNG" and not plt.fignum_exists(fig.number)
    fig, _ = plt.subplots()
    assert save_figure(fig, tmp_path / "f.svg").read_text().lstrip().startswith("<?xml")
    assert sorted(os.listdir(tmp_path)) == ["f.png", "f.svg"]


def test_save_figure_stores_a_palette_png_smaller_than_full_colour(tmp_path):
    import matplotlib.pyplot as plt
    from PIL import Image

    def figure():
        fig, ax = plt.subplots()
        x = np.linspace(0, 20, 4000)
        ax.plot(x, np.sin(x) + 0.05 * np.random.default_rng(0).standard_normal(x.size))
        ax.fill_between(x, np.sin(x) - 0.3, np.sin(x) + 0.3, alpha=0.3)
        return fig

    full = save_figure(figure(), tmp_path / "full.png", palette=False)
    small = save_figure(figure(), tmp_path / "small.png")
    with Image.open(small) as image, Image.open(full) as reference:
        assert image.mode == "P" and image.size == reference.size
    assert small.stat().st_size < 0.7 * full.stat().st_size
    fig = figure()
    assert not plt.fignum_exists(fig.number) or save_figure(fig, tmp_path / "f.svg")
    assert not plt.fignum_exists(fig.number)  # closed whichever the format
    assert sorted(os.listdir(tmp_path)) == ["f.svg", "full.png", "small.png"]


def test_read_format_json_names_the_file_and_what_is_wrong(tmp_path):
    good = write_json(tmp_path / "g.json", {"format": "gripper-x", "a": 1})
    assert read_format_json(good, "gripper-x", "x file") == {"format": "gripper-x", "a": 1}
    (tmp_path / "bad.json").write_text("{oops")
    with pytest.raises(KeyError, match=r"bad\.json: not valid JSON"):
        read_format_json(tmp_path / "bad.json", "gripper-x", "x file", KeyError)
    with pytest.raises(
        ValueError, match=r'g\.json: not a y file \(expected "format": "gripper-y"\)'
    ):
        read_format_json(good, "gripper-y", "y file")
    with pytest.raises(ValueError, match=r"cannot read x file .*none\.json: No such file"):
        read_format_json(tmp_path / "none.json", "gripper-x", "x file")


def test_a_run_writes_one_sidecar_with_its_provenance_and_the_volatile_values(tmp_path):
    from gripper_env.io.files import collect_provenance, write_result_json

    result = {"P": 1.0, "provenance": {"command": "x", "wall_time_s": 3.5},
              "rows": [{"cost": 2.0, "train_wall_time_s": 9.0}]}  # fmt: skip
    with collect_provenance(tmp_path, "study", command="python -m x", extra_fact=7):
        write_result_json(tmp_path / "a.json", result)
        with collect_provenance(tmp_path / "sub", "inner"):  # adds to the enclosing run
            write_result_json(tmp_path / "sub" / "b.json", {"date": "today", "n": 1})
        write_atomic(tmp_path / "c.md", "text\n")
    assert sorted(p.name for p in tmp_path.rglob("*")) == [
        "a.json", "b.json", "c.md", "study.provenance.json", "sub"]  # fmt: skip
    assert json.loads((tmp_path / "a.json").read_text()) == {
        "P": 1.0, "provenance": {"command": "x"}, "rows": [{"cost": 2.0}]}  # fmt: skip
    side = json.loads((tmp_path / "study.provenance.json").read_text())
    assert side["format"] == "gripper-provenance" and side["command"] == "python -m x"
    for key in ("version", "git_commit", "git_dirty", "python", "machine", "libraries", "date",
                "argv", "wall_time_s"):  # fmt: skip
        assert key in side
    assert side["extra_fact"] == 7 and side["libraries"]["numpy"] == np.__version__
    assert side["files"] == {
        "a.json": {"/provenance/wall_time_s": 3.5, "/rows/0/train_wall_time_s": 9.0},
        "sub/b.json": {"/date": "today"},
    }


def test_a_rerun_that_reproduces_every_file_keeps_the_sidecar(tmp_path):
    """The no-churn rule: same bytes, same sidecar (only touched); a changed file, a new one."""
    from gripper_env.io.files import collect_provenance, write_result_json

    def run(value, wall):
        with collect_provenance(tmp_path, "r", command="c"):
            write_result_json(tmp_path / "r.json", {"v": value, "wall_time_s": wall})
            write_atomic(tmp_path / "r.md", f"v = {value}\n")

    run(1, 1.0)
    sidecar = tmp_path / "r.provenance.json"
    first = sidecar.read_bytes()
    os.utime(sidecar, (0, 0))
    run(1, 2.0)  # same numbers, another wall time
    assert sidecar.read_bytes() == first and sidecar.stat().st_mtime > 0
    run(2, 3.0)
    assert json.loads(sidecar.read_text())["files"]["r.json"] == {"/wall_time_s": 3.0}


def test_no_sidecar_for_a_failed_run_and_one_of_its_own_outside_a_run(tmp_path):
    from gripper_env.io.files import collect_provenance, write_result_json

    with pytest.raises(RuntimeError), collect_provenance(tmp_path, "failed"):
        write_atomic(tmp_path / "partial.md", "x")
        raise RuntimeError("boom")
    assert not (tmp_path / "failed.provenance.json").exists()
    write_result_json(tmp_path / "alone.json", {"v": 1, "elapsed_s": 0.5})
    side = json.loads((tmp_path / "alone.provenance.json").read_text())
    assert side["files"] == {"alone.json": {"/elapsed_s": 0.5}} and side["date"]


def test_a_task_with_its_own_sidecar_inside_a_run(tmp_path):
    """A task's scratch folder keeps its own sidecar (sent back to the driver, which records
    its values: tuners.engine.write_files); the driver's run does not count the task's
    sidecar as one of its files."""
    from gripper_env.io.files import collect_provenance, write_result_json
    from tuners.engine import gather_files, write_files

    with collect_provenance(tmp_path / "out", "driver") as driver:
        with collect_provenance(tmp_path / "task", "task", own=True):
            write_result_json(tmp_path / "task" / "history.json", {"train_wall_time_s": 4.0})
        assert driver.written == 0
        write_files(tmp_path / "out" / "seed-0", gather_files(tmp_path / "task"))
    assert sorted(p.name for p in (tmp_path / "out").rglob("*")) == [
        "driver.provenance.json", "history.json", "seed-0"]  # fmt: skip
    side = json.loads((tmp_path / "out" / "driver.provenance.json").read_text())
    assert side["files"] == {"seed-0/history.json": {"/train_wall_time_s": 4.0}}


def test_a_figure_gives_the_same_bytes_without_version_or_date(tmp_path):
    import matplotlib.pyplot as plt
    from PIL import Image

    def draw(name):
        fig, ax = plt.subplots()
        ax.plot(np.linspace(0, 1, 50), np.sin(np.linspace(0, 6, 50)), label="sin")
        ax.fill_between([0, 1], [0, 0], [0.5, 0.5], alpha=0.2)
        ax.legend()
        return save_figure(fig, tmp_path / name, dpi=60)

    a, b = draw("a.png"), draw("b.png")
    assert a.read_bytes() == b.read_bytes()
    with Image.open(a) as im:
        assert im.mode == "P" and "Software" not in im.info  # 256 colours, no text chunk
    for suffix in (".svg", ".pdf"):
        first, second = draw(f"c{suffix}"), draw(f"d{suffix}")
        assert first.read_bytes() == second.read_bytes(), suffix


@pytest.mark.parametrize(
    "name",
    ["..", ".", "../results/test2", "/etc/passwd", "a/b", "a\\b", "nul\x00byte", "", "  ",
     "tab\tname", "-rf", "~root", "x" * 101, None, 3],
)  # fmt: skip
def test_a_name_that_is_not_one_plain_path_component_is_refused(name):
    with pytest.raises(ValueError) as info:
        safe_name(name, "plant name")
    line = str(info.value)
    assert line.startswith("plant name ") and "\n" not in line
    with pytest.raises(ValueError):
        path_in("runs", "ok", name)


@pytest.mark.parametrize("name", ["test2", "mine", "test2+test3+test4", "my gripper", "v1.2_a-b"])
def test_plain_names_pass(name, tmp_path):
    assert safe_name(name) == name
    assert path_in(tmp_path, name).parent == tmp_path


def test_files_are_written_with_the_users_umask(tmp_path, monkeypatch):
    import gripper_env.io.files as files

    mask = os.umask(0o022)
    os.umask(mask)
    assert files._UMASK == mask  # read at import
    q = write_atomic(tmp_path / "default.txt", "x")
    assert q.stat().st_mode & 0o777 == 0o666 & ~mask  # as open() makes it, not mkstemp's 0600
    monkeypatch.setattr(files, "_UMASK", 0o027)
    p = write_atomic(tmp_path / "new.txt", "x")
    assert p.stat().st_mode & 0o777 == 0o640
    os.chmod(p, 0o604)
    write_atomic(p, "y")  # a replaced file keeps its own permissions
    assert p.stat().st_mode & 0o777 == 0o604


def test_a_group_of_files_appears_whole_or_not_at_all(tmp_path):
    keep = write_atomic(tmp_path / "a.json", "old")
    with pytest.raises(RuntimeError), write_group():
        write_atomic(tmp_path / "a.json", "new")
        write_atomic(tmp_path / "b.png", b"png")
        assert keep.read_text() == "old"  # nothing visible until the block ends
        raise RuntimeError("disk full while writing the third")
    assert sorted(os.listdir(tmp_path)) == ["a.json"] and keep.read_text() == "old"
    with write_group():
        write_atomic(tmp_path / "a.json", "new")
        write_atomic(tmp_path / "b.png", b"png")
    assert sorted(os.listdir(tmp_path)) == ["a.json", "b.png"]
    assert keep.read_text() == "new"


def test_a_result_prints_as_this_run_wrote_it(tmp_path):
    """``--json`` prints the result's own text, byte for byte the file this run wrote (not the
    file read back, which a concurrent worker of the same study may have replaced: three Optuna
    workers on one journal printed each other's trial counts)."""
    from gripper_env.io.files import result_json_text, write_result_json

    result = {"tuner": "optuna", "P": 0.5, "wall_time_s": 3.2, "tuning": {"trials_this_run": 4}}
    path = write_result_json(tmp_path / "optuna.json", result)
    assert result_json_text(result) == path.read_text()
    assert "wall_time_s" not in result_json_text(result)  # volatile values go to the sidecar
    write_result_json(path, {**result, "tuning": {"trials_this_run": 16}})  # another worker
    assert '"trials_this_run": 4' in result_json_text(result)
