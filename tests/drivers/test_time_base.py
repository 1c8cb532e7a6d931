"""A process's side of simulated time: /clock read from its bytes, the lockstep answers, a stopped clock."""

import pytest

from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock

from drivers.common.time_base import ClockStopped, SimTime, parse_clock
from rig.sim_server.lockstep import parse_answer


class FakeNode:
    """The /clock subscription's callback and the answers' publisher, for a test to drive."""

    def __init__(self):
        self.on_clock = None
        self.answers = []

    def create_subscription(self, msg_type, topic, callback, qos, raw=False):
        assert topic == "/clock" and msg_type is Clock and raw
        self.on_clock = callback
        return object()

    def create_publisher(self, msg_type, topic, qos):
        node = self

        class Pub:
            def publish(self, m):
                node.answers.append((m.stamp.sec * 1_000_000_000 + m.stamp.nanosec, *parse_answer(m.frame_id)))
        return Pub()

    def clock(self, ns: int) -> None:
        m = Clock()
        m.clock.sec, m.clock.nanosec = divmod(ns, 1_000_000_000)
        self.on_clock(serialize_message(m))


class Cell:
    """A load cell's reader that has taken what the world wrote up to `upto` s."""

    upto = 0.0

    def caught_up(self, t):
        return self.upto >= t


def test_parse_clock_reads_rclpy_bytes_and_refuses_others():
    m = Clock()
    m.clock.sec, m.clock.nanosec = 12, 345_678_901
    assert parse_clock(serialize_message(m)) == 12_345_678_901
    with pytest.raises(ValueError):
        parse_clock(b"\x00\x01\x00")


def test_a_free_process_answers_every_clock_and_a_holding_one_only_when_its_loop_does():
    node = FakeNode()
    tb = SimTime(node)
    assert not tb.heard() and tb.now() == 0.0
    node.clock(2_000_000)
    assert tb.now() == pytest.approx(0.002)
    assert node.answers[-1][:4] == (2_000_000, tb.client, 0, "free")
    tb.hold()
    tb.sent(2)  # two commands published for this period
    node.clock(4_000_000)
    assert node.answers[-1][0] == 2_000_000  # held: the executor does not answer
    assert tb.answer(next_ns=9_000_000) == 4_000_000
    assert node.answers[-1] == (4_000_000, tb.client, 2, "hold", 9_000_000)
    tb.release()  # a driver's wait frees the world
    node.clock(6_000_000)
    assert node.answers[-1][:4] == (6_000_000, tb.client, 2, "free")
    tb.close()
    assert node.answers[-1][3] == "bye"


def test_a_free_process_waits_for_its_load_cells_reader_before_it_answers():
    node, cell = FakeNode(), Cell()
    tb = SimTime(node)
    tb.add_sync(cell)
    node.clock(50_000_000)
    assert not node.answers  # the reader has not read what the world wrote up to 50 ms
    cell.upto = 0.045
    tb.notify()  # the reader caught up (within SYNC_LAG of the clock)
    assert node.answers[-1][0] == 50_000_000


def test_the_clock_standing_still_while_waited_for_is_a_stopped_simulator_but_not_while_held():
    import time as _time

    looked = [_time.monotonic()]  # when the executor last looked for messages
    node = FakeNode()
    tb = SimTime(node, stall=2.0, polled=lambda: looked[0])
    node.clock(1_000_000)
    looked[0] = _time.monotonic()
    assert tb.stalled() is None
    tb._advanced -= 3.0  # the clock last moved 3 s ago ...
    looked[0] = tb._advanced + 1.0  # ... but the executor has not looked since (a starved process)
    assert tb.stalled() is None
    looked[0] = _time.monotonic()  # it kept looking, and no /clock came
    err = tb.stalled()
    assert isinstance(err, ClockStopped) and "/clock" in str(err) and "rig sim --sim-time" in str(err)
    # held, with a period not yet answered: the world waits for this process, not the other way
    tb.hold()
    node.clock(2_000_000)
    tb._advanced -= 10.0
    assert tb.stalled() is None


def test_a_repeated_clock_is_a_simulator_that_waits_for_another_follower_not_a_stopped_one():
    import time as _time

    node = FakeNode()
    tb = SimTime(node, stall=2.0, polled=_time.monotonic)
    node.clock(1_000_000)  # answered (free): the world now waits for somebody else
    tb._advanced -= 3.0  # the clock has not moved for 3 s ...
    assert isinstance(tb.stalled(), ClockStopped)
    node.clock(1_000_000)  # ... but the simulator repeats it: it is alive and waiting
    assert tb.stalled() is None
    assert node.answers[-1][0] == 1_000_000 and len(node.answers) == 1  # a repeat is not answered again
    tb._repeated -= 3.0  # and then falls silent too: gone
    assert isinstance(tb.stalled(), ClockStopped)


def test_a_live_process_repeats_its_answer_when_it_has_nothing_new_to_say():
    node, cell = FakeNode(), Cell()
    tb = SimTime(node)
    node.clock(10_000_000)
    tb.add_sync(cell)
    node.clock(50_000_000)  # free, its load cell's reader behind: no answer for 50 ms
    assert [a[0] for a in node.answers] == [10_000_000]
    tb.poll()  # within HEARTBEAT of the last answer: nothing
    assert len(node.answers) == 1
    tb._answered_at -= 1.0
    tb.poll()  # silent for a heartbeat: the last answer again, so the simulator keeps waiting for it
    assert node.answers[-1][:4] == (10_000_000, tb.client, 0, "free")
    assert len(node.answers) == 2
    cell.upto = 0.05
    tb._answered_at -= 1.0
    tb.poll()  # the reader has caught up meanwhile: the newest clock, not a repeat
    assert node.answers[-1][0] == 50_000_000
    tb.hold()
    tb._answered_at -= 1.0
    tb.poll()  # held while its loop computes: the last answer again, in hold mode
    assert node.answers[-1][:4] == (50_000_000, tb.client, 0, "hold")


def test_nothing_is_answered_after_bye():
    node = FakeNode()
    tb = SimTime(node)
    node.clock(10_000_000)
    tb.close()
    assert node.answers[-1][3] == "bye"
    n = len(node.answers)
    node.clock(12_000_000)  # a /clock the executor takes after the process said bye
    tb._answered_at -= 1.0
    tb.poll()
    tb.answer()
    tb.close()
    assert len(node.answers) == n
