"""The process runtime: the supervisor, the table of processes and their entry points, real-time set-up."""
