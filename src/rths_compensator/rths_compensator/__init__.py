"""Actuator delay compensation for rths: plant identification (ARX), FIR compensator design by LS/WLS/minimax and the seed's comparison compensators, and the compensator node."""
