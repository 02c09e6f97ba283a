"""Hostile input to every command a user runs: each case is refused with exit status 2 and one
line on stderr that names the input, no traceback, under a 1 GiB address-space limit (a run
that tried to allocate gigabytes would die with a MemoryError traceback instead).

The commands run as real processes, a few at a time; the time limit is only a guard against a
hang (a refusal takes a few seconds, nearly all of it importing the package).
"""

import importlib.util
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from gripper_env.model.gains_file import FORMAT, FORMAT_VERSION

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Address-space limit of each command (bytes). A normal refusal needs about 0.5 GiB of address
#: space (numba and LLVM reserve some); the issue's tiny-dt run asked for 7.45 GiB.
MEMORY_LIMIT = 1 << 30
HANG_GUARD_S = 90
#: Commands running at once.
CONCURRENCY = 3
#: Sets the memory limit inside the command's own process, then runs the module as ``-m`` would.
LAUNCHER = (
    "import resource, runpy, sys; n = int(sys.argv[1]); "
    "resource.setrlimit(resource.RLIMIT_AS, (n, n)); "
    "sys.argv = [sys.argv[2], *sys.argv[3:]]; "
    "runpy.run_module(sys.argv[0], run_name='__main__', alter_sys=True)"
)


@dataclass(frozen=True)
class Case:
    """One hostile input: the command, and what its one line must name."""

    name: str
    module: str
    args: tuple[str, ...]
    names: tuple[str, ...]


CASES = [
    Case("plant dt_s 1e-9", "tuners.manual",
         ("--plant", "{tiny_dt}", "--gains", "paper-tuned"), ("tiny_dt.yaml", "dt_s")),
    Case("13 million physics steps per run", "tuners.manual",
         ("--plant", "{fine_dt}", "--gains", "paper-tuned", "--profile", "slope60"),
         ("slope60", "dt_s", "physics steps")),
    Case("reference CSV of 100,000 s", "tuners.optuna",
         ("--plant", "test2", "--profile", "{long_csv}"), ("long.csv", "physics steps")),
    Case("10,000 [ as --plant", "tuners.manual",
         ("--plant", "{brackets}", "--gains", "paper-tuned"), ("brackets.yaml",)),
    Case("3,000-level mapping as --config", "tuners.classical",
         ("--plant", "test2", "--config", "{mapping}"), ("mapping.yaml", "nested deeper")),
    Case("3,000-level list as --plant", "tuners.rl",
         ("train", "--plant", "{dashes}"), ("dashes.yaml", "nested deeper")),
    Case("50 MB YAML as --config", "tuners.optuna",
         ("--plant", "test2", "--config", "{huge_yaml}"), ("huge.yaml", "MiB")),
    Case("billion laughs as --config", "tuners.benchmark",
         ("--config", "{laughs}"), ("laughs.yaml", "values")),
    Case("3,000-level list as --base", "tuners.sysid",
         ("greybox", "{small_log}", "--base", "{dashes}"), ("dashes.yaml", "nested deeper")),
    Case("40 MiB log", "tuners.sysid", ("tf", "{huge_csv}"), ("huge.csv", "MiB")),
    Case("--out naming a file", "tuners.manual",
         ("--plant", "test2", "--gains", "paper-tuned", "--out", "{a_file}"), ("--out", "a_file")),
    Case("--gains 1e308", "tuners.manual",
         ("--plant", "test2", "--gains", "1e308,1,0"), ("--gains", "P = 1e+308")),
    Case("gains file with P = 1e308", "tuners.rig.deploy",
         ("--gains", "{gains_1e308}", "--port", "/no/such/port", "--boot-wait", "0"),
         ("gains_1e308.json", "P = 1e+308")),
    Case("gains file nested 100,000 deep", "tuners.manual",
         ("--plant", "test2", "--gains", "{deep_json}"), ("deep.json", "nested")),
    Case("--trials 1e12", "tuners.optuna",
         ("--plant", "test2", "--trials", "1000000000000"), ("--trials",)),
    Case("--search-seeds 1e6", "tuners.optuna",
         ("--plant", "test2", "--search-seeds", "1000000"), ("--search-seeds",)),
    Case("open-loop-unstable plant", "tuners.classical",
         ("--plant", "{unstable}"), ("'unstable'", "not open-loop stable")),
    # names from files never become paths (gripper_env.io.files.safe_name)
    Case("plant named ../results/test2", "tuners.manual",
         ("--plant", "{climbing}", "--gains", "paper-tuned"), ("plant name", "../results/test2")),
    Case("plant with an absolute name", "tuners.optuna",
         ("--plant", "{absolute}", "--trials", "4"), ("plant name", "/tmp/gripper-absolute")),
    Case("plant name with a NUL", "tuners.classical",
         ("--plant", "{nul_name}"), ("plant name", "\\x00")),
    Case("gains file whose tuner climbs folders", "tuners.rig.deploy",
         ("--gains", "{climbing_gains}", "--port", "/no/such/port", "--boot-wait", "0"),
         ("tuner", "../../../outside")),
    Case("--name climbing out of the configurations", "tuners.sysid",
         ("greybox", "{small_log}", "--name", "../../outside", "--save-plant"), ("--name",)),
    Case("--plant NUL", "tuners.manual",
         ("--plant", "te\x01st", "--gains", "paper-tuned"), ("--plant",)),
    # every input that sizes memory or work is capped before it is read
    Case("a log that never ends (/dev/zero)", "tuners.sysid",
         ("tf", "/dev/zero"), ("/dev/zero", "character device")),
    Case("a gains file that never ends", "tuners.rig.deploy",
         ("--gains", "/dev/zero", "--port", "/no/such/port", "--boot-wait", "0"),
         ("/dev/zero", "character device")),
    # issue 45: devices and named pipes refused from their stat, before they are opened (a FIFO
    # blocks its reader until a writer comes); storages, calibrations, logs, agents, lists
    Case("--storage /dev/zero", "tuners.optuna",
         ("--plant", "test2", "--storage", "/dev/zero"), ("--storage", "/dev/zero", "device")),
    Case("a FIFO as --storage", "tuners.optuna",
         ("--plant", "test2", "--storage", "{fifo}"), ("--storage", "fifo", "named pipe")),
    Case("a FIFO as --storage sqlite", "tuners.optuna",
         ("--plant", "test2", "--storage", "sqlite:///{fifo}"),
         ("--storage", "fifo", "named pipe")),
    Case("a 300 MiB journal as --storage", "tuners.optuna",
         ("--plant", "test2", "--storage", "{big_journal}"),
         ("--storage", "big.journal", "300 MiB", "256 MiB")),
    Case("greybox /dev/zero", "tuners.sysid", ("greybox", "/dev/zero"), ("/dev/zero", "device")),
    Case("a FIFO as a log", "tuners.sysid", ("greybox", "{fifo}"), ("fifo", "named pipe")),
    Case("--calibration /dev/zero", "tuners.rig.deploy",
         ("--gains", "{good_gains}", "--calibration", "/dev/zero", "--port", "/no/such/port",
          "--boot-wait", "0"), ("--calibration", "/dev/zero", "device")),
    Case("a FIFO as --calibration", "tuners.rig.record",
         ("--calibration", "{fifo}", "--port", "/no/such/port", "--boot-wait", "0",
          "--output", "{out_csv}"), ("--calibration", "fifo", "named pipe")),
    Case("rl play /dev/zero", "tuners.rl", ("play", "/dev/zero"), ("/dev/zero",)),
    Case("an agent whose model is a FIFO", "tuners.rl", ("play", "{fifo_agent}"),
         ("fifo_agent",)),
    Case("--plants with 2001 names", "tuners.classical",
         ("--plant", "test2", "--plants", ",".join(["test2"] * 2001)), ("--plants", "2001", "16")),
    Case("--gains /dev/zero", "tuners.manual",
         ("--plant", "test2", "--gains", "/dev/zero"), ("--gains", "/dev/zero")),
    Case("--seeds 0-1000000000", "tuners.rl",
         ("train", "--plant", "test2", "--seeds", "0-1000000000"), ("--seeds", "at most")),
    Case("--seeds 1e8 paper", "tuners.paper", ("--seeds", "100000000"), ("--seeds",)),
    Case("--timesteps 1e15", "tuners.rl",
         ("controller", "--plant", "test2", "--timesteps", "1000000000000000"), ("--timesteps",)),
    Case("--tf-records 1e9", "tuners.sysid",
         ("coverage", "--tf-records", "1000000000"), ("--tf-records",)),
    # checked before the work, named as given
    Case("--engine junk", "tuners.benchmark",
         ("--quick", "--engine", "junk"), ("--engine", "junk")),
    Case("a folder as --config", "tuners.optuna",
         ("--plant", "test2", "--config", "{a_folder}"), ("a_folder", "folder")),
    Case("a folder as --plant", "tuners.manual",
         ("--plant", "{a_folder}/", "--gains", "paper-tuned"), ("a_folder", "folder")),
    Case("--save-trajectory in a file's place", "tuners.manual",
         ("--plant", "test2", "--gains", "paper-tuned", "--save-trajectory",
          "{a_file}/run.csv"), ("--save-trajectory", "a_file")),
]  # fmt: skip

#: The commands that take ``--out`` (the tuners, the benchmark, the paper).
TUNING = {"tuners.manual", "tuners.classical", "tuners.optuna", "tuners.rl", "tuners.benchmark",
          "tuners.paper"}  # fmt: skip


def _files(folder):
    """The hostile files, by the keys the cases use."""
    paths = {}

    def write(key, name, text):
        paths[key] = p = folder / name
        p.write_text(text)
        return p

    tf = "num: [20.7, 0.002852]\nden: [2.0, 20.68, 0.003084]\n"
    write("tiny_dt", "tiny_dt.yaml", f"name: tiny_dt\n{tf}dt_s: 1.0e-9\n")
    write("fine_dt", "fine_dt.yaml", f"name: fine_dt\n{tf}dt_s: 1.0e-5\n")
    write("unstable", "unstable.yaml", "name: unstable\nnum: [1.0]\nden: [1.0, -1.0]\n")
    write("long_csv", "long.csv", "t_s,reference_deg\n0,92\n100000,21\n")
    write("brackets", "brackets.yaml", "[" * 10_000)
    write("mapping", "mapping.yaml", "{a: " * 3000 + "1" + "}" * 3000)
    write("dashes", "dashes.yaml", "- " * 3000 + "1\n")
    laughs = ['a: &a ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        laughs.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    write("laughs", "laughs.yaml", "\n".join(laughs) + "\n")
    with write("huge_yaml", "huge.yaml", "plants: [").open("r+b") as f:
        f.truncate(50_000_000)  # sparse: 50 MB that cost no disk
    with write("huge_csv", "huge.csv", "t_s,desired_deg,actual_deg\n").open("r+b") as f:
        f.truncate(40 << 20)
    write("small_log", "small.csv", "t_s,desired_deg,actual_deg\n0,92,92\n0.001,92,92\n")
    write("a_file", "a_file", "not a folder\n")
    paths["a_folder"] = folder / "a_folder"
    paths["a_folder"].mkdir()
    write("climbing", "climbing.yaml", f"name: ../results/test2\n{tf}")
    write("absolute", "absolute.yaml", f"name: /tmp/gripper-absolute\n{tf}")
    write("nul_name", "nul_name.yaml", f'name: "a\\0b"\n{tf}')
    climbing = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "plant": "test2",
        "tuner": "../../../outside",
        "P": 1.0,
        "I": 9.0,
        "D": -0.001,
        "N": 100.0,
    }
    write("climbing_gains", "climbing_gains.json", json.dumps(climbing))
    gains = {"format": FORMAT, "format_version": FORMAT_VERSION, "plant": "test2",
             "tuner": "manual", "P": 1e308, "I": 1.0, "D": 0.0, "N": 100.0}  # fmt: skip
    write("gains_1e308", "gains_1e308.json", json.dumps(gains))
    write("deep_json", "deep.json", "[" * 100_000 + "]" * 100_000)
    paths["fifo"] = folder / "fifo"
    os.mkfifo(paths["fifo"])
    with write("big_journal", "big.journal", "").open("r+b") as f:
        f.truncate(300 << 20)  # sparse
    good = {**gains, "P": 1.0, "I": 9.0, "D": -0.001}
    write("good_gains", "good_gains.json", json.dumps(good))
    paths["out_csv"] = folder / "runs" / "record.csv"
    paths["fifo_agent"] = agent = folder / "fifo_agent"
    agent.mkdir()
    (agent / "agent.json").write_text(json.dumps({"format": "gripper-agent"}))
    os.mkfifo(agent / "model.zip")
    return paths


@dataclass
class Outcome:
    returncode: int
    stderr: str
    seconds: float


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """Every case run as a command, ``CONCURRENCY`` at a time: their outcomes by name."""
    folder = tmp_path_factory.mktemp("hostile")
    files = _files(folder)
    out = folder / "runs"
    cwd = folder / "cwd"  # where a default output would land (runs/...): must stay empty
    cwd.mkdir()
    inputs = set(folder.rglob("*"))
    status = _repo_status()
    env = dict(os.environ, MPLBACKEND="Agg")
    results, queue, running = {}, list(CASES), []
    while queue or running:
        while queue and len(running) < CONCURRENCY:
            case = queue.pop(0)
            args = [a.format(**files) for a in case.args]
            if case.module in TUNING and "--out" not in args:  # nothing lands in the checkout
                args += ["--out", str(out)]
            err = (folder / f"{len(results) + len(running)}.err").open("w+")
            cmd = [sys.executable, "-c", LAUNCHER, str(MEMORY_LIMIT), case.module, *args]
            proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err)
            running.append((case, proc, err, time.monotonic()))
        case, proc, err, started = running.pop(0)
        try:
            proc.wait(timeout=HANG_GUARD_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        seconds = time.monotonic() - started
        err.seek(0)
        results[case.name] = Outcome(proc.returncode, err.read(), seconds)
        err.close()
    written = {
        str(p.relative_to(folder)) for p in set(folder.rglob("*")) - inputs
        if not p.name.endswith(".err") and out not in p.parents and p != out
    }  # fmt: skip
    outside = sorted(written) + [str(p) for p in (Path("/tmp/gripper-absolute"),) if p.exists()]
    if _repo_status() != status:
        outside.append("the checkout's git status changed")
    return results, outside


def _repo_status() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=REPO,
                          capture_output=True, text=True, check=False).stdout  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_refused_in_one_line_naming_the_input(case, outcomes):
    if case.module == "tuners.rl" and importlib.util.find_spec("stable_baselines3") is None:
        pytest.skip("tuners.rl needs the rl extra: pip install -e '.[rl]'")
    got = outcomes[0][case.name]
    lines = got.stderr.strip().splitlines()
    assert got.returncode == 2, got.stderr[-2000:]
    assert "Traceback" not in got.stderr
    assert len(lines) == 1, got.stderr[-2000:]
    assert "error" in lines[0]
    for name in case.names:
        assert name in lines[0], lines[0]


def test_nothing_is_written_outside_out(outcomes):
    assert outcomes[1] == [], outcomes[1]


@pytest.mark.parametrize("kind", ["not a directory", "file exists", "permission denied"])
def test_any_os_error_is_one_line_naming_the_path(tmp_path, capsys, kind):
    """A path that cannot be written after the inputs were checked (a file made by another
    process meanwhile, permissions): ``tuners.cli.run`` prints the path and the reason."""
    from tuners import cli

    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    under = a_file / "test2"
    error, line = {
        "not a directory": (NotADirectoryError(20, "Not a directory", str(under)),
                            f"{under}: Not a directory"),
        "file exists": (FileExistsError(17, "File exists", str(a_file)),
                        f"{a_file}: exists and is not a folder"),
        "permission denied": (PermissionError(13, "Permission denied", "/results/x.json"),
                              "/results/x.json: Permission denied"),
    }[kind]  # fmt: skip

    def main(argv):
        raise error

    assert cli.run(main, []) == 2
    assert capsys.readouterr().err == f"error: {line}\n"


def _run_command(module, *args, cwd):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600, check=False)  # fmt: skip


def _one_line_no_space(proc):
    lines = proc.stderr.strip().splitlines()
    compile_note = [x for x in lines if x.startswith("compiling the simulation kernels")]
    lines = [x for x in lines if x not in compile_note]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(lines) == 1 and "No space left on device" in lines[0], proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_a_full_disk_leaves_a_result_whole_or_not_at_all(small_disk, filled, tmp_path):
    """The gains file and its plot are written together or not at all: a full disk leaves
    neither (nor a temporary file), and says so in one line."""
    disk = small_disk(512)
    filled(disk, leave_bytes=16 * 1024)  # room for the JSON, not for the plot
    proc = _run_command("tuners.manual", "--plant", "test2", "--gains", "paper-tuned",
                        "--out", disk, cwd=tmp_path)  # fmt: skip
    _one_line_no_space(proc)
    assert sorted(p.name for p in disk.rglob("*") if p.is_file()) == ["filler"]
    assert list(tmp_path.iterdir()) == [disk]  # nothing beside --out (no runs/ in the cwd)


@pytest.mark.slow
def test_a_result_its_plot_and_its_provenance_are_written_together(small_disk, tmp_path):
    """Issue 45: on an 80 KiB disk the gains file (18 KB) and its plot (59 KB) fit and their
    provenance sidecar did not, and the two were left without it; now none of the three is
    written, and the one line names the file that did not fit."""
    disk = small_disk(80)
    proc = _run_command("tuners.manual", "--plant", "test2", "--gains", "paper-tuned",
                        "--out", disk, cwd=tmp_path)  # fmt: skip
    _one_line_no_space(proc)
    assert str(disk) in proc.stderr
    assert [p for p in disk.rglob("*") if p.is_file()] == []


@pytest.mark.slow
def test_a_full_disk_under_sqlite_is_one_line_naming_the_storage(small_disk, filled, tmp_path):
    """Issue 45: SQLite's "database or disk is full" reached the user as 69 lines of three
    chained tracebacks (Optuna's StorageInternalError), naming neither the disk nor the file.
    Now one line names the storage and the disk's free space, and the trials finished before
    stay in the database, readable by Optuna."""
    import optuna

    disk = small_disk(1024)
    filled(disk, leave_bytes=360 * 1024)
    url = f"sqlite:///{disk}/study.db"
    proc = _run_command("tuners.optuna", "--plant", "test2", "--trials", "2000",
                        "--search-seeds", "1", "--out", disk, "--storage", url, "--no-progress",
                        cwd=tmp_path)  # fmt: skip
    lines = [x for x in proc.stderr.strip().splitlines() if not x.startswith("compiling the")]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert len(lines) == 1 and f"--storage {url}: " in lines[0], proc.stderr[-3000:]
    assert "disk is full" in lines[0] and f"{disk}: " in lines[0]
    (summary,) = optuna.get_all_study_summaries(url)
    assert summary.n_trials >= 1
    assert not (disk / "test2" / "optuna.json").exists()


@pytest.mark.slow
def test_a_full_disk_keeps_the_optuna_journal_readable(small_disk, filled, tmp_path):
    """The studies' journal on a disk that fills during the search: one line, exit 2, and the
    journal stays readable by Optuna itself, every record whole; with room again, the same
    command resumes the study."""
    import optuna
    from optuna.storages.journal import JournalFileBackend

    disk = small_disk(512)
    args = ["--plant", "test2", "--trials", "24", "--search-seeds", "1", "--out", disk,
            "--no-progress"]  # fmt: skip
    filler = filled(disk, leave_bytes=12 * 1024)  # a few trials' records, then none
    proc = _run_command("tuners.optuna", *args, cwd=tmp_path)
    _one_line_no_space(proc)
    assert list(tmp_path.iterdir()) == [disk]  # nothing beside --out (no runs/ in the cwd)
    journal = disk / "optuna.journal"
    assert journal.read_bytes().endswith(b"\n")
    storage = optuna.storages.JournalStorage(JournalFileBackend(str(journal)))
    (summary,) = optuna.get_all_study_summaries(storage)
    assert summary.n_trials >= 1
    filler.unlink()
    proc = _run_command("tuners.optuna", *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    study = optuna.load_study(storage=storage, study_name=summary.study_name)
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(done) == 24
