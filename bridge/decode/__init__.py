"""Frames to signals: cantools per bus, and the protobuf schema of every DBC message."""
