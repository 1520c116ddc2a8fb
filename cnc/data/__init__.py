"""The shared-memory data plane: the blocks of the data server, their layouts, the setpoint FIFO and the trace ring."""
