"""Shared numerical solvers: mass-spring-damper, FEM, PBD/XPBD, rods, contact."""
