import sys

from garage_exp.scenario.xosc_import import main

if __name__ == "__main__":
    sys.exit(main())
