"""`python -m garage_exp`: one job; `-m` sweeps (Hydra). Exit codes: 0 done, 2 bad input (one line on stderr,
nothing run), 1 a sweep with failed jobs (listed in its summary) or a crash (traceback), 130 Ctrl-C, 143 SIGTERM."""

from garage_exp.cli.app import cli

if __name__ == "__main__":
    cli()
