"""docs/cli.md and docs/performance.md are generated: they must match the code and the results."""

import json

import pytest

from rths_bench import refdocs
from rths_common.datasets import repo_root

ROOT = repo_root()


@pytest.mark.parametrize('name', sorted(refdocs.DOCS))
def test_generated_document_is_current(name):
    text = refdocs.DOCS[name]()
    assert (ROOT / name).read_text() == text, f'{name} is out of date: run make docs'


def test_every_subcommand_and_option_is_in_cli_md():
    text = (ROOT / 'docs' / 'cli.md').read_text()
    from rths_bringup.cli import build_parser

    for words, parser in refdocs._leaves(build_parser(), ['rths']):
        assert f"## {' '.join(words)}\n" in text
        for action in parser._actions:
            for option in set(action.option_strings) - {'-h', '--help'}:
                assert f'`{option}' in text or f', {option}' in text, (words, option)


def test_every_figure_has_a_source():
    for section, label, name, path, unit, target in refdocs.FIGURES:
        doc = json.loads((ROOT / 'docs' / 'bench' / name).read_text())
        refdocs.lookup(doc, path)   # KeyError: the figure has no source


def test_a_figure_without_a_source_is_refused():
    with pytest.raises(KeyError, match='no .latency'):
        refdocs.lookup({'deadline_miss_pct': 0.0}, 'latency_us_p99')
    assert refdocs.lookup({'cases': {'1': {'J2': 3.3}}}, 'cases/1/J2') == 3.3
    assert refdocs.lookup({'sets': [{'x': 1}]}, 'sets/0/x') == 1


def test_provenance_says_what_a_file_does_not_record():
    assert refdocs.provenance({}) == 'date not recorded; machine not recorded'
    doc = {'date': '2026-11-25', 'machine': {'nproc': 2, 'loadavg': [0.5, 0.4, 0.3]}}
    assert refdocs.provenance(doc) == '2026-11-25; nproc 2, loadavg [0.5, 0.4, 0.3]'
