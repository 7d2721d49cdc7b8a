"""Numerical substructure of rths: building models, integrators, ground motions, DTM, node.

Linear MDOF building models, the RTHS integrators (CR, KR-alpha, Newmark), ground
motions, the DTM model and the numerical-substructure node.
"""
