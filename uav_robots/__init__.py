"""The system command `uav-robots`: launches missions, plans and benchmarks alone, runs the conformance suites."""
