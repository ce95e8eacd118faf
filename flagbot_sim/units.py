"""Units at the program's edges: everything inside is SI; the paper quotes motor speeds in rpm."""
import math

RPM = 2.0 * math.pi / 60.0  # rad/s per rpm
