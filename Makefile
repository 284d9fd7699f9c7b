# glacimap — the two fresh-machine commands are `make demo` and `make test` (see README.md).
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.glacimap-installed

.PHONY: setup demo test test-slow lint format bench clean

setup: $(STAMP)
$(STAMP): pyproject.toml scripts/setup.sh scripts/apt-packages.txt
	bash scripts/setup.sh $(VENV)
	touch $(STAMP)

## the main job on the embedded default scenario: plan -> traverse -> iSAM2 -> GP -> certify -> products
demo: setup
	$(BIN)/glacimap run --out out/run

## lint + the default test suite (< 10 min on 2 cores)
test: setup lint
	$(BIN)/python -m pytest -m "not slow" -q

## full-size checks (the issue's "must show" numbers); .ci/run runs these too
test-slow: setup
	$(BIN)/python -m pytest -m slow -q

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: setup
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

## benchmarks: printed table + JSON in benchmarks/results/
bench: setup
	$(BIN)/python benchmarks/gp_exact.py --out benchmarks/results/gp_exact.json
	$(BIN)/python benchmarks/planners.py --out benchmarks/results/planners.json
	$(BIN)/python benchmarks/gp_scalable.py --out benchmarks/results/gp_scalable.json
	$(BIN)/python benchmarks/emcee_posterior.py --out benchmarks/results/emcee_posterior.json
	$(BIN)/python benchmarks/localization.py --out benchmarks/results/localization.json
	$(BIN)/python benchmarks/real_terrain.py --out benchmarks/results/real_terrain.json
	$(BIN)/python benchmarks/map_speed.py --out benchmarks/results/map_speed.json
	$(BIN)/python benchmarks/change.py --pairs 50 --out benchmarks/results/change.json
	$(BIN)/python benchmarks/ground_control.py --out benchmarks/results/ground_control.json
	$(BIN)/python benchmarks/vision.py --out benchmarks/results/vision.json
	$(BIN)/python benchmarks/landmark_nees.py --seeds 0-9 --out benchmarks/results/landmark_nees.json
	$(BIN)/python benchmarks/marginals_order.py --out benchmarks/results/marginals_order.json
	$(BIN)/python benchmarks/breakline_steps.py --out benchmarks/results/breakline_steps.json
	$(BIN)/python benchmarks/real_contours.py --out benchmarks/results/real_contours.json
	$(BIN)/python benchmarks/profile_prior.py --out benchmarks/results/profile_prior.json
	$(BIN)/python benchmarks/profile_prior.py --dem-error smooth --out benchmarks/results/profile_prior_smooth.json
	$(BIN)/python benchmarks/profile_prior.py --dem-error coarse --out benchmarks/results/profile_prior_coarse.json
	$(BIN)/python benchmarks/gnss_heights.py --out benchmarks/results/gnss_heights.json
	$(BIN)/python benchmarks/point_cloud.py --out benchmarks/results/point_cloud.json
	$(BIN)/python benchmarks/dsm_voids.py --out benchmarks/results/dsm_voids.json
	$(BIN)/python benchmarks/void_fill.py --out benchmarks/results/void_fill.json

clean:
	rm -rf out .pytest_cache .ruff_cache
