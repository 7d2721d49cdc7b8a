"""The bridge's command delay line is part of the plant the compensator is designed on.

Issue 8: "Show how the compensator design absorbs a known constant network
delay when the identification run is made through the same network (the
identified plant then includes it)."  Over a network the bridge buffers
commands for D steps (``command_delay_steps``: command k is written at tick
k + D), so the round trip may take D + 1 periods; the loop then sees the
plant P(z) z^-D.  This test runs the whole lab procedure (``rths run``:
identification, ARX, WLS design, RTHS, review) in lock-step with D = 3 and
checks that the identification saw the extra 3 steps and the compensator
removed them.  It records sqlite3 bags (``--storage sqlite3``; the default is
MCAP) and checks that the run leaves its ``--config`` untouched (issue 17).
The network version of the same study, through the emulated link at 512 Hz, is
``rths bench absorb-delay`` (docs/bench/absorb_delay_512hz.json).
"""

import json
import shutil

import yaml

from rths_system_tests import REPO, rths

D = 3
FS_HZ = 1024.0


def test_identification_through_the_delay_line_lets_the_compensator_absorb_it(tmp_path):
    from rths_common import bagio
    from rths_review.tracking import weighted_delay_ms

    config = tmp_path / 'config'
    shutil.copytree(REPO / 'config', config)
    path = config / 'bridge.yaml'
    doc = yaml.safe_load(path.read_text())
    doc['bridge']['ros__parameters']['command_delay_steps'] = D
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    before = {p.name: p.read_bytes() for p in config.iterdir() if p.is_file()}
    out = tmp_path / 'run'
    # composed: the lock-step history is bit for bit the processes layout's (test_composed),
    # in about half the time
    rths('run', '--config', config, '--duration', 8, '--ident-duration', 15, '--out', out,
         '--layout', 'composed',
         '--storage', 'sqlite3', timeout=900)

    # Issue 17: a run writes its plant and taps only into its own results directory (the RTHS
    # phase's params file holds the designed taps); config/ is left byte for byte as it was.
    assert {p.name: p.read_bytes() for p in config.iterdir() if p.is_file()} == before
    designed = yaml.safe_load((out / 'compensator.yaml').read_text())
    ran = yaml.safe_load((out / 'rths' / 'config' / 'compensator.yaml').read_text())
    assert ran['compensator']['ros__parameters']['taps'] == \
        designed['compensator']['ros__parameters']['taps']
    assert (out / 'plant.yaml').is_file()
    # The RTHS phase drives the building, not the identification's 0-64 Hz excitation (from
    # 2026-11-25 a reassigned variable in rths run passed the excitation on: a compensator
    # designed for 0-10 Hz then amplified it into the velocity limit at step 112)
    numerical = yaml.safe_load((out / 'rths' / 'config' / 'numerical.yaml').read_text())
    assert numerical['numerical']['ros__parameters']['model'] == 'building2story'
    assert numerical['numerical']['ros__parameters']['record'] == 'kobe'
    # ... and the one-file review beside summary.json, every plot embedded
    report = (out / 'report.html').read_text()
    assert report.count('src="data:image/png;base64,') == 3
    assert 'http://' not in report and 'https://' not in report
    # the older sqlite3 storage is still written (--storage sqlite3) and read by every step
    for phase in ('identification', 'rths'):
        meta = yaml.safe_load((out / phase / 'bag' / 'metadata.yaml').read_text())
        assert meta['rosbag2_bagfile_information']['storage_identifier'] == 'sqlite3'

    # The identification bag: the actuator alone (applied -> measured at the same tick)
    # and the plant the loop sees (command of step k -> measurement k) differ by D steps.
    bag = out / 'identification' / 'bag'
    assert bagio.delay_steps(bag) == D
    _, applied, measured = bagio.read_identification(bag, loop=False)
    actuator_ms = weighted_delay_ms(applied, measured, FS_HZ)
    _, command, measured = bagio.read_identification(bag, loop=True)
    loop_ms = weighted_delay_ms(command, measured, FS_HZ)
    assert abs(loop_ms - actuator_ms - 1000.0 * D / FS_HZ) < 0.3, (loop_ms, actuator_ms)

    # The RTHS review's plant delay (PSD-weighted over the building's response) includes the
    # D steps too; the compensator designed on that plant removes both (issue 6: |delay| < 1 ms).
    summary = json.loads((out / 'summary.json').read_text())
    _, applied, measured = bagio.read_identification(out / 'rths' / 'bag', loop=False)
    actuator_rths_ms = weighted_delay_ms(applied, measured, FS_HZ)
    assert abs(summary['delay_ms_before'] - actuator_rths_ms - 1000.0 * D / FS_HZ) < 0.3, \
        (summary['delay_ms_before'], actuator_rths_ms)
    assert abs(summary['delay_ms_after']) < 1.0, summary['delay_ms_after']
    assert summary['tracking_rel_rms_pct_after'] < 0.1 * summary['tracking_rel_rms_pct_before']
