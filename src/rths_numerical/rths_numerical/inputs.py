"""A run's inputs and whole response as data: what a bag carries so it needs nothing else.

* :func:`inputs_text` / :func:`parse_inputs`: the model (its matrices, DOF names,
  interface and output DOFs) and the ground motion as the run used it (after its
  processing), as one JSON text; the numerical node publishes it once on
  ``/rths/run_inputs`` and the review and replay rebuild the substructure from it
  when the model and record files are gone.
* :func:`response_table`: the whole structure per step: ``time_s`` (the record's
  own time), ``ground_accel_m_s2`` and ``dof1_m`` ... ``dofN_m``, the relative
  displacements of the model's DOFs numbered from 1; written to ``response.csv``
  (:func:`write_response_csv`) and published on ``/rths/response`` in chunks
  (:func:`response_chunks`, ``std_msgs/Float64MultiArray``: ``layout.dim[0].label``
  the run identity, ``dim[1].label`` the column names, ``data_offset`` the first step).
"""

import json

import numpy as np

from .ground_motion import GroundMotion
from .model import LinearModel, model_from_dict

#: Rows per ``/rths/response`` message.
CHUNK_ROWS = 1024


def model_dict(model) -> dict | None:
    """Return a LinearModel as the model-file mapping (None for a model that is not linear)."""
    if not isinstance(model, LinearModel) or model.external_force_time is not None:
        return None
    return {'name': model.name, 'M': model.M.tolist(), 'K': model.K.tolist(),
            'C': model.C.tolist(), 'influence': model.gamma.tolist(),
            'external_force': model.external_force.tolist(),
            'interface_dofs': list(model.interface_dofs), 'output_dof': int(model.output_dof),
            'dof_names': list(model.dof_names)}


def inputs_text(sub, run_id: str = '') -> str:
    """Return the JSON of a substructure's model and prepared ground motion."""
    motion = sub.motion
    return json.dumps({
        'run_id': run_id,
        'model': model_dict(sub.model),
        'motion': None if motion is None else {
            'accel_m_s2': motion.accel.tolist(), 'dt_s': motion.dt, 't0_s': motion.t0,
            'source': motion.source, 'format': motion.fmt, 'units': motion.units,
            'processing': list(motion.processing)},
    })


def parse_inputs(text: str):
    """Return ``(model or None, GroundMotion or None, run_id)`` of :func:`inputs_text`."""
    data = json.loads(text)
    model = (model_from_dict(data['model'], 'the run inputs in the bag')
             if data.get('model') else None)
    m = data.get('motion')
    motion = None if not m else GroundMotion(
        np.asarray(m['accel_m_s2'], dtype=float), float(m['dt_s']), m['source'], m['format'],
        m['units'], float(m['t0_s']), tuple(m['processing']))
    return model, motion, data.get('run_id', '')


def response_columns(n_dofs: int) -> list:
    """Return the column names of the response: time, ground acceleration, every DOF."""
    return ['time_s', 'ground_accel_m_s2'] + [f'dof{i}_m' for i in range(1, n_dofs + 1)]


def response_table(sub) -> tuple:
    """Return ``(columns, rows x columns array)`` of the finished steps of ``sub``."""
    hist = sub.history()
    disp = np.asarray(hist['displacements'], dtype=float)
    t0 = sub.motion.t0 if getattr(sub, 'motion', None) is not None else 0.0
    table = np.column_stack([t0 + np.asarray(hist['time']), hist['ground_accel'], disp])
    return response_columns(disp.shape[1]), table


def write_response_csv(path, columns, table):
    """Write the response table as CSV with a header row (10 significant digits)."""
    np.savetxt(path, table, delimiter=',', header=','.join(columns), comments='', fmt='%.10g')


def response_chunks(columns, table, run_id: str = ''):
    """Yield ``(first step, flat data, run_id, columns text)`` in chunks of CHUNK_ROWS rows."""
    for first in range(0, table.shape[0], CHUNK_ROWS):
        part = table[first:first + CHUNK_ROWS]
        yield first, part.ravel().tolist(), part.shape, run_id, ','.join(columns)


def table_from_chunks(chunks) -> tuple:
    """Return ``(columns, table)`` rebuilt from ``(first step, data, cols text)`` chunks."""
    rows, columns = {}, None
    for first, data, cols in chunks:
        columns = cols.split(',')
        rows[int(first)] = np.asarray(data, dtype=float).reshape(-1, len(columns))
    if not rows:
        return None, None
    return columns, np.vstack([rows[k] for k in sorted(rows)])
