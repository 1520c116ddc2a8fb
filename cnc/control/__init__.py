"""Control programs: the axis control law as a program the servo runs (`program.py`)."""
