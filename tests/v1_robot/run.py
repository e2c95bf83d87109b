"""Start the frozen protocol 1 robot: `python tests/v1_robot/run.py --id 7 --fleet F --connect ENDPOINT`.

This directory comes first on sys.path (Python puts a script's own directory there), so its
`protocol` and `robot_agents` are the frozen ones, never the repository's.
"""
import runpy
import sys

sys.dont_write_bytecode = True   # nothing written beside the frozen files
runpy.run_module("robot_agents", run_name="__main__", alter_sys=True)
