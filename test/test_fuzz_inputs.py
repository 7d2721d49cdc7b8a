"""Fuzz campaign: every parser a lab feeds, given malformed input, refuses it cleanly.

For each parser hypothesis generates inputs (a valid file mutated: truncated,
bytes overwritten or inserted, a line replaced, a value of the YAML replaced by
any scalar; or plain garbage).  Each case must end in one of two ways: the
parser accepts it, or it raises ValueError/OSError whose message (as ``rths``
prints it: :func:`rths_bringup.cli.error_line`) is one line naming the file.
Anything else fails the test: another exception (a traceback for the user), a
case running longer than :data:`HANG_S` (a hang), or a file changed outside
the case's own directory (a sentinel tree beside it, and the valid inputs the
cases are made from).  Each case runs in-process, through the function the
``rths`` command calls, in a directory on tmpfs (/dev/shm) where there is one.

``make test`` runs a fixed-seed corpus of :data:`EXAMPLES` cases per parser;
``make fuzz`` runs ``RTHS_FUZZ_EXAMPLES`` (10 000) per parser and writes the
counts to ``RTHS_FUZZ_REPORT`` (docs/fuzz.json, summarised in docs/reliability.md).
"""

from collections import Counter
import contextlib
import json
import os
from pathlib import Path
import re
import shutil
import signal
import tempfile
import time

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
import yaml

from rths_bringup.cli import error_line

EXAMPLES = int(os.environ.get('RTHS_FUZZ_EXAMPLES', '40'))
REPORT = os.environ.get('RTHS_FUZZ_REPORT', '')
HANG_S = float(os.environ.get('RTHS_FUZZ_HANG_S', '20'))
CONFIG = Path(__file__).resolve().parents[1] / 'config'
STATS: dict = {}
#: Where the cases' directories go: tmpfs when the machine has one (no disk I/O per case).
SCRATCH = '/dev/shm' if os.access('/dev/shm', os.W_OK) else None
#: What the report counts for each parser; the last three must stay 0 (the test fails first).
COUNTS = ('cases', 'accepted', 'refused', 'max_ms', 'tracebacks', 'hangs', 'changed_outside')

FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))


class Hang(Exception):
    """A case ran longer than HANG_S."""


@contextlib.contextmanager
def _alarm(seconds):
    def ring(signum, frame):
        raise Hang(f'no answer within {seconds} s')
    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in root.rglob('*') if p.is_file()}


@pytest.fixture(scope='module', autouse=True)
def _report():
    yield
    if REPORT:
        old = json.loads(Path(REPORT).read_text()) if Path(REPORT).exists() else {}
        old.update({name: dict(c) for name, c in STATS.items() if c['cases']})
        Path(REPORT).write_text(json.dumps(old, indent=1, sort_keys=True) + '\n')


@contextlib.contextmanager
def _case(name: str):
    """Give one case a fresh directory, beside a sentinel tree nobody may touch."""
    root = Path(tempfile.mkdtemp(prefix='rths-fuzz-', dir=SCRATCH))
    (root / 'outside').mkdir()
    (root / 'outside' / 'recorded.txt').write_text('a recording nobody may touch\n')
    case = root / 'case'
    case.mkdir()
    before = _snapshot(root / 'outside')
    cwd = os.getcwd()
    os.chdir(case)
    try:
        yield case
    finally:
        os.chdir(cwd)
        changed = _snapshot(root / 'outside') != before
        shutil.rmtree(root, ignore_errors=True)
        _stats(name)['changed_outside'] += changed
        assert not changed, f'{name}: a file outside the case changed'


@contextlib.contextmanager
def _unchanged(name: str, *roots: Path):
    """Fail ``name`` if a case changed the valid inputs it was made from (``roots``)."""
    before = [_snapshot(r) for r in roots]
    yield
    changed = [str(r) for r, b in zip(roots, before, strict=True) if _snapshot(r) != b]
    _stats(name)['changed_outside'] += len(changed)
    assert not changed, f'{name}: the cases changed {changed}'


def _stats(name: str) -> Counter:
    return STATS.setdefault(name, Counter({k: 0 for k in COUNTS}))


def check(name: str, func, *args, where=None):
    """Run ``func(*args)``; accepted, or refused with one line naming ``where``; count it."""
    stats = _stats(name)
    stats['cases'] += 1
    start = time.monotonic()
    try:
        with _alarm(HANG_S):
            func(*args)
    except Hang:
        stats['hangs'] += 1
        raise
    except (ValueError, OSError) as err:
        line = error_line(err)
        assert line and '\n' not in line, f'{name}: empty or multi-line error {err!r}'
        if where is not None:
            assert str(where) in line, f'{name}: error does not name {where}: {line}'
        stats['refused'] += 1
    except BaseException:
        stats['tracebacks'] += 1
        raise
    else:
        stats['accepted'] += 1
    finally:
        stats['max_ms'] = max(stats['max_ms'], round(1e3 * (time.monotonic() - start)))


def _examples(found, **more):
    """Return a decorator: hypothesis runs each ``data`` of ``found`` before generated ones."""
    def wrap(func):
        for data in reversed(found):
            func = example(data=data, **more)(func)
        return func
    return wrap


# -- mutations of a valid input ------------------------------------------------------------------

def _overwrite(data: bytes, at: int, junk: bytes) -> bytes:
    at = min(at, len(data))
    return data[:at] + junk + data[at + len(junk):]


def _replace_line(data: bytes, index: int, line: str) -> bytes:
    lines = data.split(b'\n')
    lines[index % len(lines)] = line.encode('utf-8', 'surrogatepass')
    return b'\n'.join(lines)


def mutated(valid: bytes):
    """Strategy: ``valid`` truncated, overwritten, with bytes inserted, a line replaced, garbage."""
    n = len(valid)
    return st.one_of(
        st.integers(0, n).map(lambda k: valid[:k]),
        st.tuples(st.integers(0, n), st.binary(min_size=1, max_size=16)).map(
            lambda t: _overwrite(valid, *t)),
        st.tuples(st.integers(0, n), st.binary(min_size=1, max_size=32)).map(
            lambda t: valid[:t[0]] + t[1] + valid[t[0]:]),
        st.tuples(st.integers(0, 10_000), st.text(max_size=40)).map(
            lambda t: _replace_line(valid, *t)),
        st.binary(max_size=200),
    )


SCALARS = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                    st.text(max_size=20), st.lists(st.floats(), max_size=3),
                    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2))


def _leaves(tree, path=()):
    if isinstance(tree, dict):
        for key, value in tree.items():
            yield from _leaves(value, path + (key,))
    elif isinstance(tree, list) and tree and len(tree) < 50:
        for i, value in enumerate(tree):
            yield from _leaves(value, path + (i,))
    else:
        yield path


def _set(tree, path, value):
    node = tree
    for key in path[:-1]:
        node = node[key]
    key = path[-1]
    if isinstance(node, list) and not isinstance(key, int):
        key = 0   # a new key under a list: replace its first item instead
    if value is _DELETE and isinstance(node, dict):
        node.pop(key, None)
    else:
        node[key] = None if value is _DELETE else value


_DELETE = object()


def yaml_mutated(valid: dict):
    """Strategy: the YAML text of ``valid`` with one value replaced or deleted, or a key added."""
    paths = [p for p in _leaves(valid) if p]

    def build(args):
        index, value, extra = args
        tree = json.loads(json.dumps(valid))
        path = paths[index % len(paths)]
        if extra is not None:
            _set(tree, path[:-1] + (extra,), value)
        else:
            _set(tree, path, value)
        return yaml.safe_dump(tree).encode()
    return st.tuples(st.integers(0, 10_000), st.one_of(SCALARS, st.just(_DELETE)),
                     st.one_of(st.none(), st.text(min_size=1, max_size=8))).map(build)


def file_input(valid: bytes, tree=None):
    """Strategy for a file: byte mutations of ``valid``, and YAML-level ones of ``tree``."""
    return mutated(valid) if tree is None else st.one_of(mutated(valid), yaml_mutated(tree))


# -- params files and the configuration ---------------------------------------------------------

def _config_case(case: Path, name: str, data: bytes) -> Path:
    config = case / 'config'
    shutil.copytree(CONFIG, config, ignore=shutil.ignore_patterns('studies', 'models'))
    (config / name).write_bytes(data)
    return config


#: Findings of the long run, kept as cases of every run: each gave a traceback.
PARAMS_FOUND = {
    'numerical.yaml': [   # fs_hz: null reached the rate check: TypeError
        (CONFIG / 'numerical.yaml').read_bytes().replace(b'fs_hz: 1024.0', b'fs_hz: null'),
        # duration_s outside its range built first: 37 GiB MemoryError, or a 20 s hang
        re.sub(rb'duration_s: \S+', b'duration_s: 986136556',
               (CONFIG / 'numerical.yaml').read_bytes()),
        # inside its range (1e6 s) but ~8 GB for one array at 1024 Hz: refused by its steps
        re.sub(rb'duration_s: \S+', b'duration_s: 999999.0',
               (CONFIG / 'numerical.yaml').read_bytes())],
    'compensator.yaml': [   # scheme: [] looked up in the scheme registry: TypeError
        re.sub(rb'scheme: \S+', b'scheme: []', (CONFIG / 'compensator.yaml').read_bytes())],
    'bridge.yaml': [   # actuator_model: null read as the plant file 'None', not naming the file
        re.sub(rb'actuator_model: \S+', b'actuator_model: null',
               (CONFIG / 'bridge.yaml').read_bytes()),
        re.sub(rb'actuator_model: \S+', b'actuator_model: nowhere.yaml',
               (CONFIG / 'bridge.yaml').read_bytes())]}


@pytest.mark.parametrize('name', ['numerical.yaml', 'compensator.yaml', 'bridge.yaml'])
def test_params_files(name):
    from rths_bringup import preflight

    valid = (CONFIG / name).read_bytes()
    with _case('warm-up') as case:   # imports SciPy, rclpy: outside the cases' hang alarm
        preflight.check_config(_config_case(case, name, valid))

    @FUZZ
    @given(data=file_input(valid, yaml.safe_load(valid)))
    @_examples(PARAMS_FOUND.get(name, []))
    def run(data):
        with _case(f'params {name}') as case:
            config = _config_case(case, name, data)
            check(f'params {name}', preflight.check_config, config, where=name)
    with _unchanged(f'params {name}', CONFIG):
        run()


#: Findings of the long run, kept as cases of every run: each gave a traceback.
PLANT_FOUND = [b'kind: arx\nfs_hz: null\na: [1.0, -0.5]\nb: [0.1]\n',   # TypeError in float()
               b'fs_hz: 1024.0\na: [1.0, -0.5]\nb: [0.1]\nna: [1]\n',    # int() of a list
               b'fs_hz: 1024.0\na: [1.0, null]\nb: [0.1]\n',
               b'fs_hz: 1024.0\na: [1.0]\nb: [0.1]\nd: 1.0e+300\n',      # zeros(d) later
               b'fs_hz: true\na: [1.0]\nb: {x: 1}\nd: 1.5\n']


def test_plant_file():
    from rths_compensator.identification import load_plant

    valid = (CONFIG / 'plant.yaml').read_bytes()

    @FUZZ
    @given(data=file_input(valid, yaml.safe_load(valid)))
    @_examples(PLANT_FOUND)
    def run(data):
        with _case('plant.yaml') as case:
            path = case / 'plant.yaml'
            path.write_bytes(data)
            check('plant.yaml', load_plant, path, where=path)
    with _unchanged('plant.yaml', CONFIG):
        run()


MODEL = {'M': [[1000.0, 0.0], [0.0, 1000.0]], 'K': [[2e6, -1e6], [-1e6, 1e6]],
         'damping': {'ratio': 0.02}}


def test_building_model_file():
    from rths_numerical.model import load_model_yaml

    valid = yaml.safe_dump(MODEL).encode()

    @FUZZ
    @given(data=file_input(valid, MODEL))
    def run(data):
        with _case('model yaml') as case:
            path = case / 'model.yaml'
            path.write_bytes(data)
            check('model yaml', load_model_yaml, path, where=path)
    run()


# -- column files: ground motion records, identification and discrepancy CSVs ---------------------

AT2 = (b'PEER NGA STRONG MOTION DATABASE RECORD\nSYNTHETIC, TEST\n'
       b'ACCELERATION TIME SERIES IN UNITS OF G\n'
       b'NPTS=   12, DT=   .0100 SEC\n'
       b'  .1000000E-02  .2000000E-02 -.1000000E-02  .0000000E+00  .3000000E-02\n'
       b'  .1000000E-02 -.2000000E-02  .1000000E-02  .0000000E+00  .3000000E-02\n'
       b'  .1000000E-02  .2000000E-02\n')
CSV = ('time [s],command [mm],measured [mm]\n'
       + ''.join(f'{k / 1024:.6f},{np.sin(k / 9):.5f},{np.sin(k / 9 - 0.1):.5f}\n'
                 for k in range(40))).encode()


def test_ground_motion_record():
    from rths_numerical.ground_motion import load_record

    @FUZZ
    @given(data=mutated(AT2), suffix=st.sampled_from(['.AT2', '.dat', '.csv']))
    def run(data, suffix):
        with _case('ground motion') as case:
            path = case / f'record{suffix}'
            path.write_bytes(data)
            check('ground motion', load_record, str(path), where=path.name)
    run()


def test_column_file():
    from rths_common.columns import read_columns

    @FUZZ
    @given(data=mutated(CSV), keep_nan=st.booleans())
    def run(data, keep_nan):
        with _case('csv columns') as case:
            path = case / 'io.csv'
            path.write_bytes(data)
            check('csv columns', read_columns, path, ['time', 'command', 'measured'],
                  where=path, )
    run()


# -- bags ---------------------------------------------------------------------------------------

def _valid_bag(root: Path, storage: str) -> Path:
    from rths_common import bagio

    store = bagio.typestore()
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    cls = store.types['rths_msgs/msg/Measurement']
    bag = root / f'valid-{storage}'
    with bagio.BagWriter(bag, run_info={'fs_hz': 1024.0, 'kind': 'rths'}, storage=storage,
                         commit_period_s=0.0) as writer:
        for k in range(60):
            writer.write_msg('/rths/measurement', 1000 + k, cls(
                header=header(stamp=stamp(sec=0, nanosec=0), frame_id=''), step=k,
                applied=np.array([1e-3 * k]), displacement=np.array([1e-3 * k]),
                force=np.array([2.0 * k])))
    return bag


def _read_bag(bag: Path):
    """``rths bag info``'s read: every message, through one open of the bag.

    :func:`bagio.info` reads every message with the generator :func:`bagio.read_messages`
    uses and keeps its BagDamaged line in ``damaged``: raised here as the reader raises it.
    """
    from rths_common import bagio

    out = bagio.info(bag)
    if out['damaged']:
        raise bagio.BagDamaged(out['damaged'])


@pytest.fixture(scope='module')
def valid_bags(tmp_path_factory):
    root = tmp_path_factory.mktemp('bags')
    return {storage: _valid_bag(root, storage) for storage in ('mcap', 'sqlite3')}


def _topic_as_list(tree):
    """Fuzz finding: a topic name replaced by [] (TypeError: unhashable in bagio.info)."""
    tree = json.loads(json.dumps(tree))
    tree['rosbag2_bagfile_information']['topics_with_message_count'][0]['topic_metadata'][
        'name'] = []
    return tree


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('part', ['data', 'metadata'])
def test_bag(valid_bags, storage, part):
    from rths_common import bagstore

    valid = valid_bags[storage]
    data_name = bagstore.data_file(valid).name
    target = data_name if part == 'data' else 'metadata.yaml'
    original = (valid / target).read_bytes()
    tree = yaml.safe_load(original) if part == 'metadata' else None
    name = f'bag {storage} {part}'
    with _case('warm-up') as case:   # imports rosbags' reader: outside the cases' hang alarm
        shutil.copytree(valid, case / 'bag')
        _read_bag(case / 'bag')

    found = {'metadata': [yaml.safe_dump(_topic_as_list(tree)).encode()] if tree else [],
             'data': [_replace_line(original, 498, '')] if storage == 'sqlite3' else []}

    @FUZZ
    @given(data=file_input(original, tree), drop_metadata=st.booleans())
    @_examples(found[part], drop_metadata=False)
    def run(data, drop_metadata):
        with _case(name) as case:
            bag = case / 'bag'
            shutil.copytree(valid, bag)
            (bag / target).write_bytes(data)
            if part == 'data' and drop_metadata:   # as a SIGKILL leaves it: reindexed on read
                (bag / 'metadata.yaml').unlink()
            check(name, _read_bag, bag, where=bag)
    with _unchanged(name, valid):
        run()


# -- packets: the UDP servo controller and the TCP site -----------------------------------------

def test_udp_controller_datagram():
    from rths_actuator_bridge import protocol

    valid = [protocol.pack(k, 7, [0.001, 2.0, 0.0], 1, version=v)
             for v in (1, 2) for k in sorted(protocol.KIND_NAMES)
             if not (v == 1 and k == protocol.HEARTBEAT)]

    @FUZZ
    @given(data=st.one_of(st.sampled_from(valid).flatmap(mutated), st.binary(max_size=300)))
    def run(data):
        check('udp datagram', protocol.unpack, data)
    run()


def test_tcp_site_stream():
    from rths_actuator_bridge import openfresco

    sizes = openfresco.Sizes.generic_client(1, data_size=8)
    trial = openfresco.encode_request(sizes, openfresco.SET_TRIAL_RESPONSE, disp=[0.001])
    valid = sizes.pack() + trial + openfresco.encode_request(sizes, openfresco.COMMIT_STATE)

    def feed(stream, cuts):
        framer = openfresco.Framer()
        at = 0
        for cut in sorted(cuts) + [len(stream)]:
            for unit in framer.feed(stream[at:cut]):
                if isinstance(unit, bytes):
                    openfresco.decode(unit, framer.sizes)
            at = max(at, cut)
        framer.truncation()

    @FUZZ
    @given(data=st.one_of(mutated(valid), st.binary(max_size=400)),
           cuts=st.lists(st.integers(0, 400), max_size=4))
    def run(data, cuts):
        check('tcp site stream', feed, data, cuts)
    run()


# -- command-line arguments ---------------------------------------------------------------------

def _commands(parser, path=()):
    """(command path, parser) of every leaf command below ``parser``."""
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    for name, sub in subs[0].choices.items():
        yield from _commands(sub, path + (name,))


def test_command_line_arguments():
    """Any option of any command with any value: parsed, or one error line and exit 2."""
    import io

    from rths_bringup import cli

    parser = cli.build_parser()
    leaves = list(_commands(parser))
    options = [(path, o) for path, p in leaves for a in p._actions for o in a.option_strings
               if o not in ('-h', '--help')]

    def parse(argv):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                parser.parse_args(argv)
            except SystemExit as exc:
                # a renamed option's 'note: ... is now called ...' line may precede the error
                lines = [t for t in err.getvalue().split('\n') if t and not t.startswith('note: ')]
                text = '\n'.join(lines)
                assert exc.code == 2 and len(lines) == 1 and 'error:' in text, (argv, text)
                raise ValueError(text) from None

    @FUZZ
    @given(index=st.integers(0, len(options) - 1),
           values=st.lists(st.one_of(st.text(max_size=12), st.floats().map(repr),
                                     st.integers().map(str)), max_size=2))
    def run(index, values):
        path, option = options[index]
        check('command line', parse, list(path) + [option] + values)
    run()
