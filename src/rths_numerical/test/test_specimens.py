"""The specimen registry: each entry's reference, frame and parameters (Table 4, eq. 24, 46)."""

import numpy as np
import pytest

from rths_numerical.dtm import FRAME_MASS_KG, TABLE4
from rths_numerical.mr_damper import MRSpecimen
from rths_numerical.reference import DTMSpecimen
from rths_numerical.specimens import (
    DEFAULT_SPECIMEN,
    SPECIMENS,
    specimen_of,
    specimen_settings,
)

DT = 1 / 1024


def _stroke(n=2048):
    t = np.arange(n) * DT
    return 0.004 * np.sin(2 * np.pi * 2.0 * t) * np.minimum(t / 0.3, 1.0)


@pytest.mark.parametrize('name', list(TABLE4))
def test_a_table4_entry_is_the_dtm_on_its_frame(name):
    entry = SPECIMENS.entry(name)
    assert entry.table_mass == TABLE4[name] and entry.frame_mass_kg == FRAME_MASS_KG
    ref, old = entry.reference(DT), DTMSpecimen(name, DT)
    x = _stroke()
    assert [ref(v)[0] for v in x] == [old(v)[0] for v in x]
    # riding the table: the absolute frame; P_I^E's mass is frame + moving mass (seed 5.1)
    assert entry.numerical_params() == {'interface_frame': 'absolute',
                                        'specimen_mass_kg': FRAME_MASS_KG + TABLE4[name].m_d}


def test_the_mr_entry_is_the_damper_between_floor_and_ground():
    entry = SPECIMENS.entry('mr')
    ref = entry.reference(DT, {'mr_voltage_v': 1.5})
    old = MRSpecimen(DT, 1.5)
    x = _stroke()
    assert [ref(v)[0] for v in x] == [old(v)[0] for v in x]
    assert entry.numerical_params() == {'interface_frame': 'relative', 'specimen_mass_kg': 0.0}
    assert entry.settings({}) == {'mr_voltage_v': 1.0, 'mr_substeps': 8}


def test_the_bare_table_has_no_reference_and_the_default_is_the_seeds():
    assert SPECIMENS.entry('none').reference(DT) is None
    assert DEFAULT_SPECIMEN == 'valve4'                      # seed section 6.2
    assert specimen_of({'dtm': 'novalve'}) == 'novalve'      # a bag recorded before the rename
    assert specimen_of({}) == DEFAULT_SPECIMEN


def test_specimen_settings_are_checked():
    assert specimen_settings('mr', ['mr_voltage_v=2'], '--x') == {'mr_voltage_v': 2.0}
    with pytest.raises(ValueError, match='specimen valve4 takes no parameters'):
        specimen_settings('valve4', ['mr_voltage_v=2'], '--x')
    with pytest.raises(ValueError, match=r'outside its range \[0, 10\]'):
        specimen_settings('mr', ['mr_voltage_v=-1'], '--x')
    with pytest.raises(ValueError, match="specimen = 'valve5' is an unknown specimen"):
        specimen_settings('valve5', [], '--x')
