"""Configuration: the service's settings, the partitioning options, sharing a host's router."""
