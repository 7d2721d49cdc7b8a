"""Discrepancy workflow of rths (issue 7).

Localise where simulation and measurement disagree, name the missing physical
effect, add it to the model and show the gap shrink.  Entry points:
:func:`rths_discrepancy.workflow.run_discrepancy`, :mod:`rths_discrepancy.cli`;
the reference of an RTHS bag re-run with the updated specimen model:
:mod:`rths_discrepancy.rerun`.
"""
