"""Test support: the tests of truth, which may not skip in CI, and a package's commands alone.

A test that compares rths with measured data or a published figure calls :func:`require_data`
(or :func:`require`, for an optional dependency) first.  When what it needs is missing it
skips with the reason on a user's machine, and FAILS with the same one-line reason in CI
(``CI=true``), so a change that breaks such a figure can never pass CI by skipping.  The one
exception is a data set that may not be redistributed (the RTHS benchmark's ground-motion
records): CI cannot have it, so its test skips everywhere, saying why.
"""

import argparse
import os
from pathlib import Path

import pytest

from . import datasets


def in_ci() -> bool:
    """Tell whether this is a CI run (``CI`` is ``true``, ``1`` or ``yes``)."""
    return os.environ.get('CI', '').strip().lower() in ('true', '1', 'yes')


def require(available: bool, reason: str) -> None:
    """Go on if ``available``; else skip with ``reason``, or fail with it in CI."""
    if available:
        return
    if in_ci():
        pytest.fail(f'{reason} [CI=true: a test of truth may not skip]', pytrace=False)
    pytest.skip(reason)


def require_data(name: str) -> Path:
    """Return the folder of data set ``name`` (:data:`rths_common.datasets.DATASETS`).

    Missing: skip (fail in CI) with the reason naming the data set and where it comes from;
    a data set that may not be redistributed skips in CI too.
    """
    reason = datasets.missing(name)
    if reason and not datasets.DATASETS[name].redistributable:
        pytest.skip(f'{reason}; it may not be redistributed, so CI has it neither')
    require(reason is None, reason or '')
    return datasets.dataset_dir(name)


def command_parser(register) -> argparse.ArgumentParser:
    """Return an ``rths`` parser holding one package's commands (its ``register``)."""
    parser = argparse.ArgumentParser(prog='rths')
    commands = parser.add_subparsers(dest='command', required=True)
    benches = commands.add_parser('bench').add_subparsers(dest='bench', required=True)
    register(commands, benches)
    return parser


def run_command(register, argv: list) -> int:
    """Parse ``argv`` with :func:`command_parser` and run the command; return its exit code."""
    args = command_parser(register).parse_args(argv)
    return args.func(args)
