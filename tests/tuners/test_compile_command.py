"""``python -m tuners.compile``: its shares cover every warm-up unit once."""

from __future__ import annotations

import pytest

from tuners.compile import COMPILE_SECONDS, _units, main, share


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_the_shares_cover_every_unit_exactly_once(n):
    names = list(_units())
    shares = [share(names, k, n) for k in range(n)]
    assert sorted(name for s in shares for name in s) == sorted(names)
    # longest first to the least loaded: no share exceeds the ideal by more than its largest
    # unit (the list-scheduling bound), and with two shares the two parallel step kernels
    # (over a minute each) land in different processes
    cost = [sum(COMPILE_SECONDS.get(m, 5.0) for m in s) for s in shares]
    biggest = max(COMPILE_SECONDS.values())
    assert max(cost) <= sum(cost) / n + biggest
    if n == 2:
        par = [k for k, s in enumerate(shares) for m in s if m.endswith("(parallel)")
               and COMPILE_SECONDS.get(m, 0) > 60]  # fmt: skip
        assert sorted(par) == [0, 1]


@pytest.mark.parametrize("argv", [["--jobs", "0"], ["--shard", "2/2"], ["--shard", "x"]])
def test_bad_jobs_or_shares_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as caught:
        main(argv)
    assert caught.value.code == 2
    assert argv[0] in capsys.readouterr().err


def test_the_compile_says_what_comes_before_it_starts_and_each_unit_as_it_is_done(monkeypatch):
    """The test run prints these lines before pytest's header (tests/conftest.py): the first
    names every unit before any runs, then one line per unit as soon as it is done."""
    import tuners.compile as compile_module

    lines: list[str] = []
    units = {name: (lambda name=name: lines.append(f"ran {name}")) for name in ("a", "b", "c")}
    monkeypatch.setattr(compile_module, "_units", lambda: units)
    compile_module.warm_up(lines.append)
    assert lines[0].startswith("  3 kernel units to compile or load: a, b, c")
    assert [line.split(":")[0].strip() for line in lines[1:]] == [
        "ran a", "[1/3] a", "ran b", "[2/3] b", "ran c", "[3/3] c",
    ]  # fmt: skip


@pytest.mark.slow
def test_a_parallel_test_run_prints_the_compile_before_pytests_header(tmp_path):
    """Issue 45: ``python -m pytest`` sat silent for 35 minutes on a fresh clone, compiling the
    kernels before pytest's header with the message after it. Run as a user runs it (xdist
    workers), the compile's lines come first, then the header."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "1", "-p", "no:cacheprovider",
         "--basetemp", str(tmp_path / "inner"), "tests/tuners/test_compile_command.py",
         "-k", "shares_cover"],
        cwd=root, env=env, capture_output=True, text=True, timeout=1800, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    first = next(i for i, x in enumerate(lines) if x.startswith("compiling the simulation"))
    ready = next(i for i, x in enumerate(lines) if x.startswith("kernels ready in "))
    units = [x for x in lines[first:ready] if x.startswith("  [")]
    assert units and first < ready
    header = next(i for i, x in enumerate(lines) if "simulation kernels compiled or loaded" in x)
    assert ready < header
