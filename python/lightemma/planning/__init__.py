"""NAVSIM's planning score (PDMS / EPDMS) on nuScenes.

``simulation`` re-simulates a plan as NAVSIM does (LQR tracking on a kinematic bicycle) and scores
comfort; ``scores`` computes the sub-scores on the simulated states and the aggregates. Definitions,
sources and deviations: ``docs/definitions.md#planning-score``.
"""
