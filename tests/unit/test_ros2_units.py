"""The ROS 2 output's parts in process: the [ros2] table, odometry poses to increments (the file
path's conversion), the health counters it adds, and the checks `--ros2` makes before it opens."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from pfdoa.errors import ConfigError
from pfdoa.gateway.health import HealthSnapshot
from pfdoa.gateway.ros2odom import OdometryPoses
from pfdoa.odometry import increments
from pfdoa.ros2.config import Ros2Settings, name_token, ros2_settings
from pfdoa.sinks import options, ros
from pfdoa.site import load_site

import gateway_feed

pytestmark = pytest.mark.unit


def settings(table=None, env=None) -> Ros2Settings:
    return ros2_settings({} if table is None else {"ros2": table}, "site.toml", environ=env or {})


def test_the_table_defaults_and_topic_names():
    s = settings()
    assert (s.domain_id, s.namespace) == (0, "")
    assert (s.odom_topic, s.odom_reliable, s.pose_reliable, s.pose_depth) == ("/odom", False, True, 10)
    assert s.pose_topic() == "/pfdoa/pose" and s.topic("/diagnostics") == "/diagnostics"
    r = settings({"namespace": "/robot1", "odom_topic": "wheel/odom", "pose_reliability": "best_effort",
                  "pose_depth": 50, "odom_reliability": "reliable"})
    assert r.pose_topic() == "/robot1/pfdoa/pose" and r.pose_topic("b1") == "/robot1/pfdoa/b1/pose"
    assert r.odom_topic == "/robot1/wheel/odom"
    assert (r.pose_reliable, r.pose_depth, r.odom_reliable) == (False, 50, True)
    assert settings({"namespace": "/r", "odom_topic": "/odom"}).odom_topic == "/odom"  # absolute stays
    assert settings({"odom_topic": ""}).odom_topic == ""  # no subscription


def test_the_domain_comes_from_the_table_else_ros_domain_id():
    assert settings(env={"ROS_DOMAIN_ID": "42"}).domain_id == 42
    assert settings({"domain_id": 7}, env={"ROS_DOMAIN_ID": "42"}).domain_id == 7
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
        settings(env={"ROS_DOMAIN_ID": "300"})


@pytest.mark.parametrize("table, key", [
    ({"domain_id": 233}, "ros2.domain_id"), ({"domain_id": "1"}, "ros2.domain_id"),
    ({"namespace": "robot1"}, "ros2.namespace"), ({"namespace": "/1robot"}, "ros2.namespace"),
    ({"namespace": "/a//b"}, "ros2.namespace"), ({"odom_topic": "odom/"}, "ros2.odom_topic"),
    ({"odom_topic": "od__om"}, "ros2.odom_topic"), ({"odom_reliability": "sometimes"}, "ros2.odom_reliability"),
    ({"pose_depth": 0}, "ros2.pose_depth"), ({"pose_reliability": True}, "ros2.pose_reliability"),
    ({"domain": 1}, "ros2.domain"), ({"site_in_map": [1, 2, 3]}, "ros2.site_in_map"),  # [site] map_pose places it
])
def test_a_bad_value_is_one_error_naming_its_key(table, key):
    with pytest.raises(ConfigError) as e:
        settings(table)
    assert e.value.key == key and "\n" not in str(e.value)


def test_beacon_ids_become_distinct_ros_name_tokens():
    assert name_token("kitchen_tag") == "kitchen_tag"
    ids = ["phone:12", "phone_12", "phone-12", "12ab", "a__b", "", "x/y"]
    tokens = [name_token(i) for i in ids]
    assert len(set(tokens)) == len(ids)
    for t in tokens:
        assert t[0].isalpha() and all(c.isalnum() or c == "_" for c in t) and "__" not in t


def test_odometry_poses_become_the_files_increments_exactly():
    rng = np.random.default_rng(3)
    t = 1.7e9 + np.cumsum(rng.uniform(0.01, 0.05, 200))
    track = np.column_stack([t, np.cumsum(rng.normal(0, 0.02, 200)), np.cumsum(rng.normal(0, 0.02, 200)),
                             np.cumsum(rng.normal(0, 0.05, 200))])
    poses = OdometryPoses()
    got = [poses.add(*row) for row in track.tolist()]
    assert got == [tuple(row) for row in increments(track).tolist()]  # bit for bit, row by row


def test_odometry_poses_that_cannot_be_differenced_are_skipped_and_counted():
    poses = OdometryPoses()
    assert poses.add(10.0, 0.0, 0.0, 0.0, source=1) == (10.0, 0.0, 0.0, 0.0)  # the first pose: no motion
    assert poses.add(10.5, 1.0, 0.0, 0.0, source=1) == (10.5, 1.0, 0.0, 0.0)
    assert poses.add(10.5, 2.0, 0.0, 0.0, source=1) is None and poses.out_of_order == 1  # not after the last
    assert poses.add(11.0, float("nan"), 0.0, 0.0, source=1) is None and poses.bad == 1
    # Another publisher: a new stream, never a difference across two sources.
    assert poses.add(11.0, 50.0, 50.0, 1.0, source=2) == (11.0, 0.0, 0.0, 0.0) and poses.restarts == 1
    dx, dy, dth = poses.add(12.0, 50.0, 51.0, 1.0, source=2)[1:]
    assert (dx, dy, dth) == pytest.approx((math.sin(1.0), math.cos(1.0), 0.0))  # in the robot frame


def test_the_yaw_of_an_orientation():
    for yaw in (0.0, 0.3, -2.0, math.pi - 1e-9):
        q = ros.yaw_quaternion(yaw)
        assert ros.quaternion_yaw(q["x"], q["y"], q["z"], q["w"]) == pytest.approx(yaw, abs=1e-12)
    # roll and pitch aside: a robot on a ramp, heading 0.7 rad (Z-Y-X: yaw 0.7, pitch 0.2, roll 0.1)
    cy, sy, cp, sp, cr, sr = (math.cos(0.35), math.sin(0.35), math.cos(0.1), math.sin(0.1), math.cos(0.05),
                              math.sin(0.05))
    w, x, y, z = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                  cr * cp * sy - sr * sp * cy)
    assert ros.quaternion_yaw(x, y, z, w) == pytest.approx(0.7, abs=1e-12)


def snapshot(**kw) -> HealthSnapshot:
    return HealthSnapshot(t=3.0, period_s=1.0, frames_per_s=10.0, sets_per_s=2.0, estimates_per_s=2.0, errors={},
                          anchors={}, open_sets=0, frames=10, sets=2, estimates=2, **kw)


def test_the_outputs_and_odometry_counters_are_in_every_health_form():
    plain = snapshot()
    assert "outputs" not in plain.to_json() and "odometry" not in plain.to_json()
    snap = snapshot(outputs={"ros2": {"published": 5, "dropped": 1, "matched": 2}}, odometry={"lines": 9, "waited": 1})
    assert snap.line() == plain.line() + " | ros2 published=5 dropped=1 matched=2"
    js = snap.to_json()
    assert js["outputs"] == {"ros2": {"published": 5, "dropped": 1, "matched": 2}}
    assert js["odometry"] == {"lines": 9, "waited": 1}
    kv = {v["key"]: v["value"] for v in ros.diagnostics_message(snap)["status"][0]["values"]}
    assert (kv["ros2.published"], kv["ros2.dropped"], kv["ros2.matched"], kv["odometry.lines"]) == ("5", "1", "2", "9")


def test_ros2_settings_only_with_the_option(tmp_path):
    p = tmp_path / "site.toml"
    p.write_text(gateway_feed.TEST_SITE + "\n[ros2]\ndomain_id = 12\n")
    site = load_site(p)
    assert options.ros2_settings(argparse.Namespace(ros2=True), site, p).domain_id == 12
    assert options.ros2_settings(argparse.Namespace(ros2=False), site, p) is None
    assert options.ros2_settings(argparse.Namespace(), site, p) is None  # a command without --ros2
