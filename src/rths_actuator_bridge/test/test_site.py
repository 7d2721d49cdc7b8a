"""The experimental site: step mapping, multi-DOF, bad peers (safe state + readable bag), TLS.

A Python client speaks the genericClient protocol to the site served in a thread (the
OpenSeesPy client is in rths_bench/test/test_bench_site.py: it needs its own process).
"""

import socket
import subprocess
import threading

import numpy as np
import pytest

from rths_actuator_bridge import openfresco as of
from rths_actuator_bridge import safety
from rths_actuator_bridge.site import SiteCore, SiteStopped, build_site, site_params
from rths_actuator_bridge.site_server import allowed, listen, run
from rths_common import bagio, topics

FS = 1000.0


def ideal_config(n=1, k=(1.0e5,), mode='pseudodynamic', **site):
    """Return a site over the ideal specimen (force = K x) with the identity compensator."""
    return {'site': site_params(dict(site, mode=mode)),
            'bridge': {'backend': 'ideal', 'n_channels': n, 'stiffness_n_m': list(k),
                       'fs_hz': FS, 'velocity_m_s': 1.0, 'acceleration_m_s2': 1000.0},
            'compensator': {'scheme': 'identity', 'taps': [1.0], 'denominator': [1.0],
                            'fs_hz': FS}}


class Served:
    """The site serving one session in a thread on a free port."""

    def __init__(self, config, bag, tls=None, wait_s=20.0):
        self.wait_s = wait_s
        self.listener = listen('127.0.0.1', 0)
        self.port = self.listener.getsockname()[1]
        self.summary = None
        self.thread = threading.Thread(target=self._run, args=(config, bag, tls), daemon=True)
        self.thread.start()

    def _run(self, config, bag, tls):
        try:
            self.summary = run(config, self.listener, bag, tls, wait_s=self.wait_s)
        finally:
            self.listener.close()

    def join(self):
        self.thread.join(30.0)
        assert not self.thread.is_alive(), 'the site did not end'
        return self.summary


class Client:
    """A minimal genericClient: set-up, then whole messages."""

    def __init__(self, port, sizes, wrap=None):
        sock = socket.create_connection(('127.0.0.1', port), timeout=10.0)
        self.sock = wrap(sock) if wrap else sock
        self.sizes = sizes
        self.sock.sendall(sizes.pack())

    def send(self, action, disp=(), time=0.0):
        n = self.sizes.n
        self.sock.sendall(of.encode_request(self.sizes, action, disp, np.zeros(n), np.zeros(n),
                                            time=time))

    def ask(self, action):
        self.send(action)
        data = b''
        while len(data) < self.sizes.message_bytes:
            chunk = self.sock.recv(self.sizes.message_bytes - len(data))
            assert chunk, 'the site closed the connection'
            data += chunk
        return np.frombuffer(data, '<f8')

    def close(self):
        self.sock.close()


def bag_status(bag):
    """Return the bridge's safety states and the site's events, read back from the closed bag."""
    states, events = [], []
    for _, _, msg in bagio.read_messages(bag, [topics.STATUS]):
        (states if msg.node == 'bridge' else events).append(msg.safety_state if
                                                            msg.node == 'bridge' else msg.fault)
    return states, events


def test_trials_through_the_ideal_specimen_multi_dof(tmp_path):
    k = [1.0e5, -2.0e4, -2.0e4, 5.0e4]   # a coupled 2 x 2 spring
    served = Served(ideal_config(n=2, k=k, initial_stiffness_n_m=k), tmp_path / 'bag')
    client = Client(served.port, of.Sizes.generic_client(2))
    np.testing.assert_array_equal(client.ask(of.GET_TANGENT_STIFF)[:4], [1e5, -2e4, -2e4, 5e4])
    client.send(of.SET_TRIAL_RESPONSE, [0.0, 0.0])   # at rest, as OpenSees starts
    forces = []
    for step in range(1, 6):
        x = np.array([1e-4, -5e-5]) * step
        client.send(of.SET_TRIAL_RESPONSE, x, time=step / FS)
        forces.append(client.ask(of.GET_FORCE)[:2])
        np.testing.assert_allclose(client.ask(of.GET_DISP)[:2], x)
        client.send(of.COMMIT_STATE)
    client.send(of.DIE)
    summary = served.join()
    client.close()
    kmat = np.reshape(k, (2, 2))
    np.testing.assert_allclose(forces, [kmat @ (np.array([1e-4, -5e-5]) * s) for s in range(1, 6)],
                               rtol=1e-12)
    assert summary['exit_code'] == 0 and summary['steps'] == 6 and summary['safety_state'] == 0
    meas = bagio.step_arrays(tmp_path / 'bag', topics.MEASUREMENT, ('force',))
    np.testing.assert_allclose(meas['force'], [[0.0, 0.0], *forces], rtol=1e-12)


def core_for(config):
    core = build_site(config)
    return core


def trial(core, x):
    n = core.n
    sizes = core.sizes
    return core.handle(of.decode(of.encode_request(sizes, of.SET_TRIAL_RESPONSE, [x] * n,
                                                   [0] * n, [0] * n, 0.0), sizes))


def commit(core):
    return core.handle(of.decode(of.encode_request(core.sizes, of.COMMIT_STATE), core.sizes))


def test_one_loop_step_per_analysis_step_for_opensees_central_difference():
    # CentralDifference sends per analysis step: the previous displacement again, then the
    # new one, then commitState (recorded from OpenSeesPy 3.7.1.2); a first trial at rest.
    core = core_for(ideal_config())
    core.accept(of.Sizes.generic_client(1))
    trial(core, 0.0)                       # the structure at rest: step 0
    for new, old in ((0.0, 0.0), (1e-4, 0.0), (3e-4, 1e-4), (3e-4, 3e-4)):
        trial(core, old)
        trial(core, new)
        commit(core)
    # four analysis steps: four loop steps after step 0, also where nothing moved
    assert core.k == 5
    np.testing.assert_array_equal([r for r in (core.applied_trial,)], [[3e-4]])


def test_new_displacement_first_then_commit_is_one_step_as_newmark_explicit():
    core = core_for(ideal_config())
    core.accept(of.Sizes.generic_client(1))
    trial(core, 0.0)
    for d in (1e-4, 2e-4):
        trial(core, d)                     # predicted displacement: the step
        force = np.frombuffer(core.handle(of.Request(of.GET_FORCE, *[np.zeros(0)] * 4, 0.0)),
                              '<f8')[0]
        assert force == pytest.approx(1.0e5 * d)   # the force of this step's displacement
        trial(core, d)                     # corrector: same displacement
        commit(core)
    assert core.k == 3


def test_size_mismatch_is_refused_before_anything_moves(tmp_path):
    served = Served(ideal_config(n=1), tmp_path / 'bag')
    client = Client(served.port, of.Sizes.generic_client(2))
    summary = served.join()
    client.close()
    assert summary['exit_code'] == 3 and summary['steps'] == 0
    assert '2 basic DOF(s)' in summary['problem'] and 'nothing was moved' in summary['problem']
    assert summary['safety_state'] == safety.STOPPED
    states, events = bag_status(tmp_path / 'bag')
    assert states == [] and 'bad peer' in events[0]


def _run_then(tmp_path, misbehave, steps=20, **site):
    """Drive a few steps, then ``misbehave(client, port)``; return the summary and the bag."""
    served = Served(ideal_config(**site), tmp_path / 'bag')
    client = Client(served.port, of.Sizes.generic_client(1))
    client.send(of.SET_TRIAL_RESPONSE, [0.0])
    for k in range(1, steps):
        client.send(of.SET_TRIAL_RESPONSE, [2e-3 * np.sin(k / 10)], time=k / FS)
        client.ask(of.GET_FORCE)
        client.send(of.COMMIT_STATE)
    misbehave(client, served.port)
    summary = served.join()
    client.close()
    return summary, tmp_path / 'bag'


def _truncated(client, port):
    client.sock.sendall(of.encode_request(client.sizes, of.GET_FORCE)[:100])
    client.sock.shutdown(socket.SHUT_WR)


def _non_finite(client, port):
    client.send(of.SET_TRIAL_RESPONSE, [float('nan')])


def _unknown_action(client, port):
    client.send(42)


def _vanished(client, port):
    client.sock.close()


def _second_client(client, port):
    other = socket.create_connection(('127.0.0.1', port), timeout=5.0)
    other.sendall(of.Sizes.generic_client(1).pack())
    try:
        other.recv(1)
    except OSError:
        pass
    other.close()


@pytest.mark.parametrize('misbehave, words', [
    (_truncated, 'truncated'),
    (_non_finite, 'not finite'),
    (_unknown_action, 'unknown action 42'),
    (_vanished, 'vanished'),
    (_second_client, 'second client'),
])
def test_bad_peer_goes_to_the_safe_state_and_closes_the_bag(tmp_path, misbehave, words):
    summary, bag = _run_then(tmp_path, misbehave)
    assert summary['exit_code'] == 3
    assert words in summary['problem']
    assert summary['safety_state'] == safety.STOPPED
    assert 'emergency stop' in summary['fault']
    states, events = bag_status(bag)          # the bag reads back: closed, nothing lost
    assert states[:20] == [safety.ACTIVE] * 20
    assert states[-1] == safety.STOPPED and safety.RAMP in states
    assert any(words in e for e in events)
    meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied',))
    assert meas['step'].size == len(states)   # every loop step, the safe stop included
    applied = meas['applied'][np.isfinite(meas['applied'][:, 0]), 0]
    assert abs(applied[-1]) < 1e-9            # at the safe position


def test_silent_client_times_out_safely(tmp_path):
    summary, _ = _run_then(tmp_path, lambda c, p: None, steps=3, client_timeout_s=0.3)
    assert summary['exit_code'] == 3 and 'client_timeout_s' in summary['problem']
    assert summary['safety_state'] == safety.STOPPED


def test_supervisor_fault_stops_the_session(tmp_path):
    def jump(client, port):
        client.send(of.SET_TRIAL_RESPONSE, [0.2])   # 0.2 m in one sample: velocity limit
        try:
            client.ask(of.GET_FORCE)
        except (AssertionError, OSError):
            pass
    summary, bag = _run_then(tmp_path, jump)
    assert summary['exit_code'] == 3 and 'velocity' in summary['problem']
    assert summary['safety_state'] == safety.STOPPED


def test_allow_list():
    assert allowed('127.0.0.1', ['127.0.0.1'])
    assert allowed('10.0.0.7', ['10.0.0.0/24'])
    assert not allowed('10.0.1.7', ['10.0.0.0/24', '127.0.0.1'])
    assert allowed('::ffff:10.0.0.7', ['10.0.0.0/24'])
    assert not allowed('garbage', ['0.0.0.0/0'])


def test_client_not_on_the_allow_list_is_refused(tmp_path):
    served = Served(ideal_config(allow=['10.9.9.9']), tmp_path / 'bag', wait_s=1.0)
    sock = socket.create_connection(('127.0.0.1', served.port), timeout=5.0)
    sock.sendall(of.Sizes.generic_client(1).pack())
    try:
        assert sock.recv(1) == b''   # closed at once
    except ConnectionResetError:
        pass
    sock.close()
    summary = served.join()      # nobody allowed came: wait_s ends it, nothing moved
    assert summary['steps'] == 0 and summary['problem'] == 'no client connected'


def test_realtime_mode_ticks_its_own_loop(tmp_path):
    import time
    served = Served(ideal_config(mode='realtime'), tmp_path / 'bag')
    client = Client(served.port, of.Sizes.generic_client(1))
    client.send(of.SET_TRIAL_RESPONSE, [1e-4])
    time.sleep(0.2)
    force = client.ask(of.GET_FORCE)[0]
    client.send(of.DIE)
    summary = served.join()
    client.close()
    assert force == pytest.approx(10.0)
    assert summary['exit_code'] == 0 and summary['steps'] > 50   # ~200 ticks at 1 kHz


def _certs(tmp_path):
    """Make a CA and a site and a client certificate signed by it (openssl)."""
    def sh(*args):
        subprocess.run(['openssl', *args], cwd=tmp_path, check=True, capture_output=True)
    sh('req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout', 'ca.key', '-out', 'ca.pem',
       '-days', '1', '-subj', '/CN=lab-ca')
    for name in ('site', 'client'):
        sh('req', '-newkey', 'rsa:2048', '-nodes', '-keyout', f'{name}.key', '-out',
           f'{name}.csr', '-subj', f'/CN={name}')
        sh('x509', '-req', '-in', f'{name}.csr', '-CA', 'ca.pem', '-CAkey', 'ca.key',
           '-CAcreateserial', '-out', f'{name}.pem', '-days', '1')
    return {n: str(tmp_path / n) for n in ('ca.pem', 'site.pem', 'site.key', 'client.pem',
                                           'client.key')}


def test_mutual_tls_and_the_genericclient_backend(tmp_path):
    """Rths on both sides over mutual TLS: the bridge's genericclient backend reads K x."""
    from rths_actuator_bridge.bridge import Bridge
    from rths_actuator_bridge.site_server import server_tls_context
    c = _certs(tmp_path)
    tls = server_tls_context(c['site.pem'], c['site.key'], c['ca.pem'])
    served = Served(ideal_config(), tmp_path / 'bag', tls)
    lab = Bridge()
    lab.configure({'backend': 'genericclient', 'site': f'tcp://127.0.0.1:{served.port}',
                   'fs_hz': FS, 'tls_ca': c['ca.pem'], 'tls_cert': c['client.pem'],
                   'tls_key': c['client.key']})
    lab.activate()
    xs = [0.0, 0.0, 1e-4, 2e-4, 2e-4, 1e-4]
    forces = [lab.step(k, np.array([x])).force[0] for k, x in enumerate(xs)]
    lab.close()
    summary = served.join()
    np.testing.assert_allclose(forces, 1.0e5 * np.array(xs), rtol=1e-12, atol=1e-12)
    assert summary['exit_code'] == 0 and summary['steps'] == len(xs)


def test_tls_site_refuses_a_client_without_certificate(tmp_path):
    import ssl

    from rths_actuator_bridge.site_server import server_tls_context
    c = _certs(tmp_path)
    served = Served(ideal_config(), tmp_path / 'bag',
                    server_tls_context(c['site.pem'], c['site.key'], c['ca.pem']), wait_s=1.0)
    ctx = ssl.create_default_context(cafile=c['ca.pem'])
    ctx.check_hostname = False
    with pytest.raises((ssl.SSLError, OSError)):
        sock = ctx.wrap_socket(socket.create_connection(('127.0.0.1', served.port)))
        sock.sendall(of.Sizes.generic_client(1).pack())
        sock.recv(1)
    summary = served.join()
    assert summary['steps'] == 0


def test_site_core_refuses_a_delay_line_in_pseudodynamic_mode():
    config = ideal_config()
    config['bridge']['command_delay_steps'] = 2
    with pytest.raises(ValueError, match='command_delay_steps'):
        build_site(config)


def test_site_stopped_raised_on_fault_then_safe_stop_reaches_stopped():
    core = core_for(ideal_config())
    core.accept(of.Sizes.generic_client(1))
    trial(core, 0.0)
    with pytest.raises(SiteStopped, match='velocity'):
        trial(core, 0.1)
    steps = core.safe_stop('test')
    assert core.bridge.state == safety.STOPPED and steps > 0
    assert isinstance(core, SiteCore)
