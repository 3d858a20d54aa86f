"""`python -m garage_exp.scenario.import FILE.xosc` (the package's name is Python's keyword `import`, so it is
run, never imported by name): garage_exp/scenario/xosc_import.py."""
