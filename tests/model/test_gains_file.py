"""The gains file format (``gripper_env.model.gains_file``): round trip, nulls, refusals, old
versions."""

import json

import pytest

from gripper_env.evaluation.objective import load_objective
from gripper_env.io.files import write_json
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.gains_file import (
    FORMAT_VERSION,
    GainsFileError,
    build_gains_file,
    load_gains_file,
)
from gripper_env.model.pid import GraspOptions, PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from tuners.evaluation import evaluate

ACTUAL, IDEAL = load_disturbance("actual"), load_disturbance("ideal")
OBJECTIVE = load_objective()


def _content(plant="test2", gains=None, sign=1):
    gains = gains or PIDGains(1.0, 9.0, -0.001)
    opts = PIDOptions(output_limits=(0.0, 180.0), sign=sign)
    p = load_plant(plant)
    ev = evaluate(
        p, gains, opts, profile=load_reference("step", p.dt_s), disturbance=ACTUAL, ideal=IDEAL,
        objective=OBJECTIVE, seeds=[100000, 100001],
    )  # fmt: skip
    return build_gains_file(
        plant=plant,
        tuner="manual",
        gains=gains,
        options=opts,
        evaluation=ev,
        evaluation_settings={"profile": "step"},
    )


def test_round_trip(tmp_path):
    content = _content(sign=-1, gains=PIDGains(-0.5, -3.6, 0.000186))
    path = write_json(tmp_path / "g.json", content)
    loaded = load_gains_file(path)
    assert loaded.gains == PIDGains(-0.5, -3.6, 0.000186, 100.0)
    assert loaded.options.sign == -1 and loaded.options.output_limits == (0.0, 180.0)
    assert content["sign_convention"] == "e = y - r"
    for model in ("ideal",):
        m = content["metrics"][model]
        assert set(m["grip"]) >= {
            "overshoot_pct",
            "rise_time_s",
            "settling_time_s",
            "steady_state_error_deg",
        }
        assert set(m) >= {
            "sd_deg",
            "sd_gap_deg",
            "iae",
            "ise",
            "itae",
            "control_effort",
            "servo_effort_deg",
            "stall_s",
            "stable",
            "cost",
        }
    assert set(content["metrics"]["actual"]) >= {"mean", "std", "ci95_low", "ci95_high"}
    rb = content["robustness"]
    assert rb["refresh_period_s"] == pytest.approx(0.020) and "loop_1ms" in rb
    assert rb["meets_constraints"] in (True, False) and rb["constraints"]["ms_max"] == 1.6
    assert not list(tmp_path.glob(".*tmp"))  # no temporary file left behind


def test_unreachable_values_are_written_as_null(tmp_path):
    # test1 is slow (time constant ~20 s): a weak P never settles inside the 20 s step profile
    content = _content("test1", PIDGains(0.2, 0.0, 0.0))
    path = write_json(tmp_path / "g.json", content)
    text = path.read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text)["metrics"]["ideal"]["grip"]["settling_time_s"] is None


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"format_version": FORMAT_VERSION + 1}, "format version"),
        ({"format_version": 0}, "format version"),
        ({"format": "something-else"}, "not a gains file"),
        ({"P": "one"}, "'P' must be a finite number"),
        ({"P": None}, "'P' must be a finite number"),
        ({"sign": 3}, "sign"),
        ({"limits": {"grasp": 1.0}}, "limits.grasp must be null or a mapping"),
        ({"limits": {"grasp": {"squeez_deg": 1.0}}}, r"unknown keys \['squeez_deg'\]"),
        ({"limits": {"grasp": {"squeeze_deg": -1.0}}}, "squeeze_deg must be finite and > 0"),
    ],
)
def test_bad_files_are_refused(tmp_path, patch, message):
    content = {
        "format": "gripper-gains",
        "format_version": FORMAT_VERSION,
        "P": 1.0,
        "I": 9.0,
        "D": -0.001,
        "N": 100.0,
        "sign": 1,
    }
    content.update(patch)
    path = tmp_path / "g.json"
    path.write_text(json.dumps(content))
    with pytest.raises(GainsFileError, match=message):
        load_gains_file(path)


def test_not_json_and_missing(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(GainsFileError, match="not valid JSON"):
        load_gains_file(tmp_path / "bad.json")
    with pytest.raises(GainsFileError, match="cannot read"):
        load_gains_file(tmp_path / "missing.json")


def test_version_1_files_still_load(tmp_path):
    """Gains files written before the robustness block (format 1) are still read."""
    path = tmp_path / "old.json"
    path.write_text(
        json.dumps(
            {
                "format": "gripper-gains",
                "format_version": 1,
                "P": 1.0,
                "I": 9.0,
                "D": -0.001,
                "N": 100.0,
                "sign": 1,
                "stability": {"stable": True},
            }
        )
    )
    assert load_gains_file(path).gains == PIDGains(1.0, 9.0, -0.001, 100.0)


def test_the_grasp_mode_is_written_and_read_back(tmp_path):
    """``limits.grasp``: the mode's settings, or null for none; a file from before the mode
    (no key) gets the default mode."""
    content = _content()
    assert content["limits"]["grasp"] == GraspOptions().as_dict()
    assert load_gains_file(write_json(tmp_path / "on.json", content)).options.grasp == (
        GraspOptions()
    )
    content["limits"]["grasp"] = {"squeeze_deg": 0.5, "dwell_s": 0.05}
    loaded = load_gains_file(write_json(tmp_path / "own.json", content)).options.grasp
    assert loaded == GraspOptions(squeeze_deg=0.5, dwell_s=0.05)
    content["limits"]["grasp"] = None
    assert load_gains_file(write_json(tmp_path / "off.json", content)).options.grasp is None
    del content["limits"]["grasp"]
    assert load_gains_file(write_json(tmp_path / "old.json", content)).options.grasp == (
        GraspOptions()
    )
