"""The control logic (soft-PLC) run every logic scan: modes, interlocks, the automatic cycle, guided procedures."""
