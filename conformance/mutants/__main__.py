"""`python -m conformance.mutants`: see `conformance.mutants.runner`."""
import sys

from .runner import main

sys.exit(main())
