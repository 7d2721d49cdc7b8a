"""The maRTHS benchmark's numbers (``data/marths.json``), shared by the packages that model it.

The rig's physics (the 2 x 2 control plant, the physical frame, the coupler) is in
:mod:`rths_actuator_bridge.marths_rig`; the reference and numerical structures in
:mod:`rths_numerical.marths`; the loop and the criteria in :mod:`rths_bench.marths`.
Source and licence: the file's ``_source`` and ``_licence`` entries
(github.com/FermandoisLab/maRTHS-bmk-RoDeAC, MIT).
"""

import json
from pathlib import Path

from .coupler import Coupler

DATA_FILE = Path(__file__).parent / 'data' / 'marths.json'
#: [m] one inch (the benchmark's section properties are in inches).
INCH = 0.0254


def load_config(path=DATA_FILE) -> dict:
    """Return the benchmark's numbers (``data/marths.json``)."""
    with open(path) as fh:
        return json.load(fh)


def rig_coupler(cfg: dict) -> Coupler:
    """Return the rig's coupler (``fcn_coupler_geometry.m``: the two attachment offsets)."""
    return Coupler.from_offsets(cfg['coupler']['offsets_m'])
