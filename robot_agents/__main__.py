"""`python -m robot_agents ...`: a robot, or a pool of robots (the same as `uav-robots robot ...`)."""
import sys

from .agent import robot_main

sys.exit(robot_main())
