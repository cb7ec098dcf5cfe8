"""Tools that drive the service and the client together (demo, benchmarks)."""
