"""Scenario TOML shared by the tests that run the whole pipeline on a small site."""

#: a 300 m corner of the default site (its south-west), used by every small run
SMALL_BOUNDS = (526000.0, 6475000.0, 526300.0, 6475300.0)


def small_run(n_boot: int = 500, extra: str = "") -> str:
    """A small seeded ``glacimap run``: the 300 m corner, two swaths, a 5 m grid, 100
    checkpoints, ``n_boot`` bootstrap draws; ``extra`` TOML lines appended to ``[certify]``
    (e.g. ``heldout_folds = 0``) or as further tables."""
    return f"""
seed = 0
[site]
bounds = {list(SMALL_BOUNDS)}
[plan]
n_swaths = 2
[reconstruct]
resolution_m = 5.0
max_fit_samples = 300
n_restarts = 0
[certify]
n_checkpoints = 100
n_boot = {n_boot}
{extra}"""
