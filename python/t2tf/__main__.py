"""`python -m t2tf ...` runs the `t2tf` command."""
import sys

from ._cli import main

sys.exit(main())
