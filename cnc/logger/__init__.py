"""The data logger: its process, log runs and variables, the `waterjet log` command and plots."""
