"""What the fit's costly steps buy: the default fit against variants of it, on real terrain.

    python benchmarks/fit_variants.py --variants default no-refine refine-m40 budget-8000 \
        exact-subset window-refit --sites bei glacier olinda \
        --out benchmarks/results/fit_variants.json

Each variant maps the sites of ``benchmarks/real_terrain.py`` (50,000 samples, constant mean,
window 0 unless ``NAME:WINDOW``) onto the truth's own 2 m cells and reports the fit's time,
the kernel, RMSE against the truth and the truth's share inside the 95 % and 68 % intervals
(docs/terrain.md "Performance notes", session 25):

``default``       ``TerrainGP(seed=0)``.
``no-refine``     the search's winner kept as screened (Vecchia m = 10), not refined at 25.
``refine-mN``     the winner refined with Vecchia conditioning sets of N instead of 25.
``budget-N``      the window evidence scores at most N left-out samples (default 16,000).
``exact-subset``  the default's pick (its non-micro-scale parts) refitted by the exact Eq 9
                  on the fit subset (``n_restarts=0``).
``window-refit``  the default's shortest part (variance, length) refitted on the exact subset
                  Eq 9 plus the window evidence (the chain rule's two terms; Nelder-Mead
                  from the default's values), the rest held.
``order-S``       the winner's refine with its Vecchia order drawn from seed S instead of the
                  fit's stream: how much the 1-sigma moves with that order alone
                  (docs/terrain.md "The refine's order", session 29).
``nearest-refine`` the winner refined on the nearest earlier samples (``sets="nearest"``)
                  instead of the search's doubling blocks.
``avg2-S``        the refine's likelihood (and gradient) averaged over two orders, drawn
                  from seeds S and S + 100, with L-BFGS-B stopping at 1e-6 (about the
                  default's cost): does averaging narrow the order's spread?

``floor``         the Microscale part's variance is the refined nugget less the fit subset's
                  detection floor, ``1.645 * sqrt(2 / n_fit) * mean(z_var)`` (measured in
                  session 30, not adopted: docs/terrain.md "The nugget's detection floor";
                  the white nugget, when there is no part, stays as fitted here).

Variants combine with ``+`` (``order-1+floor``: that order, the floor).

``--n 3000`` maps the 3,000-sample sites instead of 50,000.

Variants run in one process one after another (they patch module constants), so the fit
times are comparable within a run only.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _harness import table, write_json  # noqa: E402
from real_terrain import _data, _provenance, parse_site  # noqa: E402

N = 50_000


def _scores(gp, truth, grid) -> dict[str, float]:
    ds = gp.predict_grid(grid)
    mean, sd = ds.elevation.values, ds.elevation_std.values
    t = np.asarray(truth.values, dtype=float).reshape(mean.shape)
    ok = np.isfinite(t) & np.isfinite(mean) & np.isfinite(sd)
    z = np.abs(mean - t)[ok] / sd[ok]
    return {
        "rmse_m": float(np.sqrt(np.mean((mean - t)[ok] ** 2))),
        "cov95": float(100.0 * np.mean(z <= 1.96)),
        "cov68": float(100.0 * np.mean(z <= 1.0)),
    }


def _short_part_refit(gp, samples) -> tuple[Any, dict[str, float]]:
    """The default's shortest part refitted on subset Eq 9 + window evidence."""
    from scipy.optimize import minimize
    from threadpoolctl import threadpool_limits

    from terrain import TerrainGP
    from terrain.kernels import SumKernel
    from terrain.likelihood import gaussian_lml
    from terrain.microscale import without_microscale

    parts = list(without_microscale(gp.kernel_))
    extra = [p for p in getattr(gp.kernel_, "parts", ()) if p not in parts]
    short = min(range(len(parts)), key=lambda i: float(parts[i].lengths[0]))
    idx = gp.fit_index_
    X, r, zv = gp.X_train_[idx], gp.y_resid_[idx], gp.z_var_[idx]
    plan, nugget = gp.window_plan_, gp.nugget_

    def kernel(u):
        ps = list(parts)
        p = ps[short]
        ps[short] = replace(
            p, variance=p.variance * np.exp(u[0]), lengthscale=float(p.lengths[0]) * np.exp(u[1])
        )
        ps += extra
        return SumKernel(tuple(ps)) if len(ps) > 1 else ps[0]

    def objective(u):
        k = kernel(u)
        with threadpool_limits(1):
            return -(gaussian_lml(k, X, r, zv + nugget) + plan.lml(k, nugget))

    simplex = np.array([[0.0, 0.0], [0.7, 0.0], [0.0, 0.5]])
    opts = {"xatol": 0.02, "fatol": 0.2, "maxfev": 60, "initial_simplex": simplex}
    res = minimize(objective, np.zeros(2), method="Nelder-Mead", options=opts)
    info = {
        "variance_factor": float(np.exp(res.x[0])),
        "length_factor": float(np.exp(res.x[1])),
        "evidence_gain_nats": float(objective(np.zeros(2)) - res.fun),
    }
    fixed = {"optimize": False, "nugget": nugget, "nugget_bounds": "fixed"}
    return TerrainGP(kernel=kernel(res.x), seed=0, **fixed).fit(samples), info


def _refine_plan(variant: str, real: Any) -> Any:
    """``VecchiaPlan`` as the kernel search sees it, with the refine's plan (m = 25, the
    second of ``select_kernel``'s ``neighbours``) drawn another way."""
    seed = int(variant.removeprefix("order-")) if variant.startswith("order-") else None
    sets = "nearest" if variant == "nearest-refine" else "blocks"

    class Plan:
        @staticmethod
        def build(X, m, rng):
            if m != 25:  # the screen's plan: as it is
                return real.build(X, m, rng)
            return real.build(X, m, rng if seed is None else np.random.default_rng(seed), sets)

    return Plan


def _averaged_lml(real_lml: Any, plan_type: Any, seeds: tuple[int, int]) -> Any:
    """``FamilySearch.lml`` whose refine (m = 25) averages its value and gradient over the plans
    drawn from ``seeds``; the screen's is as it is."""

    def lml(self, kernel, nugget, grad=False):
        if self.plan.m != 25:
            return real_lml(self, kernel, nugget, grad)
        if not hasattr(self, "_plans"):
            self._plans = [plan_type.build(self.X, 25, np.random.default_rng(s)) for s in seeds]
        outs = []
        for plan in self._plans:
            self.plan = plan
            outs.append(real_lml(self, kernel, nugget, grad))
        if not grad:
            return float(np.mean(outs))
        return float(np.mean([o[0] for o in outs])), np.mean([o[1] for o in outs], axis=0)

    return lml


def detection_floor(z_var: np.ndarray, n_fit: int) -> float:
    """The nugget, m^2, that ``n_fit`` samples with stated noise ``z_var`` (m^2) cannot tell
    from none: 1.645 standard errors of a variance from ``n_fit`` independent residuals,
    ``1.645 * sqrt(2 / n_fit) * mean(z_var)`` (0.0 with nothing stated)."""
    stated = float(np.mean(z_var)) if np.size(z_var) else 0.0
    return 1.645 * float(np.sqrt(2.0 / n_fit)) * stated if stated > 0.0 and n_fit else 0.0


def case(site: dict, variant: str, data: tuple) -> dict[str, Any]:
    """One variant on one site's ``(truth, grid, samples)``: fit seconds, kernel, RMSE and
    truth coverage."""
    import terrain.gp as gp_module
    import terrain.kernel_search as search
    import terrain.window_evidence as windows
    from terrain import TerrainGP
    from terrain.kernels import SumKernel
    from terrain.microscale import without_microscale

    truth, grid, samples = data
    out: dict[str, Any] = {"site": site["label"], "variant": variant}
    patched = [  # what a variant may replace, restored after it
        (search.FamilySearch, "optimize"),
        (gp_module, "select_kernel"),
        (windows, "BUDGET_SAMPLES"),
        (search, "VecchiaPlan"),
        (search.FamilySearch, "lml"),
        (search, "REFINE_FTOL"),
        (gp_module, "microscale_part"),
    ]
    saved = [getattr(owner, name) for owner, name in patched]
    try:
        for part in variant.split("+"):
            _patch(part, search, gp_module, windows, saved)
        t0 = time.perf_counter()
        gp = TerrainGP(seed=0).fit(samples)
        if variant == "exact-subset":
            parts = without_microscale(gp.kernel_)
            start = parts[0] if len(parts) == 1 else SumKernel(tuple(parts))
            gp = TerrainGP(kernel=start, seed=0, n_restarts=0).fit(samples)
        elif variant == "window-refit":
            gp, info = _short_part_refit(gp, samples)
            out.update(info)
        out["fit_s"] = time.perf_counter() - t0
    finally:
        for (owner, name), value in zip(patched, saved, strict=True):
            setattr(owner, name, value)
    out["kernel"] = repr(gp.kernel_)
    out.update(_scores(gp, truth, grid))
    return out


def _patch(variant: str, search: Any, gp_module: Any, windows: Any, saved: list) -> None:
    """Apply one variant's patch (``saved``: the patched names' values, in ``case``'s order)."""
    if variant == "no-refine":
        screen = search.FamilySearch.optimize

        def optimize(self, kernel, nugget, maxiter=200, ftol=None):
            refine = self.ftol == search.REFINE_FTOL
            return None if refine else screen(self, kernel, nugget, maxiter, ftol)

        search.FamilySearch.optimize = optimize
    elif variant.startswith("refine-m"):
        m = int(variant.removeprefix("refine-m"))
        select = saved[1]
        gp_module.select_kernel = lambda *a, **k: select(*a, neighbours=(10, m), **k)
    elif variant.startswith("budget-"):
        windows.BUDGET_SAMPLES = int(variant.removeprefix("budget-"))
    elif variant.startswith("order-") or variant == "nearest-refine":
        search.VecchiaPlan = _refine_plan(variant, saved[3])
    elif variant.startswith("avg2-"):
        seed = int(variant.removeprefix("avg2-"))
        search.FamilySearch.lml = _averaged_lml(saved[4], saved[3], (seed, seed + 100))
        search.REFINE_FTOL = 1e-6
    elif variant == "floor":
        part = saved[6]

        def floored(kernel, nugget, z_var, X_fit, fitted):
            return part(kernel, nugget - detection_floor(z_var, len(X_fit)), z_var, X_fit, fitted)

        gp_module.microscale_part = floored
    elif variant not in ("default", "exact-subset", "window-refit"):
        raise ValueError(f"variant: unknown {variant!r}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="+", default=["default", "no-refine"])
    ap.add_argument("--sites", nargs="+", type=parse_site, default=None)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "fit_variants.json")
    ap.add_argument("--n", type=int, default=N, help="samples per site (default 50,000)")
    args = ap.parse_args(argv)
    sites = args.sites or [parse_site(s) for s in ("bei", "glacier", "olinda")]
    rows = []
    for site in sites:
        data = _data(site, args.n)  # the same samples for every variant
        for variant in args.variants:
            rows.append(case(site, variant, data))
            print(
                f"{rows[-1]['site']:>10} {variant:>13}: fit {rows[-1]['fit_s']:.1f} s, "
                f"RMSE {rows[-1]['rmse_m']:.4f} m, truth in 95 / 68 %: "
                f"{rows[-1]['cov95']:.1f} / {rows[-1]['cov68']:.1f}",
                flush=True,
            )
    print(
        table(
            rows,
            [
                ("site", "site", ""),
                ("variant", "variant", ""),
                ("fit_s", "fit s", ".1f"),
                ("rmse_m", "RMSE m", ".4f"),
                ("cov95", "95 %", ".1f"),
                ("cov68", "68 %", ".1f"),
            ],
        )
    )
    settings = {"n": args.n, "variants": args.variants, "sites": sites}
    write_json(
        args.out,
        {
            "benchmark": "fit_variants",
            "settings": settings,
            "provenance": _provenance(),
            "results": rows,
        },
    )


if __name__ == "__main__":
    main()
