"""
The line's messages between segments read strictly, as protocol and as physics (no ROS).

Every payload that killed a segment or jammed the line is refused with one line naming
the field; a hand-over the line itself makes is taken bit for bit; hypothesis draws
messages of every shape and size: each is taken (and then valid) or refused with
``HandoverError``, never another exception.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from sorter_sim.runtime.cell import Cell, Handoff, ParcelSpec
from sorter_sim.runtime.handover import (
    MAX_ID,
    HandoverError,
    HandoverLimits,
    parse_answer_fields,
    parse_claim,
    parse_claim_fields,
    parse_handover_fields,
    parse_horizon_fields,
    parse_left_fields,
    parse_progress_fields,
)
from sorter_sim.runtime.line import Line, default_layout
from sorter_sim.runtime.params import SPECS, CellParams

PARAMS = CellParams.defaults()
LIMITS = HandoverLimits.from_params(PARAMS)


def fields(h: Handoff, **changes) -> list:
    """Return a hand-over's (key, value) pairs as ``segments.handover_message`` writes them."""
    values = {
        't_ns': str(h.t_ns),
        'id': str(h.parcel_id),
        'label': h.label,
        'state': ' '.join(float(v).hex() for v in h.state),
        'mode': str(h.mode),
        'gauge': ' '.join(float(v).hex() for v in h.gauge),
        'dims': ' '.join(float(v).hex() for v in h.dims),
        'wall_ns': '1',
    }
    values.update(changes)
    return list(values.items())


def real_handoffs(n: int = 6) -> list:
    """Return the hand-overs a station of the line really makes (parcels of all sizes)."""
    line = Line(PARAMS, default_layout(2, PARAMS))
    line.hand_on = True
    for c in line.stations:
        c.keep_handoffs = True
    lo_a, hi_a = SPECS['parcel_A'].lo, 1.2
    for i in range(n):
        a = lo_a + 0.05 + (hi_a - lo_a) * i / n
        line.stations[0].induct(ParcelSpec(a, 0.3, 1.0 + i, label=f'P{i}', phi0=0.2 * (i % 3 - 1)))
    out = []
    while len(out) < n and line.t < 60.0:
        line.advance(100)
        out += line.take_outgoing()
    return out


REAL = real_handoffs()


def test_every_hand_over_the_line_makes_is_taken_bit_for_bit():
    assert len(REAL) == 6
    for h in REAL:
        got, wall = parse_handover_fields(fields(h), LIMITS)
        assert got == h and wall == 1


# the payloads that killed a segment process or jammed the line, and what is named
H = REAL[0]
FORGED = [
    ({'dims': f'inf {(0.3).hex()} {(1.0).hex()}'}, 'dims must be finite'),
    ({'dims': f'{(1e6).hex()} {(0.3).hex()} {(1.0).hex()}'}, 'dims: A must be in'),
    ({'dims': f'{(1e-300).hex()} {(0.3).hex()} {(1.0).hex()}'}, 'dims: A must be in'),
    ({'id': str(2**64)}, 'id must be'),
    ({'id': '-5'}, 'id must be in'),
    ({'mode': str(10**30)}, 'mode must be'),
    ({'mode': '2'}, 'mode must be in'),
    ({'gauge': ''}, 'gauge must be 7'),
    ({'gauge': ' '.join(['0x0p+0'] * 50)}, 'gauge must be 7'),
    ({'state': '0x1p+99999 0 0 0 0 0'}, 'state must be 6 hexadecimal floats'),
    ({'state': 'nan 0x0p+0 0x0p+0 0x0p+0 0x0p+0 0x0p+0'}, 'state must be finite'),
    (
        {'state': ' '.join(float(v).hex() for v in (*H.state[:3], math.inf, *H.state[4:]))},
        'finite',
    ),
    (
        {'state': ' '.join(float(v).hex() for v in (H.state[0], 1e300, *H.state[2:]))},
        'on the belt',
    ),
    (
        {
            'state': ' '.join(
                float(v).hex() for v in (H.state[0], H.state[1], H.state[2], 30.0, 0.0, 0.0)
            )
        },
        'a speed of at most',
    ),
    ({'state': ' '.join(float(v).hex() for v in (50.0, *H.state[1:]))}, 'at the straight exit'),
    ({'label': 'x' * 10_000}, 'label is at most'),
    ({'label': 'P\x00\x1b[2J'}, 'a label is'),
    ({'label': ''}, 'a label is'),
    ({'t_ns': '-1'}, 't_ns must be in'),
    ({'t_ns': '٣'}, 't_ns must be a decimal integer'),
    ({'t_ns': str(H.t_ns + 1)}, 'the end of a control period'),
]


@pytest.mark.parametrize('change, named', FORGED, ids=[n for _, n in FORGED])
def test_a_forged_hand_over_is_refused_naming_its_field(change, named):
    with pytest.raises(HandoverError, match=None) as err:
        parse_handover_fields(fields(H, **change), LIMITS)
    text = str(err.value)
    assert named in text and '\n' not in text and len(text) < 300


def test_fields_missing_unknown_or_twice_are_refused():
    with pytest.raises(HandoverError, match='without t_ns'):
        parse_handover_fields([kv for kv in fields(H) if kv[0] != 't_ns'], LIMITS)
    with pytest.raises(HandoverError, match='has no field'):
        parse_handover_fields(fields(H) + [('teleport', '1')], LIMITS)
    with pytest.raises(HandoverError, match='twice'):
        parse_handover_fields(fields(H) + [('id', '3')], LIMITS)
    with pytest.raises(HandoverError, match='without'):
        parse_handover_fields([], LIMITS)


def test_control_messages_are_read_strictly():
    assert parse_horizon_fields([('t_ns', '5000000'), ('identity', '1-2')]) == (5_000_000, '1-2')
    assert parse_left_fields([('ids', '1 2 3'), ('identity', '1-2')]) == ([1, 2, 3], '1-2')
    assert parse_claim_fields([('identity', '12-34'), ('first', '2'), ('stations', '2')], 4) == (
        '12-34',
        2,
        2,
    )
    for bad, call in (
        ([('t_ns', '1e18')], parse_horizon_fields),
        ([('t_ns', str(2**70))], parse_horizon_fields),
        ([('ids', '1 -2')], parse_left_fields),
        ([('ids', ' '.join(['1'] * 1001))], parse_left_fields),
    ):
        with pytest.raises(HandoverError):
            call(bad)
    # a progress for stations the line does not have: the barrier's {first: 40, k: 0}
    with pytest.raises(HandoverError, match='first must be in'):
        parse_progress_fields(
            [('identity', '1-2'), ('first', '40'), ('stations', '1'), ('k', '0')], 4
        )
    with pytest.raises(HandoverError, match='stations must be in'):
        parse_claim_fields([('identity', '1-2'), ('first', '2'), ('stations', '3')], 4)
    with pytest.raises(HandoverError, match='identity'):
        parse_claim_fields([('identity', 'me'), ('first', '0'), ('stations', '1')], 4)
    # a claim names its node (a restart under the same name succeeds it) and an answer
    # to a hello names the hello
    claim = [('identity', '12-34'), ('first', '2'), ('stations', '2')]
    assert parse_claim(claim + [('node', '/line/sorter_line_b')], 4) == (
        '12-34',
        2,
        2,
        '/line/sorter_line_b',
    )
    assert parse_claim(claim, 4)[3] == ''
    for node in ('sorter_line_b', '/a b', '/x/', '/9lives', '/' + 'n' * 600):
        with pytest.raises(HandoverError, match='node'):
            parse_claim(claim + [('node', node)], 4)
    assert parse_answer_fields([('identity', '1-2'), ('hello', '3-4')]) == ('1-2', '3-4')
    with pytest.raises(HandoverError, match='without hello'):
        parse_answer_fields([('identity', '1-2')])


def test_a_taken_hand_over_is_a_parcel_a_station_can_integrate():
    """What the validator lets through, a station takes and integrates to an outcome."""
    cell = Cell(PARAMS.with_changes({'arrival': 'none'}))
    h, _ = parse_handover_fields(fields(REAL[1]), LIMITS)
    pitch = PARAMS.exit_x - PARAMS.induct_x
    cell.hand_in(h, -pitch)
    cell.advance(8000)  # 6 m of station at 1.5 m/s
    assert cell.n_in_flight == 0 and not cell.jam


FUZZ = settings(
    max_examples=800,
    deadline=None,
    derandomize=True,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=list(HealthCheck),
)
floats_text = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(float.hex),
    st.sampled_from(['0x1p+99999', '-0x1p-99999', 'inf', 'nan', '', '1', '0x', '٣']),
    st.text(max_size=30),
)
vector = st.lists(floats_text, max_size=60).map(' '.join)
integer_text = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.sampled_from(['', '-', '1e18', '٣', ' 5 ', '0x10', '1_000', '9' * 5000]),
    st.text(max_size=20),
)
# each field either the real one, or drawn from its kind's strategy or any text
FIELD_DRAWS = {
    't_ns': integer_text,
    'id': integer_text,
    'mode': integer_text,
    'wall_ns': integer_text,
    'label': st.one_of(st.text(max_size=80), st.just('x' * 10_000)),
    'state': vector,
    'gauge': vector,
    'dims': vector,
}


@st.composite
def messages(draw):
    base = dict(fields(REAL[draw(st.integers(0, len(REAL) - 1))]))
    out = []
    for key, value in base.items():
        how = draw(st.sampled_from(['keep', 'keep', 'draw', 'drop']))
        if how == 'keep':
            out.append((key, value))
        elif how == 'draw':
            out.append((key, draw(FIELD_DRAWS[key])))
    out += draw(st.lists(st.tuples(st.text(max_size=10), st.text(max_size=20)), max_size=2))
    return out


COUNTS = {'inputs': 0, 'taken': 0, 'refused': 0}


@pytest.mark.slow
@FUZZ
@given(msg=messages())
def test_fuzz_the_hand_over_parser_takes_only_valid_parcels_and_refuses_the_rest(msg):
    COUNTS['inputs'] += 1
    try:
        h, wall = parse_handover_fields(msg, LIMITS)
    except HandoverError as exc:
        COUNTS['refused'] += 1
        assert '\n' not in str(exc) and len(str(exc)) < 400
        return
    COUNTS['taken'] += 1
    assert all(math.isfinite(v) for v in (*h.state, *h.gauge, *h.dims))
    assert 0 <= h.parcel_id <= MAX_ID and h.mode in (-1, 0, 1)
    assert len(h.state) == 6 and len(h.gauge) == 7 and len(h.dims) == 3
    assert h.t_ns % LIMITS.dt_ns == 0 and wall >= 0


@pytest.mark.slow
@settings(FUZZ, max_examples=400)
@given(
    pairs=st.lists(
        st.tuples(
            st.sampled_from(['t_ns', 'ids', 'identity', 'first', 'stations', 'k', 'x']),
            integer_text,
        ),
        max_size=5,
    )
)
def test_fuzz_the_control_messages_refuse_with_their_own_error_only(pairs):
    for call in (
        parse_horizon_fields,
        parse_left_fields,
        lambda p: parse_claim_fields(p, 12),
        lambda p: parse_progress_fields(p, 12),
    ):
        COUNTS['inputs'] += 1
        try:
            call(pairs)
        except HandoverError:
            COUNTS['refused'] += 1


@pytest.mark.slow
def test_fuzz_counts_for_the_record():
    """Print what the fuzz tests above drew (``-s``): inputs, taken, refused; none escaped."""
    print(f'\nhand-over parser fuzzed: {COUNTS}')
    assert COUNTS['inputs'] == 0 or COUNTS['taken'] + COUNTS['refused'] <= COUNTS['inputs']
