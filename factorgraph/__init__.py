"""Localization: sensors, traverse simulation, the GTSAM iSAM2 factor graph, landmark selection.

Depends on :mod:`terrain` only (DESIGN.md §2). Filled by the localization issue.
"""
