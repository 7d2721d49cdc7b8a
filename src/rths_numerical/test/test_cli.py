"""CLI registration and a tiny study run."""

import json

from rths_common.testing import command_parser
from rths_numerical import cli


def _parser():
    return command_parser(cli.register)


def test_register_and_dtm_tuning_tiny(tmp_path, capsys):
    """``rths study dtm-tuning`` on a tiny grid writes JSON with optima and Den Hartog."""
    args = _parser().parse_args(['study', 'dtm-tuning', '--n-fn', '5', '--n-zeta', '3',
                                 '--duration-s', '10', '--fs-hz', '64', '--out', str(tmp_path)])
    assert args.func(args) == 0
    data = json.loads((tmp_path / 'dtm_tuning.json').read_text())
    assert set(data['optima']) == {'max_disp', 'max_accel', 'rms_disp', 'rms_accel'}
    assert 'den_hartog' in data and (tmp_path / 'dtm_tuning.png').exists()
    assert 'Den Hartog' in capsys.readouterr().out


def test_simulate_parses():
    """``rths simulate`` options."""
    args = _parser().parse_args(['simulate', '--specimen', 'valve4', '--record', 'kobe',
                                 '--scale', '0.135'])
    assert args.specimen == 'valve4' and args.scale == 0.135
    old = _parser().parse_args(['simulate', '--damper', 'novalve'])   # the former name
    assert old.specimen == 'novalve'
    args = _parser().parse_args(['bench', 'numerical', '--out', 'x.json'])
    assert args.out == 'x.json'


def test_bench_backend_comparison_tiny():
    """The opensees part of ``rths bench numerical --backend opensees`` on 4 s of record.

    Over the first second alone the two starts differ visibly (OpenSees assumes
    d_{-1} = d_0, the built-in d_{-1} = dt^2/2 a_0): 1.03e-3.
    """
    from rths_numerical.testing import require_opensees
    require_opensees()
    args = _parser().parse_args(['bench', 'numerical', '--backend', 'opensees'])
    assert args.backend == 'opensees' and args.duration_s == 0.0
    out = cli._backend_comparison('opensees', 'kobe', 0.135, 4.0, 1024.0)
    assert 0 < out['max_rel_diff_vs_builtin'] <= 1e-3
    assert out['max_rel_diff_vs_builtin_cr'] > out['max_rel_diff_vs_builtin']
    assert out['step_us_p50'] > 0
