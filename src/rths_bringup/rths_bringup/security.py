"""SROS2 enclaves for ``rths launch --enclave-keystore DIR``: DDS security where the install has it.

Each process of the run (the composed ``container`` or the three nodes, and the
``recorder``) starts inside its own enclave ``/rths/NAME`` of the keystore, through
the environment rcl reads (``ROS_SECURITY_KEYSTORE``, ``ROS_SECURITY_ENABLE=true``,
``ROS_SECURITY_STRATEGY=Enforce``: a process without valid keys does not start,
``ROS_SECURITY_ENCLAVE_OVERRIDE``).  The keystore and its enclaves are made with
the ``ros2 security`` commands (docs/lab_network.md).  The Fast DDS of the ROS 2
wheels this project installs is built without its security plugins, so
enclaves cannot be tested here: this module checks the keystore and sets the
environment; a lab's own ROS 2 install with SROS2 enforces it.
"""

from pathlib import Path

#: Enclave path prefix of the run's processes.
ENCLAVE_ROOT = '/rths'
#: The processes a run can start (launcher child names).
PROCESSES = ('container', 'recorder', 'numerical', 'compensator', 'bridge')


def enclave_env(keystore, names=PROCESSES) -> dict:
    """Return ``{process: {VAR: value}}`` to start each process in its enclave.

    ValueError (one line, with the ``ros2 security`` command that fixes it) if the
    keystore or an enclave of ``names`` is missing.
    """
    path = Path(keystore)
    if not path.is_dir():
        raise ValueError(f'--enclave-keystore {keystore}: no such directory; create it with '
                         f"'ros2 security create_keystore {keystore}' (docs/lab_network.md)")
    missing = [n for n in names
               if not (path / 'enclaves' / ENCLAVE_ROOT.strip('/') / n).is_dir()]
    if missing:
        raise ValueError(f'--enclave-keystore {keystore}: no enclave '
                         f'{", ".join(f"{ENCLAVE_ROOT}/{n}" for n in missing)}; create each '
                         f"with 'ros2 security create_enclave {keystore} {ENCLAVE_ROOT}/NAME' "
                         '(docs/lab_network.md)')
    root = str(path.resolve())
    return {n: {'ROS_SECURITY_KEYSTORE': root, 'ROS_SECURITY_ENABLE': 'true',
                'ROS_SECURITY_STRATEGY': 'Enforce',
                'ROS_SECURITY_ENCLAVE_OVERRIDE': f'{ENCLAVE_ROOT}/{n}'} for n in names}
