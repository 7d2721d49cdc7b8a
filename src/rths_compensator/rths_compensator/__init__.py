"""Actuator delay compensation for rths.

Plant identification (ARX), FIR compensator design by LS/WLS/minimax and the seed's
comparison compensators, and the compensator node.
"""
