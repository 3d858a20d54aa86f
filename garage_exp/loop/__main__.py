"""`python -m garage_exp.loop [overrides]`: the closed-loop experiment (docs/loop.md)."""

from garage_exp.loop.app import cli

if __name__ == "__main__":
    cli()
