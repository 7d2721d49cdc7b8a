"""The generated references (docs/cli.md, benchmarks.md, performance.md, package READMEs)."""

import json
import re

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
    for _, _, name, path, _, _ in refdocs.FIGURES:
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


def test_every_benchmark_is_described_once_with_its_output():
    text = (ROOT / 'docs' / 'benchmarks.md').read_text()
    benches = refdocs._bench_parsers(refdocs.build_parser())
    assert len(benches) >= 10
    for name in benches:
        assert text.count(f'## rths bench {name}\n') == 1, name
        section = text.split(f'## rths bench {name}\n')[1].split('\n## ')[0]
        assert len(section.split()) > 8, f'rths bench {name} has no description'


@pytest.mark.parametrize('package', refdocs.packages(ROOT), ids=lambda p: p.name)
def test_each_package_readme_says_what_lives_there_and_is_current(package):
    text = (package / 'README.md').read_text()
    assert '**May import:**' in text and '**Start reading:**' in text
    assert text == refdocs.package_readme(package), 'module table out of date: run make docs'


def test_a_readme_without_the_generated_table_is_refused(tmp_path):
    (tmp_path / 'README.md').write_text('# pkg\n')
    with pytest.raises(ValueError, match='no generated module table'):
        refdocs.package_readme(tmp_path)


def test_readme_is_short_and_every_command_and_link_in_it_exists():
    text = (ROOT / 'README.md').read_text()
    lines = text.splitlines()
    assert len(lines) <= 250
    assert max(len(line) for line in lines) <= 300
    commands = set(refdocs._subparsers(refdocs.build_parser()))
    table = [line for line in lines if line.startswith('| `rths ')]
    assert len(table) >= 15
    for row in table:
        word = row.split('`')[1].split()[1]
        assert word in commands, row
    for target in re.findall(r'\]\(([^)#]+)(?:#[^)]*)?\)', text):
        if not target.startswith('http'):
            assert (ROOT / target).exists(), target
