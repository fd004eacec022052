"""The simulated ecocar: its drive as frames, and a car that sends it onto a virtual bus."""
