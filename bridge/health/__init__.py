"""Is the car's data sound: bits on the wire and bus load (``wire``), alarm settings (``alarms``),
the monitor (``monitor``, with what it counts in ``counts`` and who sees what in ``sight``), what
live's bus reading mended or lost (``receive``), and the overlay in the scene (``overlay``)."""
