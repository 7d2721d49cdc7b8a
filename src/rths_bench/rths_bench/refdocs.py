"""Reference documents generated from the code and the results, so that they cannot drift.

- ``docs/cli.md``: every ``rths`` sub-command and option, from the argparse definitions
  (:func:`cli_markdown`);
- ``docs/performance.md``: the project's measured figures, each read from a JSON file under
  ``docs/bench/`` with the machine and date that file records (:func:`performance_markdown`;
  the figures and their sources are :data:`FIGURES`);
- ``docs/benchmarks.md``: each ``rths bench`` command once, from its argparse description
  (:func:`benchmarks_markdown`);
- the module table of each package's README.md, from each module's docstring
  (:func:`package_readme`; the prose around it is written by hand).

``make docs`` (``python -m rths_bench.refdocs --write``) rewrites both;
``test_refdocs.py`` fails when either is out of date or a figure has no source.
"""

import argparse
import ast
import json
from pathlib import Path
import re
import sys

from rths_bringup.cli import build_parser
from rths_common.datasets import repo_root

#: Usage and help are wrapped at this width, whatever the terminal, so the file is stable.
WIDTH = 100


# -- docs/cli.md ------------------------------------------------------------------------------

def _subcommands(parser):
    """Return the sub-command action of ``parser`` (``add_subparsers``), or None."""
    return next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)


def _subparsers(parser) -> dict:
    """Return ``{name: parser}`` of ``parser``'s sub-commands (empty for a leaf)."""
    action = _subcommands(parser)
    return dict(action.choices) if action else {}


def _leaves(parser, words):
    """Yield ``(words, parser)`` for every command that takes options (no sub-commands)."""
    subs = _subparsers(parser)
    if not subs:
        yield words, parser
        return
    for name, sub in subs.items():
        yield from _leaves(sub, words + [name])


def _help_of(parser) -> dict:
    """Return ``{name: one-line help}`` of ``parser``'s sub-commands."""
    action = _subcommands(parser)
    return {c.dest: (c.help or '') for c in action._choices_actions} if action else {}


def _cell(text) -> str:
    """Return ``text`` (argparse help: ``%%`` is a percent sign) as one markdown table cell."""
    return ' '.join(str(text).split()).replace('%%', '%').replace('|', '\\|')


def _option_rows(parser):
    """Yield ``(option, default, help)`` for each argument of ``parser`` but ``--help``."""
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = ', '.join(action.option_strings) or action.dest
        if action.option_strings and action.nargs != 0:
            choices = '{' + ','.join(map(str, action.choices)) + '}' if action.choices else ''
            name += ' ' + (choices or action.metavar or action.dest.upper())
        default = action.default
        shown = '' if default in (None, argparse.SUPPRESS, False) or action.nargs == 0 \
            else f'`{default}`'
        help_text = action.help or ''
        if action.help and '%(default)' in action.help:
            help_text = help_text.replace('%(default)s', str(default))
        yield name, shown, help_text


def cli_markdown(parser=None) -> str:
    """Return the text of ``docs/cli.md`` for ``parser`` (default: the full ``rths`` parser)."""
    if parser is None:
        parser = build_parser()
    leaves = list(_leaves(parser, ['rths']))
    helps = {}
    for words, _ in leaves:
        node = parser
        for i, word in enumerate(words[1:], start=1):
            helps[' '.join(words[:i + 1])] = _help_of(node).get(word, '')
            node = _subparsers(node)[word]
    out = ['# The `rths` command', '',
           'Generated from the argparse definitions by `make docs` '
           '(`src/rths_bench/rths_bench/refdocs.py`); a test fails when this file is out of '
           'date. `rths COMMAND --help` prints the same.', '',
           '| command | what it does |', '|---|---|']
    for words, _ in leaves:
        name = ' '.join(words)
        out.append(f'| [`{name}`](#{_anchor(name)}) | {_cell(helps.get(name, ""))} |')
    for words, sub in leaves:
        name = ' '.join(words)
        sub.prog = name
        sub.formatter_class = _fixed_width
        out += ['', f'## {name}', '']
        if sub.description:
            out += [_cell(sub.description), '']
        out += ['```', sub.format_usage().strip(), '```', '',
                '| option | default | meaning |', '|---|---|---|']
        out += [f'| `{_cell(o)}` | {d} | {_cell(h)} |' for o, d, h in _option_rows(sub)]
    return '\n'.join(out) + '\n'


def _fixed_width(prog):
    """Argparse formatter at :data:`WIDTH` columns, whatever ``$COLUMNS`` says."""
    return argparse.HelpFormatter(prog, width=WIDTH, max_help_position=40)


def _anchor(title: str) -> str:
    """Return the GitHub anchor of a markdown heading."""
    return ''.join(c for c in title.lower().replace(' ', '-') if c.isalnum() or c in '-_')


# -- docs/performance.md ----------------------------------------------------------------------

#: The figures of docs/performance.md: (section, label, file under docs/bench, JSON path, unit,
#: target or ''). A path is keys joined by '/'; a list index is a number.
MAIN = 'The main job (rths run, Kobe x 0.135, valve 4, real time, 20 s)'
SILVA = 'RTHS benchmark (Silva et al. 2020), case 1'
FAULTS = 'Load and faults (composed 1024 Hz, 10 s each; rths bench faults)'
FAULTS_JSON = 'faults_1024hz_10s.json'
PROBE = ('The same, beside the machine (rths bench faults --cases baseline,cpu_hog: an empty '
         'SCHED_FIFO 99 probe and the hypervisor steal in the same run)')
PROBE_JSON = 'faults_cpu_hog_probe.json'
HOG_RUNS = ('The CPU hog, eleven runs on one VM (rths bench faults --cases baseline,cpu_hog, '
            'three of them with --cpus 1: the loop and the probe on one CPU)')
HOG_RUNS_JSON = 'faults_cpu_hog_runs_20261128.json'
DIRECT = ('Direct delivery between the composed nodes (rths bench loop --duration 10, with '
          'and without --no-direct-delivery, one after the other)')
DIRECT_JSON = 'loop_direct_delivery_20261128.json'
PASS = ('The composed loop sleeps to its ticks (rths bench loop --duration 10, three runs per '
        'rate before and after, medians; the executor once a millisecond instead of twice a tick)')
PASS_JSON = 'loop_executor_pass_20261128.json'
MULTIRATE = ('The numerical substructure at a quarter of the loop rate (rths bench loop --rate '
             '4096 --duration 10 --rate-divisor N, N = 1 and 4 alternating, three pairs, medians)')
MULTIRATE_JSON = 'loop_multirate_20261129.json'
MULTIRATE_GRAPH = 'rths_benchmark_realtime/fir_rate_divisor_20261129/'
TICK_COSTS = ('Three per-tick costs cut (rths bench loop --rate 4096 --duration 10 --floor 5, '
              'before and after alternating, three pairs, medians)')
TICK_COSTS_JSON = 'loop_tick_costs_20261129.json'
STALLS = ("The loop's own stalls: worked through or waited (rths bench loop --rate 1024 "
          '--duration 20, four runs; the work floor: the same Python work every 1/1024 s)')
STALLS_JSON = 'loop_stalls_20261128.json'
HOSTS = ('One loop on three hosts (rths bench loop --rate 2048, composed): commit 679051c on '
         '2026-11-23 (Intel Xeon, kernel fc-v669), the same commit and main on 2026-11-28 (AMD '
         'EPYC, kernel fc-v782), main later that day (AMD EPYC, kernel fc-v669)')
LATER = 'later_host_2026_11_28/'
HOSTS_JSON = 'loop_2048hz_host_compare.json'
MARTHS = 'maRTHS (two actuators) through the node graph, mimo, El Centro x 0.4'
MARTHS_RT = 'marths_graph/realtime_mimo_elcentro.json'
MARTHS_FIDELITY = ('maRTHS port fidelity (rths bench marths-fidelity: Initial_parameters.mat of '
                   'FermandoisLab/maRTHS-bmk-RoDeAC)')
FIGURES = (
    (MAIN, 'actuator delay before compensation',
     'run_realtime_kobe_20s_summary.json', 'delay_ms_before', 'ms', ''),
    (MAIN, 'actuator delay after compensation',
     'run_realtime_kobe_20s_summary.json', 'delay_ms_after', 'ms', ''),
    (MAIN, 'tracking error after compensation',
     'run_realtime_kobe_20s_summary.json', 'tracking_rel_rms_pct_after', '%', ''),
    ('Real-time loop', '1024 Hz composed, deadline misses', 'loop_1024hz_60s_composed_quiet.json',
     'deadline_miss_pct', '%', '<= 0.1 %'),
    ('Real-time loop', '1024 Hz composed, command latency p99',
     'loop_1024hz_60s_composed_quiet.json', 'latency_us_p99', 'us', '< 500 us'),
    ('Real-time loop', '1024 Hz composed, late or missed ticks',
     'loop_1024hz_60s_composed_quiet.json', 'late_or_missed_pct', '%', ''),
    ('Real-time loop', '2048 Hz composed, deadline misses', 'loop_2048hz_30s_composed_quiet.json',
     'deadline_miss_pct', '%', '<= 0.2 %'),
    ('Real-time loop', '2048 Hz composed, late or missed ticks',
     'loop_2048hz_30s_composed_quiet.json', 'late_or_missed_pct', '%', ''),
    ('Real-time loop', 'highest rate at <= 0.1 % late or missed (--find-max)',
     'loop_findmax_30s_composed_quiet.json', 'max_rate_hz', 'Hz', ''),
    (HOSTS, 'Intel Xeon, 679051c: command latency p50', 'loop_2048hz_30s_composed_quiet.json',
     'latency_us_p50', 'us', ''),
    (HOSTS, 'Intel Xeon, 679051c: CPU of the loop process', 'loop_2048hz_30s_composed_quiet.json',
     'cpu_pct', '%', ''),
    (HOSTS, 'AMD EPYC, 679051c: command latency p50', HOSTS_JSON,
     'same_commit_679051c/latency_us_p50', 'us', ''),
    (HOSTS, 'AMD EPYC, 679051c: CPU of the loop process', HOSTS_JSON,
     'same_commit_679051c/cpu_pct', '%', ''),
    (HOSTS, 'AMD EPYC, 679051c: late or missed ticks', HOSTS_JSON,
     'same_commit_679051c/late_or_missed_pct', '%', ''),
    (HOSTS, 'AMD EPYC, main: command latency p50', HOSTS_JSON, 'main_2cd863b/latency_us_p50',
     'us', ''),
    (HOSTS, 'AMD EPYC, main: CPU of the loop process', HOSTS_JSON, 'main_2cd863b/cpu_pct', '%',
     ''),
    (HOSTS, 'AMD EPYC, main: late or missed ticks', HOSTS_JSON,
     'main_2cd863b/late_or_missed_pct', '%', ''),
    (HOSTS, 'AMD EPYC (fc-v669), main, 30 s: command latency p50', HOSTS_JSON,
     LATER + 'main_fc_v669_2048hz_30s/latency_us_p50', 'us', ''),
    (HOSTS, 'AMD EPYC (fc-v669), main, 30 s: CPU of the loop process', HOSTS_JSON,
     LATER + 'main_fc_v669_2048hz_30s/cpu_pct', '%', ''),
    (HOSTS, 'AMD EPYC (fc-v669), main, 30 s: deadline misses', HOSTS_JSON,
     LATER + 'main_fc_v669_2048hz_30s/deadline_miss_pct', '%', '<= 0.2 %'),
    (HOSTS, 'AMD EPYC (fc-v669), main, 30 s: late or missed ticks', HOSTS_JSON,
     LATER + 'main_fc_v669_2048hz_30s/late_or_missed_pct', '%', ''),
    (HOSTS, 'AMD EPYC (fc-v669), main, 4096 Hz: CPU of the loop process', HOSTS_JSON,
     LATER + 'main_fc_v669_4096hz_10s/cpu_pct', '%', ''),
    (HOSTS, 'AMD EPYC (fc-v669), main, 4096 Hz: late or missed ticks', HOSTS_JSON,
     LATER + 'main_fc_v669_4096hz_10s/late_or_missed_pct', '%', '<= 0.2 %'),
    (FAULTS, 'CPU hog on every core: late or missed ticks',
     FAULTS_JSON, 'cases/cpu_hog/late_or_missed_pct', '%', '<= 0.1 %'),
    (FAULTS, 'CPU hog: samples lost from the bag',
     FAULTS_JSON, 'cases/cpu_hog/samples_lost', '', '0'),
    (FAULTS, 'memory hog: samples lost from the bag',
     FAULTS_JSON, 'cases/memory_hog/samples_lost', '', '0'),
    (FAULTS, 'I/O hog on the bag disk: samples lost from the bag',
     FAULTS_JSON, 'cases/io_hog/samples_lost', '', '0'),
    (FAULTS, 'stalls 20/50/200 ms in each node: command within its limits',
     FAULTS_JSON, 'summary/all_within_limits', '', 'true'),
    (FAULTS, 'stalls: supervisor state as documented',
     FAULTS_JSON, 'summary/stall_states_as_documented', '', 'true'),
    (FAULTS, 'SIGKILL of the container: bag ends before the kill',
     FAULTS_JSON, 'cases/kill_container/loss_before_kill_ms', 'ms', '<= 100 ms'),
    (FAULTS, 'SIGKILL of the recorder: repaired bag ends before the kill',
     FAULTS_JSON, 'cases/kill_recorder/loss_before_kill_ms', 'ms', '<= 100 ms'),
    (PROBE, 'CPU hog: late or missed ticks', PROBE_JSON, 'cases/cpu_hog/late_or_missed_pct', '%',
     '<= 0.1 %'),
    (PROBE, 'CPU hog: the empty probe, late or missed', PROBE_JSON,
     'cases/cpu_hog/floor_late_or_missed_pct', '%', ''),
    (PROBE, 'CPU hog: hypervisor steal', PROBE_JSON, 'cases/cpu_hog/steal_pct', '%', ''),
    (PROBE, 'no hog: late or missed ticks', PROBE_JSON, 'cases/baseline/late_or_missed_pct', '%',
     ''),
    (PROBE, 'no hog: the empty probe, late or missed', PROBE_JSON,
     'cases/baseline/floor_late_or_missed_pct', '%', ''),
    (PROBE, 'no hog: hypervisor steal', PROBE_JSON, 'cases/baseline/steal_pct', '%', ''),
    (HOG_RUNS, 'CPU hog: runs with late or missed ticks <= 0.1 %', HOG_RUNS_JSON,
     'summary/cpu_hog_runs_within_0_1_pct', 'of 11', 'every run'),
    (HOG_RUNS, 'CPU hog: late or missed ticks, median', HOG_RUNS_JSON,
     'summary/cpu_hog_late_or_missed_pct_median', '%', '<= 0.1 %'),
    (HOG_RUNS, 'CPU hog: late or missed ticks, worst run', HOG_RUNS_JSON,
     'summary/cpu_hog_late_or_missed_pct_max', '%', '<= 0.1 %'),
    (HOG_RUNS, 'CPU hog: samples lost from the bag, all runs', HOG_RUNS_JSON,
     'summary/cpu_hog_samples_lost', '', '0'),
    (HOG_RUNS, 'no hog: late or missed ticks, median', HOG_RUNS_JSON,
     'summary/baseline_late_or_missed_pct_median', '%', ''),
    (DIRECT, '1024 Hz: late or missed ticks over DDS', DIRECT_JSON,
     'summary/1024hz/late_or_missed_pct_dds', '%', ''),
    (DIRECT, '1024 Hz: late or missed ticks, direct', DIRECT_JSON,
     'summary/1024hz/late_or_missed_pct_direct', '%', '<= 0.1 %'),
    (DIRECT, '1024 Hz: round trip p50 over DDS', DIRECT_JSON,
     'summary/1024hz/loop_us_p50_dds', 'us', ''),
    (DIRECT, '1024 Hz: round trip p50, direct', DIRECT_JSON,
     'summary/1024hz/loop_us_p50_direct', 'us', ''),
    (DIRECT, '1024 Hz: CPU of the container over DDS', DIRECT_JSON,
     'summary/1024hz/cpu_pct_dds', '%', ''),
    (DIRECT, '1024 Hz: CPU of the container, direct', DIRECT_JSON,
     'summary/1024hz/cpu_pct_direct', '%', ''),
    (DIRECT, '2048 Hz: late or missed ticks over DDS', DIRECT_JSON,
     'summary/2048hz/late_or_missed_pct_dds', '%', ''),
    (DIRECT, '2048 Hz: late or missed ticks, direct', DIRECT_JSON,
     'summary/2048hz/late_or_missed_pct_direct', '%', ''),
    (DIRECT, '2048 Hz: round trip p50 over DDS', DIRECT_JSON,
     'summary/2048hz/loop_us_p50_dds', 'us', ''),
    (DIRECT, '2048 Hz: round trip p50, direct', DIRECT_JSON,
     'summary/2048hz/loop_us_p50_direct', 'us', ''),
    (DIRECT, '2048 Hz: CPU of the container over DDS', DIRECT_JSON,
     'summary/2048hz/cpu_pct_dds', '%', ''),
    (DIRECT, '2048 Hz: CPU of the container, direct', DIRECT_JSON,
     'summary/2048hz/cpu_pct_direct', '%', ''),
    (DIRECT, '4096 Hz: late or missed ticks over DDS', DIRECT_JSON,
     'summary/4096hz/late_or_missed_pct_dds', '%', ''),
    (DIRECT, '4096 Hz: late or missed ticks, direct', DIRECT_JSON,
     'summary/4096hz/late_or_missed_pct_direct', '%', '<= 0.2 % (issue 24)'),
    (DIRECT, '4096 Hz: round trip p50 over DDS', DIRECT_JSON,
     'summary/4096hz/loop_us_p50_dds', 'us', ''),
    (DIRECT, '4096 Hz: round trip p50, direct', DIRECT_JSON,
     'summary/4096hz/loop_us_p50_direct', 'us', ''),
    (DIRECT, '4096 Hz: CPU of the container over DDS', DIRECT_JSON,
     'summary/4096hz/cpu_pct_dds', '%', ''),
    (DIRECT, '4096 Hz: CPU of the container, direct', DIRECT_JSON,
     'summary/4096hz/cpu_pct_direct', '%', ''),
    (PASS, '1024 Hz: tick late p50, before', PASS_JSON,
     'summary/1024hz/tick_late_us_p50_before', 'us', ''),
    (PASS, '1024 Hz: tick late p50, after', PASS_JSON,
     'summary/1024hz/tick_late_us_p50_after', 'us', ''),
    (PASS, '1024 Hz: late or missed ticks, before', PASS_JSON,
     'summary/1024hz/late_or_missed_pct_before', '%', ''),
    (PASS, '1024 Hz: late or missed ticks, after', PASS_JSON,
     'summary/1024hz/late_or_missed_pct_after', '%', ''),
    (PASS, '2048 Hz: tick late p50, before', PASS_JSON,
     'summary/2048hz/tick_late_us_p50_before', 'us', ''),
    (PASS, '2048 Hz: tick late p50, after', PASS_JSON,
     'summary/2048hz/tick_late_us_p50_after', 'us', ''),
    (PASS, '2048 Hz: late or missed ticks, before', PASS_JSON,
     'summary/2048hz/late_or_missed_pct_before', '%', ''),
    (PASS, '2048 Hz: late or missed ticks, after', PASS_JSON,
     'summary/2048hz/late_or_missed_pct_after', '%', ''),
    (PASS, '4096 Hz: tick late p50, before', PASS_JSON,
     'summary/4096hz/tick_late_us_p50_before', 'us', ''),
    (PASS, '4096 Hz: tick late p50, after', PASS_JSON,
     'summary/4096hz/tick_late_us_p50_after', 'us', ''),
    (PASS, '4096 Hz: late or missed ticks, before', PASS_JSON,
     'summary/4096hz/late_or_missed_pct_before', '%', ''),
    (PASS, '4096 Hz: late or missed ticks, after', PASS_JSON,
     'summary/4096hz/late_or_missed_pct_after', '%', ''),
    (PASS, '4096 Hz: CPU of the ticking thread per tick p50, before', PASS_JSON,
     'summary/4096hz/tick_cpu_us_p50_before', 'us', ''),
    (PASS, '4096 Hz: CPU of the ticking thread per tick p50, after', PASS_JSON,
     'summary/4096hz/tick_cpu_us_p50_after', 'us', ''),
    (MULTIRATE, 'the numerical node, measurement to output p50, single rate', MULTIRATE_JSON,
     'summary/single_rate/numerical_us_p50', 'us', ''),
    (MULTIRATE, 'the numerical node, measurement to output p50, divisor 4', MULTIRATE_JSON,
     'summary/divisor_4/numerical_us_p50', 'us', ''),
    (MULTIRATE, 'CPU of the ticking thread per tick p50, single rate', MULTIRATE_JSON,
     'summary/single_rate/tick_cpu_us_p50', 'us', ''),
    (MULTIRATE, 'CPU of the ticking thread per tick p50, divisor 4', MULTIRATE_JSON,
     'summary/divisor_4/tick_cpu_us_p50', 'us', ''),
    (MULTIRATE, 'late or missed ticks, single rate', MULTIRATE_JSON,
     'summary/single_rate/late_or_missed_pct', '%', ''),
    (MULTIRATE, 'late or missed ticks, divisor 4', MULTIRATE_JSON,
     'summary/divisor_4/late_or_missed_pct', '%', '<= 0.2 % (issue 24)'),
    (MULTIRATE, 'samples lost from the bag, divisor 4', MULTIRATE_JSON,
     'summary/divisor_4/samples_lost', '', '0'),
    (MULTIRATE, 'RTHS benchmark, fir, through the graph: late or missed (worst case), single rate',
     MULTIRATE_GRAPH + 'single_rate/summary.json', 'realtime/late_or_missed_pct', '%', ''),
    (MULTIRATE, 'RTHS benchmark, fir, through the graph: late or missed (worst case), divisor 4',
     MULTIRATE_GRAPH + 'divisor_4/summary.json', 'realtime/late_or_missed_pct', '%',
     '<= 0.2 % (issue 24)'),
    (MULTIRATE, 'RTHS benchmark, fir, case 4: J5, single rate',
     MULTIRATE_GRAPH + 'single_rate/summary.json', 'cases/4/J5', '%', ''),
    (MULTIRATE, 'RTHS benchmark, fir, case 4: J5, divisor 4',
     MULTIRATE_GRAPH + 'divisor_4/summary.json', 'cases/4/J5', '%', 'within 5 % of single rate'),
    (TICK_COSTS, 'CPU of the ticking thread per tick p50, before', TICK_COSTS_JSON,
     'summary/before/tick_cpu_us_p50', 'us', ''),
    (TICK_COSTS, 'CPU of the ticking thread per tick p50, after', TICK_COSTS_JSON,
     'summary/after/tick_cpu_us_p50', 'us', ''),
    (TICK_COSTS, 'late or missed ticks, before', TICK_COSTS_JSON,
     'summary/before/late_or_missed_pct', '%', ''),
    (TICK_COSTS, 'late or missed ticks, after', TICK_COSTS_JSON,
     'summary/after/late_or_missed_pct', '%', '<= 0.2 % (issue 24)'),
    (STALLS, 'stalls (ticks more than a period late), four runs', STALLS_JSON,
     'summary/loop_stalls', '', ''),
    (STALLS, 'of them worked through: the ticking thread never left the CPU', STALLS_JSON,
     'summary/loop_stalls_on_cpu', '', ''),
    (STALLS, 'stall time worked through', STALLS_JSON, 'summary/loop_stall_ms_on_cpu', 'ms', ''),
    (STALLS, 'stall time waited (off the CPU)', STALLS_JSON, 'summary/loop_stall_ms_off_cpu',
     'ms', ''),
    (STALLS, 'no ROS at all: Python work chunks of 132 us stretched over 3x, of 20 000',
     STALLS_JSON, 'standalone_work_probe/one_probe_unpinned/stretched_gt_3x', '', ''),
    (STALLS, 'no ROS at all: the longest of those chunks', STALLS_JSON,
     'standalone_work_probe/one_probe_unpinned/chunk_us_max', 'us', ''),
    (MARTHS, 'realtime composed 1024 Hz: deadline misses', MARTHS_RT,
     'realtime/deadline_miss_pct', '%', '<= 0.1 %'),
    (MARTHS, 'realtime: late or missed ticks', MARTHS_RT, 'realtime/late_or_missed_pct', '%', ''),
    (MARTHS, 'realtime: samples lost from the bag', MARTHS_RT, 'samples_lost', '', '0'),
    (MARTHS, 'realtime: largest J difference from the offline loop', MARTHS_RT,
     'j_max_relative_difference', '', '<= 0.05'),
    (MARTHS, 'lock-step, first 10 s: largest J difference from the offline loop',
     'marths_graph/lockstep_mimo_elcentro_10s.json', 'j_max_relative_difference', '',
     '<= 0.05'),
    (MARTHS_FIDELITY, 'RoDeAC calibration rerun: largest difference of theta and P0',
     'marths_fidelity/summary.json', 'max_abs_rel_diff_pct', '%', '<= 15 %'),
    (MARTHS_FIDELITY, 'all 16 coefficients within 15 %', 'marths_fidelity/summary.json',
     'all_within_tolerance', '', 'true'),
    (SILVA, 'example controller (the published one): J1',
     'rths_benchmark_example/summary.json', 'cases/1/J1', 'ms', 'Table 3: 4.6 ms'),
    (SILVA, 'example controller: J2',
     'rths_benchmark_example/summary.json', 'cases/1/J2', '%', 'Table 3, within 15 %'),
    (SILVA, 'rths FIR: J1', 'rths_benchmark_fir/summary.json',
     'cases/1/J1', 'ms', '<= 1 ms'),
    (SILVA, 'rths FIR: J2', 'rths_benchmark_fir/summary.json',
     'cases/1/J2', '%', '<= 1/3 of the example'),
    (SILVA, 'rths FIR, 20 perturbed plants: worst J2',
     'rths_benchmark_fir/summary.json', 'perturbed/J2_max', '%', ''),
    (SILVA, 'rths FIR, 20 perturbed plants: unstable',
     'rths_benchmark_fir/summary.json', 'perturbed/unstable', '', '0'),
    ('Adaptive compensation', 'stiffness drop: fixed FIR, error after the change',
     'adaptive/summary.json', 'scenarios/stiffness_drop/fir/rms_pct_after_change', '%', ''),
    ('Adaptive compensation', 'stiffness drop: amb, error after the change',
     'adaptive/summary.json', 'scenarios/stiffness_drop/amb/rms_pct_after_change', '%',
     '<= half the FIR'),
    ('Adaptive compensation', 'plant drift: fixed FIR, error after the change',
     'adaptive/summary.json', 'scenarios/plant_drift/fir/rms_pct_after_change', '%', ''),
    ('Adaptive compensation', 'plant drift: rls_fir, error after the change',
     'adaptive/summary.json', 'scenarios/plant_drift/rls_fir/rms_pct_after_change', '%',
     '<= half the FIR'),
    ('Adaptive compensation', 'rls_fir step in the node core, 4096 Hz (benchmark), p99',
     'adaptive_step_cost/summary.json', 'rates/4096/methods/rls_fir/core_step_us_p99', 'us',
     '<= 50 us'),
    ('Adaptive compensation', 'ats step in the node core, 4096 Hz (benchmark), p99',
     'adaptive_step_cost/summary.json', 'rates/4096/methods/ats/core_step_us_p99', 'us',
     '<= 50 us'),
    ('Adaptive compensation', 'amb step in the node core, 4096 Hz (benchmark), p99',
     'adaptive_step_cost/summary.json', 'rates/4096/methods/amb/core_step_us_p99', 'us',
     '<= 50 us'),
    ('Adaptive compensation', 'rls_fir step in the node core, 1024 Hz (400 taps), p99',
     'adaptive_step_cost/summary.json', 'rates/1024/methods/rls_fir/core_step_us_p99', 'us',
     '<= 50 us'),
    ('Numerical substructure', 'one step of the 16-DOF building', 'numerical.json',
     'step_us_16dof', 'us', ''),
    ('Numerical substructure', 'one step of the 240-DOF frame', 'numerical.json',
     'step_us_240dof', 'us', ''),
    ('Numerical substructure', 'OpenSeesPy vs the built-in backend, largest difference',
     'numerical_opensees.json', 'max_rel_diff_vs_builtin', 'relative', ''),
    ('Specimens', 'DTM Table 4 reproduced: worst parameter error', 'dtm.json',
     'details/worst_error_pct', '%', '<= 3 %'),
    ('Specimens', 'MR damper fitted to 30 real tests: mean force error', 'mr_fit.json',
     'fit_error_mean_pct', '%', ''),
    ('Specimens', "MR damper, the paper's parameters at the best voltage: mean force error",
     'mr_fit.json', 'paper_error_mean_pct', '%', ''),
    ('Discrepancy workflow', 'hidden effects named (291 synthetic cases)', 'discrepancy.json',
     'correct_naming_percent', '%', ''),
    ('Discrepancy workflow', 'false names on 24 controls', 'discrepancy.json',
     'false_effects_on_controls', '', '0'),
    ('Discrepancy workflow', 'held-out set A named', 'discrepancy.json', 'heldout/A/named', '',
     '>= 13 of 14'),
    ('Discrepancy workflow', 'held-out set B named', 'discrepancy.json', 'heldout/B/named', '',
     '>= 11 of 12'),
    ('Discrepancy workflow', 'EMPS (real): NRMSE after naming the effect',
     'discrepancy_real.json', 'records/0/nrmse_after', 'relative', '<= 0.05'),
    ('Discrepancy workflow', 'cascaded tanks (real): linear baseline / published linear',
     'discrepancy_v3.json', 'sets/0/baseline_vs_published_linear', 'x', '<= 1.2'),
    ('OpenSees / OpenFresco site', 'round trip per analysis step, p50', 'site.json',
     'round_trip_us_p50', 'us', '<= 200 us'),
    ('OpenSees / OpenFresco site', 'round trip per analysis step, p99', 'site.json',
     'round_trip_us_p99', 'us', '<= 1000 us'),
    ('OpenSees / OpenFresco site', 'difference to the in-process loop, ideal specimen',
     'site_ideal.json', 'max_abs_diff_vs_direct', 'relative', '<= 1e-9'),
    ('OpenSees / OpenFresco site', 'difference to the in-process loop, simulated actuator',
     'site.json', 'max_abs_diff_vs_direct', 'relative', '<= 1 %'),
    ('Studies on Dask', 'speed-up of 2 workers over 1', 'study.json', 'speedup', 'x', '>= 1.7'),
    ('Studies on Dask', 'tasks lost after a worker is killed', 'study.json',
     'tasks_lost_after_worker_kill', '', '0'),
    ('Studies on Dask', 'rows identical to a serial run', 'study.json', 'identical_to_serial',
     '', 'true'),
    ('Studies on Dask', '1000 perturbed benchmark plants x 2 controllers: wall time',
     'study_benchmark_1000/summary.json', 'session/wall_s', 's', ''),
)


def lookup(doc, path: str):
    """Return the value at ``path`` ('a/b/0/c') in a JSON document; KeyError if absent."""
    value = doc
    for key in path.split('/'):
        if isinstance(value, list):
            value = value[int(key)]
        elif isinstance(value, dict) and key in value:
            value = value[key]
        else:
            raise KeyError(f'{path}: no {key!r}')
    return value


def provenance(doc: dict, path: str = '') -> str:
    """Return where and when a result was measured, as far as its file records it.

    ``path``: the figure's; a ``machine`` or ``date`` deeper along it (a file that
    collects runs of several hosts) wins over the file's own.
    """
    if path and isinstance(doc, dict):
        deepest = dict(doc)
        value = doc
        for key in path.split('/')[:-1]:
            value = value[int(key)] if isinstance(value, list) else value.get(key)
            if isinstance(value, dict):
                deepest.update({k: value[k] for k in ('machine', 'date') if k in value})
        doc = deepest
    machine = doc.get('machine') if isinstance(doc, dict) else None
    if isinstance(machine, dict):
        keys = ('cpu', 'cpu_model', 'cores', 'nproc', 'load', 'loadavg', 'kernel')
        host = ', '.join(f'{k} {v}' for k, v in machine.items() if k in keys)
    else:
        host = str(machine) if machine else ''
    date = (doc.get('date') or doc.get('created')) if isinstance(doc, dict) else None
    return '; '.join([date or 'date not recorded', host or 'machine not recorded'])


def _format(value, unit: str) -> str:
    """Format a figure for the table."""
    if isinstance(value, bool) or value is None:
        return str(value).lower()
    if isinstance(value, float):
        text = f'{value:.4g}'
    else:
        text = str(value)
    return f'{text} {unit}'.strip() if unit not in ('', 'relative', 'x') else \
        (f'{text}x' if unit == 'x' else text)


def performance_markdown(root: Path = None) -> str:
    """Return the text of ``docs/performance.md``; KeyError/OSError when a figure has no source."""
    root = Path(root) if root else repo_root()
    bench = root / 'docs' / 'bench'
    out = ['# Performance', '',
           'Every figure here is read from a JSON file under `docs/bench/` that a benchmark '
           'command wrote (the commands: [benchmarks.md](benchmarks.md)). Generated by '
           '`make docs` (`src/rths_bench/rths_bench/refdocs.py`); a test fails when a figure '
           'has no source or this file is out of date. Timings depend on the machine and its '
           'load: each row says what its file records.', '']
    section = None
    for sect, label, name, path, unit, target in FIGURES:
        file = bench / name
        doc = json.loads(file.read_text())
        value = lookup(doc, path)
        if sect != section:
            out += ['', f'## {sect}', '', '| figure | value | target | source | measured |',
                    '|---|---|---|---|---|']
            section = sect
        out.append(f'| {label} | {_format(value, unit)} | {target} | '
                   f'`{name}`: `{path}` | {provenance(doc, path)} |')
    return '\n'.join(out) + '\n'


# -- docs/benchmarks.md ----------------------------------------------------------------------

def _bench_parsers(parser) -> dict:
    """Return ``{name: parser}`` of the ``rths bench`` sub-commands."""
    bench = _subparsers(parser)['bench']
    return _subparsers(bench)


def benchmarks_markdown(parser=None) -> str:
    """Return the text of ``docs/benchmarks.md``: what each benchmark runs and where it writes."""
    parser = parser or build_parser()
    helps = _help_of(_subparsers(parser)['bench'])
    out = ['# Benchmarks', '',
           'Each `rths bench` command once: what it runs and measures (its `--help` '
           'description) and the file it writes. The figures they produced are collected in '
           '[performance.md](performance.md); every option is in [cli.md](cli.md). Generated '
           'by `make docs` from the argparse definitions; a test fails when it is out of date.',
           '']
    for name, sub in _bench_parsers(parser).items():
        out += [f'## rths bench {name}', '']
        text = ' '.join((sub.description or helps.get(name) or '').split()).replace('%%', '%')
        out += [text, '']
        outs = [a for a in sub._actions if '--out' in a.option_strings]
        if outs:
            default = outs[0].default
            where = f'`{default}` (or `--out`)' if default else 'the path given with `--out`'
            out += [f'Writes: {where}. Options: [cli.md](cli.md#'
                    f'{_anchor("rths bench " + name)}).', '']
    return '\n'.join(out).rstrip() + '\n'


# -- src/*/README.md ---------------------------------------------------------------------------

#: The generated part of a package's README.md lies between these two lines.
BEGIN = '<!-- modules: generated by make docs from each module\'s docstring -->'
END = '<!-- end of the generated modules -->'


def _first_line(path: Path) -> str:
    """Return the first line of a module's docstring, or of a message file's first comment."""
    text = path.read_text()
    if path.suffix == '.py':
        doc = ast.get_docstring(ast.parse(text)) or ''
        line = doc.strip().splitlines()[0] if doc.strip() else ''
        return re.sub(r':(?:mod|class|func|data|meth):', '', line).replace('``', '`')
    comment = [line.lstrip('# ').rstrip() for line in text.splitlines() if line.startswith('#')]
    return comment[0] if comment else ''


def module_table(package: Path) -> str:
    """Return the markdown table of a package's modules (or message files) and what each is."""
    inner = package / package.name
    if inner.is_dir():
        files = sorted(f for f in inner.glob('*.py') if f.name != '__init__.py')
        base = inner
    else:
        files = sorted(package.glob('msg/*.msg')) + sorted(package.glob('srv/*.srv'))
        base = package
    rows = [f'| `{f.relative_to(base)}` | {_cell(_first_line(f))} |' for f in files]
    return '\n'.join(['| module | what it is |', '|---|---|'] + rows)


def package_readme(package: Path, text: str = None) -> str:
    """Return ``package``'s README.md with its module table regenerated; ValueError without one."""
    path = package / 'README.md'
    text = path.read_text() if text is None else text
    if BEGIN not in text or END not in text:
        raise ValueError(f'{path}: no generated module table (the lines {BEGIN!r} and {END!r})')
    head, rest = text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    return f'{head}{BEGIN}\n{module_table(package)}\n{END}{tail}'


def packages(root: Path = None) -> list:
    """Return every directory under ``src/`` that holds a package.xml: the workspace's."""
    root = Path(root) if root else repo_root()
    return sorted(p for p in (root / 'src').iterdir() if (p / 'package.xml').exists())


# -- command line ---------------------------------------------------------------------------

DOCS = {'docs/cli.md': cli_markdown, 'docs/performance.md': performance_markdown,
        'docs/benchmarks.md': benchmarks_markdown}


def main(argv=None) -> int:
    """Write (``--write``) or check the generated documents; exit 1 when one is out of date."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--write', action='store_true', help='rewrite the documents')
    args = parser.parse_args(argv)
    root = repo_root()
    stale = []
    for name, make in DOCS.items():
        text = make()
        path = root / name
        if args.write:
            path.write_text(text)
            print(f'wrote {name}')
        elif not path.exists() or path.read_text() != text:
            stale.append(name)
    for package in packages(root):
        path = package / 'README.md'
        text = package_readme(package)
        if args.write:
            path.write_text(text)
            print(f'wrote {path.relative_to(root)}')
        elif path.read_text() != text:
            stale.append(str(path.relative_to(root)))
    for name in stale:
        print(f'{name} is out of date: run make docs', file=sys.stderr)
    return 1 if stale else 0


if __name__ == '__main__':
    sys.exit(main())
