"""Registries and the schema's allowed values: lookups explain, choices are checked."""

from typing import NamedTuple

import pytest

from rths_common.params import Spec, check_spec, node_schema, renamed
from rths_common.registry import Registry


class Entry(NamedTuple):
    summary: str


def test_registry_lookup_lists_the_choices():
    reg = Registry('colour', 'colour', {'red': Entry('warm'), 'blue': Entry('cold')})
    assert reg.names() == ('red', 'blue') and reg.entry('blue').summary == 'cold'
    with pytest.raises(ValueError, match=r"bridge.yaml: colour = 'green' is an unknown colour; "
                                         'use one of red, blue'):
        reg.entry('green', 'bridge.yaml')
    with pytest.raises(ValueError, match='already registered'):
        reg.add('red', Entry('again'))
    with pytest.raises(ValueError, match='one-line summary'):
        reg.add('grey', Entry(''))
    assert '| `red` | warm |' in reg.markdown()


def test_spec_choices_checked_and_described():
    schema = node_schema(('mode',), {'scheme': ('wls', 'design scheme')},
                         choices={'scheme': ('ls', 'wls')})
    assert schema['mode'].choices == ('lockstep', 'realtime')
    assert schema['scheme'].text() == 'design scheme (one of: ls, wls)'
    check_spec('scheme', 'wls', schema['scheme'])
    with pytest.raises(ValueError, match="scheme = 'lms' is not one of ls, wls"):
        check_spec('scheme', 'lms', schema['scheme'])
    check_spec('x', 5, Spec('[-] x', (0, 10)))


def test_a_per_channel_parameter_takes_a_number_or_a_list_each_in_range():
    schema = node_schema((), {'stroke_m': '[m] stroke', 'fs_hz': '[Hz] rate'},
                         ranges={'stroke_m': (0.0, 1.0), 'fs_hz': (1.0, 1e5)},
                         per_channel=('stroke_m',))
    stroke, fs = schema['stroke_m'], schema['fs_hz']
    assert stroke.per_channel and not fs.per_channel
    assert 'a list of one per actuator' in stroke.text()
    check_spec('stroke_m', 0.2, stroke)
    check_spec('stroke_m', [0.2, 0.03], stroke)
    with pytest.raises(ValueError, match=r'parameter stroke_m\[1\] = 3.0 is outside its range '
                                         r'\[0, 1\] \[m\]'):
        check_spec('stroke_m', [0.2, 3.0], stroke)
    with pytest.raises(ValueError, match='stroke_m is an empty list'):
        check_spec('stroke_m', [], stroke)
    with pytest.raises(ValueError, match=r'fs_hz = \[1024.0\] must be a number'):
        check_spec('fs_hz', [1024.0], fs)


def test_renamed_key_is_accepted_with_one_note(capsys):
    out = renamed({'dtm': 'valve1', 'seed': 1}, 'dtm', 'specimen', 'bridge.yaml')
    assert out == {'specimen': 'valve1', 'seed': 1}
    renamed({'dtm': 'valve1'}, 'dtm', 'specimen', 'bridge.yaml')
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and "'dtm' is now called 'specimen'" in err
    # both given: the later one wins (an override of a file that has the new key)
    assert renamed({'specimen': 'b', 'dtm': 'a'}, 'dtm', 'specimen', 'x') == {'specimen': 'a'}
    assert renamed({'dtm': 'a', 'specimen': 'b'}, 'dtm', 'specimen', 'y') == {'specimen': 'b'}
