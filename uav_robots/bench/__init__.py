"""`uav-robots bench NAME`: every benchmark a module here, registered in `bench.cli.BENCHMARKS`."""
