"""E2E receiver: counter sequences (repeats, jumps, wrap-around, reorder, restart), timeouts, block = scalar."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.e2e import E2EConfigError, E2EReceiver, E2EState, E2EStatus, usable

MOTOR = 0x101  # 8-bit tick counter, max_delta 16
STATUS = 0x080  # 4-bit counter, max_delta 3
S = E2EStatus


def run(receiver: E2EReceiver, arbitration_id: int, counters, crc_ok=None, t0=0.0, dt=0.002):
    crc_ok = [True] * len(counters) if crc_ok is None else crc_ok
    return [receiver.check(arbitration_id, c, ok, t0 + i * dt) for i, (c, ok) in enumerate(zip(counters, crc_ok))]


def statuses(results):
    return [s for s, _ in results]


def test_in_sequence_with_wrap_around_is_ok():
    rx = E2EReceiver()
    counters = [(250 + i) % 256 for i in range(20)]
    assert statuses(run(rx, MOTOR, counters)) == [S.OK] * 20
    assert rx.state(MOTOR) is E2EState.VALID
    rx4 = E2EReceiver()
    assert statuses(run(rx4, STATUS, [(13 + i) % 16 for i in range(40)])) == [S.OK] * 40
    assert rx.stats["ok"] == 20 and rx.stats["lost_frames"] == 0


def test_jumps_within_max_delta_report_lost_frames():
    rx = E2EReceiver()
    results = run(rx, MOTOR, [10, 11, 14, 15, 31, 32])  # jumps of 3 and 16 (= max_delta)
    assert results == [(S.OK, 0), (S.OK, 0), (S.OK_SOME_LOST, 2), (S.OK, 0), (S.OK_SOME_LOST, 15), (S.OK, 0)]
    assert rx.stats["lost_frames"] == 17 and rx.stats["some_lost"] == 2
    # across the wrap: 254 -> 2 is a jump of 4
    assert rx.check(MOTOR, 254, True, 1.0)[0] == S.WRONG_SEQUENCE  # 32 -> 254: jump of 222
    rx2 = E2EReceiver()
    assert run(rx2, MOTOR, [254, 2]) == [(S.OK, 0), (S.OK_SOME_LOST, 3)]


def test_jump_beyond_max_delta_is_wrong_sequence_then_resyncs():
    rx = E2EReceiver()
    assert statuses(run(rx, STATUS, [0, 1, 6, 7, 8])) == [S.OK, S.OK, S.WRONG_SEQUENCE, S.OK, S.OK]
    assert rx.stats["resyncs"] == 1 and rx.stats["wrong_sequence"] == 1
    assert rx.check(STATUS, 9, True, 1.0) == (S.OK, 0)


def test_repeated_frames_are_flagged_and_not_used():
    rx = E2EReceiver()
    results = run(rx, MOTOR, [5, 5, 6, 6, 6, 7])
    assert statuses(results) == [S.OK, S.REPEATED, S.OK, S.REPEATED, S.REPEATED, S.OK]
    assert rx.stats["repeated"] == 3
    assert rx.state(MOTOR) is E2EState.VALID  # REPEATED is neutral for the state machine
    assert usable(np.array(statuses(results))).tolist() == [True, False, True, False, False, True]


def test_reordered_and_stale_frames_do_not_move_the_reference_backwards():
    rx = E2EReceiver()
    # 1 2 4 3 5: frame 3 arrives late
    assert statuses(run(rx, MOTOR, [1, 2, 4, 3, 5])) == [S.OK, S.OK, S.OK_SOME_LOST, S.WRONG_SEQUENCE, S.OK]
    # Two *consecutive* out-of-window frames look exactly like a restart, so the receiver resyncs
    # on them; the live stream then costs one WRONG_SEQUENCE frame and resyncs back.
    assert statuses(run(rx, MOTOR, [200, 201, 6, 7], t0=1.0)) == [S.WRONG_SEQUENCE, S.OK, S.WRONG_SEQUENCE, S.OK]
    assert rx.stats["resyncs"] == 2
    rx = E2EReceiver()
    run(rx, MOTOR, [100, 101, 102])
    assert rx.check(MOTOR, 90, True, 1.0) == (S.WRONG_SEQUENCE, -1)
    assert rx.check(MOTOR, 103, True, 1.002) == (S.OK, 0)  # continues from 102, not from 90


def test_single_stale_frame_followed_by_live_stream():
    rx = E2EReceiver()
    run(rx, MOTOR, list(range(50, 60)))
    # stale 40, then live 60, 61
    assert statuses(run(rx, MOTOR, [40, 60, 61], t0=1.0)) == [S.WRONG_SEQUENCE, S.OK, S.OK]
    assert rx.stats["resyncs"] == 0


def test_counter_reset_after_controller_restart_resyncs():
    rx = E2EReceiver()
    run(rx, MOTOR, list(range(100, 120)))
    after = statuses(run(rx, MOTOR, list(range(0, 10)), t0=5.0))
    assert after[0] == S.WRONG_SEQUENCE and after[1:] == [S.OK] * 9
    assert rx.state(MOTOR) is E2EState.VALID


def test_state_machine_init_valid_invalid_valid():
    rx = E2EReceiver(ok_to_valid=3)
    assert rx.state(MOTOR) is E2EState.INIT
    assert rx.check(MOTOR, 7, False, 0.0) == (S.ERROR, 0)
    assert rx.state(MOTOR) is E2EState.INIT  # an error before any valid frame keeps INIT
    rx.check(MOTOR, 7, True, 0.0)
    assert rx.state(MOTOR) is E2EState.VALID
    assert rx.check(MOTOR, 8, False, 0.1)[0] == S.ERROR
    assert rx.state(MOTOR) is E2EState.INVALID and rx.stats["crc_errors"] == 2
    seen = []
    for i, counter in enumerate([8, 9, 10, 11]):
        rx.check(MOTOR, counter, True, 0.2 + i)
        seen.append(rx.state(MOTOR))
    assert seen == [E2EState.INVALID, E2EState.INVALID, E2EState.VALID, E2EState.VALID]


def test_unknown_id_is_error_without_creating_state():
    rx = E2EReceiver()
    assert rx.check(0x7FF, 1, True, 0.0) == (S.ERROR, 0)
    assert rx.stats["unknown_id"] == 1 and rx.states() == {}


def test_no_new_data_from_poll_with_explicit_timestamps():
    rx = E2EReceiver(timeout_s=0.1, timeouts={STATUS: 0.5})
    rx.check(MOTOR, 1, True, 10.0)
    rx.check(STATUS, 1, True, 10.0)
    assert rx.poll(10.05) == []
    assert rx.poll(10.2) == [(MOTOR, S.NO_NEW_DATA)]
    assert rx.state(MOTOR) is E2EState.INVALID
    assert rx.poll(10.3) == []  # once per outage
    assert rx.poll(10.6) == [(STATUS, S.NO_NEW_DATA)]
    assert rx.stats["no_new_data"] == 2
    # a repeating sender is not new data either
    rx.check(MOTOR, 2, True, 11.0)
    rx.check(MOTOR, 2, True, 11.05)
    rx.check(MOTOR, 2, True, 11.15)
    assert rx.poll(11.15) == [(MOTOR, S.NO_NEW_DATA)]
    assert rx.check(MOTOR, 3, True, 11.2) == (S.OK, 0)


def test_configuration_errors_name_the_parameter():
    with pytest.raises(E2EConfigError, match="max_delta"):
        E2EReceiver(max_delta=256)
    with pytest.raises(E2EConfigError, match="max_delta_status"):
        E2EReceiver(max_delta_status=16)
    with pytest.raises(E2EConfigError, match="timeout_s"):
        E2EReceiver(timeout_s=0)
    with pytest.raises(ValueError, match="ok_to_valid"):
        E2EReceiver(ok_to_valid=0)


# --------------------------------------------------------------------------- block == scalar

ids_strategy = st.sampled_from([0x100, 0x101, 0x080, 0x0A0, 0x7FF])


@st.composite
def frame_sequences(draw):
    """Per-ID counter streams with random repeats, jumps, reorders, restarts and CRC errors."""
    n = draw(st.integers(1, 200))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    ids = rng.choice([0x100, 0x101, 0x080, 0x0A0, 0x7FF], size=n, p=[0.35, 0.35, 0.1, 0.1, 0.1])
    counters = np.zeros(n, dtype=np.int64)
    nxt: dict[int, int] = {}
    for i, arbitration_id in enumerate(ids):
        modulus = 16 if arbitration_id < 0x100 else 256
        c = nxt.get(arbitration_id, int(rng.integers(modulus)))
        event = rng.random()
        if event < 0.05:
            c = c - 1  # repeat
        elif event < 0.10:
            c = c + int(rng.integers(2, 40))  # jump
        elif event < 0.13:
            c = c - int(rng.integers(2, 10))  # stale
        elif event < 0.15:
            c = int(rng.integers(modulus))  # restart
        counters[i] = c % modulus
        nxt[arbitration_id] = (c + 1) % modulus
    crc_ok = rng.random(n) > 0.05
    timestamps = np.cumsum(rng.exponential(0.01, n))
    return ids, counters, crc_ok, timestamps


@settings(max_examples=120, deadline=None)
@given(frame_sequences(), st.integers(1, 4))
def test_check_block_equals_check_row_by_row(sequence, n_blocks):
    ids, counters, crc_ok, timestamps = sequence
    scalar, block = E2EReceiver(), E2EReceiver()
    expected = [scalar.check(*row) for row in zip(ids.tolist(), counters.tolist(), crc_ok.tolist(), timestamps.tolist())]
    got_status, got_lost = [], []
    for part in np.array_split(np.arange(len(ids)), n_blocks):
        s, lost = block.check_block(ids[part], counters[part], crc_ok[part], timestamps[part])
        got_status += s.tolist()
        got_lost += lost.tolist()
    assert got_status == [int(s) for s, _ in expected]
    assert got_lost == [lost for _, lost in expected]
    assert block.stats == scalar.stats
    assert block.states() == scalar.states()


def test_check_block_clean_stream_statistics():
    ticks = np.arange(1000)
    keep = np.ones(1000, dtype=bool)
    keep[[100, 500, 501]] = False  # three frames lost on the way
    ids = np.full(keep.sum(), MOTOR)
    rx = E2EReceiver()
    s, lost = rx.check_block(ids, ticks[keep] % 256, np.ones(keep.sum(), bool), ticks[keep] * 0.002)
    assert rx.stats["lost_frames"] == 3 and rx.stats["some_lost"] == 2
    assert np.count_nonzero(s == S.OK_SOME_LOST) == 2 and lost.sum() == 3
