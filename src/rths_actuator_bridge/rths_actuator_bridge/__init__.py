"""Actuator bridge of rths.

Simulated servo-hydraulic plant with the DTM specimen, a UDP hardware backend
and its controller emulator, safety limits, DTM characterisation, and the
bridge node.
"""
