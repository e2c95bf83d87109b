"""Plain-Python reading copies of the MAPF algorithms the numba kernels implement (PIBT, LaCAM,
SIPP): short, clear and slow, with no numba. The kernels' docstrings link here; the tests run
both on tiny instances as two oracles of each other (tests/uav_agent/planning/test_reference.py)."""
