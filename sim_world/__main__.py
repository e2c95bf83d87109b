"""`python -m sim_world ...`: the world process (the same as `uav-robots world ...`)."""
import sys

from protocol.process import command_main, one_command

from .cli import add_world_arguments, world_command

sys.exit(command_main(one_command("python -m sim_world", "The simulated world: floor, robots' physics, vehicle, camera.",
                                  add_world_arguments, world_command)))
