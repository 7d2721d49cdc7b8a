"""YAML a lab writes: a key given twice or a syntax error is one line naming file and line."""

import pytest

from rths_common import yamlfile


def test_a_key_given_twice_is_refused_with_both_lines(tmp_path):
    path = tmp_path / 'bridge.yaml'
    path.write_text('bridge:\n  ros__parameters:\n    stroke_m: 0.254\n    stroke_m: 0.1\n')
    with pytest.raises(ValueError, match=r"^\S+bridge.yaml: key 'stroke_m' is given twice "
                                         r'\(lines 3 and 4\); keep one$'):
        yamlfile.load(path)


def test_a_syntax_error_is_a_value_error_with_its_line(tmp_path):
    path = tmp_path / 'numerical.yaml'
    path.write_text('numerical:\n  ros__parameters:\n    fs_hz: [1024\n')
    with pytest.raises(ValueError, match=r'numerical.yaml: not valid YAML at line 4, column 1: '
                                         r".*; fix the syntax$"):
        yamlfile.load(path)


def test_equal_keys_in_different_mappings_and_plain_files_load():
    text = 'a: {x: 1, y: 2}\nb: {x: 3}\nc: [1, 2]\n'
    assert yamlfile.loads(text, 'f') == {'a': {'x': 1, 'y': 2}, 'b': {'x': 3}, 'c': [1, 2]}
    with pytest.raises(OSError, match='cannot read the file'):
        yamlfile.load('/nonexistent/x.yaml')


def test_a_key_given_twice_on_one_line_is_refused():
    with pytest.raises(ValueError, match=r"^f.yaml: key 'a' is given twice \(line 1\); keep one$"):
        yamlfile.loads('{a: 1, a: 2}\n', 'f.yaml')


@pytest.mark.parametrize('text', ['x: "\x00"\n', '\x01: 1\n', 'a: \x7f\n'])
def test_a_control_character_is_one_line_naming_the_file(text):
    with pytest.raises(ValueError) as err:
        yamlfile.loads(text, 'f.yaml')
    assert '\n' not in str(err.value)
    assert str(err.value).startswith('f.yaml: not valid YAML at character ')
    assert str(err.value).endswith('without control characters')
