"""``rths install-taps RUN_DIR``: the explicit step that makes a run's taps the lab's taps."""

from rths_bringup.cli import main
from rths_compensator.params import load_compensator_params, write_compensator_params


def _run_dir(tmp_path, plant=True):
    run = tmp_path / 'run'
    run.mkdir()
    write_compensator_params(run / 'compensator.yaml', [2.0, -1.0], [1.0], 1024.0, 'wls',
                             provenance={'plant': str(run / 'plant.yaml'), 'n_taps': 2})
    if plant:
        (run / 'plant.yaml').write_text('plant: identified\n')
    return run


def test_install_taps_copies_taps_and_plant_into_the_config(tmp_path, capsys):
    run = _run_dir(tmp_path)
    config = tmp_path / 'config'
    config.mkdir()
    assert main(['install-taps', str(run), '--config', str(config)]) == 0
    params = load_compensator_params(config / 'compensator.yaml')
    assert params['taps'] == [2.0, -1.0] and params['provenance']['n_taps'] == 2
    assert params['provenance']['plant'] == 'plant.yaml'  # beside it in the config directory
    assert (config / 'plant.yaml').read_text() == 'plant: identified\n'
    assert 'wrote' in capsys.readouterr().out


def test_install_taps_of_an_external_plant_keeps_its_reference(tmp_path):
    run = _run_dir(tmp_path, plant=False)
    config = tmp_path / 'config'
    config.mkdir()
    main(['install-taps', str(run), '--config', str(config)])
    installed = load_compensator_params(config / 'compensator.yaml')
    assert installed['provenance']['plant'] == str(run / 'plant.yaml')
    assert not (config / 'plant.yaml').exists()


def test_install_taps_names_a_wrong_run_dir(tmp_path, capsys):
    assert main(['install-taps', str(tmp_path), '--config', str(tmp_path)]) == 2
    assert 'compensator.yaml' in capsys.readouterr().err


def test_install_taps_names_a_missing_config(tmp_path, capsys):
    run = _run_dir(tmp_path)
    assert main(['install-taps', str(run), '--config', str(tmp_path / 'nowhere')]) == 2
    assert 'config directory' in capsys.readouterr().err
