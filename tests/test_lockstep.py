"""The whole-loop lockstep protocol, pure: the simulator's barrier, the consumers' hold, the attachment."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.keys import Keys, Service, user_service_name
from schemas.tokens import parse_ticks_key
from schemas.topics import Topic
from services.clock.lockstep import (
    MAX_PARTICIPANTS,
    Hold,
    StepMark,
    TickBarrier,
    decode_mark,
    decode_owed,
    encode_mark,
    observed,
)

MS = 1_000_000
STEP = MS


def _steps(barrier: TickBarrier, until_ms: int) -> dict[int, list[Service]]:
    """The participants each step up to ``until_ms`` waits for, each answering at once."""
    waits = {}
    for k in range(until_ms + 1):
        now = k * STEP
        due = barrier.ticks(now)
        if due:
            waits[k] = due
        for service in due:
            barrier.took(service, now, now)
        assert barrier.missing() == []
    return waits


def test_a_participant_there_at_the_start_is_waited_for_at_every_tick_from_zero():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=True)
    barrier.announce(Service.LOCALIZATION, 1.0, from_start=True)
    waits = _steps(barrier, 2000)
    assert sorted(k for k, due in waits.items() if Service.DRIVE in due) == list(range(0, 2001, 20))
    assert sorted(k for k, due in waits.items() if Service.LOCALIZATION in due) == [0, 1000, 2000]


def test_a_tick_between_steps_is_waited_for_at_the_first_step_after_it():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 3.0, from_start=True)
    assert sorted(_steps(barrier, 1000)) == [0, 334, 667, 1000]


def test_a_participant_that_comes_later_is_waited_for_from_its_first_output():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=False)
    assert barrier.ticks(0) == [] and barrier.ticks(20 * MS) == []
    barrier.took(Service.DRIVE, 33 * MS, 33 * MS)
    assert [k for k in range(34, 100) if barrier.ticks(k * MS)] == [40, 60, 80]


def test_missing_lists_the_outputs_not_yet_taken_and_an_output_completes_its_tick():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=True)
    barrier.announce(Service.LOCALIZATION, 1.0, from_start=True)
    assert set(barrier.ticks(0)) == {Service.LOCALIZATION, Service.DRIVE}
    barrier.took(Service.DRIVE, 0, 0)
    assert barrier.missing() == [Service.LOCALIZATION]
    barrier.took(Service.LOCALIZATION, 0, 0)
    assert barrier.missing() == []
    assert barrier.owed() == {Topic.DRIVE_TARGET_VELOCITY: 0, Topic.LOCALIZATION_POSE: 0}


def test_one_given_up_on_is_waited_for_again_only_once_it_outputs_again():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=True)
    assert barrier.ticks(0) == [Service.DRIVE]
    barrier.gave_up(Service.DRIVE)
    assert barrier.missing() == []
    assert not any(barrier.ticks(k * MS) for k in range(1, 100))
    barrier.took(Service.DRIVE, 100 * MS, 100 * MS)
    assert barrier.ticks(120 * MS) == [Service.DRIVE]


def test_one_that_rejoins_behind_the_present_is_waited_for_from_its_first_tick_after_it():
    """Its output stamped 100 ms arrives at 1005 ms (the steps did not wait for it): the ticks
    in between, and a catch-up tick at the next step, are none it would answer."""
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=False)
    barrier.took(Service.DRIVE, 100 * MS, 1005 * MS)
    assert [k for k in range(1006, 1041) if barrier.ticks(k * MS)] == [1020, 1040]


def test_a_withdrawn_or_finished_participant_is_not_waited_for():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=True)
    barrier.announce(Service.LOCALIZATION, 1.0, from_start=True)
    barrier.ticks(0)
    assert barrier.withdraw(Service.LOCALIZATION)
    barrier.took(Service.DRIVE, 0, 0, final=True)
    assert barrier.missing() == [] and barrier.final(Service.DRIVE)
    assert not any(barrier.ticks(k * MS) for k in range(1, 2001))
    assert not barrier.withdraw(Service.LOCALIZATION)


def test_an_output_stamped_after_the_present_is_bad_input_and_changes_nothing():
    barrier = TickBarrier()
    barrier.announce(Service.DRIVE, 50.0, from_start=True)
    barrier.ticks(0)
    with pytest.raises(BadInput, match="after the present"):
        barrier.took(Service.DRIVE, 20 * MS, 0)
    assert barrier.missing() == [Service.DRIVE] and barrier.owed() == {}


def test_the_mark_round_trips_and_a_forged_one_is_bad_input():
    attachment = encode_mark({Topic.DRIVE_TARGET_VELOCITY: 20 * MS}, observed=False)
    assert decode_owed(attachment, 21 * MS) == {"drive/target_velocity": 20 * MS}
    assert decode_mark(attachment, 21 * MS) == StepMark({"drive/target_velocity": 20 * MS}, observed=False)
    assert decode_owed(None, 21 * MS) is None
    forgeries = (
        b"x",
        b'{"owed": 1}',
        b'{"owed": {}, "more": 1}',
        b'{"owed": {"a": 1, "b": 2, "c": 3}}',
        b'{"observed": "yes"}',
        b"[]",
    )
    for forged in forgeries:
        with pytest.raises(BadInput):
            decode_mark(forged, 21 * MS)
    with pytest.raises(BadInput, match="not before the sample"):
        decode_owed(attachment, 20 * MS)


def test_a_realtime_mark_owes_nothing_and_says_whether_the_step_is_observed():
    unobserved, seen = encode_mark(None, observed=False), encode_mark(None, observed=True)
    assert len(unobserved) < len(seen) <= len(b'{"observed":true}'), "the every-step mark stays small"
    assert decode_owed(unobserved, 0) is None and decode_owed(seen, 0) is None
    assert not observed(decode_mark(unobserved, 0))
    assert observed(decode_mark(seen, 0))
    assert observed(decode_mark(encode_mark({Topic.LOCALIZATION_POSE: 0}, observed=True), MS))


def test_a_sample_without_a_mark_counts_as_observed():
    """A replayed or hand-made stream has no mark: every sample of it is observed, as before marks."""
    assert decode_mark(None, 0) is None
    assert observed(None)


def test_the_ticks_token_names_the_participant_and_its_rate():
    keys = Keys("rh0")
    assert keys.ticks(Service.DRIVE, 50.0) == "invent/rh0/drive/ticks/50.0"
    assert parse_ticks_key(keys.ticks(Service.LOCALIZATION, 1 / 3)) == (Service.LOCALIZATION, 1 / 3)
    for key in (
        "invent/rh0/drive/ticks/-1.0",
        "invent/rh0/drive/ticks/nan",
        "invent/rh0/drive/alive",
        "x/rh0/drive/ticks/1.0",
    ):
        assert parse_ticks_key(key) is None


def _hold(capacity: int) -> tuple[Hold[int], list[int]]:
    taken: list[int] = []
    return Hold(Topic.LOCALIZATION_POSE, taken.append, capacity), taken


def test_a_sample_owed_an_output_waits_for_it_and_later_samples_wait_behind_it():
    hold, taken = _hold(capacity=100)
    owed = {"localization/pose": 1000}
    hold.offer(1, None)
    hold.offer(2, owed)
    hold.offer(3, owed)
    hold.offer(4, None)
    assert taken == [1] and hold.holds == 2
    hold.took(999)
    assert taken == [1]
    hold.took(1000)
    assert taken == [1, 2, 3, 4]


def test_a_full_hold_takes_its_oldest_sample_without_its_output():
    hold, taken = _hold(capacity=1)
    owed = {"localization/pose": 1000}
    hold.offer(1, owed)
    hold.offer(2, owed)
    assert taken == [1] and hold.overflows == 1
    hold.took(1000)
    assert taken == [1, 2]


def test_a_hold_forgets_its_samples_and_stamps_for_a_new_time_base():
    hold, taken = _hold(capacity=10)
    hold.took(5000)
    hold.offer(1, {"localization/pose": 6000})
    hold.forget()
    hold.took(10)
    hold.offer(2, {"localization/pose": 20})
    assert taken == []


def test_a_sample_taken_at_once_raises_to_the_caller_and_released_ones_go_through_the_guard():
    """The caller's input handler counts what the direct take raises; a release takes every
    sample through the guard, so a bad one never keeps back those after it."""
    taken: list[int] = []
    guarded: list[tuple[int, str]] = []

    def take(sample: int) -> None:
        if sample < 0:
            raise BadInput(f"sample {sample}")
        taken.append(sample)

    def guard(action, sample: int) -> None:
        try:
            action(sample)
        except BadInput as error:
            guarded.append((sample, str(error)))

    hold = Hold(Topic.LOCALIZATION_POSE, take, 10, guard=guard)
    with pytest.raises(BadInput, match="sample -1"):
        hold.offer(-1, None)
    owed = {"localization/pose": 1000}
    hold.offer(1, owed)
    hold.offer(-2, owed)
    hold.offer(3, owed)
    hold.took(1000)
    assert taken == [1, 3]
    assert guarded == [(-2, "sample -2")]


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 3)), max_size=40))
def test_samples_are_taken_in_order_each_once(events):
    """Whatever interleaving of samples and outputs, nothing is lost, doubled or reordered."""
    hold, taken = _hold(capacity=5)
    offered = []
    for index, (is_sample, stamp) in enumerate(events):
        if is_sample:
            offered.append(index)
            hold.offer(index, {"localization/pose": stamp})
        else:
            hold.took(stamp)
    hold.took(10)
    assert taken == offered


def test_participants_beyond_the_most_one_robot_waits_for_are_refused_and_the_others_kept():
    barrier = TickBarrier()
    assert barrier.announce(Service.DRIVE, 50.0, from_start=True)
    names = [user_service_name(f"peer{index}") for index in range(MAX_PARTICIPANTS)]
    accepted = [barrier.announce(name, 10.0, from_start=True, output=f"{name}/out") for name in names]
    assert accepted == [True] * (MAX_PARTICIPANTS - 1) + [False], "a token beyond the bound is refused"
    assert not barrier.announced(names[-1]) and barrier.announced(names[0])
    assert barrier.announce(names[0], 5.0, from_start=True, output=f"{names[0]}/out"), "a known one may change its rate"
    assert barrier.withdraw(names[0]) and barrier.announce(names[-1], 10.0, from_start=True, output=f"{names[-1]}/out")
