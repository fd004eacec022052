"""Observations in the vehicle frame and the latest state built from them: objects with their
lifetimes, lanes, the ego, the lead / MIO check."""
