"""Simulation and test aids: fault injection, the demo operator, `waterjet simulate`."""
