"""The change Monte Carlo through the real chain (``benchmarks/change.py --parts chain`` and
``--parts calib``): each epoch simulated (GPS with its Gauss-Markov bias, odometry, camera
tracks), localized by iSAM2 (optionally with ground control), selected and reconstructed as
``glacimap run`` does. Nothing is drawn by hand: each survey's offset and along-track error
are what the localization leaves.

``calib``  surveys with seeds disjoint from the Monte Carlo's: the realised relative vertical
           error of every selected landmark, its correlation against the time lag between
           landmarks, and the fit of ``terrain.along_track`` (fraction, tau).
``chain``  epoch pairs: the volume error over sigma_dV with and without the along-track term,
           the negative controls, and the along-track check (realised offsets removed).
"""

from __future__ import annotations

import time

import numpy as np

#: The chain Monte Carlo's smaller plan: a 300 m x 300 m square in the middle of the default
#: site (the truth and the prior DEM cover the whole 600 m site, so every landmark is over
#: the prior), 4 lawnmower swaths with a 10 m margin; the glacier is default_outline of it.
CHAIN_BOUNDS = (526150.0, 6475150.0, 526450.0, 6475450.0)
CHAIN_SWATHS = 4
MC_RESOLUTION = 4.0  # m, reconstruction grid
#: Ground control of the controlled runs: the default scenario's 4 corner stops at 2 cm
#: (docs/ground-control.md), ``[control] n_targets = 4, mode = "stops"``.
CONTROL = {"n_targets": 4, "mode": "stops"}
#: Other correlation times (s) at which each pair's along-track 1-sigma is also reported: the
#: GPS bias's own tau and the calibration's integral time scale (sensitivity, not used).
TAU_SENSITIVITY_S = (60.0, 116.0)
#: Time-lag bins (s) of the along-track calibration.
LAG_EDGES_S = np.array([0.0, 5, 10, 20, 30, 45, 60, 90, 120, 180, 240, 360, 480, 720, 1e9])


def chain_epoch(truth, plan, seed: int, grid, control: bool):
    """One epoch: simulate -> (control) -> iSAM2 -> select -> reconstruct_selection (kernel by
    evidence, the simulated 75 m prior DEM as the mean, offset fitted). Returns the
    reconstruction, the realised survey offset (mean vertical error of the keyframes, m), the
    selection counts and the realised vertical error of each GP sample (m, aligned with
    ``rec.gp.samples_``), the shared offset stated by the localization (m)."""
    from factorgraph.sensors import SensorSuite
    from factorgraph.simulate import simulate_traverse
    from toolkit.config import load_scenario
    from toolkit.field_survey import simulated_control, simulated_prior
    from toolkit.processing import prior_mean
    from toolkit.stages import localize_stage, reconstruct_selection, select_stage

    over = {"seed": seed, "control": dict(CONTROL) if control else {"n_targets": 0}}
    settings = load_scenario(overrides=over)
    log = simulate_traverse(truth, plan, SensorSuite.from_dict(settings["sensors"]), seed=seed)
    log, ctrl = simulated_control(settings, truth, log, plan)
    loc = localize_stage(log, settings, control=ctrl)
    sel = select_stage(loc, settings)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3,)))
    p = settings["prior"]
    prior = simulated_prior(truth, p["resolution_m"], p["offset_m"], p["noise_sd_m"], rng)
    rec = reconstruct_selection(sel, grid, prior_mean(prior, settings), settings, seed, 0)
    offset = float(np.mean(loc.keyframe_xyz[:, 2] - log.truth["xyz"][:, 2]))
    s = rec.gp.samples_
    tr = log.truth
    true_z = tr["landmark_xyz"][np.searchsorted(tr["landmark_id"], s.extra["landmark_id"]), 2]
    err = s.z - true_z  # local ENU z = projected elevation (origin at 0 m)
    return rec, offset, sel.counts, err, float(sel.shared_offset_std_m[2])


def calib_epoch(seed: int, control: bool = True) -> dict:
    """One calibration survey of the chain plan (the site unchanged): binned correlation of
    the realised relative errors (survey offset removed) against the time lag."""
    from survey.lawnmower import lawnmower
    from terrain import Grid, default_site
    from terrain.along_track import empirical_time_correlation

    t0 = time.perf_counter()
    truth = default_site(resolution=2.0)
    plan = lawnmower(CHAIN_BOUNDS, CHAIN_SWATHS, margin=10.0)
    grid = Grid.from_bounds(CHAIN_BOUNDS, MC_RESOLUTION)
    rec, offset, counts, err, shared = chain_epoch(truth, plan, seed, grid, control)
    s = rec.gp.samples_
    rel = err - offset
    corr = empirical_time_correlation(s.extra["t_s"], rel, np.sqrt(s.z_var), LAG_EDGES_S)
    return {
        "seed": seed,
        "control": control,
        "n": int(s.n),
        "offset_realised_m": offset,
        "shared_offset_std_m": shared,
        "rel_error_rms_m": float(np.sqrt(np.mean(rel**2))),
        "sigma_rms_m": float(np.sqrt(np.mean(s.z_var))),
        **{k: np.asarray(v).tolist() for k, v in corr.items()},
        "seconds": time.perf_counter() - t0,
    }


def pool_calibration(epochs: list[dict]) -> dict:
    """Pool the epochs' binned correlations (pair-weighted) and fit (fraction, tau)."""
    from terrain.along_track import fit_along_track, pool_time_correlations

    pooled = pool_time_correlations(epochs)
    fit = fit_along_track(pooled["lag_s"], pooled["corr"], pooled["pairs"], float(pooled["nees"]))
    return {k: np.asarray(v).tolist() for k, v in pooled.items()} | {"fit": fit}


def chain_pair(seed: int, control: bool) -> dict:
    """A pair of epochs on the chain plan: the site after second_epoch(seed) for epoch 2, each
    survey with its own seed (2k, 2k + 1); sigma_dV with and without the along-track term."""
    from survey.lawnmower import lawnmower
    from terrain import Grid, default_outline, default_site, difference, second_epoch
    from terrain.along_track import ALONG_TRACK_FRACTION, AlongTrackModel
    from terrain.volume import gp_integral, outline_weights, volume_change

    t0 = time.perf_counter()
    truth = default_site(resolution=2.0)
    outline = default_outline(CHAIN_BOUNDS)
    after_truth = second_epoch(truth, outline, seed=seed)
    plan = lawnmower(CHAIN_BOUNDS, CHAIN_SWATHS, margin=10.0)
    grid = Grid.from_bounds(CHAIN_BOUNDS, MC_RESOLUTION)
    rec_b, off_b, cnt_b, err_b, sh_b = chain_epoch(truth, plan, 2 * seed, grid, control)
    rec_a, off_a, cnt_a, err_a, sh_a = chain_epoch(after_truth, plan, 2 * seed + 1, grid, control)
    diff = difference(rec_b.product, rec_a.product, coregister=False)
    W = outline_weights(grid, outline)
    true_v = float(np.sum(W * (after_truth - truth).interp(x=grid.x, y=grid.y).values))
    gpv = volume_change(diff, outline, models=(rec_b.gp, rec_a.gp))
    var = volume_change(diff, outline)  # the variogram of dh outside the outline
    b = gpv.budget_m3
    resp = [gpv.details[f"gp_{k}"]["offset_response_m2"] for k in ("before", "after")]
    along = [b.get(f"along_track_{k}", 0.0) for k in ("before", "after")]
    gp_only = float(np.hypot(b["gp_before"], b["gp_after"]))
    # The samples' own part of the volume error: u^T r with u the estimator's weights and r
    # the realised relative errors (offset removed), against the 1-sigma the model gives it:
    # independent sum_i u_i^2 z_var_i, plus the along-track term.
    sample_err, sample_var_indep = 0.0, 0.0
    for sign, rec, err, off in ((-1, rec_b, err_b, off_b), (1, rec_a, err_a, off_a)):
        g = gp_integral(rec.gp, grid, W)
        u = g["sample_weights"]
        sample_err += sign * float(u @ (err[g["sample_index"]] - off))
        sample_var_indep += float(np.sum(u**2 * rec.gp.z_var_[g["sample_index"]]))
    tau_sens = {}
    for tau in TAU_SENSITIVITY_S:  # the along-track 1-sigma of the pair at other tau
        m = AlongTrackModel(ALONG_TRACK_FRACTION, tau)
        v = volume_change(diff, outline, models=(rec_b.gp, rec_a.gp), along_track=m)
        tau_sens[str(tau)] = float(
            np.hypot(
                v.budget_m3.get("along_track_before", 0), v.budget_m3.get("along_track_after", 0)
            )
        )
    return {
        "seed": seed,
        "control": control,
        "true_volume_m3": true_v,
        "volume_m3": gpv.volume_m3,
        "sigma_glacimap_m3": gpv.volume_std_m3,
        "sigma_no_along_track_m3": float(np.sqrt(gpv.volume_std_m3**2 - sum(a**2 for a in along))),
        "sigma_gp_only_m3": gp_only,
        "sigma_gp_along_m3": float(np.sqrt(gp_only**2 + sum(a**2 for a in along))),
        "sigma_independent_m3": gpv.independent_std_m3,
        "sigma_variogram_m3": var.volume_std_m3,
        "budget_m3": b,
        "sample_error_m3": sample_err,
        "sigma_sample_indep_m3": float(np.sqrt(sample_var_indep)),
        "sigma_sample_along_m3": float(np.sqrt(sample_var_indep + sum(a**2 for a in along))),
        "along_track_sigma_by_tau_m3": tau_sens,
        "along_track": gpv.details.get("along_track"),
        "offsets_realised_m": [off_b, off_a],
        "offset_error_m3": off_a * resp[1] - off_b * resp[0],
        "shared_offset_std_m": [sh_b, sh_a],
        "n_samples": [int(rec_b.samples.n), int(rec_a.samples.n)],
        "kernels": [repr(rec_b.gp.kernel_), repr(rec_a.gp.kernel_)],
        "selection_counts": [cnt_b, cnt_a],
        "seconds": time.perf_counter() - t0,
    }


def summarize_chain(pairs: list[dict]) -> list[dict]:
    """z = error / sigma per method. Rows 5-6 remove each pair's realised survey offsets
    (their response times the keyframes' mean vertical error): what is left is the GP's
    error plus the along-track correlated error, over the GP term alone and over the GP and
    along-track terms. Rows 7-8 isolate the samples' own errors: ``u^T r`` (the estimator's
    weights times the realised relative errors of the samples, both epochs) over the 1-sigma
    of independent errors ``sqrt(sum u_i^2 z_var_i)``, and with the along-track term. Row 9:
    the realised offsets' effect over the two stated shared-offset terms."""
    from change import z_rows

    err = np.array([p["volume_m3"] - p["true_volume_m3"] for p in pairs])
    rel = err - np.array([p["offset_error_m3"] for p in pairs])
    smp = np.array([p["sample_error_m3"] for p in pairs])
    off = np.array([p["offset_error_m3"] for p in pairs])
    for p in pairs:  # the two stated shared-offset terms together
        b = p["budget_m3"]
        p["sigma_offsets_m3"] = float(
            np.hypot(b.get("shared_offset_before", 0.0), b.get("shared_offset_after", 0.0))
        )
    return z_rows(
        pairs,
        (
            ("glacimap (GP + offsets + along-track)", "sigma_glacimap_m3", err),
            ("glacimap without the along-track term", "sigma_no_along_track_m3", err),
            ("per-cell independent (control)", "sigma_independent_m3", err),
            ("variogram of stable dh (control)", "sigma_variogram_m3", err),
            ("GP term only, realised offsets removed", "sigma_gp_only_m3", rel),
            ("GP + along-track, realised offsets removed", "sigma_gp_along_m3", rel),
            ("samples' relative errors u^T r, independent", "sigma_sample_indep_m3", smp),
            ("samples' relative errors u^T r, + along-track", "sigma_sample_along_m3", smp),
            ("realised offsets' effect, shared-offset terms", "sigma_offsets_m3", off),
        ),
    )
