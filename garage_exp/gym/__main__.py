"""`python -m garage_exp.gym [mode=train|check|export] overrides...`: train an adversary (docs/adversary.md).
Exit codes: 0 done, 2 bad input (one line, nothing written)."""

from garage_exp.gym.app import cli

if __name__ == "__main__":
    cli()
