# Two entry points for a fresh Debian machine: `make run` and `make test`. Each brings the machine up to
# what it needs (idempotent: a second call skips finished steps) and then does its job.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
KSERVE_VENV := .venv-kserve
KSERVE_STAMP := $(KSERVE_VENV)/.installed
# ASAM's Quality Checker bundles for OpenSCENARIO and OpenDRIVE pin lxml<6 (the project's is 6): their own venv,
# which tests/test_esmini.py runs on the exports
QC_VENV := .venv-qc
QC_STAMP := $(QC_VENV)/.installed
# The default experiment: a factorial sweep of lighting x case on the default plan, each cell twice (replicates:
# intervals and an ANOVA with its interaction in the report; 2 keeps it under 3 minutes on 2 cores).
RUN_ARGS ?= -m light=bright,dim case=1,2,3 replicates=2
export YOLO_OFFLINE := 1

.PHONY: setup system python data run test ui dashboard map bench bench-long bench-cluster bench-gpu clean mutation docs

setup: system python data

system:
	@bash scripts/setup_vulkan.sh
	@bash scripts/setup_browser.sh
	@bash scripts/setup_postgres.sh

python: $(STAMP) $(KSERVE_STAMP) $(QC_STAMP)

$(QC_STAMP):
	@test -x $(QC_VENV)/bin/python || $(PYTHON) -m venv $(QC_VENV)
	$(QC_VENV)/bin/pip install -q --disable-pip-version-check asam-qc-openscenarioxml==1.0.0 asam-qc-opendrive==1.0.0
	@touch $@

$(STAMP): pyproject.toml constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --disable-pip-version-check -c constraints.txt -e '.[test]'
	@# openvino phones home from a background thread on import unless opted out
	@$(BIN)/opt_in_out --opt_out >/dev/null 2>&1 || true
	@touch $@

# A stock KServe server for tests/test_kserve_stock.py, in an environment of its own: kserve 0.21 pins a protobuf,
# pandas and psutil older than the project's (requirements-kserve.txt).
$(KSERVE_STAMP): requirements-kserve.txt
	@test -x $(KSERVE_VENV)/bin/python || $(PYTHON) -m venv $(KSERVE_VENV)
	$(KSERVE_VENV)/bin/pip install -q --disable-pip-version-check -r requirements-kserve.txt
	@touch $@

data: python
	@$(BIN)/python -m garage_exp.assets ensure

run: setup
	$(BIN)/python -m garage_exp $(RUN_ARGS)
	@echo "Results: outputs/ (frames, tables, plots); MLflow: make ui, then open the link it prints"

# GARAGE_EXP_PROVISIONED: setup provided Vulkan, vehicles and weights, so a render/detect/slow skip is an error.
# -n auto --dist loadfile: a worker per core, each test file on one worker (its module-scoped sweeps run once, its
# jobs share that worker's warm renderer and detector). --no-loadscope-reorder: the files go out in the order
# tests/conftest.py gives them, the slowest first (tests/file_seconds.json), not xdist's most-tests-first.
test: setup docs
	$(BIN)/lint-imports --no-cache
	GARAGE_EXP_PROVISIONED=1 $(BIN)/python -m pytest -q -p no:cacheprovider -n auto --dist loadfile --no-loadscope-reorder

# The docs site (mkdocs.yml, docs/) into outputs/site. --strict: a broken link, anchor or image fails the build, and
# `make test` builds it first. mkdocs-material is in the `test` extra; installed here too if the venv lacks it.
docs: python
	@$(BIN)/python -c "import material, mkdocs" 2>/dev/null || \
		$(BIN)/pip install -q --disable-pip-version-check -c constraints.txt mkdocs-material
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict -d outputs/site

# Mutation testing of the pure modules ([tool.mutmut] in pyproject.toml; results in docs/testing.md). Not part
# of `make test`: it runs the fast unit tests once per mutant (CPU-heavy).
MUTANTS := 'garage_exp.plan.*' 'garage_exp.perception.detect.matching.*' 'garage_exp.perception.groundtruth.*' 'garage_exp.perception.sensor.*' \
	'garage_exp.report.tables.x_*' 'garage_exp.results.stats.x_*'
mutation: python
	$(BIN)/pip install -q --disable-pip-version-check -c constraints.txt -e '.[mutation]'
	rm -rf mutants
	$(BIN)/mutmut run --max-children 2 $(MUTANTS)
	$(BIN)/python scripts/mutation_score.py $(MUTANTS) | tee mutants/score.txt

# The MLflow UI over a store (UI_STORE: a tracking URI as `tracking.uri=` takes it, sqlite:///PATH or a database;
# default the project's own), local only. A sqlite store is created or checked first (a broken one is one line).
UI_STORE ?= sqlite:///$(CURDIR)/outputs/mlflow.db
ui: python
	@case '$(UI_STORE)' in sqlite:///*) $(BIN)/python -m garage_exp.tracking.store '$(UI_STORE:sqlite:///%=%)';; esac
	@$(BIN)/python -m garage_exp.tracking.ui --uri '$(UI_STORE)'
	$(BIN)/mlflow ui --backend-store-uri '$(UI_STORE)' --host 127.0.0.1 --port 5000

# optuna-dashboard over a search's study (issue 10): the same storage the sweeper writes, local only.
DASHBOARD_STORAGE ?= sqlite:///$(CURDIR)/outputs/search/optuna.db
DASHBOARD_PORT ?= 8080
dashboard: python
	@mkdir -p outputs/search
	$(BIN)/optuna-dashboard $(DASHBOARD_STORAGE) --host 127.0.0.1 --port $(DASHBOARD_PORT)

map: python
	@for p in plans/*.yaml plans/*.csv; do $(BIN)/python -m garage_exp.plan map $$p -o outputs/maps/$$(basename $${p%.*}).png; done

# Benchmarks (benchmarks/README.md), each `python -m benchmarks.GROUP.NAME`: `make bench` runs the quick ones (about
# 20 minutes on 2 cores, estimated from the documented runs), the others by name. Their numbers are in docs/performance.md and benchmarks/results/.
BENCH_QUICK := performance.scene performance.look performance.detect performance.rigs performance.pipeline studies.slot_detector
BENCH_LONG := performance.sweep performance.garage_size performance.profile_job studies.search studies.falsification studies.soak performance.gym_vector studies.archive_cells performance.oneshot performance.oneshot_stages performance.space_check studies.blank_factors
BENCH_CLUSTER := performance.ray_nodes
BENCH_GPU := performance.gpu performance.gpu_pipeline
define run_benchmarks
	@for b in $(1); do echo "== python -m benchmarks.$$b"; $(BIN)/python -m benchmarks.$$b || exit 1; done
endef

bench: setup
	$(call run_benchmarks,$(BENCH_QUICK))

# an hour or more: sweeps, the garage-size rounds, a profile, searches, the falsification study (1.5 h)
bench-long: setup
	$(call run_benchmarks,$(BENCH_LONG))

# Ray nodes, a PostgreSQL study and an MLflow server on this machine (scripts/setup_postgres.sh, done by setup)
bench-cluster: setup
	$(call run_benchmarks,$(BENCH_CLUSTER))

# the GPU path against the CPU one; on a CPU-only machine its GPU parts are skipped with a message
bench-gpu: setup
	$(call run_benchmarks,$(BENCH_GPU))

clean:
	rm -rf outputs mutants
