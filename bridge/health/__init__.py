"""Is the car's data sound: bits on the wire and bus load, alarm settings, the monitor, and its
overlay in the scene."""
