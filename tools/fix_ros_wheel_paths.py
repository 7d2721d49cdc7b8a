#!/usr/bin/env python3
"""Repair the build-machine paths baked into the ROS 2 Jazzy PyPI wheels.

The ``ros-jazzy-*`` wheels were built in a manylinux container whose Python
lived in ``/opt/python/cp311-cp311``.  Their exported CMake files (e.g.
``share/std_msgs/cmake/export_std_msgs__rosidl_generator_pyExport.cmake``)
list that prefix's Python and NumPy include directories, and the ament index
``parent_prefix_path`` entries name it as a prefix.  CMake refuses to build a
custom message package against an imported target whose include directory
does not exist, so this script rewrites those paths to the real ones of the
running interpreter (the project's venv).

Only files inside ``sys.prefix`` (the venv) are touched; system paths are
never modified.  The script is idempotent and exits non-zero, naming the
file, if any reference to the build prefix remains afterwards or if a
replacement directory does not exist.

Usage: ``.venv/bin/python tools/fix_ros_wheel_paths.py [--check]``
"""

import argparse
import sys
import sysconfig
from pathlib import Path

BUILD_PREFIX = "/opt/python/cp311-cp311"


def replacements():
    """Return (old, new) pairs, most specific first."""
    import numpy

    py_include = sysconfig.get_paths()["include"]
    np_include = numpy.get_include()
    for path in (py_include, np_include):
        if not Path(path, "Python.h" if path == py_include else "numpy").exists():
            sys.exit(f"fix_ros_wheel_paths: include directory {path} is missing; "
                     "install the Python development headers (python3-dev) and numpy")
    return [
        (f"{BUILD_PREFIX}/include/python3.11", py_include),
        (f"{BUILD_PREFIX}/lib/python3.11/site-packages/numpy/_core/include", np_include),
        (BUILD_PREFIX, sys.prefix),
    ]


def candidate_files(prefix: Path):
    """Files of the venv that can carry the build prefix."""
    yield from (prefix / "share").rglob("*.cmake")
    index = prefix / "share" / "ament_index" / "resource_index" / "parent_prefix_path"
    if index.is_dir():
        yield from index.iterdir()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="only report files that still need repair; exit 1 if any")
    args = parser.parse_args(argv)
    prefix = Path(sys.prefix)
    if prefix == Path(sys.base_prefix):
        sys.exit("fix_ros_wheel_paths: run me with the venv's python, not the system one")
    pairs = replacements()
    pending, fixed = [], 0
    for path in candidate_files(prefix):
        if not path.is_file():
            continue
        text = path.read_text(errors="surrogateescape")
        if BUILD_PREFIX not in text:
            continue
        if args.check:
            pending.append(path)
            continue
        for old, new in pairs:
            text = text.replace(old, new)
        path.write_text(text, errors="surrogateescape")
        fixed += 1
    if args.check:
        for path in pending:
            print(f"needs repair: {path}")
        return 1 if pending else 0
    left = [p for p in candidate_files(prefix) if p.is_file()
            and BUILD_PREFIX in p.read_text(errors="surrogateescape")]
    if left:
        sys.exit(f"fix_ros_wheel_paths: {BUILD_PREFIX} still referenced in {left[0]}")
    print(f"fix_ros_wheel_paths: rewrote {fixed} file(s); no {BUILD_PREFIX} reference left in {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
