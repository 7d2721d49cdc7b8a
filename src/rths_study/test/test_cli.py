"""``rths bench rths-benchmark --draws N`` through the study runner; the commands' help."""

import json

import numpy as np
import pyarrow.parquet as pq

from rths_bringup.cli import build_parser, main


def test_benchmark_draws_go_through_the_runner_with_the_commands_own_draws(tmp_path):
    # A synthetic 1.5 s record (a 3.5 Hz burst) in a 2-column file: no data set needed.
    t = np.arange(0, 1.5, 0.01)
    record = tmp_path / 'burst.txt'
    np.savetxt(record, np.column_stack([t, 1.5 * np.sin(2 * np.pi * 3.5 * t)]))
    common = ['bench', 'rths-benchmark', '--controller', 'example', '--record', str(record),
              '--draws', '3', '--seed', '5', '--no-plots', '--cases', '1']
    assert main(common + ['--out', str(tmp_path / 'direct')]) == 0
    assert main(common + ['--out', str(tmp_path / 'runner'), '--workers', '1']) == 0
    direct, runner = ({name: json.loads((tmp_path / d / name).read_text())
                       for name in ('summary.json', 'details.json')}
                      for d in ('direct', 'runner'))
    assert runner['summary.json']['perturbed']['n'] == 3
    assert runner['summary.json']['perturbed']['unstable'] == 0
    assert runner['details.json']['draws'] == direct['details.json']['draws']
    # the nominal case runs in this process either way (its noise stream differs with the
    # batch it is in)
    ours, theirs = runner['summary.json']['cases']['1'], direct['summary.json']['cases']['1']
    assert ours['J1'] == theirs['J1'] and abs(ours['J2'] - theirs['J2']) < 1.0
    rows = pq.read_table(tmp_path / 'runner' / 'study' / 'runs').to_pylist()
    assert sorted(round(r['b1'], 6) for r in rows) == sorted(
        d['b1'] for d in direct['details.json']['draws'])
    # each draw has its own noise through the runner: close to, not equal to, the batch's
    assert abs(runner['summary.json']['perturbed']['J2_max']
               - direct['summary.json']['perturbed']['J2_max']) < 5.0


def test_help_names_the_scenarios_and_the_cluster_options():
    parser = build_parser()
    study = next(a for a in parser._actions if a.dest == 'command').choices['study']
    sub = next(a for a in study._actions if a.dest == 'study').choices
    assert {'run', 'dtm-tuning', 'building-frequency'} <= set(sub)
    text = sub['run'].format_help()
    for word in ('benchmark', 'dtm-tuning', 'building-frequency', 'design', '--scheduler',
                 '--workers', 'cluster-check'):
        assert word in text


def test_the_benchmark_gets_its_cluster_options_whatever_order_the_modules_load_in(
        monkeypatch):
    from rths_bringup import cli
    modules = cli.cli_modules()
    assert 'rths_study.cli' in modules and 'rths_bench.rths_benchmark' in modules
    plugins = [m for m in modules if m not in cli.CLI_MODULES]   # the entry points'
    for order in (modules, list(cli.CLI_MODULES) + plugins[::-1]):
        monkeypatch.setattr(cli, 'cli_modules', lambda order=order: list(order))
        bench = next(a for a in cli.build_parser()._actions
                     if a.dest == 'command').choices['bench']
        benches = next(a for a in bench._actions if a.dest == 'bench').choices
        text = ' '.join(benches['rths-benchmark'].format_help().split())  # as read, not wrapped
        assert '--scheduler' in text and '--workers' in text and 'study runner' in text


def test_a_missing_benchmark_command_is_an_error_not_a_silent_skip():
    import argparse

    from rths_study import cli
    benches = argparse.ArgumentParser().add_subparsers()
    try:
        cli.extend(None, benches)
    except RuntimeError as err:
        assert 'rths bench rths-benchmark' in str(err)
    else:
        raise AssertionError('extend() passed without the command it extends')


def _json_numbers(path):
    data = json.loads(path.read_text())
    return data, {k: np.asarray(v, dtype=float) for k, v in _flat(data)}


def _flat(data, prefix=''):
    for k, v in data.items():
        if isinstance(v, dict):
            yield from _flat(v, f'{prefix}{k}.')
        elif isinstance(v, (int, float, list)) and not isinstance(v, bool):
            yield f'{prefix}{k}', v


def _direct(argv):
    """Run a ``rths study`` sub-command in this process, without the runner."""
    from rths_numerical import cli
    args = build_parser().parse_args(argv)
    command = {'dtm-tuning': cli.cmd_study_dtm_tuning,
               'building-frequency': cli.cmd_study_building_frequency}[argv[1]]
    return command(args)


def test_rths_study_dtm_subcommands_run_their_grids_on_the_runner_same_outputs(tmp_path):
    cases = {'dtm-tuning': (['--n-fn', '4', '--n-zeta', '3', '--duration-s', '8',
                             '--fs-hz', '128', '--seed', '3'], 'dtm_tuning.json'),
             'building-frequency': (['--n-freq', '3', '--n-ratio', '2', '--fs-hz', '50',
                                     '--dampers', 'valve4'], 'building_frequency.json')}
    for name, (options, output) in cases.items():
        routed, alone = tmp_path / name / 'runner', tmp_path / name / 'direct'
        argv = ['study', name, *options]
        assert main(argv + ['--out', str(routed), '--workers', '1']) == 0
        assert _direct(argv + ['--out', str(alone)]) == 0
        ours, ours_n = _json_numbers(routed / output)
        theirs, theirs_n = _json_numbers(alone / output)
        assert set(ours_n) == set(theirs_n) and len(ours_n) > 10
        for key, value in theirs_n.items():
            np.testing.assert_allclose(ours_n[key], value, rtol=1e-12, err_msg=key)
        runs = [p for p in routed.iterdir() if p.name.startswith('runs_')]
        assert len(runs) == 1 and pq.read_table(runs[0] / 'runs').num_rows in (6, 12)
    # rerunning skips every grid point already in the table
    before = pq.read_table(runs[0] / 'runs').num_rows
    argv = ['study', 'building-frequency', *cases['building-frequency'][0]]
    assert main(argv + ['--out', str(tmp_path / 'building-frequency' / 'runner'),
                        '--workers', '1']) == 0
    assert pq.read_table(runs[0] / 'runs').num_rows == before
