"""`python -m garage_exp`: one job; `-m` sweeps (Hydra)."""

import sys

from garage_exp.app import main, quote_numeric_choices

if __name__ == "__main__":
    sys.argv[1:] = quote_numeric_choices(sys.argv[1:])
    main()
