"""SimTracker (the mocap fake): marker noise, occlusion, latency, quaternion order."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.interfaces import Tracker
from drivers.mocap.sim import (SimTracker, kabsch, matrix_from_quaternion, quaternion_from_matrix,
                               record_to_motive_csv)
from drivers.mocap.motive_csv import read_motive_csv
from drivers.arm.sim import SimArm
from rig import config
from rig.devices.clock import SimClock
from rig.sim.world import world_from_config
from scipy.spatial.transform import Rotation


def make(**kw):
    world = world_from_config(config.parse({}, "test"), seed=2)
    clock = SimClock(world)
    return world, clock, SimTracker(world, clock, **kw)


def test_is_a_tracker_at_its_rate():
    world, clock, tr = make()
    assert isinstance(tr, Tracker)
    clock.sleep(1.0)
    frames = tr.frames()
    assert len(frames) in (119, 120)  # the last one may still be in flight (5 ms latency)
    dt = np.diff([f.t for f in frames])
    assert dt.mean() == pytest.approx(1 / 120, rel=1e-2) and dt.max() <= 1 / 120 + world.dt + 1e-9
    assert tr.frames() == []


def test_marker_noise_matches_the_configured_level():
    world, clock, tr = make(noise=0.0002, latency=0.0)
    errs = []
    for _ in range(60):
        truth = world.marker_positions()  # the world is at rest between ticks
        f = tr.capture(clock.now())
        for b in tr.bodies:
            for k in range(3):
                errs.append(f.markers[f"{b}:Marker{k + 1}"] - truth[b][k])
        clock.tick()
    errs = np.array(errs)
    assert abs(errs.mean()) < 2e-5
    assert errs.std() == pytest.approx(0.0002, rel=0.05)


def test_body_pose_is_fitted_from_the_noisy_markers():
    world, clock, tr = make(noise=0.00025, latency=0.0)
    f = tr.capture(clock.now())
    truth = world.body_poses()
    for b in tr.bodies:
        pose = f.bodies[b]
        # re-fitting the frame's own markers gives its pose exactly: it was solved from them
        markers = np.array([f.markers[f"{b}:Marker{k + 1}"] for k in range(3)])
        R, p, rms = kabsch(tr.layouts[b], markers)
        assert np.allclose(pose.rotation, R, atol=1e-9) and np.allclose(pose.position, p)
        assert f.marker_error[b] == pytest.approx(rms)
        # and it is near the truth, but not equal to it (the frame origin can sit 0.35 m
        # from its markers, so the fit's rotation noise moves it by a few mm)
        err = np.linalg.norm(pose.position - truth[b][:3, 3])
        assert 0 < err < 0.01
    noiseless = make(noise=0.0)[2].capture(0.0)
    w2 = make(noise=0.0)[0].body_poses()
    assert all(np.allclose(noiseless.bodies[b].matrix(), w2[b], atol=1e-12) for b in w2)


def test_occluded_bodies_and_markers_are_none_and_counted_never_zero():
    world, clock, tr = make(occlusion=0.3, latency=0.0, seed=4)
    clock.sleep(1.0)
    frames = tr.frames()
    lost = sum(f.bodies[b] is None for f in frames for b in tr.bodies)
    assert lost == sum(tr.stats.occluded.values()) > 0
    assert lost / (len(frames) * len(tr.bodies)) == pytest.approx(0.3, abs=0.05)
    for f in frames:
        for b in tr.bodies:
            hidden = [f.markers[f"{b}:Marker{k + 1}"] is None for k in range(3)]
            assert (f.bodies[b] is None) == any(hidden)
            assert (f.quaternions[b] is None) == any(hidden)
        for m in f.markers.values():
            assert m is None or (m.shape == (3,) and np.any(m != 0))


def test_latency_delays_delivery_but_keeps_the_capture_stamp():
    world, clock, tr = make(latency=0.020, noise=0.0)
    arm = SimArm(world, "PSM1", clock)
    arm.move_jp([0.5, 0.0, 0.12], wait=False)  # so the poses change from frame to frame
    clock.tick()  # t = 1 ms: first capture
    assert tr.frames() == []
    captured_at = world.t
    truth = world.body_poses()["PSM1_tool"]
    while world.t < captured_at + 0.020 - 1e-9:
        assert tr.frames() == [], f"delivered early at {world.t}"
        clock.tick()
    (f,) = tr.frames()
    assert f.t == pytest.approx(captured_at)
    assert np.allclose(f.bodies["PSM1_tool"].matrix(), truth, atol=1e-12)
    assert not np.allclose(world.body_poses()["PSM1_tool"], truth, atol=1e-6)
    assert tr.latest() is f


@pytest.mark.parametrize("order", ["xyzw", "wxyz"])
def test_quaternion_order_round_trip_and_declared_order(order):
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    q = quaternion_from_matrix(R, order)
    assert np.allclose(matrix_from_quaternion(q, order), R)
    w = q[3] if order == "xyzw" else q[0]
    assert w == pytest.approx(np.cos(np.linalg.norm([0.3, -1.1, 0.7]) / 2), abs=1e-12)
    other = "wxyz" if order == "xyzw" else "xyzw"
    wrong = matrix_from_quaternion(q, other)
    assert np.degrees(Rotation.from_matrix(wrong.T @ R).magnitude()) > 10

    world, clock, tr = make(quaternion_order=order, noise=0.0, latency=0.0)
    clock.sleep(0.05)
    f = tr.latest()
    truth = world.body_poses()
    for b in tr.bodies:
        assert f.quaternion_order == order
        assert np.allclose(matrix_from_quaternion(f.quaternions[b], order), f.bodies[b].rotation)
        assert np.allclose(f.bodies[b].rotation, truth[b][:3, :3], atol=1e-9)


def test_record_to_motive_csv_reads_back(tmp_path):
    world, clock, tr = make(occlusion=0.1, latency=0.0, seed=1)
    clock.sleep(0.25)
    frames = tr.frames()
    path = record_to_motive_csv(tmp_path / "take.csv", frames, quat_order="wxyz")
    take = read_motive_csv(path)
    body = take.body("PSM1_tool")
    ok = np.array([f.bodies["PSM1_tool"] is not None for f in frames])
    assert np.array_equal(body.valid, ok)
    k = int(np.flatnonzero(ok)[0])
    assert np.allclose(body.position[k], frames[k].bodies["PSM1_tool"].position, atol=2e-6)
    assert np.allclose(body.rotation()[k], frames[k].bodies["PSM1_tool"].rotation, atol=1e-5)
    assert np.isnan(take.marker("PSM1_tool:Marker1").position[~np.array(
        [f.markers["PSM1_tool:Marker1"] is not None for f in frames])]).all()
