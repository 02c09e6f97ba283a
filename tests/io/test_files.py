"""The one atomic writer and JSON helper (``gripper_env.io.files``)."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from gripper_env.io.files import (
    json_ready,
    read_format_json,
    save_figure,
    write_atomic,
    write_csv,
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


def test_save_figure_with_a_palette_is_smaller_and_refuses_other_formats(tmp_path):
    import matplotlib.pyplot as plt
    from PIL import Image

    def figure():
        fig, ax = plt.subplots()
        x = np.linspace(0, 20, 4000)
        ax.plot(x, np.sin(x) + 0.05 * np.random.default_rng(0).standard_normal(x.size))
        ax.fill_between(x, np.sin(x) - 0.3, np.sin(x) + 0.3, alpha=0.3)
        return fig

    full = save_figure(figure(), tmp_path / "full.png")
    small = save_figure(figure(), tmp_path / "small.png", colors=256)
    with Image.open(small) as image:
        assert image.mode == "P" and image.size == Image.open(full).size
    assert small.stat().st_size < 0.7 * full.stat().st_size
    for name, colors in (("f.svg", 256), ("f.png", 1), ("f.png", 257)):
        fig = figure()
        with pytest.raises(ValueError, match="palette of 2 to 256"):
            save_figure(fig, tmp_path / name, colors=colors)
        assert not plt.fignum_exists(fig.number)
    assert sorted(os.listdir(tmp_path)) == ["full.png", "small.png"]


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
