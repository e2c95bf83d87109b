"""`python -m uav_robots ...`: the same as the `uav-robots` command."""
import sys

from .cli import main

sys.exit(main())
