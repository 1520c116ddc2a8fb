"""Simulation and test aids: the scripted operator, fault injection, the demo, `waterjet simulate`."""
