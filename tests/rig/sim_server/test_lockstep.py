"""The simulator's side of lockstep: who it waits for, and when it steps on (rig.sim_server.lockstep)."""

import threading

import pytest

from std_msgs.msg import Header

from rig.sim_server.lockstep import Lockstep, parse_answer


class FakeNode:
    """Takes the answers' subscription; the test calls its callback as the executor would."""

    def __init__(self):
        self.callback = None

    def create_subscription(self, msg_type, topic, callback, qos):
        assert topic == "/rig_sim/clock_answer" and msg_type is Header
        self.callback = callback
        return object()


def answer(node, client, t_ns, sent=0, mode="hold", next_ns=0):
    m = Header()
    m.stamp.sec, m.stamp.nanosec = divmod(t_ns, 1_000_000_000)
    m.frame_id = f"client={client} sent={sent} mode={mode} next={next_ns}"
    node.callback(m)


def waited(lock: Lockstep, t_ns: int) -> bool:
    """Whether wait(t_ns) blocks: run here, with a stop that comes after 2 s. A wait with
    nothing to wait for returns at once, long before it; one that blocks returns on it."""
    stop = threading.Event()
    timer = threading.Timer(2.0, stop.set)
    timer.start()
    try:
        lock.wait(t_ns, stop)
    finally:
        timer.cancel()
    return stop.is_set()


def test_parse_answer_reads_the_fields_and_refuses_anything_else():
    assert parse_answer("client=12-ab sent=3 mode=hold next=2000000") == ("12-ab", 3, "hold", 2_000_000)
    assert parse_answer("client=1 sent=0 mode=free") == ("1", 0, "free", 0)
    for bad in ("", "client=1 sent=x mode=hold", "client=1 sent=1 mode=sleep", "sent=1 mode=hold"):
        with pytest.raises(ValueError):
            parse_answer(bad)


def test_no_client_no_wait_and_a_holding_client_is_waited_for_until_it_answers():
    node = FakeNode()
    lock = Lockstep(node, timeout=60.0)
    assert not lock.active and not waited(lock, 10_000_000)
    answer(node, "a", 8_000_000)
    assert lock.active
    assert waited(lock, 10_000_000)  # answered 8 ms, the world is at 10 ms
    answer(node, "a", 10_000_000)
    assert not waited(lock, 10_000_000)


def test_a_loop_slower_than_the_streams_lets_the_world_run_to_its_next_period():
    node = FakeNode()
    lock = Lockstep(node, timeout=60.0)
    answer(node, "a", 10_000_000, next_ns=19_000_000)  # acts next at the first period >= 19 ms
    assert not waited(lock, 12_000_000) and not waited(lock, 18_000_000)
    assert waited(lock, 20_000_000)


def test_a_free_client_may_lag_by_the_lead():
    node = FakeNode()
    lock = Lockstep(node, timeout=60.0, free_lead=0.05)
    answer(node, "a", 100_000_000, mode="free")
    assert not waited(lock, 150_000_000)
    assert waited(lock, 151_000_000)


def test_commands_counted_by_an_answer_are_waited_for_then_taken_as_come():
    node = FakeNode()
    lock = Lockstep(node, timeout=60.0, command_wait=60.0)
    answer(node, "a", 10_000_000, sent=2)
    lock.command_received()
    assert waited(lock, 10_000_000)  # one of the two commands is still on its way
    lock.command_received()
    assert not waited(lock, 10_000_000)
    # a command that never comes (published before its subscription matched): waited for
    # command_wait, then taken as come, once
    node2 = FakeNode()
    lock2 = Lockstep(node2, timeout=60.0, command_wait=0.01)
    answer(node2, "b", 10_000_000, sent=1)
    lock2.wait(10_000_000, threading.Event())
    assert lock2.late_commands == 1 and lock2.received == 1
    assert not waited(lock2, 10_000_000)


def test_a_client_that_leaves_or_goes_silent_is_not_waited_for_and_its_commands_stay_counted():
    node = FakeNode()
    lock = Lockstep(node, timeout=60.0, command_wait=60.0)
    answer(node, "a", 10_000_000, sent=1)
    lock.command_received()
    answer(node, "a", 10_000_000, sent=1, mode="bye")
    assert not lock.active and not waited(lock, 50_000_000)
    # a new client's commands are owed on top of the ones already received
    answer(node, "b", 50_000_000, sent=1)
    assert waited(lock, 50_000_000)
    lock.command_received()
    assert not waited(lock, 50_000_000)
    # silent for the timeout while the world waits: let go, and back with its next answer
    node2 = FakeNode()
    lock2 = Lockstep(node2, timeout=0.05)
    answer(node2, "c", 0)
    lock2.wait(10_000_000, threading.Event())
    assert lock2.lost == 1 and not lock2.active
    answer(node2, "c", 10_000_000)
    assert lock2.active and not waited(lock2, 10_000_000)


def test_a_waiting_world_repeats_its_clock_every_heartbeat():
    from drivers.common.time_base import HEARTBEAT

    node = FakeNode()
    repeats = []
    lock = Lockstep(node, timeout=60.0, repeat=lambda: repeats.append(1))
    answer(node, "a", 0)
    stop = threading.Event()
    # the wait ends on a stop set after the test saw the world repeat its clock twice (the
    # test's thread waits on it, so no scheduling of this machine's is read as a repeat)
    watcher = threading.Thread(target=lambda: (lock.wait(10_000_000, stop)), daemon=True)
    watcher.start()
    while len(repeats) < 2 and watcher.is_alive():
        watcher.join(HEARTBEAT / 4)
    stop.set()
    watcher.join(10.0)
    assert len(repeats) >= 2 and not watcher.is_alive()
    # answered at once: no repeat
    repeats.clear()
    answer(node, "a", 20_000_000)
    lock.wait(20_000_000, threading.Event())
    assert repeats == []
