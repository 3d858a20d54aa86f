"""The command line: `python -m garage_exp` (app) and the sweep's lifecycle around its jobs (callbacks)."""
