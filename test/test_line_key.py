"""
The line key, and what no line takes even without one (``line_key``, ``handover``).

The key file (``sorter line-key``: new, random, mode 0600, never overwritten, refused
when others can read it), the seal (a message altered, moved to another topic, sent
again or without a seal is refused; one sealed under the key is taken once), and the
plausibility checks an open line keeps: a claim from an identity older than the host,
an exit into a chute of another station, a loss always with its cause.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import subprocess
import sys
import time

import pytest

from sorter_control.wcs import LineWcs, PlanError, parse_exit
from sorter_ros.line_key import (
    FRESH_S,
    KEY_ENV,
    LineKeyError,
    SealCheck,
    SealError,
    Sealer,
    _signed_bytes,
    key_from_env,
    new_key_file,
    read_key_file,
)
from sorter_sim.runtime.handover import HandoverError, check_claim_age, host_boot_ns

TOPIC = '/line/handover/S02'
HEAD = ('horizon', '0', '', '')
PAIRS = [('t_ns', '5000000'), ('identity', f'{os.getpid()}-{time.time_ns()}')]


def test_sorter_line_key_writes_a_new_key_for_its_owner_only_and_never_overwrites(tmp_path):
    path = tmp_path / 'line.key'
    run = [sys.executable, '-m', 'sorter_cell', 'line-key', str(path)]
    out = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    key = read_key_file(str(path))
    assert len(key) == 32
    assert key.hex() not in out.stdout + out.stderr  # the path is said, never the key
    again = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and 'exists already' in again.stderr
    assert again.stderr.count('\n') == 1
    assert read_key_file(str(path)) == key
    other = tmp_path / 'other.key'
    new_key_file(str(other))
    assert read_key_file(str(other)) != key  # random, not derived


def test_a_key_file_others_can_read_or_that_holds_no_key_is_refused(tmp_path):
    path = tmp_path / 'k'
    new_key_file(str(path))
    os.chmod(path, 0o644)
    with pytest.raises(LineKeyError, match='readable by others'):
        read_key_file(str(path))
    bad = tmp_path / 'bad'
    bad.write_text('not a key\n')
    os.chmod(bad, 0o600)
    with pytest.raises(LineKeyError, match='64 hexadecimal digits'):
        read_key_file(str(bad))
    with pytest.raises(LineKeyError, match='cannot open'):
        read_key_file(str(tmp_path / 'missing'))
    link = tmp_path / 'link'
    link.symlink_to(bad)
    with pytest.raises(LineKeyError, match='cannot open'):
        read_key_file(str(link))
    assert key_from_env({}) is None
    os.chmod(path, 0o600)
    assert key_from_env({KEY_ENV: str(path)}) == read_key_file(str(path))


def test_a_sealed_message_is_taken_once_and_an_altered_moved_or_unsealed_one_never():
    key = os.urandom(32)
    sealer, check = Sealer(key), SealCheck(key)
    seal = ('seal', sealer.seal(TOPIC, HEAD, PAIRS))
    assert check.check(TOPIC, HEAD, PAIRS + [seal]) == PAIRS
    with pytest.raises(SealError, match='a replay'):
        check.check(TOPIC, HEAD, PAIRS + [seal])
    fresh = ('seal', sealer.seal(TOPIC, HEAD, PAIRS))
    altered = [('t_ns', '9000000'), PAIRS[1], fresh]
    with pytest.raises(SealError, match='not the line key'):
        check.check(TOPIC, HEAD, altered)
    with pytest.raises(SealError, match='not the line key'):
        check.check('/line/handover/S03', HEAD, PAIRS + [fresh])  # another topic
    with pytest.raises(SealError, match='not the line key'):
        check.check(TOPIC, ('parcel', '0', '', ''), PAIRS + [fresh])  # another kind
    with pytest.raises(SealError, match='not sealed'):
        check.check(TOPIC, HEAD, PAIRS)
    with pytest.raises(SealError, match='not the line key'):
        SealCheck(os.urandom(32)).check(TOPIC, HEAD, PAIRS + [fresh])  # another line's key
    for junk in ('', 'x', 'a b c', f'{"0" * 16} 1 {"g" * 64}', f'{"0" * 16} ٣ {"0" * 64}'):
        with pytest.raises(SealError):
            check.check(TOPIC, HEAD, PAIRS + [('seal', junk)])
    assert check.check(TOPIC, HEAD, PAIRS + [fresh]) == PAIRS  # none of the above counted
    assert check.counts == {'unsealed': 1, 'bad_seal': 8, 'replayed': 1}


def test_a_sender_first_heard_with_an_old_counter_is_a_replay():
    """A message recorded from a sender long gone is refused by a segment started later."""
    key = os.urandom(32)
    old = Sealer(key)
    old._counter = time.time_ns() + 10**12  # the counter is at least the last one plus one
    sealed_later = old.seal(TOPIC, HEAD, PAIRS)
    assert SealCheck(key).check(TOPIC, HEAD, PAIRS + [('seal', sealed_later)]) == PAIRS
    c = time.time_ns() - int((FRESH_S + 5) * 1e9)
    tag = hmac.new(key, _signed_bytes(TOPIC, HEAD, PAIRS, 'f' * 16, c), hashlib.sha256)
    recorded = ('seal', f'{"f" * 16} {c} {tag.hexdigest()}')
    with pytest.raises(SealError, match='a replay: sender f+ first heard'):
        SealCheck(key).check(TOPIC, HEAD, PAIRS + [recorded])


def test_a_claim_from_an_identity_older_than_the_host_or_from_the_future_is_refused():
    with pytest.raises(HandoverError, match='older than the line itself'):
        check_claim_age('4242-1')  # the forged claims of the adversarial pass
    with pytest.raises(HandoverError, match='from now'):
        check_claim_age(f'4242-{time.time_ns() + 3600 * 10**9}')
    check_claim_age(f'{os.getpid()}-{time.time_ns()}')  # a segment started now
    assert 0 < host_boot_ns() < time.time_ns()


CHUTES = [('S01L', 'S01R'), ('S02L', 'S02R'), ('S03L', 'S03R')]


def _exit(**changes):
    v = {'id': '7', 'label': 'P00007', 'exit': 'S03R', 'station': 'S03', 't': '1.5'}
    v.update(changes)
    return list(v.items())


def test_an_exit_into_another_stations_chute_is_refused_and_a_loss_has_its_cause():
    assert parse_exit(_exit(), CHUTES)[:3] == ('P00007', 'S03R', 2)
    with pytest.raises(PlanError, match='S03R at station S01'):
        parse_exit(_exit(station='S01'), CHUTES)
    label, exit, k, t, cause = parse_exit(
        _exit(exit='lost', station='S02', cause='handed over twice, differently'), CHUTES
    )
    wcs = LineWcs(CHUTES)
    d = wcs.exited(label, exit, k, t, cause)
    assert (d.code, d.cause, d.station) == ('lost', 'handed over twice, differently', 'S02')
    # lost on the straight end: it passed its station, which never answered: said so
    wcs.set_plan('v1', [('D01', 'S01L')])
    wcs.request('P00008', 'D01')
    d = wcs.exited('P00008', 'straight_end', 2, 2.0)
    assert d.code == 'lost' and d.cause


@pytest.mark.parametrize(
    'command',
    [
        ['-m', 'sorter_sim.frontends.line_node'],
        ['-m', 'sorter_control.wcs_node'],
        ['-m', 'sorter_cell', 'demo', '--stations', '2', '--segments', '2'],
    ],
    ids=['line_node', 'wcs_node', 'line demo'],
)
def test_a_key_file_others_can_read_stops_the_line_in_one_line(tmp_path, command):
    path = tmp_path / 'line.key'
    new_key_file(str(path))
    os.chmod(path, 0o644)
    done = subprocess.run(
        [sys.executable, *command],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, KEY_ENV: str(path)},
    )
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert 'readable by others' in lines[-1] and str(path) in lines[-1], lines
    assert 'Traceback' not in done.stderr
    assert path.read_text().strip() not in done.stdout + done.stderr
