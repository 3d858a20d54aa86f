import sys

from garage_exp.report import main

sys.exit(main())
