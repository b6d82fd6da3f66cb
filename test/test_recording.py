"""ros/recording.py's Recording, the one bag writer of sim_node and the headless tools: the
order a batch's held-back /clock takes in the bag, and what a failed write does."""
from __future__ import annotations

import pytest

from abd_joint_sim.record import read_messages
from abd_joint_sim.record.bag import BagError
from abd_joint_sim.ros import convert
from abd_joint_sim.ros.params import config_from_values
from abd_joint_sim.ros.recording import bag_custom_data, Recording, resolve_root


def _open(path, on_error=None) -> Recording:
    config = config_from_values({'scene': 'hinge'})
    bag_data = bag_custom_data(config, 'hinge', 'dt: 0.001\n', 0.001, ['hinge'])
    return Recording.open(str(path), bag_data, ['hinge'], resolve_root, '/sim_node',
                          markers=False, on_error=on_error)


def test_a_batch_writes_its_clock_before_anything_else(tmp_path):
    clock = convert.ClockEncoder()
    states = convert.JointStateEncoder(['hinge'], 'world')
    rec = _open(tmp_path / 'bag')
    rec.batch_begin()
    rec.clocks([1, 2], clock.encode_many([1, 2]))
    rec.clock(3, clock.encode(3))
    assert rec.counts == {}                       # held back
    rec.joint_state(3, states.encode(3, [0.5], [0.0], [0.0]))
    rec.clock(4, clock.encode(4))
    rec.batch_end()
    rec.close()
    rec.close()                                   # idempotent
    got = [(topic, t) for topic, _, t, _ in read_messages(tmp_path / 'bag')]
    assert got == [('/clock', 1), ('/clock', 2), ('/clock', 3), ('/joint_states', 3),
                   ('/clock', 4)]
    assert rec.counts == {'/clock': 4, '/joint_states': 1}


def test_a_failed_write_raises_or_goes_to_on_error(tmp_path):
    rec = _open(tmp_path / 'raises')
    rec.writer.close()                            # every write fails from here on
    with pytest.raises(BagError):
        rec.write('/diagnostics', 0, b'\0\1\0\0')
    errors = []
    rec = _open(tmp_path / 'reports', on_error=errors.append)
    rec.batch_begin()
    rec.clock(1, convert.ClockEncoder().encode(1))
    rec.writer.close()
    rec.batch_end()                               # the held /clock cannot be written
    assert len(errors) == 1 and errors[0].startswith('writing /clock failed')
    assert rec.counts == {}
