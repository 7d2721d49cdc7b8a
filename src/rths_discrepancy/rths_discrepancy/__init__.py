"""Discrepancy workflow of rths: localise where simulation and measurement disagree, name the missing physical effect, add it to the model and show the gap shrink."""
