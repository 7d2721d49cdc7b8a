"""Separate "hosts" on one machine: Linux network namespaces joined by veth links to a switch.

:class:`LabNetwork` creates (as root, with iproute2) one namespace per host,
``rths_<tag>_<host>``, each with ``lo`` and one veth whose peer is enslaved to
a Linux bridge in a switch namespace ``rths_<tag>_sw``; hosts get
``10.<net>.0.<i>/24``.  Nothing is created in the root namespace, so the
machine's own networking is untouched; :meth:`LabNetwork.close` deletes every
namespace (their veths and the bridge go with them).

DDS settings for such a network (also documented in docs/lab_network.md):

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``: multicast discovery on the lab
  subnet (Jazzy's default in this project is LOCALHOST); a multicast route
  (224.0.0.0/4) is set on each host's veth;
* ``ROS_STATIC_PEERS``: the other hosts' addresses (unicast discovery, for
  networks that drop multicast);
* ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``: namespaces share /dev/shm, so without
  it Fast DDS would carry the data over shared memory, not the network;
* ``ROS_DOMAIN_ID``: one per lab graph (the link relay joins two).
"""

import subprocess
import sys


def _ip(*args, check=True):
    proc = subprocess.run(['ip', *map(str, args)], capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise OSError(f"'ip {' '.join(map(str, args))}' failed: {proc.stderr.strip()} "
                      '(network namespaces need root and iproute2)')
    return proc


def available() -> str:
    """'' if network namespaces can be created here, else the reason."""
    name = 'rths_probe_ns'
    proc = _ip('netns', 'add', name, check=False)
    if proc.returncode != 0:
        return proc.stderr.strip() or 'ip netns add failed'
    _ip('netns', 'del', name, check=False)
    return ''


class LabNetwork:
    """Hosts in their own network namespaces on one switched /24 subnet."""

    def __init__(self, hosts, tag: str = 'lab', net: int = 77):
        self.tag = tag
        self.hosts = list(hosts)
        self.switch = f'rths_{tag}_sw'
        self.ns = {h: f'rths_{tag}_{h}' for h in self.hosts}
        self.addr = {h: f'10.{net}.0.{i + 1}' for i, h in enumerate(self.hosts)}
        self.created = []

    def __enter__(self):
        self.create()
        return self

    def __exit__(self, *exc):
        self.close()

    def create(self):
        """Create the switch and the hosts (removing leftovers of an earlier run first)."""
        for name in [self.switch, *self.ns.values()]:
            _ip('netns', 'del', name, check=False)
        _ip('netns', 'add', self.switch)
        self.created.append(self.switch)
        sw = ['-n', self.switch]
        _ip(*sw, 'link', 'add', 'br0', 'type', 'bridge')
        _ip(*sw, 'link', 'set', 'br0', 'up')
        _ip(*sw, 'link', 'set', 'lo', 'up')
        for i, host in enumerate(self.hosts):
            ns = self.ns[host]
            _ip('netns', 'add', ns)
            self.created.append(ns)
            port = f'p{i}'
            _ip(*sw, 'link', 'add', port, 'type', 'veth', 'peer', 'name', 'eth0', 'netns', ns)
            _ip(*sw, 'link', 'set', port, 'master', 'br0')
            _ip(*sw, 'link', 'set', port, 'up')
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
            _ip('-n', ns, 'addr', 'add', f'{self.addr[host]}/24', 'dev', 'eth0')
            _ip('-n', ns, 'link', 'set', 'eth0', 'up')
            _ip('-n', ns, 'route', 'add', '224.0.0.0/4', 'dev', 'eth0')
        return self

    def prefix(self, host: str) -> list:
        """Argv prefix that runs a command on ``host``."""
        return ['ip', 'netns', 'exec', self.ns[host]]

    def dds_env(self, host: str, domain_id: int) -> dict:
        """Environment of a ROS process on ``host`` (module docstring)."""
        peers = ';'.join(a for h, a in self.addr.items() if h != host)
        return {'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
                'ROS_STATIC_PEERS': peers, 'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}

    def reachable(self, src: str, dst: str, port: int = 47999) -> bool:
        """Return True if a UDP datagram from ``src`` reaches ``dst`` (no ping needed)."""
        recv = subprocess.Popen(
            [*self.prefix(dst), sys.executable, '-c',
             'import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); '
             f's.bind(("{self.addr[dst]}", {port})); s.settimeout(5); '
             'print(s.recvfrom(64)[0].decode())'],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        send = (f'import socket, time; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n'
                f'for _ in range(20): s.sendto(b"rths", ("{self.addr[dst]}", {port})); '
                'time.sleep(0.1)')
        subprocess.run([*self.prefix(src), sys.executable, '-c', send], capture_output=True)
        try:
            out = recv.communicate(timeout=10)[0]
        except subprocess.TimeoutExpired:
            recv.kill()
            return False
        return 'rths' in out

    def close(self):
        """Delete what was created, newest first."""
        for name in reversed(self.created):
            _ip('netns', 'del', name, check=False)
        self.created = []
