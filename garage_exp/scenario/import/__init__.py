"""`python -m garage_exp.scenario.import FILE.xosc` (the package's name is Python's keyword `import`, so it is
run, never imported by name): the importer is garage_exp/openscenario/xosc_import.py; this folder keeps the
documented command's path (its one import up a layer is named in pyproject.toml's layers contract)."""
