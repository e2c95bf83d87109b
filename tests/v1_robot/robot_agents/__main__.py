"""`python -m robot_agents ...`: a robot, or a pool of robots (the same as `uav-robots robot ...`)."""
import sys

from protocol.process import command_main, one_command

from .agent import add_robot_arguments, robot_command

sys.exit(command_main(one_command("python -m robot_agents",
                                  "Simulated robots that execute plans tick by tick over Zenoh.",
                                  add_robot_arguments, robot_command)))
