"""People ground truth from a bag (`bags.read_people`, a custom message type defined only in the
bag) and `jaxtrack track --gt-topic`: the replay scored against it in one step."""

import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack import geometry  # noqa: E402
from jaxtrack.io import bags, trajectories  # noqa: E402
from sims import cli  # noqa: E402

PERSON = "my_msgs/msg/TrackedPerson"
PEOPLE = "my_msgs/msg/TrackedPeople"


def _write(path, laser, people_times, people, names=False):
    """A ROS 1 bag of the laser scans and a custom people topic ``/gt`` (ids 0, 1, ... or
    names "p0", ...); people [T, P, 2], NaN rows absent."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    ident = "string name" if names else "int32 track_id"
    ts.register(get_types_from_msg(f"{ident}\ngeometry_msgs/Point position", PERSON))
    ts.register(get_types_from_msg("std_msgs/Header header\nmy_msgs/TrackedPerson[] people",
                                   PEOPLE))
    T = ts.types

    def header(t, frame):
        sec = int(t)
        return T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    with Writer(path) as w:
        scan = w.add_connection("/scan", bags.LASER_SCAN, typestore=ts)
        gt = w.add_connection("/gt", PEOPLE, typestore=ts)
        a = np.asarray(laser.angles, np.float64)
        for t, r in zip(laser.times, laser.ranges):
            msg = T[bags.LASER_SCAN](
                header=header(t, "laser"), angle_min=float(a[0]), angle_max=float(a[-1]),
                angle_increment=float(a[1] - a[0]), time_increment=0.0, scan_time=0.1,
                range_min=float(laser.range_min), range_max=float(laser.range_max),
                ranges=np.asarray(r, np.float32), intensities=np.zeros(0, np.float32))
            w.write(scan, int(round(t * 1e9)), ts.serialize_ros1(msg, bags.LASER_SCAN))
        for t, row in zip(people_times, people):
            entries = []
            for k, p in enumerate(row):
                if np.isnan(p[0]):
                    continue
                ident = {"name": f"p{k}"} if names else {"track_id": k}
                entries.append(T[PERSON](**ident, position=T["geometry_msgs/msg/Point"](
                    x=float(p[0]), y=float(p[1]), z=0.0)))
            msg = T[PEOPLE](header=header(t, "laser"), people=entries)
            w.write(gt, int(round(t * 1e9)) + 1000, ts.serialize_ros1(msg, PEOPLE))


@pytest.fixture(scope="module")
def truth(following_recording):
    """The recording's laser and its people in the (moving) robot frame, as a tracker without
    odometry reports them."""
    _, rec, (laser, _, _) = following_recording
    people = np.stack([np.asarray(geometry.to_frame(jnp.asarray(r), jnp.asarray(p)))
                       for r, p in zip(rec.robot, rec.people)])
    return laser, people


def test_read_people_from_a_message_type_only_the_bag_defines(truth, tmp_path):
    laser, people = truth
    people = people.copy()
    people[3, 1] = np.nan                             # person 1 absent at frame 3
    for names in (False, True):
        path = tmp_path / f"gt{int(names)}.bag"
        _write(path, laser, laser.times, people, names=names)
        got = bags.read_people(path, "/gt", 8)
        np.testing.assert_allclose(got.times, laser.times, atol=1e-6)
        P = people.shape[1]
        present = ~np.isnan(people[..., 0])
        assert np.array_equal(got.ids[:, :P] >= 0, np.sort(present, 1)[:, ::-1])
        for t in (0, 3, 10):
            ids = got.ids[t][got.ids[t] >= 0]
            want = np.flatnonzero(present[t])
            if names:
                assert [got.names[i] for i in ids] == [f"p{k}" for k in want]
            else:
                np.testing.assert_array_equal(ids, want)
            np.testing.assert_allclose(got.xy[t, :len(ids)], people[t, want], atol=1e-12)
    with pytest.raises(bags.BagError, match="no list of entries"):
        bags.read_people(tmp_path / "gt0.bag", "/scan", 8)
    small = bags.read_people(tmp_path / "gt0.bag", "/gt", 2)
    assert "beyond max_people=2" in small.report.detail


def test_track_scores_the_replay_against_the_bag_ground_truth(truth, tmp_path, capsys):
    laser, people = truth
    path = tmp_path / "run.bag"
    _write(path, laser, laser.times, people)
    out = tmp_path / "out"

    def argv(bag, out, *extra):
        return ["track", "--bag", str(bag), "--laser-topic", "/scan", "--detector", "geometric",
                "--estimator", "gnn", "--chunk", "16", "--gt-topic", "/gt", "--out", str(out),
                *extra]

    assert cli.main(argv(path, out)) == 0
    text = capsys.readouterr().out
    assert "MOTA" in text and "run.bag" in text
    want = trajectories.evaluate_files(out / "gt.csv", out / "tracks.csv", 0.5, "mot")
    gt = trajectories.read_mot_csv(out / "gt.csv")
    assert len(np.unique(gt.ids[gt.mask])) == people.shape[1]
    # Scored again from the files: the printed summary's row.
    line = next(ln for ln in text.splitlines() if ln.startswith("run.bag"))
    assert f"{100 * want['mota']:.1f}%" in line
    # Only the user (id 0) labelled: the other people's tracks are no longer false positives.
    only_user = people.copy()
    only_user[:, 1:] = np.nan
    _write(tmp_path / "user.bag", laser, laser.times, only_user)
    plain, target = tmp_path / "plain", tmp_path / "target"
    assert cli.main(argv(tmp_path / "user.bag", plain)) == 0
    assert cli.main(argv(tmp_path / "user.bag", target, "--target-only")) == 0
    a = trajectories.evaluate_files(plain / "gt.csv", plain / "tracks.csv", 0.5, "mot")
    b = trajectories.evaluate_files(target / "gt.csv", target / "tracks.csv", 0.5, "mot",
                                    target_only=True)
    assert b["num_false_positives"] < a["num_false_positives"]
    assert b["num_misses"] == a["num_misses"]
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(path), "--laser-topic", "/scan", "--target-only",
                  "--out", str(out)])
    assert exc.value.code == 2 and "--target-only needs --gt-topic" in capsys.readouterr().err
