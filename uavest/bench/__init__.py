"""Monte Carlo harness, scenarios and the ``uavest bench`` command."""
