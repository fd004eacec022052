"""What Foxglove shows: the bundled layouts checked against what the bridge produces."""
