"""The one atomic writer and JSON helper (``gripper_env.files``)."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from gripper_env.files import json_ready, write_atomic, write_json


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
