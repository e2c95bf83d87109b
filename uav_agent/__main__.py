"""`python -m uav_agent ...`: the UAV agent process (the same as `uav-robots uav ...`)."""
import sys

from protocol.process import command_main

from .cli import build_parser

sys.exit(command_main(build_parser))
