"""Odometry from a bag's transform tree (`bags.read_tf`): a chain of a moving and static links,
frame names with and without a leading slash, either direction, against closed-form poses."""

import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack.io import bags  # noqa: E402


def _tf_bag(path, slash: str):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    msgtype = "tf2_msgs/msg/TFMessage"
    if msgtype not in ts.types:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", msgtype))
    T = ts.types

    def stamped(t, parent, child, x, y, yaw):
        sec = int(t)
        return T["geometry_msgs/msg/TransformStamped"](
            header=T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=slash + parent),
            child_frame_id=slash + child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.3),
                rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                           w=math.cos(yaw / 2))))

    times = 100.0 + 0.1 * np.arange(20)
    robot = np.stack([0.5 * (times - 100), 0.2 * (times - 100) ** 2, 0.3 * (times - 100)], -1)
    with Writer(path) as w:
        dyn = w.add_connection("/tf", msgtype, typestore=ts)
        stat = w.add_connection("/tf_static", msgtype, typestore=ts)
        static = T[msgtype](transforms=[stamped(100.0, "base_footprint", "base_link", 0.1, 0.0,
                                                0.0),
                                        stamped(100.0, "base_link", "laser", 0.2, -0.05,
                                                math.pi / 2)])
        w.write(stat, int(100e9), ts.serialize_ros1(static, msgtype))
        for t, (x, y, yaw) in zip(times, robot):
            # Another robot's transform in the same message, which the chain must skip.
            msg = T[msgtype](transforms=[stamped(t, "odom", "base_footprint", x, y, yaw),
                                         stamped(t, "map", "other", 5.0, 5.0, 0.0)])
            w.write(dyn, int(round(t * 1e9)), ts.serialize_ros1(msg, msgtype))
    return times, robot


def _compose(a, b):
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


@pytest.mark.parametrize("slash", ["", "/"])
def test_a_chain_of_moving_and_static_transforms_gives_the_laser_pose(tmp_path, slash):
    path = tmp_path / "tf.bag"
    times, robot = _tf_bag(path, slash)
    # Asked with the other spelling of the frame names.
    other = "/" if slash == "" else ""
    odom = bags.read_tf(path, other + "odom", other + "laser")
    np.testing.assert_allclose(odom.times, times, atol=1e-9)
    expected = np.array([_compose(_compose(p, [0.1, 0.0, 0.0]), [0.2, -0.05, math.pi / 2])
                         for p in robot])
    expected[:, 2] = np.angle(np.exp(1j * expected[:, 2]))
    np.testing.assert_allclose(odom.pose, expected, atol=1e-9)
    # The twist: the pose difference over the step, in the child frame.
    d = expected[2] - expected[1]
    c, s = math.cos(expected[1, 2]), math.sin(expected[1, 2])
    np.testing.assert_allclose(odom.twist[2], [(c * d[0] + s * d[1]) / 0.1,
                                               (-s * d[0] + c * d[1]) / 0.1, d[2] / 0.1],
                               atol=1e-6)
    # Either direction: the inverse chain.
    back = bags.read_tf(path, "laser", "odom")
    for p, q in zip(odom.pose, back.pose):
        np.testing.assert_allclose(_compose(p, q)[:2], [0.0, 0.0], atol=1e-9)
    with pytest.raises(bags.BagError, match="no chain of transforms"):
        bags.read_tf(path, "odom", "other")
    with pytest.raises(ValueError, match="same frame"):
        bags.read_tf(path, "odom", "/odom")


def test_track_takes_the_odometry_from_the_transform_tree(tmp_path, capsys):
    from sims import cli

    path = tmp_path / "tf.bag"
    _tf_bag(path, "/")
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(path), "--laser-topic", "/scan", "--odom-topic", "/odom",
                  "--tf-frames", "odom", "base_link", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "not both" in capsys.readouterr().err
    # The bag has no scans: a one-line error naming the missing topic.
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(path), "--laser-topic", "/scan", "--tf-frames", "odom",
                  "base_link", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "'/scan' is not in" in capsys.readouterr().err
