"""Survey planning and certification: plans, coverage metrics, mapping standards, Monte Carlo.

Depends on :mod:`terrain` only (DESIGN.md §2). Filled by the survey-planning issue.
"""
