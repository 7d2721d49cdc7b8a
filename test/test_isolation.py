"""Runs cannot drive each other's actuator: two graphs at once, and a rogue with their names.

Each lock-step run is compared bit for bit with the offline coupled simulation of
its own parameters (rths_bringup.offline, as test_lockstep_equivalence): a single
message of another run or of the rogue acted on would change it.
"""

import subprocess
import threading
import time

import numpy as np

from rths_system_tests import REPO, graph_env, rths, rths_executable, wait_for

DURATION_S = 1.0


def lockstep_config(directory, scale, duration_s=DURATION_S):
    """Write a lock-step run (building, Kobe x ``scale``, valve4); return its sections."""
    from rths_common import runinfo

    config = REPO / 'config'
    numerical = dict(runinfo.load_params(config / 'numerical.yaml', 'numerical'),
                     model='building2story', record='kobe', scale=scale,
                     duration_s=duration_s, force_scale=5.0)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta'):
        numerical.pop(key)
    sections = {'numerical': numerical,
                'compensator': runinfo.load_params(config / 'compensator.yaml', 'compensator'),
                'bridge': dict(runinfo.load_params(config / 'bridge.yaml', 'bridge'),
                               specimen='valve4')}
    for node, params in sections.items():
        runinfo.write_params(directory / f'{node}.yaml', node, params)
    return sections


def assert_bag_is_its_own_run(bag, sections):
    """Check that the bag holds each step once and equals the offline simulation of ``sections``."""
    from rths_bringup.offline import offline_rths
    from rths_common import bagio, topics

    ref = offline_rths(sections['numerical'], sections['compensator'], sections['bridge'])
    meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied', 'displacement', 'force'))
    cmd = bagio.step_arrays(bag, topics.COMMAND, ('command',))
    assert np.array_equal(meas['step'], np.arange(ref['force'].shape[0]))
    assert np.array_equal(cmd['command'], ref['command'])
    assert np.array_equal(meas['applied'], ref['applied'])
    assert np.array_equal(meas['force'], ref['force'])


class Rogue:
    """Nodes named compensator, numerical and bridge flooding the loop topics.

    The rogue 'compensator' sends its own writer gid as the sender, as a second
    run's compensator would; commands of 0.2 m for every step.  About 200 messages a
    second per topic: a flood that fills a lock-step reader's history (10000 samples)
    while its node is still starting would stall the loop (never move the actuator),
    which on a loaded machine would only time the test out.
    """

    def __init__(self, domain_id: int):
        import rclpy
        from rclpy.context import Context

        from rths_common import node_support as ns
        from rths_common import topics
        from rths_common.qos import loop_qos
        from rths_msgs.msg import Command, InterfaceDisplacement, Measurement

        self.rclpy, self.ns, self.topics = rclpy, ns, topics
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        qos = loop_qos('lockstep')
        self.nodes = {name: rclpy.create_node(name, context=self.context)
                      for name in ('compensator', 'numerical', 'bridge')}
        self.pubs = [
            (self.nodes['compensator'].create_publisher(Command, topics.COMMAND, qos),
             lambda k: Command(step=k, command=[0.2])),
            (self.nodes['numerical'].create_publisher(
                InterfaceDisplacement, topics.INTERFACE_DISPLACEMENT, qos),
             lambda k: InterfaceDisplacement(step=k, displacement=[0.2])),
            (self.nodes['bridge'].create_publisher(Measurement, topics.MEASUREMENT, qos),
             lambda k: Measurement(step=k, applied=[0.2], displacement=[0.2], force=[5e3])),
        ]
        self.sent = 0
        self.running = True
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        gid = ''
        step = 0
        while self.running:
            if not gid:
                gid = self.ns.own_writer_gid(self.nodes['compensator'], self.topics.COMMAND)
            for k in (step % 1024, step % 1024 + 1):
                for pub, make in self.pubs:
                    msg = make(k)
                    msg.header.frame_id = gid
                    pub.publish(msg)
                    self.sent += 1
            step += 1
            time.sleep(0.01)

    def close(self):
        self.running = False
        self.thread.join(timeout=5.0)
        for node in self.nodes.values():
            node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def test_a_rogue_with_the_loop_node_names_never_moves_the_actuator(tmp_path):
    sections = lockstep_config(tmp_path, 0.135)
    rogue = Rogue(int(graph_env()['ROS_DOMAIN_ID']))
    try:
        proc = rths('launch', '--config', tmp_path, '--bag', tmp_path / 'bag', timeout=300)
    finally:
        rogue.close()
    assert rogue.sent > 300
    assert 'run finished' in proc.stdout
    assert '/rths/command:' in proc.stdout and 'of another run (run identity (none))' in proc.stdout
    assert_bag_is_its_own_run(tmp_path / 'bag', sections)


def test_two_runs_at_once_each_its_own_and_a_third_in_a_held_domain_refused(tmp_path):
    """A in ROS_DOMAIN_ID D, B with the default environment (no domain): both run, exact.

    C, started in D while A runs, refuses before anything starts, naming A.  A runs
    4 s of the record, so that on a loaded machine C and B start while it runs.
    """
    runs = {}
    for name, scale, duration in (('a', 0.135, 4.0), ('b', 0.0675, DURATION_S)):
        (tmp_path / name).mkdir()
        runs[name] = lockstep_config(tmp_path / name, scale, duration)
    env = graph_env()
    unset = {k: v for k, v in env.items() if k != 'ROS_DOMAIN_ID'}
    argv = [rths_executable(), 'launch', '--config']
    a = subprocess.Popen([*argv, tmp_path / 'a', '--bag', tmp_path / 'a' / 'bag'], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    b = None
    try:
        seen = wait_for(a, 'run identity', timeout=120)
        c = subprocess.run([*argv, tmp_path / 'b', '--bag', tmp_path / 'c'], env=env,
                           capture_output=True, text=True, timeout=120)
        b = subprocess.Popen([*argv, tmp_path / 'b', '--bag', tmp_path / 'b' / 'bag'],
                             env=unset, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
        overlapping = a.poll() is None      # B starts while A runs
        out_a = seen + a.communicate(timeout=300)[0]
        out_b = b.communicate(timeout=300)[0]
    finally:
        for proc in (a, b):
            if proc is not None and proc.poll() is None:
                proc.kill()
    domain = env['ROS_DOMAIN_ID']
    assert f'ROS domain {domain} (ROS_DOMAIN_ID)' in out_a
    assert 'a free domain taken for this run' in out_b
    assert a.returncode == 0 and b.returncode == 0, out_a[-2000:] + out_b[-2000:]
    assert overlapping
    assert c.returncode == 2 and not (tmp_path / 'c').exists()
    assert (f'ROS domain {domain} (ROS_DOMAIN_ID) is in use by another rths run: rths launch '
            f'--config {tmp_path / "a"}') in c.stderr
    assert f'(pid {a.pid},' in c.stderr
    for name in ('a', 'b'):
        assert_bag_is_its_own_run(tmp_path / name / 'bag', runs[name])
