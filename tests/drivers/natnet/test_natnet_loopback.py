"""The fake Motive on the loopback and the NatNet driver over real UDP sockets.

The simulated rig's marker bodies go through `FakeMotiveOnWorld` (SimTracker's noise, occlusion
and latency, FakeMotive's bytes) and `NatNetTracker`; what comes out is checked against
what was sent (bit for bit, up to float32) and against the true marker positions (within
the marker noise). The waits are guards against a hang, never figures.
"""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

from drivers.natnet.fake_motive import FakeMotive, FakeMotiveOnWorld, check_loopback
from drivers.natnet.frame_of_data import decode_frame
from drivers.natnet.messages import decode_server_info, encode_connect, pack_message, split_message
from drivers.natnet.model_definitions import decode_modeldef
from drivers.natnet.tracker import NatNetTracker, open_natnet_tracker
from drivers.natnet.udp import UdpTransport
from drivers.natnet.wire_format import (NAT_DISCONNECT, NAT_FRAMEOFDATA, NAT_KEEPALIVE, NAT_MODELDEF,
                                        NAT_REQUEST_MODELDEF, NAT_SERVERINFO)
from rig.config import parse
from rig.devices.clock import SimClock
from rig.sim.world import world_from_config

NOISE = 0.00025  # m, the simulated marker noise (1 sigma per coordinate)


def wait_for(pred, timeout=30.0) -> None:  # a guard against a hang, not a figure
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.002)


def world_and_clock(seed=0):
    world = world_from_config(parse({}, "built-in simulated rig"), seed=seed)
    return world, SimClock(world)


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.10", "localhost-ish", "::1"])
def test_the_fake_serves_on_the_ipv4_loopback_only(host):
    with pytest.raises(ValueError, match="loopback only"):
        FakeMotive([("a", np.eye(3))], host=host, command_port=0, data_port=0)
    assert check_loopback("127.0.0.1") == "127.0.0.1"
    with pytest.raises(ValueError, match="not an IPv4 multicast"):
        FakeMotive([("a", np.eye(3))], command_port=0, data_port=0, multicast="10.1.2.3")


def test_the_command_channel_answers_as_motive_and_frames_come_from_the_data_port():
    m = FakeMotive([("tool", np.eye(3) * 0.03)], command_port=0, data_port=0, version=(4, 1, 0, 0)).start()
    assert m.cmd.getsockname()[0] == m.data.getsockname()[0] == "127.0.0.1"
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.bind(("127.0.0.1", 0))
    c.settimeout(30.0)
    server = ("127.0.0.1", m.command_port)
    c.sendto(encode_connect(), server)
    reply, src = c.recvfrom(1 << 16)
    assert src == server
    mid, payload = split_message(reply)
    info = decode_server_info(payload)
    assert (mid, info.app_name, info.natnet_version, info.data_port, info.clock_hz) == (
        NAT_SERVERINFO, "Motive", (4, 1, 0, 0), m.data_port, 10_000_000)
    assert m.clients == [c.getsockname()]
    c.sendto(pack_message(NAT_KEEPALIVE), server)  # no answer: the next datagram is the model definitions
    c.sendto(pack_message(NAT_REQUEST_MODELDEF), server)
    reply, src = c.recvfrom(1 << 16)
    mid, payload = split_message(reply)
    assert (mid, src) == (NAT_MODELDEF, server)
    (rb,) = decode_modeldef(payload, (4, 1, 0, 0)).rigid_bodies
    assert (rb.name, rb.id, rb.marker_names) == ("tool", 1, ("Marker1", "Marker2", "Marker3"))
    c.sendto(pack_message(42, b"?"), server)  # a request Motive does not know
    reply, src = c.recvfrom(1 << 16)
    assert (reply, src) == (bytes.fromhex("64 00 00 00"), server)
    c.sendto(b"\x07", server)  # not even a header: counted, not answered
    # a frame of the simulated kind, sent from the data port
    from drivers.interfaces import Pose
    from drivers.mocap.sim import SimFrame

    f = SimFrame(t=1.0, bodies={"tool": Pose(1.0, np.array([0.1, 0.2, 0.3]), np.eye(3))},
                 markers={"tool:Marker1": np.array([0.13, 0.2, 0.3])},
                 quaternions={"tool": np.array([0.0, 0.0, 0.0, 1.0])}, marker_error={"tool": 0.0002})
    assert m.send(f, captured=1.0, sent=1.005) == 1
    reply, src = c.recvfrom(1 << 16)
    assert src == ("127.0.0.1", m.data_port)
    mid, payload = split_message(reply)
    frame = decode_frame(payload, (4, 1, 0, 0))
    assert (mid, frame.frame_number) == (NAT_FRAMEOFDATA, 1)
    assert frame.rigid_bodies[0].position == pytest.approx((0.1, 0.2, 0.3))
    assert frame.transmit_ticks - frame.mid_exposure_ticks == 50_000  # 5 ms at 10 MHz
    (lm,) = frame.labeled_markers
    assert (lm.model_id, lm.marker_id, lm.residual) == (1, 1, pytest.approx(0.0, abs=1e-7))
    c.sendto(pack_message(NAT_DISCONNECT), server)
    wait_for(lambda: m.clients == [])
    assert m.send(f, captured=1.1, sent=1.105) == 0  # nobody to send to
    assert (m.stats.connects, m.stats.modeldefs, m.stats.keepalives, m.stats.refused, m.stats.bad) == (1, 1, 1, 1, 1)
    c.close()
    m.close()


def test_a_unicast_client_that_stops_keeping_alive_is_forgotten():
    m = FakeMotive([("tool", np.eye(3) * 0.03)], command_port=0, data_port=0, client_timeout=0.001).start()
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.bind(("127.0.0.1", 0))
    c.settimeout(30.0)
    c.sendto(encode_connect(), ("127.0.0.1", m.command_port))
    c.recvfrom(1 << 16)
    time.sleep(0.01)  # longer than the client timeout
    from drivers.mocap.sim import SimFrame

    assert m.send(SimFrame(t=0.0, bodies={"tool": None}), captured=0.0, sent=0.0) == 0
    assert m.stats.expired == 1 and m.clients == []
    c.close()
    m.close()


def _run(version, multicast="", occlusion=0.1, frames=150, latency=0.005):
    """Serve the simulated rig through FakeMotiveOnWorld to a NatNetTracker; (sent SimFrames by
    frame number, true markers by capture time, received frames, motive, tracker)."""
    world, clock = world_and_clock(seed=3)
    sm = FakeMotiveOnWorld(world, clock, noise=NOISE, latency=latency, occlusion=occlusion, rate=120.0, seed=11,
                           command_port=0, data_port=0, version=version, multicast=multicast).start()
    truth = {}
    clock.add_listener(lambda t: truth.__setitem__(round(t, 6), world.marker_positions()))
    sent = {}
    send = sm.motive.send

    def spy(frame, captured, sent_at):
        n = send(frame, captured, sent_at)
        sent[sm.motive._last_number] = frame
        return n

    sm.motive.send = spy
    tracker = NatNetTracker(UdpTransport("127.0.0.1", sm.motive.command_port, sm.motive.data_port, multicast),
                            stale_timeout=1e9)
    tracker.connect(timeout=30.0)
    from drivers.arm.sim import SimArm

    for name in world.names:  # the arms move: the poses change from frame to frame
        SimArm(world, name, clock).move_jp(np.array([0.3, -0.2, 0.14]), wait=False)
    got = []
    while sm.motive.stats.frames < frames:
        clock.tick()
        sm.pump()
        got += tracker.frames()
    wait_for(lambda: tracker.stats.frames == sm.motive.stats.frames)
    got += tracker.frames()
    tracker.close()
    sm.close()
    return sent, truth, got, sm.motive, tracker


@pytest.mark.parametrize("version", [(3, 1, 0, 0), (4, 0, 0, 0), (4, 1, 0, 0)])
def test_poses_through_the_fake_motive_are_the_simulated_bodies_within_the_noise(version):
    sent, truth, got, motive, tracker = _run(version)
    assert len(got) == motive.stats.frames == 150
    st = tracker.stats
    assert (st.gaps, st.out_of_order, st.truncated, st.malformed, st.unknown_body) == (0, 0, 0, 0, 0)
    layouts = {d.name: d.markers for d in motive.descriptions}
    errors, lost, seen = [], 0, 0
    for f in got:
        src = sent[f.frame_number]
        true = truth[round(src.t, 6)]
        for b, pose in f.bodies.items():
            want = src.bodies[b]
            if want is None:  # occluded in the simulation: tracking-valid cleared on the wire
                assert pose is None and f.marker_error[b] is None
                lost += 1
                continue
            seen += 1
            # what the simulated tracker solved, through the bytes (float32)
            assert pose.position == pytest.approx(want.position, abs=1e-6)
            assert pose.rotation == pytest.approx(want.rotation, abs=2e-6)
            assert f.marker_error[b] == pytest.approx(src.marker_error[b], rel=1e-6)
            # and the truth: the body's markers where the pose puts them, within the noise
            errors.append((layouts[b] @ pose.rotation.T + pose.position) - true[b])
        for label, v in f.markers.items():
            w = src.markers.get(label)
            assert (v is None) == (w is None)
            if v is not None:
                assert v == pytest.approx(w, abs=1e-6)
    e = np.concatenate(errors)
    rms = float(np.sqrt(np.mean(e ** 2)))
    assert 0.5 * NOISE < rms < 1.2 * NOISE  # the noise is there, and nothing more
    moved = [np.ptp([f.bodies["PSM1_tool"].position for f in got if f.bodies["PSM1_tool"] is not None], axis=0)]
    assert np.max(moved) > 0.01  # m: the bodies moved while streamed
    assert np.max(np.linalg.norm(e, axis=1)) < 8 * NOISE
    assert lost == sum(st.untracked.values()) > 0 and seen == sum(st.tracked.values())
    assert st.system_latency_mean == pytest.approx(0.005, abs=2e-7)


def test_frame_times_are_capture_times_on_the_host_clock():
    _, _, got, _, _ = _run((4, 1, 0, 0), occlusion=0.0, frames=40, latency=0.02)
    for f in got:
        assert f.t <= f.received
        assert all(p is None or p.t == f.t for p in f.bodies.values())
    assert all(b.frame_number > a.frame_number and b.t > a.t for a, b in zip(got, got[1:]))


def test_multicast_on_the_loopback():
    try:
        sent, _, got, motive, tracker = _run((4, 1, 0, 0), multicast="239.255.42.99", frames=30)
    except OSError as exc:  # a machine that allows no multicast, even on the loopback
        pytest.skip(f"multicast on the loopback not allowed here: {exc}")
    assert motive.info.multicast and motive.clients == []  # no unicast client list in multicast
    assert [f.frame_number for f in got] == sorted(sent) and len(got) == 30


def test_the_configured_tracker_opens_connects_and_names_the_rigs_bodies():
    world, clock = world_and_clock()
    sm = FakeMotiveOnWorld(world, clock, command_port=0, data_port=0).start()
    cfg = {"server": "127.0.0.1", "command_port": sm.motive.command_port, "data_port": sm.motive.data_port,
           "multicast": ""}
    tracker = open_natnet_tracker(cfg, ["PSM1_tool", "world"], timeout=30.0, stale_timeout=1e9)
    assert tracker.bodies == ("PSM1_tool", "world")
    assert tracker.transport.sock.getsockname()[0] == "127.0.0.1"
    for _ in range(20):
        clock.tick()
        sm.pump()
    assert tracker.wait_for_frames(2, 30.0)
    f = tracker.frames()[0]
    assert set(f.bodies) == {"PSM1_tool", "world"}
    assert set(f.markers) == {"PSM1_tool:Marker1", "PSM1_tool:Marker2", "PSM1_tool:Marker3",
                              "world:Marker1", "world:Marker2", "world:Marker3"}
    tracker.close()
    sm.close()
