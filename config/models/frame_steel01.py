"""A 2-story, 1-bay steel moment frame whose beams yield: OpenSeesPy model for rths.

Used by ``rths run --numerical opensees --model frame-steel01`` (the numerical
node's ``backend: opensees`` with ``model:`` this file's path).  The contract of
a model script (rths_numerical/opensees_backend.py, README "Your own OpenSees model"):

* define ``build(ops)``; rths calls it in an empty OpenSees domain (``ops`` is
  the ``openseespy.opensees`` module) and adds the ground motion, the measured
  force and the analysis itself;
* every free DOF needs a mass (the explicit CentralDifference integrator);
* return a dict with ``interface_node`` and ``interface_dof`` (1-based) where
  the specimen's force acts and whose displacement the actuator follows;
  optional: ``ground_dof`` (direction of the ground motion, default 1),
  ``hinge`` = ``(element, section)`` whose moment-rotation the review plots,
  ``hinge_length_m`` (rotation = curvature x length).

SI units (N, m, s, kg).  Frame: bay 6 m, stories 3.5 m; columns elastic
(E 200 GPa, A 1.71e-2 m^2, I 4.16e-4 m^4); beams forceBeamColumn with
HingeRadau plastic hinges (length 0.3 m) at both ends: Steel01 moment-curvature
(yield moment 8 kN m, 2 % hardening: weak beams, sized to yield under
the default record, Kobe x 0.135) aggregated with an elastic axial
response, elastic in between (A 9.5e-3 m^2, I 3.33e-4 m^4).  Floor mass 30 t
per floor, half at each joint, in x and y, with 1500 kg m^2 of rotational
inertia per joint.  Rayleigh damping 5 % on the first two modes (initial
stiffness).  Modes 1 and 2: 2.31 and 8.37 Hz.
"""

E = 200e9
BAY, STORY = 6.0, 3.5
COLUMN = {'A': 1.71e-2, 'I': 4.16e-4}
BEAM = {'A': 9.5e-3, 'I': 3.33e-4}
HINGE = {'My': 8e3, 'b': 0.02, 'lp': 0.3}
FLOOR_MASS = 30e3
ROT_INERTIA = 1500.0
ZETA = 0.05


def build(ops):
    """Build the frame; return its interface (2nd floor, left joint, x) and a hinge.

    The hinge: the 2nd-floor beam (element 12) at its left end (section 1).
    """
    ops.model('basic', '-ndm', 2, '-ndf', 3)
    for i, y in enumerate((0.0, STORY, 2 * STORY)):
        ops.node(10 * i + 1, 0.0, y)
        ops.node(10 * i + 2, BAY, y)
    ops.fix(1, 1, 1, 1)
    ops.fix(2, 1, 1, 1)
    m = FLOOR_MASS / 2
    for node in (11, 12, 21, 22):
        ops.mass(node, m, m, ROT_INERTIA)
    ops.geomTransf('Linear', 1)
    for tag, (i, j) in enumerate(((1, 11), (2, 12), (11, 21), (12, 22)), start=1):
        ops.element('elasticBeamColumn', tag, i, j, COLUMN['A'], E, COLUMN['I'], 1)
    ei = E * BEAM['I']
    ops.uniaxialMaterial('Steel01', 1, HINGE['My'], ei, HINGE['b'])   # moment-curvature
    ops.uniaxialMaterial('Elastic', 2, E * BEAM['A'])                 # axial force-strain
    ops.section('Aggregator', 1, 2, 'P', 1, 'Mz')
    ops.section('Elastic', 2, E, BEAM['A'], BEAM['I'])
    ops.beamIntegration('HingeRadau', 1, 1, HINGE['lp'], 1, HINGE['lp'], 2)
    for tag, (i, j) in enumerate(((11, 12), (21, 22)), start=11):
        ops.element('forceBeamColumn', tag, i, j, 1, 1)
    w2 = ops.eigen(2)
    w1, w2 = w2[0] ** 0.5, w2[1] ** 0.5
    a0 = 2 * ZETA * w1 * w2 / (w1 + w2)
    a1 = 2 * ZETA / (w1 + w2)
    ops.rayleigh(a0, 0.0, a1, 0.0)
    return {'interface_node': 21, 'interface_dof': 1, 'ground_dof': 1,
            'hinge': (12, 1), 'hinge_length_m': HINGE['lp']}
