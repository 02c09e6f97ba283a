import itertools

import numpy as np
import pytest

from gripper_env.model.references import PROFILES, load_reference, random_profile


def test_step_profile():
    ref = load_reference("step")
    assert ref.dt_s == 1e-3 and len(ref) == 20000
    assert ref.values_deg[0] == 92.0 and ref.values_deg[999] == 92.0
    assert ref.values_deg[1000] == 21.0 and ref.values_deg[-1] == 92.0
    grip, ungrip = ref.segments
    assert (grip.kind, grip.start, grip.initial_deg, grip.final_deg) == ("grip", 1000, 92, 21)
    assert (ungrip.kind, ungrip.start, ungrip.stop) == ("ungrip", 10000, 20000)


@pytest.mark.parametrize("ramp", [60, 40, 20])
def test_slopes_take_their_time(ramp):
    ref = load_reference(f"slope{ramp}")
    r = ref.values_deg
    assert len(ref) == round((1 + ramp + 5 + ramp + 5) / 1e-3)
    slope = np.diff(r[1000 : 1000 + ramp * 1000])
    np.testing.assert_allclose(slope, -71.0 / (ramp * 1000), rtol=1e-9)
    assert r.min() == 21.0 and r.max() == 92.0
    assert [s.kind for s in ref.segments] == ["grip", "ungrip"]


def test_ramp3_is_figure_2():
    ref = load_reference("ramp3")
    assert ref.values_deg[1000 + 3000 - 1] == pytest.approx(21.0)
    assert ref.values_deg[1000] < 92.0


def test_csv_profile_round_trip(tmp_path):
    path = tmp_path / "prof.csv"
    path.write_text("t_s,reference_deg\n0,92\n1,92\n1.001,21\n3,21\n")
    ref = load_reference(path)
    assert len(ref) == 3001
    assert ref.values_deg[1001] == pytest.approx(21.0)
    assert ref.segments[0].kind == "grip"


def test_csv_errors(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("time,angle\n0,1\n")
    with pytest.raises(ValueError, match="needs columns 't_s'"):
        load_reference(path)
    path.write_text("t_s,desired_deg\n0,1\n0,2\n")
    with pytest.raises(ValueError, match="strictly increasing"):
        load_reference(path)
    with pytest.raises(ValueError, match="does not exist"):
        load_reference(tmp_path / "nope.csv")


def test_unknown_profile_lists_names():
    with pytest.raises(ValueError, match="unknown reference profile 'zigzag'; available: step"):
        load_reference("zigzag")
    assert set(PROFILES) == {"step", "slope60", "slope40", "slope20", "ramp3"}


def test_random_profiles_are_seeded_and_in_range():
    a = random_profile(3, duration_s=20.0)
    b = random_profile(3, duration_s=20.0)
    c = random_profile(4, duration_s=20.0)
    np.testing.assert_array_equal(a.values_deg, b.values_deg)
    assert not np.array_equal(a.values_deg, c.values_deg)
    assert len(a) == 20000
    assert a.values_deg.min() >= 21.0 and a.values_deg.max() <= 92.0
    kinds = [s.kind for s in a.segments]
    assert kinds[0] == "grip" and all(k1 != k2 for k1, k2 in itertools.pairwise(kinds))


def test_a_run_of_more_than_a_million_physics_steps_is_refused_before_it_is_built():
    from gripper_env.model.references import MAX_STEPS_PER_RUN, step_profile

    assert len(step_profile(dt_s=20.0 / MAX_STEPS_PER_RUN)) == MAX_STEPS_PER_RUN
    with pytest.raises(ValueError, match=r"2e\+10 physics steps.*dt_s >= 2e-05 s"):
        step_profile(dt_s=1e-9)
    with pytest.raises(ValueError, match="reference 'slope60' lasts 131 s"):
        load_reference("slope60", 1e-5)
    with pytest.raises(ValueError, match="random reference"):
        random_profile(0, duration_s=1e4, dt_s=1e-3)
