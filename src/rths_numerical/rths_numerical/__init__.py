"""Numerical substructure of rths: linear MDOF building models, RTHS integrators (CR, KR-alpha, Newmark), ground motions, the DTM model and the numerical-substructure node."""
