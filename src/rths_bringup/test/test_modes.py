"""One timing mode for the whole graph (rths launch --mode; preflight.check_modes)."""

import pytest

from rths_bringup.preflight import check_modes


def test_mixed_modes_are_refused_and_one_override_sets_all():
    files = {'numerical': {'mode': 'realtime'}, 'compensator': {}, 'bridge': {'mode': 'lockstep'}}
    with pytest.raises(ValueError, match='different timing modes.*--mode'):
        check_modes('cfg', files, {})
    every = {n: {'mode': 'lockstep'} for n in files}
    assert check_modes('cfg', files, every) == 'lockstep'
    assert check_modes('cfg', {'numerical': {}, 'compensator': {}, 'bridge': {}}, {}) == \
        'lockstep'
    with pytest.raises(ValueError, match="mode = 'fast'"):
        check_modes('cfg', {'numerical': {'mode': 'fast'}}, {})


def test_launcher_gives_a_node_without_mode_the_runs_mode(tmp_path):
    import shutil

    import yaml

    from rths_bringup.commands import default_config_dir
    from rths_bringup.launcher import Launcher
    cfg = tmp_path / 'config'
    shutil.copytree(default_config_dir(), cfg)
    doc = yaml.safe_load((cfg / 'numerical.yaml').read_text())
    doc['numerical']['ros__parameters']['mode'] = 'realtime'
    (cfg / 'numerical.yaml').write_text(yaml.safe_dump(doc))
    launcher = Launcher(cfg, preflight=False)
    assert launcher.overrides['compensator']['mode'] == 'realtime'   # its file has none
    assert 'mode' not in launcher.overrides.get('bridge', {})         # its file says lockstep
    launcher = Launcher(cfg, mode='lockstep', preflight=False)
    assert {launcher.overrides[n]['mode'] for n in ('numerical', 'compensator', 'bridge')} == \
        {'lockstep'}


def test_the_mode_written_in_every_file_passes_the_preflight(tmp_path):
    """mode: realtime in all three files (as rths bench loop writes them) is one mode."""
    import shutil

    import yaml

    from rths_bringup.commands import default_config_dir
    from rths_bringup.preflight import check_config
    cfg = tmp_path / 'config'
    shutil.copytree(default_config_dir(), cfg)
    for node in ('numerical', 'compensator', 'bridge'):
        doc = yaml.safe_load((cfg / f'{node}.yaml').read_text())
        doc[node]['ros__parameters']['mode'] = 'realtime'
        (cfg / f'{node}.yaml').write_text(yaml.safe_dump(doc))
    check_config(cfg)
