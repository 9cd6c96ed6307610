import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from evpose.core.data.clock import ClockModel
from evpose.core.data.geometry import rotation_angle
from evpose.core.data.trajectory import Trajectory, TrajectoryError


def make_traj(n=20, seed=0, t0=0, dt=10_000):
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n, dtype=np.int64) * dt
    pos = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    q = Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.2, size=(n, 3)), axis=0)).as_quat()
    return Trajectory(t, pos, q)


def test_slerp_matches_scipy_and_lerp():
    tr = make_traj()
    tq = np.sort(np.random.default_rng(1).integers(0, 190_000, 500))
    T, valid = tr.interpolate(tq)
    assert valid.all()
    ref = Slerp(tr.t_us.astype(float), Rotation.from_quat(tr.quats_xyzw))(tq.astype(float)).as_matrix()
    np.testing.assert_allclose(T[:, :3, :3], ref, atol=1e-12)
    for k in (0, 7, 499):
        i = np.searchsorted(tr.t_us, tq[k], side="right") - 1
        a = (tq[k] - tr.t_us[i]) / (tr.t_us[i + 1] - tr.t_us[i])
        np.testing.assert_allclose(T[k, :3, 3], (1 - a) * tr.positions_m[i] + a * tr.positions_m[i + 1], atol=1e-15)


def test_samples_are_reproduced_exactly_at_their_times():
    tr = make_traj()
    T, valid = tr.interpolate(tr.t_us)
    assert valid.all()
    np.testing.assert_allclose(T, tr.T(), atol=1e-12)


def test_no_extrapolation_and_no_nan():
    tr = make_traj()
    T, valid = tr.interpolate(np.array([-1, 0, 190_000, 190_001, 10**9]))
    assert valid.tolist() == [False, True, True, False, False]
    assert np.all(np.isfinite(T))
    np.testing.assert_array_equal(T[~valid], np.broadcast_to(np.eye(4), (3, 4, 4)))


def test_antipodal_and_nonunit_quaternions():
    q = Rotation.from_rotvec([[0, 0, 0.1], [0, 0, 0.3]]).as_quat()
    q_flip = q.copy()
    q_flip[1] *= -3.0  # antipodal and non-unit: the same rotation
    tr = Trajectory(np.array([0, 1000]), np.zeros((2, 3)), q_flip)
    assert any("normalised" in n for n in tr.notes)
    T, _ = tr.interpolate(np.array([500]))
    assert rotation_angle(T[0, :3, :3]) == pytest.approx(0.2, abs=1e-12)  # shortest path, not the long way


def test_180_degree_turn_between_samples_stays_a_rotation():
    q = Rotation.from_rotvec([[0, 0, 0], [0, 0, np.pi]]).as_quat()
    tr = Trajectory(np.array([0, 1000]), np.zeros((2, 3)), q)
    T, valid = tr.interpolate(np.arange(0, 1001, 100))
    assert valid.all()
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(rotation_angle(R), np.linspace(0, np.pi, 11), atol=1e-9)


def test_identical_quaternions_interpolate_constant():
    q = np.tile(Rotation.from_rotvec([0.3, 0.2, 0.1]).as_quat(), (2, 1))
    tr = Trajectory(np.array([0, 1000]), np.zeros((2, 3)), q)
    T, _ = tr.interpolate(np.arange(0, 1001, 250))
    np.testing.assert_allclose(T[:, :3, :3], np.broadcast_to(Rotation.from_quat(q[0]).as_matrix(), (5, 3, 3)), atol=1e-12)


def test_duplicate_and_decreasing_timestamps():
    q = np.tile([0, 0, 0, 1.0], (4, 1))
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    # exact duplicate sample: dropped silently (noted)
    tr = Trajectory(np.array([0, 10, 10, 20]), pos, q)
    assert len(tr) == 3 and tr.notes
    # conflicting duplicate: error naming the row unless repair
    pos2 = pos.copy()
    pos2[2, 0] = 1.5
    with pytest.raises(TrajectoryError, match="t_us.*row 2"):
        Trajectory(np.array([0, 10, 10, 20]), pos2, q, source="traj.csv")
    tr = Trajectory(np.array([0, 10, 10, 20]), pos2, q, repair=True)
    assert len(tr) == 3 and tr.positions_m[1, 0] == 1.5  # kept the last
    with pytest.raises(TrajectoryError, match="decreases"):
        Trajectory(np.array([0, 20, 10, 30]), pos, q)
    tr = Trajectory(np.array([0, 20, 10, 30]), pos, q, repair=True)
    assert np.all(np.diff(tr.t_us) > 0)


def test_bad_values_are_named():
    q = np.tile([0, 0, 0, 1.0], (2, 1))
    with pytest.raises(TrajectoryError, match="zero quaternion"):
        Trajectory(np.array([0, 1]), np.zeros((2, 3)), np.zeros((2, 4)))
    pos = np.zeros((2, 3))
    pos[1, 2] = np.inf
    with pytest.raises(TrajectoryError, match="z: row 1"):
        Trajectory(np.array([0, 1]), pos, q)
    with pytest.raises(TrajectoryError, match="no samples"):
        Trajectory(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 4)))


def test_single_sample_is_valid_only_at_its_time():
    tr = Trajectory(np.array([5]), np.ones((1, 3)), np.array([[0, 0, 0, 1.0]]))
    T, valid = tr.interpolate(np.array([4, 5, 6]))
    assert valid.tolist() == [False, True, False]
    assert T[1, 0, 3] == 1.0


def test_csv_roundtrip_exact(tmp_path):
    tr = make_traj(t0=1_600_000_000_000_000)  # epoch microseconds
    p = tr.save_csv(tmp_path / "traj.csv")
    back = Trajectory.load_csv(p)
    np.testing.assert_array_equal(back.t_us, tr.t_us)
    np.testing.assert_array_equal(back.positions_m, tr.positions_m)
    np.testing.assert_array_equal(back.quats_xyzw, tr.quats_xyzw)


def test_csv_errors_name_file_line_and_field(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("t_us,x,y,z,qx,qy,qz\n")
    with pytest.raises(TrajectoryError, match="t.csv: header: missing column.*qw"):
        Trajectory.load_csv(p)
    p.write_text("t_us,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n10,0,abc,0,0,0,0,1\n")
    with pytest.raises(TrajectoryError, match="t.csv: line 3: y: not a number"):
        Trajectory.load_csv(p)
    with pytest.raises(TrajectoryError, match="cannot open"):
        Trajectory.load_csv(tmp_path / "missing.csv")


def test_clock_model_epoch_precision_and_skew():
    t_ref = 1_700_000_000_000_000
    clock = ClockModel(offset_us=-120_000, skew_ppm=1000.0, t_ref_us=t_ref)
    t = np.array([t_ref, t_ref + 10_000_000])
    tp = clock.pose_time(t)
    assert tp[0] == t_ref - 120_000
    assert tp[1] == t_ref + 10_000_000 - 120_000 + 10_000  # 1000 ppm of 10 s = 10 ms
    np.testing.assert_array_equal(clock.event_time(tp), t)
    rel = clock.pose_time_rel(t, origin_us=t_ref)
    np.testing.assert_allclose(rel, [-120_000.0, 9_890_000.0], atol=1e-6)


def test_at_event_time_shifts_by_offset():
    tr = make_traj()
    clock = ClockModel(offset_us=5_000, t_ref_us=0)
    T1, v1 = tr.at_event_time(np.array([20_000]), clock)
    T2, v2 = tr.interpolate(np.array([25_000]))
    np.testing.assert_allclose(T1, T2, atol=1e-12)
    _, v = tr.at_event_time(np.array([188_000]), clock)
    assert not v[0]  # pose time 193 ms beyond the last sample (190 ms)


def test_speed_piecewise_constant():
    t = np.array([0, 1_000_000, 2_000_000])
    pos = np.array([[0, 0, 0], [0.5, 0, 0], [0.5, 0, 0.0]])
    q = Rotation.from_rotvec([[0, 0, 0], [0, 0, 0], [0, 0, 1.0]]).as_quat()
    tr = Trajectory(t, pos, q)
    v, w, valid = tr.speed(np.array([500_000, 1_500_000, 3_000_000]))
    np.testing.assert_allclose(v, [0.5, 0.0, 0.0])
    np.testing.assert_allclose(w, [0.0, 1.0, 0.0])
    assert valid.tolist() == [True, True, False]
