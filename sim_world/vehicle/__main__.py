"""`python -m sim_world.vehicle ...`: the simulated autopilot alone (the same as `uav-robots vehicle ...`)."""
import sys

from sim_world.vehicle_cli import main

sys.exit(main())
